"""The kernels' inputs: the declared layout of every packed record, the packing, the
acceleration structures and the voxel bricks."""
