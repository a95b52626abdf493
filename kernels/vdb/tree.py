"""Tree topology (root, two internal levels, leaf masks) of a standard 5-4-3 tree, v >= 222.

Fast path: one compiled walk (_walk) reads every internal node below the root: header, values
codec (raw or blosc-LZ4 chunks), tiles, children and leaf masks, with no Python per node (Python
cost ~100 us a node, a third of a big level set's read). Whatever it does not handle (zip chunks,
frames it declines) or finds wrong, it hands back untouched to the Python walk below, which reads
each node's header and codec in Python and runs one compiled pass per node (_node_scan); that
walk also raises the precise errors.
"""

import threading

import numpy as np

from ..jit import njit
from .codec import (
    COMPRESS_ACTIVE_MASK,
    COMPRESS_BLOSC,
    COMPRESS_ZIP,
    HALF_LUT,
    inactive_values,
    popcount_bytes,
    read_node_parts,
)
from .frames import HAVE_NUMBA, blosc_frame, copy_bytes

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

    def finish(self, ncomp, owned=False):
        """Concatenate the parts; ``owned``: no part is a view of the file (no copy needed)."""
        def cat(parts, shape, dtype):
            if not parts:
                return np.zeros(shape, dtype)
            if len(parts) == 1:
                return parts[0].astype(dtype, copy=not owned)  # never a view of the file
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


@njit(cache=True, nogil=True)
def _full_bits(buf, p, fsz):
    """Bit pattern of the full-precision float (fsz = 4 or 8 bytes) at buf[p], as uint64."""
    v = np.uint64(0)
    for k in range(fsz):
        v |= np.uint64(buf[p + k]) << np.uint64(8 * k)
    return v


