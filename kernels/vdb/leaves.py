"""Leaf buffers: one compiled scan finds every leaf's chunk, then decompress and scatter in bulk.

The scan and the scatter are plain Python written for numba; without numba they still run (slowly).
"""

import numpy as np

from .codec import COMPRESS_ACTIVE_MASK, COMPRESS_BLOSC, COMPRESS_ZIP, HALF_LUT, decompress

try:
    from blosc.blosc_extension import decompress_ptr as blosc_ptr
except ImportError:  # pragma: no cover
    blosc_ptr = None

try:
    from numba import njit, prange
except ImportError:  # pragma: no cover - numba is optional at run time
    def njit(*args, **kwargs):
        return (lambda f: f) if not args or not callable(args[0]) else args[0]

    prange = range

# Below this many leaves the scatter runs serially: starting threads would cost more than it saves.
PARALLEL_LEAVES = 512

_POPC8 = np.array([bin(i).count("1") for i in range(256)], np.int64)

# scan status codes
_OK, _TRUNC, _MASK, _CODE, _RAWSIZE, _BLOSCHDR = 0, 1, 2, 3, 4, 5
_MESSAGES = {
    _TRUNC: "truncated leaf buffer",
    _MASK: "leaf buffer mask differs from the topology mask",
    _CODE: "unknown leaf metadata code",
    _RAWSIZE: "raw leaf chunk has the wrong size",
    _BLOSCHDR: "blosc leaf chunk header disagrees with the leaf size",
}


@njit(cache=True, nogil=True)
def _scan(buf, pos, end, masks, popc, mask_comp, compressed, half, stored_size, full_size,
          codes, off0, off1, seloff, chunk_off, chunk_len, counts):
    """Walk the leaf buffers; fill per-leaf arrays. Returns (status, offset, leaf index)."""
    n = masks.shape[0]
    for i in range(n):
        if pos + 65 > end:
            return _TRUNC, pos, i
        for k in range(64):
            if buf[pos + k] != masks[i, k]:
                return _MASK, pos + k, i
        pos += 64
        code = buf[pos]
        if code > 6:
            return _CODE, pos, i
        codes[i] = code
        pos += 1
        off0[i] = -1
        off1[i] = -1
        seloff[i] = -1
        if code == 2 or code == 4 or code == 5:
            off0[i] = pos
            pos += full_size
            if code == 5:
                off1[i] = pos
                pos += full_size
        if code >= 3 and code <= 5:
            seloff[i] = pos
            pos += 64
        if pos > end:
            return _TRUNC, pos, i
        cnt = popc[i] if (mask_comp and code != 6) else 512
        counts[i] = cnt
        nbytes = cnt * stored_size
        chunk_off[i] = pos
        if half and cnt < 1:
            chunk_len[i] = 0
            continue
        if compressed:
            if pos + 8 > end:
                return _TRUNC, pos, i
            size = np.int64(0)
            for k in range(8):
                size |= np.int64(buf[pos + k]) << (8 * k)
            pos += 8
            chunk_off[i] = pos
            if size <= 0:
                if -size != nbytes:
                    return _RAWSIZE, pos - 8, i
                chunk_len[i] = size
                pos += nbytes
            else:
                if size > end - pos:
                    return _TRUNC, pos - 8, i
                if compressed == 2:  # blosc: header nbytes and cbytes must match before C sees it
                    if size < 16:
                        return _BLOSCHDR, pos, i
                    nb = np.int64(0)
                    cb = np.int64(0)
                    for k in range(4):
                        nb |= np.int64(buf[pos + 4 + k]) << (8 * k)
                        cb |= np.int64(buf[pos + 12 + k]) << (8 * k)
                    if nb != nbytes or cb != size:
                        return _BLOSCHDR, pos, i
                chunk_len[i] = size
                pos += size
        else:
            chunk_len[i] = -nbytes
            pos += nbytes
        if pos > end:
            return _TRUNC, pos, i
    return _OK, pos, n


@njit(cache=True, nogil=True)
def _copy_raw(buf, chunk_off, chunk_len, pool, starts):
    for i in range(chunk_off.shape[0]):
        if chunk_len[i] < 0:
            s = starts[i]
            o = chunk_off[i]
            for k in range(-chunk_len[i]):
                pool[s + k] = buf[o + k]


@njit(cache=True, nogil=True)
def _scatter(data, starts, masks, compact, val0, val1, sel, out):
    """out[i, slot] = next stored value for stored slots, else the inactive value the code picks.

    Branch-free per slot; ``data`` carries one padding row so the look-ahead read stays in bounds.
    """
    n = masks.shape[0]
    nc = data.shape[1]
    for i in range(n):
        s = starts[i]
        if not compact[i]:
            for slot in range(512):
                for c in range(nc):
                    out[i, slot, c] = data[s + slot, c]
            continue
        for byte in range(64):
            m = masks[i, byte]
            q = sel[i, byte]
            for bit in range(8):
                slot = byte * 8 + bit
                take = (m >> bit) & 1
                pick = (q >> bit) & 1
                for c in range(nc):
                    inact = val1[i, c] if pick else val0[i, c]
                    out[i, slot, c] = data[s, c] if take else inact
                s += take


