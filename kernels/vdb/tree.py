"""Tree topology (root, two internal levels, leaf masks) of a standard 5-4-3 tree, v >= 222."""

import numpy as np

from .codec import read_node_values

# level -> (log2 of the node's slots per axis, edge of one slot in voxels)
_LEVELS = {2: (5, 128), 1: (4, 8)}
ROOT_TILE_SIZE = 4096


class Topology:
    """What the topology section holds; leaf masks are the topology copies (N, 64) uint8."""

    def __init__(self):
        self.background = None
        self.leaf_origins = []
        self.leaf_masks = []
        self.tile_origins = []
        self.tile_sizes = []
        self.tile_values = []
        self.tile_active = []
        self.start = 0
        self.end = 0

    def finish(self, ncomp):
        def cat(parts, shape, dtype):
            return np.concatenate(parts).astype(dtype, copy=False) if parts else np.zeros(shape, dtype)
        self.leaf_origins = cat(self.leaf_origins, (0, 3), np.int32)
        self.leaf_masks = cat(self.leaf_masks, (0, 64), np.uint8)
        self.tile_origins = cat(self.tile_origins, (0, 3), np.int32)
        self.tile_sizes = cat(self.tile_sizes, (0,), np.int32)
        self.tile_values = cat(self.tile_values, (0, ncomp), np.float64)
        self.tile_active = cat(self.tile_active, (0,), bool)
        return self


def _slot_coords(slots, log2, edge, origin):
    n = slots.astype(np.int64)
    m = (1 << log2) - 1
    xyz = np.stack([n >> (2 * log2), (n >> log2) & m, n & m], axis=1)
    return xyz * edge + np.asarray(origin, np.int64)


def _differs(values, bg):
    """Slots whose value differs bitwise from the background (so NaN and -0 count as different)."""
    v = np.ascontiguousarray(values)
    u = np.dtype(f"<u{v.dtype.itemsize}")
    b = np.asarray(bg, v.dtype).reshape(1, -1)
    d = v.view(u) != b.view(u)
    return d[:, 0] if d.shape[1] == 1 else d.any(axis=1)


def _internal(cur, topo, level, origin, flags, et, bg):
    log2, edge = _LEVELS[level]
    nslots = 1 << (3 * log2)
    at = cur.pos
    cmask = np.unpackbits(cur.array(np.uint8, nslots // 8, "child mask"), bitorder="little").astype(bool)
    active = np.unpackbits(cur.array(np.uint8, nslots // 8, "value mask"), bitorder="little").astype(bool)
    values = read_node_values(cur, nslots, active, flags, et, bg)
    keep = ~cmask & (active | _differs(values, bg))
    if keep.any():
        slots = np.nonzero(keep)[0]
        topo.tile_origins.append(_slot_coords(slots, log2, edge, origin))
        topo.tile_sizes.append(np.full(len(slots), edge, np.int32))
        topo.tile_values.append(values[slots].astype(np.float64))
        topo.tile_active.append(active[slots])
    children = np.nonzero(cmask)[0]
    origins = _slot_coords(children, log2, edge, origin)
    if np.any(np.abs(origins) > 2**31 - 4096):
        raise cur.error(f"level-{level} node origin out of range", at)
    if level == 1:
        n = len(children)
        masks = cur.array(np.uint8, n * 64, "leaf masks").reshape(n, 64)
        topo.leaf_origins.append(origins)
        topo.leaf_masks.append(masks)
        return
    for o in origins:
        _internal(cur, topo, 1, o, flags, et, bg)


def read_tree_topology(cur, flags, et):
    """Parse Tree::readTopology; returns a Topology. ``cur`` is left at the first leaf buffer."""
    topo = Topology()
    topo.start = cur.pos
    nbuf = cur.i32("buffer count")
    if nbuf != 1:
        raise cur.error(f"tree has {nbuf} buffers; only single-buffer trees are supported", cur.pos - 4)
    bg = cur.array(et.full, et.ncomp, "background").astype(et.full)
    topo.background = bg
    ntiles = cur.u32("root tile count")
    nchild = cur.u32("root child count")
    tile_dt = np.dtype([("o", "<i4", 3), ("v", et.full, (et.ncomp,)), ("a", "u1")])
    # Each root child needs at least its origin and two 4096-byte masks: bound the counts first.
    if ntiles * tile_dt.itemsize + nchild * (12 + 8192) > cur.remaining():
        raise cur.error(f"absurd root counts: {ntiles} tiles, {nchild} children", cur.pos - 8)
    if ntiles:
        t = cur.array(tile_dt, ntiles, "root tiles")
        topo.tile_origins.append(t["o"].astype(np.int64))
        topo.tile_sizes.append(np.full(ntiles, ROOT_TILE_SIZE, np.int32))
        topo.tile_values.append(t["v"].astype(np.float64).reshape(ntiles, et.ncomp))
        topo.tile_active.append(t["a"] != 0)
    for _ in range(nchild):
        at = cur.pos
        o = cur.array("<i4", 3, "root child origin").astype(np.int64)
        if np.any(o % ROOT_TILE_SIZE):
            raise cur.error(f"root child origin {tuple(o)} is not a multiple of 4096", at)
        _internal(cur, topo, 2, o, flags, et, bg)
    topo.end = cur.pos
    return topo.finish(et.ncomp)
