"""Leaf buffers: one compiled scan finds every leaf's chunk, then one compiled (and for big grids
parallel) loop decodes each leaf: blosc frame decoded in place (frames.py), values gathered to
float32 bits, scattered over the leaf's 512 slots. Zip chunks are inflated first (C zlib from a
compiled loop where found); any chunk the compiled code declines goes through the Python modules.

The scan and the scatter are plain Python written for numba; without numba they still run (slowly)
and every chunk goes through the Python modules.
"""

import mmap

import numpy as np

from .codec import COMPRESS_ACTIVE_MASK, COMPRESS_BLOSC, COMPRESS_ZIP, HALF_LUT, decompress
from .frames import HAVE_NUMBA, blosc_frame, inflate_all

try:
    from blosc.blosc_extension import decompress_ptr as blosc_ptr
except ImportError:  # pragma: no cover
    blosc_ptr = None

from ..jit import njit, parallel_for

# Below this many leaves (or zip chunks) the loops run on the calling thread: starting threads
# would cost more than it saves, and on a busy machine the last chunk can wait a whole time slice
# for its thread. The same compiled kernel either way (a warm-up's small file loads what a large
# file runs).
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


@njit(cache=True, nogil=True, inline="always")
def _u64(a, p):
    v = np.uint64(0)
    for k in range(8):
        v |= np.uint64(a[p + k]) << np.uint64(8 * k)
    return v


@njit(cache=True, nogil=True)
def _scan(buf, pos, end, masks, popc, mask_comp, compressed, half, stored_size, full_size,
          codes, off0, off1, seloff, chunk_off, chunk_len, counts):
    """Walk the leaf buffers; fill per-leaf arrays. Returns (status, offset, leaf index)."""
    n = masks.shape[0]
    for i in range(n):
        if pos + 65 > end:
            return _TRUNC, pos, i
        for w in range(8):  # word-wise (LLVM fuses the byte loads); bytewise only to report
            if _u64(buf, pos + 8 * w) != _u64(masks[i], 8 * w):
                for k in range(8 * w, 8 * w + 8):
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
    f = np.empty((6, n), np.int64)  # one block: _scan writes every field of every leaf it passes
    t = {"codes": np.empty(n, np.uint8), "off0": f[0], "off1": f[1], "seloff": f[2],
         "chunk_off": f[3], "chunk_len": f[4], "counts": f[5], "popc": popc}
    compressed = 2 if flags & COMPRESS_BLOSC else (1 if flags & COMPRESS_ZIP else 0)
    status, pos, i = _scan(cur.arr, cur.pos, cur.end, masks, popc, bool(flags & COMPRESS_ACTIVE_MASK),
                           compressed, et.half, et.stored_size, et.full_size, t["codes"], t["off0"],
                           t["off1"], t["seloff"], t["chunk_off"], t["chunk_len"], t["counts"])
    if status != _OK:
        raise cur.error(f"{_MESSAGES[status]} (leaf {i} of {n})", int(pos))
    cur.pos = int(pos)
    return t


def _decompress_all(cur, t, idx, pool, byte_starts, flags, et):
    """Python path: decompress the chunks of leaves ``idx`` into pool[byte_starts[i]:...]."""
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
    counts = t["counts"]
    for i, o, n, d in zip(idx.tolist(), offs, lens, dsts):
        nb = int(counts[i]) * ss
        pool[d:d + nb] = np.frombuffer(decompress(cur, o, n, nb, flags), np.uint8)


def _pool_for(idx, nbytes, n):
    """A byte pool with one slot per leaf in ``idx``; pool_start is -1 for every other leaf."""
    start = np.full(n, -1, np.int64)
    sizes = nbytes[idx]
    if len(idx):
        start[idx] = np.cumsum(sizes) - sizes
    return np.empty(max(int(sizes.sum()), 8), np.uint8), start


