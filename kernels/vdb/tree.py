"""Tree topology (root, two internal levels, leaf masks) of a standard 5-4-3 tree, v >= 222.

Python reads each internal node's header and values codec; one compiled pass per node then expands
the codec slot by slot and picks out tiles and children (no per-node numpy temporaries).
"""

import threading

import numpy as np

from .codec import inactive_values, popcount_bytes, read_node_parts

try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is optional at run time
    def njit(*args, **kwargs):
        return (lambda f: f) if not args or not callable(args[0]) else args[0]

# level -> (log2 of the node's slots per axis, edge of one slot in voxels)
_LEVELS = {2: (5, 128), 1: (4, 8)}
ROOT_TILE_SIZE = 4096
_ORIGIN_LIMIT = 2**31 - 4096


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
        self.popc = None  # per-leaf active counts, once the leaf scan has computed them

    def finish(self, ncomp):
        def cat(parts, shape, dtype):
            if not parts:
                return np.zeros(shape, dtype)
            if len(parts) == 1:
                return parts[0].astype(dtype)  # always a copy: never a view of the file
            return np.concatenate(parts).astype(dtype, copy=False)
        self.leaf_origins = cat(self.leaf_origins, (0, 3), np.int32)
        self.leaf_masks = cat(self.leaf_masks, (0, 64), np.uint8)
        self.tile_origins = cat(self.tile_origins, (0, 3), np.int32)
        self.tile_sizes = cat(self.tile_sizes, (0,), np.int32)
        self.tile_values = cat(self.tile_values, (0, ncomp), np.float64)
        self.tile_active = cat(self.tile_active, (0,), bool)
        return self


@njit(cache=True, nogil=True)
def _node_scan(cmask, vmask, sel, data, dense, val0, val1, bg, log2, edge, origin,
               tile_xyz, tile_bits, tile_act, child_xyz):
    """Expand one internal node's values (as unsigned bit patterns) and collect its tiles.

    Masks come as uint64 words. A slot is a tile when it has no child and is active or differs
    bitwise from the background (so NaN and -0 count as different). Returns (tile count, child
    count, largest |child coordinate|).
    """
    nc = bg.shape[0]
    m = (1 << log2) - 1
    v0bg = True
    v1bg = True
    for c in range(nc):
        if val0[c] != bg[c]:
            v0bg = False
        if val1[c] != bg[c]:
            v1bg = False
    nt = 0
    nch = 0
    s = 0
    big = np.int64(0)
    for w in range(cmask.shape[0]):
        cw = cmask[w]
        vw = vmask[w]
        sw = sel[w]
        if not dense and cw == 0 and vw == 0 and v0bg and (sw == 0 or v1bg):
            continue  # 64 inactive background slots: nothing to keep
        for bit in range(64):
            n = w * 64 + bit
            child = (cw >> np.uint64(bit)) & np.uint64(1)
            act = (vw >> np.uint64(bit)) & np.uint64(1)
            if dense:
                row = n
                src = 0
            elif act:
                row = s
                src = 0
                s += 1
            else:
                row = 0
                src = 2 if (sw >> np.uint64(bit)) & np.uint64(1) else 1
            x = (n >> (2 * log2)) * edge + origin[0]
            y = ((n >> log2) & m) * edge + origin[1]
            z = (n & m) * edge + origin[2]
            if child:
                child_xyz[nch, 0] = x
                child_xyz[nch, 1] = y
                child_xyz[nch, 2] = z
                nch += 1
                for v in (x, y, z):
                    a = -v if v < 0 else v
                    if a > big:
                        big = a
                continue
            keep = act != 0
            for c in range(nc):
                if src == 0:
                    b = data[row, c]
                elif src == 1:
                    b = val0[c]
                else:
                    b = val1[c]
                tile_bits[nt, c] = b
                if b != bg[c]:
                    keep = True
            if keep:
                tile_xyz[nt, 0] = x
                tile_xyz[nt, 1] = y
                tile_xyz[nt, 2] = z
                tile_act[nt] = act != 0
                nt += 1
    return nt, nch, big


_ZEROS = {}


_scratch = threading.local()


def _buffers(nslots, ncomp, u):
    """Per-thread scratch for _node_scan (results are copied out), so big nodes allocate once."""
    key = (nslots, ncomp, u)
    b = getattr(_scratch, "bufs", {}).get(key)
    if b is None:
        b = (np.empty((nslots, 3), np.int64), np.empty((nslots, ncomp), u), np.empty(nslots, np.bool_),
             np.empty((nslots, 3), np.int64))
        if not hasattr(_scratch, "bufs"):
            _scratch.bufs = {}
        _scratch.bufs[key] = b
    return b


def _bits(a, et):
    u = np.dtype(f"<u{et.full.itemsize}")
    return np.ascontiguousarray(np.asarray(a, et.full).reshape(-1, et.ncomp)).view(u)


def _internal(cur, topo, level, origin, flags, et, bg):
    log2, edge = _LEVELS[level]
    nslots = 1 << (3 * log2)
    at = cur.pos
    cmask = cur.array(np.uint8, nslots // 8, "child mask")
    vmask = cur.array(np.uint8, nslots // 8, "value mask")
    code, val0, val1, sel, data = read_node_parts(cur, nslots, popcount_bytes(vmask), flags, et)
    val0, val1 = inactive_values(code, val0, val1, bg, et)
    u = np.dtype(f"<u{et.full.itemsize}")
    tile_xyz, tile_bits, tile_act, child_xyz = _buffers(nslots, et.ncomp, u)
    if sel is None:
        sel = _ZEROS.get(nslots)
        if sel is None:
            sel = _ZEROS[nslots] = np.zeros(nslots // 64, np.uint64)
    else:
        sel = sel.view("<u8")
    nt, nch, big = _node_scan(cmask.view("<u8"), vmask.view("<u8"), sel, _bits(data, et),
                              len(data) == nslots, _bits(val0, et)[0], _bits(val1, et)[0],
                              _bits(bg, et)[0], log2, edge, np.asarray(origin, np.int64),
                              tile_xyz, tile_bits, tile_act, child_xyz)
    if nt:
        topo.tile_origins.append(tile_xyz[:nt].copy())
        topo.tile_sizes.append(np.full(nt, edge, np.int32))
        topo.tile_values.append(tile_bits[:nt].view(et.full).astype(np.float64))
        topo.tile_active.append(tile_act[:nt].copy())
    if big > _ORIGIN_LIMIT:
        raise cur.error(f"level-{level} node origin out of range", at)
    origins = child_xyz[:nch].copy()
    if level == 1:
        masks = cur.array(np.uint8, nch * 64, "leaf masks").reshape(nch, 64)
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
