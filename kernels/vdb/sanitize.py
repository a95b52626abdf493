"""Non-finite voxels: NaN or +-Inf values make no sense as density, so they are made inactive.

The reader stays faithful to the file (it returns NaN where the file holds NaN); callers that build
Gaussians call `sanitize_nonfinite` and report the count it returns.
"""

import numpy as np


def _unpack(masks):
    # Voxel n is bit (n & 63) of little-endian word n >> 6: byte order, then bit order, both "little".
    return np.unpackbits(np.ascontiguousarray(masks, "<u8").view(np.uint8), axis=-1,
                         bitorder="little").astype(bool)


def _pack(bits):
    return np.packbits(bits, axis=-1, bitorder="little").view("<u8").astype(np.uint64)


def count_nonfinite(grid) -> int:
    """Active voxels (tiles included) whose value is NaN or +-Inf."""
    n = 0
    if len(grid.leaf_values):
        bad = ~np.isfinite(grid.leaf_values)
        if bad.any():
            n += int((bad & _unpack(grid.leaf_masks)).sum())
    tv = np.asarray(grid.tile_values)
    if len(tv):
        bad_t = np.asarray(grid.tile_active, bool) & ~np.isfinite(tv)
        n += int((np.asarray(grid.tile_sizes, np.int64)[bad_t] ** 3).sum())
    return n


def sanitize_nonfinite(grid) -> int:
    """Deactivate every NaN/Inf voxel and tile of `grid` in place; returns how many voxels that was.

    Masks are replaced, not edited, because instanced grids share their parent's arrays.
    """
    n = count_nonfinite(grid)
    if n == 0:
        return 0
    if len(grid.leaf_values):
        bits = _unpack(grid.leaf_masks) & np.isfinite(grid.leaf_values)
        grid.leaf_masks = _pack(bits)
    tv = np.asarray(grid.tile_values)
    if len(tv):
        grid.tile_active = np.asarray(grid.tile_active, bool) & np.isfinite(tv)
    grid.active_voxels = int(grid.active_voxels) - n
    return n