@njit(cache=True, nogil=True)
def _codec(buf, pos, end, nslots, vmask, nc, fsz, half, mask_comp, comp, lut, bg, frames):
    """Parse one internal node's values codec at pos (as read_node_parts does).

    Returns (ok, pos, data (count, nc) uint64 bits, val0, val1, sel (nslots // 64) uint64 words);
    ok False when the Python walk must take over (zip chunk, declined frame, anything wrong).
    ``frames`` None (a grid without blosc): numba prunes the frame decoder and compiles none.
    """
    data = np.zeros((0, nc), np.uint64)
    val0 = bg.copy()
    val1 = bg.copy()
    sel = np.zeros(nslots // 64, np.uint64)
    if pos >= end:
        return False, pos, data, val0, val1, sel
    code = buf[pos]
    pos += 1
    if code > 6:
        return False, pos, data, val0, val1, sel
    sign = np.uint64(1) << np.uint64(8 * fsz - 1)
    if code != 0:  # the codes that store no val0 mean -background (code 0: +background)
        for c in range(nc):
            val0[c] = bg[c] ^ sign
    nstore = 2 if code == 5 else (1 if code == 2 or code == 4 else 0)
    if pos + nstore * nc * fsz > end:
        return False, pos, data, val0, val1, sel
    for k in range(nstore):
        for c in range(nc):
            b = _full_bits(buf, pos, fsz)
            pos += fsz
            if k == 0:
                val0[c] = b
            else:
                val1[c] = b
    if code >= 3 and code <= 5:
        if pos + nslots // 8 > end:
            return False, pos, data, val0, val1, sel
        for w in range(nslots // 64):
            sel[w] = _full_bits(buf, pos + 8 * w, np.int64(8))
        pos += nslots // 8
    count = nslots
    if mask_comp and code != 6:
        count = 0
        for w in range(vmask.shape[0]):
            x = vmask[w]
            while x:  # popcount
                x &= x - np.uint64(1)
                count += 1
    ssz = 2 if half else fsz
    vsize = ssz * nc
    nbytes = count * vsize
    data = np.zeros((count, nc), np.uint64)
    if half and count < 1:
        return True, pos, data, val0, val1, sel  # half writers store nothing for no values
    src = buf
    o = pos
    es = vsize
    bs = 1
    if comp != 0:
        if pos + 8 > end:
            return False, pos, data, val0, val1, sel
        size = np.int64(_full_bits(buf, pos, np.int64(8)))
        pos += 8
        o = pos
        if size <= 0:
            if -size != nbytes:
                return False, pos, data, val0, val1, sel
            pos += nbytes
        else:
            if frames is None or comp != 2 or size > end - pos:
                return False, pos, data, val0, val1, sel  # zip: left to Python's zlib
            a = np.empty(max(nbytes, 1), np.uint8)
            t = np.empty(max(nbytes, 1), np.uint8)
            r = blosc_frame(buf, pos, size, nbytes, vsize, a, t)
            if r < 0:
                return False, pos, data, val0, val1, sel
            if r == 0:
                src, o = a, 0
            elif r == 1:
                o = pos + 16
            else:
                src, o, es, bs = t, 0, 1, count
            pos += size
    else:
        pos += nbytes
    if pos > end:
        return False, pos, data, val0, val1, sel
    for e in range(count):
        for c in range(nc):
            p = o + e * es + c * ssz * bs
            if half:
                data[e, c] = np.uint64(lut[np.int64(src[p]) | (np.int64(src[p + bs]) << 8)])
            else:
                v = np.uint64(0)
                for k in range(fsz):
                    v |= np.uint64(src[p + k * bs]) << np.uint64(8 * k)
                data[e, c] = v
    return True, pos, data, val0, val1, sel


@njit(cache=True, nogil=True)
def _walk(buf, pos, end, nchild, nc, fsz, half, mask_comp, comp, lut, bg, sxyz, sbits, sact, kids,
          grand, leaf_cap, frames):
    """Every root child's subtree (level-2 node, its level-1 nodes, their leaf masks) in file
    order, tiles in the order the Python walk appends them. Values are uint64 bit patterns of the
    full type. sxyz/sbits/sact (32768 rows), kids (32768, 3), grand (4096, 3): reused scratch.
    Returns (ok, pos, leaf_xyz, leaf_masks, tiles); tiles rows: x, y, z, size, active, value
    bits per component. ok False: hand over to the Python walk from the start. frames: as _codec.
    (Explicit loops rather than slice assignment keep numba's compile time down.)"""
    # every leaf mask takes 64 bytes here, so this bound rarely needs growing; pages the walk
    # never touches cost nothing (capped at leaf_cap: some systems commit all they allocate)
    cap = min((end - pos) // 64 + 1, leaf_cap)
    lxyz = np.empty((cap, 3), np.int32)
    lmask = np.empty((cap, 64), np.uint8)
    tiles = np.empty((16, 5 + nc), np.int64)
    nl = 0
    nt = 0
    origin = np.zeros(3, np.int64)
    fail = (False, pos, lxyz, lmask, tiles)
    for r in range(nchild):
        if pos + 12 > end:
            return fail
        for k in range(3):
            v = np.int64(_full_bits(buf, pos + 4 * k, np.int64(4)))
            origin[k] = v - (v >> 31 << 32)  # int32
            if origin[k] % 4096:
                return fail
        pos += 12
        nkids = 0
        for level in (2, 1):
            todo = 1 if level == 2 else nkids
            log2 = 5 if level == 2 else 4
            edge = 128 if level == 2 else 8
            nslots = 1 << (3 * log2)
            for q in range(todo):
                o = origin if level == 2 else kids[q]
                if pos + nslots // 4 > end:
                    return fail
                cmask = buf[pos:pos + nslots // 8].view(np.uint64)
                vmask = buf[pos + nslots // 8:pos + nslots // 4].view(np.uint64)
                pos += nslots // 4
                ok, pos, data, val0, val1, sel = _codec(buf, pos, end, nslots, vmask, nc, fsz, half,
                                                        mask_comp, comp, lut, bg, frames)
                if not ok:
                    return fail
                out = kids if level == 2 else grand
                t, nch, big = _node_scan(cmask, vmask, sel, data, data.shape[0] == nslots, val0,
                                         val1, bg, log2, edge, o, sxyz, sbits, sact, out)
                if big > _ORIGIN_LIMIT:
                    return fail
                if nt + t > tiles.shape[0]:  # grow by doubling
                    more = np.empty((max(nt + t, 2 * nt), 5 + nc), np.int64)
                    for k in range(nt):
                        for j in range(5 + nc):
                            more[k, j] = tiles[k, j]
                    tiles = more
                for k in range(t):
                    for j in range(3):
                        tiles[nt + k, j] = sxyz[k, j]
                    tiles[nt + k, 3] = edge
                    tiles[nt + k, 4] = sact[k]
                    for j in range(nc):
                        tiles[nt + k, 5 + j] = np.int64(sbits[k, j])
                nt += t
                if level == 2:
                    nkids = nch
                    continue
                if pos + 64 * nch > end:
                    return fail
                if nl + nch > lxyz.shape[0]:  # grow by doubling
                    more = np.empty((max(nl + nch, 2 * nl), 3), np.int32)
                    mmore = np.empty((more.shape[0], 64), np.uint8)
                    for k in range(nl):
                        for j in range(3):
                            more[k, j] = lxyz[k, j]
                    copy_bytes(mmore.reshape(-1), 0, lmask.reshape(-1), 0, 64 * nl)
                    lxyz = more
                    lmask = mmore
                for k in range(nch):
                    for j in range(3):
                        lxyz[nl + k, j] = grand[k, j]
                copy_bytes(lmask.reshape(-1), 64 * nl, buf, pos, 64 * nch)  # masks lie back to back
                pos += 64 * nch
                nl += nch
    return True, pos, lxyz[:nl].copy(), lmask[:nl].copy(), tiles[:nt]


def _compiled_walk(cur, topo, flags, et, bg, nchild):
    """Run _walk from cur.pos; on success fill topo and move cur, else leave both untouched."""
    if not HAVE_NUMBA or et.full.itemsize not in (4, 8) or (et.half and et.full.itemsize == 8):
        return False  # half-stored doubles: rare, left to the Python walk
    comp = 2 if flags & COMPRESS_BLOSC else (1 if flags & COMPRESS_ZIP else 0)
    u = np.uint32 if et.full.itemsize == 4 else np.uint64
    bgb = bg.view(u).astype(np.uint64)
    sxyz, sbits, sact, kids = _buffers(32768, et.ncomp, np.uint64)
    grand = _buffers(4096, et.ncomp, np.uint64)[3]
    ok, pos, lxyz, lmask, tiles = _walk(
        cur.arr, cur.pos, cur.end, nchild, et.ncomp, et.full.itemsize, et.half,
        bool(flags & COMPRESS_ACTIVE_MASK), comp, _HALF_BITS, bgb, sxyz, sbits, sact, kids, grand,
        _LEAF_CAP, True if comp == 2 else None)
    if not ok:
        return False
    cur.pos = int(pos)
    topo.leaf_origins.append(lxyz)
    topo.leaf_masks.append(lmask)
    if len(tiles):
        topo.tile_origins.append(tiles[:, :3].astype(np.int32))
        topo.tile_sizes.append(tiles[:, 3].astype(np.int32))
        topo.tile_active.append(tiles[:, 4] != 0)
        bits = np.ascontiguousarray(tiles[:, 5:]).view(np.uint64).astype(u)
        topo.tile_values.append(bits.view(et.full).astype(np.float64))
    return True


_HALF_BITS = HALF_LUT.view(np.uint32)
_LEAF_CAP = 1 << 16  # leaves the compiled walk makes room for before it grows its arrays


_TILE_DTYPES = {}


def _tile_dtype(full, ncomp):
    """Root tile record: i32 x 3 origin, value, u8 active (cached: building it costs ~20 us)."""
    dt = _TILE_DTYPES.get((full, ncomp))
    if dt is None:
        dt = _TILE_DTYPES[(full, ncomp)] = np.dtype([("o", "<i4", 3), ("v", full, (ncomp,)), ("a", "u1")])
    return dt


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
    tile_dt = _tile_dtype(et.full, et.ncomp)
    # Each root child needs at least its origin and two 4096-byte masks: bound the counts first.
    if ntiles * tile_dt.itemsize + nchild * (12 + 8192) > cur.remaining():
        raise cur.error(f"absurd root counts: {ntiles} tiles, {nchild} children", cur.pos - 8)
    if ntiles:
        t = cur.array(tile_dt, ntiles, "root tiles")
        topo.tile_origins.append(t["o"].astype(np.int64))
        topo.tile_sizes.append(np.full(ntiles, ROOT_TILE_SIZE, np.int32))
        topo.tile_values.append(t["v"].astype(np.float64).reshape(ntiles, et.ncomp))
        topo.tile_active.append(t["a"] != 0)
    if _compiled_walk(cur, topo, flags, et, bg, nchild):
        topo.end = cur.pos
        return topo.finish(et.ncomp, owned=True)
    for _ in range(nchild):
        at = cur.pos
        o = cur.array("<i4", 3, "root child origin").astype(np.int64)
        if np.any(o % ROOT_TILE_SIZE):
            raise cur.error(f"root child origin {tuple(o)} is not a multiple of 4096", at)
        _internal(cur, topo, 2, o, flags, et, bg)
    topo.end = cur.pos
    return topo.finish(et.ncomp)