@njit(cache=True, nogil=True)
def _scatter1(data, starts, masks, compact, val0, val1, sel, out):
    """Scalar grids: the same as _scatter on 1-D data and (N, 512) output (lets LLVM do better)."""
    for i in range(masks.shape[0]):
        s = starts[i]
        if not compact[i]:
            out[i, :] = data[s:s + 512]
            continue
        v0 = val0[i, 0]
        v1 = val1[i, 0]
        for byte in range(64):
            m = masks[i, byte]
            q = sel[i, byte]
            for bit in range(8):
                take = (m >> bit) & 1
                inact = v1 if (q >> bit) & 1 else v0
                out[i, byte * 8 + bit] = data[s] if take else inact
                s += take


@njit(cache=True, nogil=True)
def _popcount(masks):
    out = np.zeros(masks.shape[0], np.int64)
    for i in range(masks.shape[0]):
        c = 0
        for k in range(masks.shape[1]):
            c += _POPC8[masks[i, k]]
        out[i] = c
    return out


def popcount_rows(masks_u8):
    """Active voxels of each leaf, from its 64 mask bytes."""
    return _popcount(np.ascontiguousarray(masks_u8))


def scan_leaves(cur, masks, flags, et):
    """Walk the leaf buffers from cur.pos (bounded by cur.end); returns the per-leaf table."""
    n = len(masks)
    popc = popcount_rows(masks)
    t = {
        "codes": np.zeros(n, np.uint8), "off0": np.zeros(n, np.int64), "off1": np.zeros(n, np.int64),
        "seloff": np.zeros(n, np.int64), "chunk_off": np.zeros(n, np.int64),
        "chunk_len": np.zeros(n, np.int64), "counts": np.zeros(n, np.int64), "popc": popc,
    }
    compressed = 2 if flags & COMPRESS_BLOSC else (1 if flags & COMPRESS_ZIP else 0)
    status, pos, i = _scan(cur.arr, cur.pos, cur.end, masks, popc, bool(flags & COMPRESS_ACTIVE_MASK),
                           compressed, et.half, et.stored_size, et.full_size, t["codes"], t["off0"],
                           t["off1"], t["seloff"], t["chunk_off"], t["chunk_len"], t["counts"])
    if status != _OK:
        raise cur.error(f"{_MESSAGES[status]} (leaf {i} of {n})", int(pos))
    cur.pos = int(pos)
    return t


def _decompress_all(cur, t, counts, pool, byte_starts, flags, et):
    idx = np.nonzero(t["chunk_len"] > 0)[0]
    if not len(idx):
        return
    offs = t["chunk_off"][idx].tolist()
    lens = t["chunk_len"][idx].tolist()
    dsts = byte_starts[idx].tolist()
    if flags & COMPRESS_BLOSC and blosc_ptr is not None:
        # The scan checked each header (nbytes fits the slot, cbytes = chunk length); blosc itself
        # refuses a frame whose cbytes disagrees with the buffer it is given.
        mv = memoryview(cur.buf)
        base = pool.ctypes.data
        try:
            for o, n, d in zip(offs, lens, dsts):
                blosc_ptr(mv[o:o + n], base + d)
        except Exception as e:  # blosc_extension.error on a corrupt frame
            raise cur.error(f"corrupt blosc chunk: {e}", o) from None
        finally:
            mv.release()
        return
    ss = et.stored_size
    for i, o, n, d in zip(idx.tolist(), offs, lens, dsts):
        nb = int(counts[i]) * ss
        pool[d:d + nb] = np.frombuffer(decompress(cur, o, n, nb, flags), np.uint8)


@njit(cache=True, nogil=True, inline="always")
def _get(src, o, k, kind, lut):
    """Float32 bits of stored component ``k`` of a chunk starting at byte ``o`` (half or float)."""
    if kind == 0:
        p = o + 2 * k
        return lut[np.int64(src[p]) | (np.int64(src[p + 1]) << 8)]
    p = o + 4 * k
    return (np.uint32(src[p]) | (np.uint32(src[p + 1]) << np.uint32(8))
            | (np.uint32(src[p + 2]) << np.uint32(16)) | (np.uint32(src[p + 3]) << np.uint32(24)))