@njit(cache=True, nogil=True, inline="always")
def _gather(src, o, es, bs, cnt, nc, kind, lut, vals):
    """vals[s * nc + c] = float32 bits of stored value s, component c, for s < cnt. Its bytes are
    src[p], src[p + bs], ... from p = o + s * es + c * (2 or 4) * bs (plain: es = value size,
    bs = 1; blosc byte-shuffled: es = 1, bs = cnt)."""
    w = 2 if kind == 0 else 4
    if es == 1:  # byte planes: one slice per byte lets LLVM vectorise (indexing src[p + k * bs]
        for c in range(nc):  # directly is 3-4x slower)
            q = o + c * w * bs
            b0 = src[q:q + cnt]
            b1 = src[q + bs:q + bs + cnt]
            if kind == 0:
                for s in range(cnt):
                    vals[s * nc + c] = lut[np.int64(b0[s]) | (np.int64(b1[s]) << 8)]
            else:
                b2 = src[q + 2 * bs:q + 2 * bs + cnt]
                b3 = src[q + 3 * bs:q + 3 * bs + cnt]
                for s in range(cnt):
                    vals[s * nc + c] = (np.uint32(b0[s]) | (np.uint32(b1[s]) << np.uint32(8))
                                        | (np.uint32(b2[s]) << np.uint32(16))
                                        | (np.uint32(b3[s]) << np.uint32(24)))
        return
    x = src[o:o + cnt * es]  # indexing a slice from 0, not src at o + ..., lets LLVM fuse the byte
    for s in range(cnt):     # loads into one word load and vectorise (up to 30x faster)
        for c in range(nc):
            p = s * es + c * w
            if kind == 0:
                vals[s * nc + c] = lut[np.int64(x[p]) | (np.int64(x[p + 1]) << 8)]
            else:
                vals[s * nc + c] = (np.uint32(x[p]) | (np.uint32(x[p + 1]) << np.uint32(8))
                                    | (np.uint32(x[p + 2]) << np.uint32(16))
                                    | (np.uint32(x[p + 3]) << np.uint32(24)))


@njit(cache=True, nogil=True, inline="always")
def _scatter(vals, i, nc, compact, masks, val0, val1, buf, sp, out):
    """out[i, slot * nc + c]: the next stored value for an active slot, else the inactive value
    the selection bit (mask at buf[sp:sp+64], none when sp < 0) picks. Branch-free per slot
    (vals has one spare entry for the look-ahead). Works on 1-D row slices (cheaper indexing)."""
    row = out[i]
    if not compact:
        for k in range(512 * nc):
            row[k] = vals[k]
        return
    mrow = masks[i]
    s = 0
    for byte in range(64):
        m = mrow[byte]
        q = buf[sp + byte] if sp >= 0 else 0
        if m == 255:  # whole and empty runs of 8 are common (narrow bands, dense fogs)
            for k in range(8 * nc):
                row[byte * 8 * nc + k] = vals[s * nc + k]
            s += 8
            continue
        if m == 0 and q == 0:
            for k in range(8 * nc):
                row[byte * 8 * nc + k] = val0[k % nc]
            continue
        for bit in range(8):
            take = (m >> bit) & 1
            pick = (q >> bit) & 1
            slot = byte * 8 + bit
            for c in range(nc):
                inact = val1[c] if pick else val0[c]
                row[slot * nc + c] = vals[s * nc + c] if take else inact
            s += take


@njit(cache=True, nogil=True)
def _values(src, o, es, cnt, nc, kind, lut, vals):
    """_gather of plain values (es bytes each from src[o]) with literal kind for scalar grids:
    each call inlines into its own specialised loop (combined loads); vector grids (rarer)
    share one generic loop."""
    if nc != 1:
        _gather(src, o, es, 1, cnt, nc, kind, lut, vals)
    elif kind == 0:
        _gather(src, o, 2, 1, cnt, 1, 0, lut, vals)
    else:
        _gather(src, o, 4, 1, cnt, 1, 1, lut, vals)


@njit(cache=True, nogil=True)
def _planes(src, cnt, nc, kind, lut, vals):
    """_gather of a blosc frame left byte-shuffled in src (vector loads across its byte planes);
    a function of its own, so that grids without blosc never compile it."""
    if nc != 1:
        _gather(src, 0, 1, cnt, cnt, nc, kind, lut, vals)
    elif kind == 0:
        _gather(src, 0, 1, cnt, cnt, 1, 0, lut, vals)
    else:
        _gather(src, 0, 1, cnt, cnt, 1, 1, lut, vals)


@njit(cache=True, nogil=True, inline="always")
def _full32(buf, p, fsz, cv):
    """The full-precision float (fsz = 4 or 8 bytes) at buf[p] as float32; cv: 1-word scratch."""
    bits = np.uint64(0)
    for k in range(fsz):
        bits |= np.uint64(buf[p + k]) << np.uint64(8 * k)
    cv[0] = bits
    return np.float32(cv.view(np.float64)[0]) if fsz == 8 else cv.view(np.float32)[0]


_TASK = 32  # leaves per task (the chunks parallel_for hands to threads are whole tasks)


@njit(cache=True, nogil=True)
def _decode_rows(lo, hi, buf, pool, kind, lut, chunk_off, chunk_len, pool_start, nbytes, ids, masks,
                 codes, off0, off1, seloff, bg, fsz, outu, outf, mag, status, frames):
    """Tasks lo..hi-1 of the decode: convert and scatter leaves ids[lo * _TASK:hi * _TASK] into
    ``outu`` (float32 bits, (N, 512 * ncomp)); vec3 magnitudes go to ``mag``. Leaves are
    independent: any split into tasks on any threads gives the same result. One compiled
    function (a per-task one called from this loop was one more, ~1 s on a first import). A leaf's values
    come from the file (raw chunk), the pool (pool_start >= 0: inflated before) or its blosc
    frame, decoded here into the task's scratch. A frame the compiled decoder declines sets
    status[i] = 1 and leaves the leaf unwritten.

    Inactive slots get -bg / +bg or the values stored at off0 / off1 (fsz-byte floats) as the
    leaf's codec code says, picked by the selection mask at seloff. kind 0: half values,
    1: float32. Every offset and length was validated by _scan before this runs; scratch holds
    512 float32 per component, the largest leaf. ``frames`` None (a grid without blosc): numba
    prunes the frame decoder and the byte-plane reads, and compiles neither.
    """
    nc = outf.shape[2]
    vsize = (2 if kind == 0 else 4) * nc
    nids = ids.shape[0]
    a = np.empty(2048 * nc, np.uint8)
    b = np.empty(2048 * nc, np.uint8)
    vals = np.zeros(512 * nc + nc, np.uint32)
    v0 = np.empty(nc, np.float32)
    v1 = np.empty(nc, np.float32)
    cv = np.empty(1, np.uint64)
    zero = np.int64(0)
    for j in range(lo * _TASK, min(nids, hi * _TASK)):
        i = ids[j]
        cnt = nbytes[i] // vsize
        for k in range(nc):
            v0[k] = np.float32(bg[k]) if codes[i] == 0 else np.float32(-bg[k])
            v1[k] = np.float32(bg[k])
            if off0[i] >= 0:
                v0[k] = _full32(buf, off0[i] + k * fsz, fsz, cv)
            if off1[i] >= 0:
                v1[k] = _full32(buf, off1[i] + k * fsz, fsz, cv)
        o = chunk_off[i]  # values at src[o:], vsize bytes each
        src = pool  # a writable scratch or pool, unless in_file: then the (read-only) file
        in_file = chunk_len[i] <= 0
        planes = False
        if not in_file and pool_start[i] >= 0:
            o = pool_start[i]
        elif not in_file:
            if frames is None:
                status[i] = 1
                continue
            r = blosc_frame(buf, o, chunk_len[i], nbytes[i], vsize, a, b)
            if r < 0:
                status[i] = 1
                continue
            if r == 2:  # still byte-shuffled: read across the byte planes
                _planes(b, cnt, nc, kind, lut, vals)
                planes = True
            in_file = r == 1  # a stored frame: read in place after its header
            o = o + 16 if r == 1 else zero
            src = a
        # two call sites, one per array type, with run-time arguments: numba compiles _values
        # once for each instead of once per literal combination (each compile costs seconds)
        if in_file and not planes:
            _values(buf, o, vsize, cnt, nc, kind, lut, vals)
        elif not planes:
            _values(src, o, vsize, cnt, nc, kind, lut, vals)
        v0u = v0.view(np.uint32)
        v1u = v1.view(np.uint32)
        if nc == 1:
            _scatter(vals, i, 1, cnt != 512, masks, v0u, v1u, buf, seloff[i], outu)
        else:
            _scatter(vals, i, 3, cnt != 512, masks, v0u, v1u, buf, seloff[i], outu)
        if nc == 3:
            for slot in range(512):
                x = outf[i, slot, 0]
                y = outf[i, slot, 1]
                z = outf[i, slot, 2]
                mag[i, slot] = np.sqrt(x * x + y * y + z * z)


def threads_for(n):
    """parallel_for's threads for a loop over n leaves or chunks: this one below PARALLEL_LEAVES."""
    return None if n >= PARALLEL_LEAVES else 1


_HALF_BITS = HALF_LUT.view(np.uint32)


BLOCK_LEAVES = 1 << 15  # leaves decoded between releases of their file pages (64 MB of values;
# each block is one parallel_for, whose last chunk on a busy machine may wait a time slice)