@njit(cache=True, nogil=True, inline="always")
def _leaf(src, o, i, kind, lut, compact, masks, val0, val1, sel, outu):
    nc = outu.shape[2]
    if not compact:
        for slot in range(512):
            for c in range(nc):
                outu[i, slot, c] = _get(src, o, slot * nc + c, kind, lut)
        return
    s = 0
    for byte in range(64):
        m = masks[i, byte]
        q = sel[i, byte]
        for bit in range(8):
            slot = byte * 8 + bit
            if (m >> bit) & 1:
                for c in range(nc):
                    outu[i, slot, c] = _get(src, o, s * nc + c, kind, lut)
                s += 1
            elif (q >> bit) & 1:
                for c in range(nc):
                    outu[i, slot, c] = val1[i, c]
            else:
                for c in range(nc):
                    outu[i, slot, c] = val0[i, c]


def _decode(buf, pool, kind, lut, chunk_off, chunk_len, pool_start, masks, compact, val0, val1,
            sel, outu, outf, mag):
    """Convert and scatter every leaf straight from the file (raw chunks) or the pool (inflated
    chunks) into ``outu`` (float32 bits, (N, 512, ncomp)); vec3 magnitudes go to ``mag``.

    kind 0: half values, 1: float32. Every offset and length was validated by _scan and the
    decompression before this runs.
    """
    nc = outu.shape[2]
    for i in prange(masks.shape[0]):  # leaves are independent: any thread count, same result
        if chunk_len[i] > 0:
            _leaf(pool, pool_start[i], i, kind, lut, compact[i], masks, val0, val1, sel, outu)
        else:
            _leaf(buf, chunk_off[i], i, kind, lut, compact[i], masks, val0, val1, sel, outu)
        if nc == 3:
            for slot in range(512):
                x = outf[i, slot, 0]
                y = outf[i, slot, 1]
                z = outf[i, slot, 2]
                mag[i, slot] = np.sqrt(x * x + y * y + z * z)


_decode_serial = njit(cache=True, nogil=True)(_decode)
_decode_parallel = njit(cache=True, nogil=True, parallel=True)(_decode)
_HALF_BITS = HALF_LUT.view(np.uint32)


def decode_leaves(cur, masks, t, flags, et, background, magnitudes=None):
    """Decompress every leaf chunk and scatter into (N, 512, ncomp) float32.

    With ``magnitudes`` (an (N, 512) float32 array) vec3 grids also get their per-voxel length.
    """
    n = len(masks)
    counts = t["counts"]
    chunk_len = t["chunk_len"]
    # only inflated chunks need a pool; raw ones are read in place
    double = not et.half and et.full.itemsize == 8
    zlen = counts * et.stored_size if double else np.where(chunk_len > 0, counts * et.stored_size, 0)
    pool_start = np.zeros(n, np.int64)
    if n > 1:
        np.cumsum(zlen[:-1], out=pool_start[1:])
    total = int(zlen.sum())
    pool = np.empty(max(total, 8), np.uint8)
    _decompress_all(cur, t, counts, pool, pool_start, flags, et)
    kind = 0 if et.half else 1
    if double:  # rare: gather every chunk, convert to float32 once, then decode as float32
        _copy_raw(cur.arr, t["chunk_off"], chunk_len, pool, pool_start)
        pool = pool[:total].view("<f8").astype("<f4").view(np.uint8)
        pool_start = pool_start // 2
        chunk_len = np.ones(n, np.int64)
    bg = np.asarray(background, np.float64).reshape(et.ncomp)
    codes = t["codes"]
    val0 = np.where((codes == 0)[:, None], bg, -bg).astype(np.float32)
    val1 = np.broadcast_to(bg.astype(np.float32), (n, et.ncomp)).copy()
    for off, dst in ((t["off0"], val0), (t["off1"], val1)):
        idx = np.nonzero(off >= 0)[0]
        if len(idx):
            raw = cur.arr[off[idx, None] + np.arange(et.full_size)]
            dst[idx] = raw.copy().view(et.full).reshape(len(idx), et.ncomp).astype(np.float32)
    sel = np.zeros((n, 64), np.uint8)
    idx = np.nonzero(t["seloff"] >= 0)[0]
    if len(idx):
        sel[idx] = cur.arr[t["seloff"][idx, None] + np.arange(64)]
    compact = counts != 512
    out = np.empty((n, 512, et.ncomp), np.float32)
    if magnitudes is None:
        magnitudes = np.empty((n if et.ncomp == 3 else 0, 512), np.float32)
    decode = _decode_parallel if n >= PARALLEL_LEAVES else _decode_serial
    decode(cur.arr, pool, kind, _HALF_BITS, t["chunk_off"], chunk_len, pool_start, masks, compact,
            val0.view(np.uint32), val1.view(np.uint32), sel, out.view(np.uint32), out, magnitudes)
    return out