def decode_leaves(cur, masks, t, flags, et, background, magnitudes=None):
    """Decompress every leaf chunk and scatter into (N, 512, ncomp) float32.

    With ``magnitudes`` (an (N, 512) float32 array) vec3 grids also get their per-voxel length.
    Blosc frames are decoded inside the compiled loop and zip chunks by C zlib in a compiled
    loop where possible; whatever those decline goes through the Python modules, which also
    produce the error for a corrupt chunk. Leaves go in blocks of BLOCK_LEAVES, in file order:
    a zip pool holds one block, and the file pages a block has read are handed back (the peak is
    the values, not values plus file).
    """
    n = len(masks)
    counts = t["counts"]
    chunk_len = t["chunk_len"]
    chunk_off = t["chunk_off"]
    nbytes = counts * et.stored_size
    double = not et.half and et.full.itemsize == 8
    if double:  # rare: gather every chunk, convert to float32 once, then decode as float32
        packed = np.nonzero(chunk_len > 0)[0]
        pool, pool_start = _pool_for(np.arange(n), nbytes, n)
        _decompress_all(cur, t, packed, pool, pool_start, flags, et)
        _copy_raw(cur.arr, chunk_off, chunk_len, pool, pool_start)
        pool = pool[:int(nbytes.sum())].view("<f8").astype("<f4").view(np.uint8)
        pool_start = pool_start // 2
        chunk_len = np.ones(n, np.int64)
        nbytes = nbytes // 2
    zip_pool = bool(flags & COMPRESS_ZIP) or (bool(flags & COMPRESS_BLOSC) and not HAVE_NUMBA)
    kind = 0 if et.half else 1
    bg = np.asarray(background, np.float64).reshape(et.ncomp)
    out = np.empty((n, 512, et.ncomp), np.float32)
    if magnitudes is None:
        magnitudes = np.empty((n if et.ncomp == 3 else 0, 512), np.float32)
    status = np.zeros(n, np.uint8)

    def run(ids, pool, pool_start):
        parallel_for(_decode_rows, (len(ids) + _TASK - 1) // _TASK, cur.arr, pool, kind, _HALF_BITS,
                     chunk_off, chunk_len, pool_start, nbytes, ids, masks, t["codes"], t["off0"],
                     t["off1"], t["seloff"], bg, et.full.itemsize,
                     out.view(np.uint32).reshape(n, 512 * et.ncomp), out, magnitudes, status,
                     True if flags & COMPRESS_BLOSC else None, threads=threads_for(len(ids)))

    for a in range(0, n, BLOCK_LEAVES):
        ids = np.arange(a, min(n, a + BLOCK_LEAVES))
        if not double:
            packed = ids[chunk_len[ids] > 0] if zip_pool else ids[:0]
            pool, pool_start = _pool_for(packed, nbytes, n)
            _inflate(cur, t, packed, pool, pool_start, nbytes, flags, et)
        run(ids, pool, pool_start)
        if not double and ids[-1] + 1 < n:
            _release(cur.buf, int(chunk_off[ids[-1] + 1]))
    declined = np.nonzero(status)[0]
    if len(declined):  # frames the compiled decoder would not take: the blosc module decides
        pool, pool_start = _pool_for(declined, nbytes, n)
        _decompress_all(cur, t, declined, pool, pool_start, flags, et)
        run(declined, pool, pool_start)
    return out


def _inflate(cur, t, packed, pool, pool_start, nbytes, flags, et):
    """Zip chunks of ``packed`` into the pool (C zlib from a compiled loop where found), the rest
    (and blosc without numba) by the Python modules."""
    left = packed
    if flags & COMPRESS_ZIP and len(packed):
        st = inflate_all(cur.arr, packed, t["chunk_off"], t["chunk_len"], nbytes, pool, pool_start,
                         threads_for(len(packed)))
        if st is not None:
            left = packed[st[packed] != 0]
    _decompress_all(cur, t, left, pool, pool_start, flags, et)


def _release(buf, upto):
    """Hand back the mapped file pages wholly before byte ``upto`` (read again from the page cache
    if touched later): the mapping's resident size stays one block, not the whole file."""
    madvise = getattr(buf, "madvise", None)
    dontneed = getattr(mmap, "MADV_DONTNEED", None)
    if madvise is None or dontneed is None:
        return
    end = upto - upto % mmap.PAGESIZE
    if end > 0:
        madvise(dontneed, 0, end)
