"""Compiled chunk decompression, so leaf chunks inflate inside the parallel decode loop instead of
one Python call per leaf (~4 us each, most of a big blosc read).

- blosc1 frames holding LZ4 (what OpenVDB writes): decoded here, written for numba from the blosc1
  frame layout and the LZ4 block format. The blosc wheel keeps its C functions private (only
  PyInit is exported), so there is nothing to call through ctypes.
- zlib: the C library's ``uncompress`` through ctypes, where one can be found and passes a
  self-test; a pointer call from a compiled loop, no Python per chunk.

Every decoder here *declines* (returns a negative status) rather than guess: on anything it does
not handle or that breaks a rule of the format, the caller decompresses that chunk through the
Python modules instead, which give the same bytes or raise the usual VDBFormatError. So this module
can make reading faster but never changes a result or an error. Nothing here writes outside the
destination range it is given: every copy is bounds-checked first.
"""

import ctypes
import ctypes.util
import sys

import numpy as np

from ..jit import HAVE_NUMBA, njit, parallel_for

if HAVE_NUMBA:
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic
else:  # pragma: no cover - without numba these would run as (slow) Python: unused
    def intrinsic(f):
        return f

DECLINED = -1
_FRAME_HEADER = 16    # blosc1 header bytes (BLOSC_MAX_OVERHEAD)
_MAX_SPLITS = 16      # blosc1 splits a block into typesize streams only up to this typesize...
_MIN_SPLIT = 128      # ...and only when the block holds at least this many elements


@njit(cache=True, nogil=True, inline="always")
def _le32(src, p):
    return (np.int64(src[p]) | (np.int64(src[p + 1]) << 8) | (np.int64(src[p + 2]) << 16)
            | (np.int64(src[p + 3]) << 24))


@intrinsic
def copy_bytes(typingctx, dst, d, src, s, n):
    """memcpy(dst.data + d, src.data + s, n) on 1-D uint8 arrays. The caller checks the bounds and
    that the two ranges do not overlap; byte loops in numba run at ~1 byte/ns, this at memcpy speed."""
    sig = types.void(dst, d, src, s, n)

    def codegen(context, builder, signature, args):
        da = context.make_array(signature.args[0])(context, builder, args[0])
        sa = context.make_array(signature.args[2])(context, builder, args[2])
        cgutils.raw_memcpy(builder, builder.gep(da.data, [args[1]]), builder.gep(sa.data, [args[3]]),
                           args[4], 1)
        return context.get_dummy_value()
    return sig, codegen


@intrinsic
def _copy8(typingctx, dst, d, src, s):
    """Copy the 8 bytes src[s:s+8] to dst[d:d+8] as one unaligned 64-bit load and store (the
    caller checks both ranges lie inside the arrays)."""
    sig = types.void(dst, d, src, s)

    def codegen(context, builder, signature, args):
        da = context.make_array(signature.args[0])(context, builder, args[0])
        sa = context.make_array(signature.args[2])(context, builder, args[2])
        i64p = ir.IntType(64).as_pointer()
        v = builder.load(builder.bitcast(builder.gep(sa.data, [args[3]]), i64p), align=1)
        builder.store(v, builder.bitcast(builder.gep(da.data, [args[1]]), i64p), align=1)
        return context.get_dummy_value()
    return sig, codegen


@njit(cache=True, nogil=True, inline="always")
def _length(src, ip, iend, n):
    """Add an LZ4 length continuation (bytes of 255, then the last one) to n: (n, ip), or
    (-1, ip) when the input ends first."""
    while True:
        if ip >= iend:
            return -1, ip
        b = src[ip]
        ip += 1
        n += b
        if b != 255:
            return n, ip


@njit(cache=True, nogil=True)
def lz4_block(src, ip, iend, dst, op, oend):
    """Decode the LZ4 block src[ip:iend] into exactly dst[op:oend]; 0 on success, else DECLINED.

    Accepts only blocks that follow the format's end rules (the last sequence is literals only,
    ending the input; a match never starts closer than 12 bytes to the output end nor covers its
    last 5), which are the blocks LZ4's own safe decoder accepts, so both give the same bytes.
    Short copies go 8 bytes at a time and may write up to 7 bytes past their end (never past
    dst's end, only over bytes decoded later) and read past it (never past src's end).
    """
    obase = op
    slen = src.shape[0]
    dlen = dst.shape[0]
    if ip >= iend or op >= oend:
        return DECLINED
    while ip < iend:
        token = src[ip]
        ip += 1
        n = np.int64(token >> 4)
        if n == 15:
            n, ip = _length(src, ip, iend, n)
            if n < 0:
                return DECLINED
        if n > iend - ip or n > oend - op:
            return DECLINED
        if n <= 16 and ip + 16 <= slen and op + 16 <= dlen:
            _copy8(dst, op, src, ip)
            _copy8(dst, op + 8, src, ip + 8)
        else:
            copy_bytes(dst, op, src, ip, n)
        ip += n
        op += n
        if ip == iend:  # the last sequence: its literals must fill the output exactly
            return 0 if op == oend else DECLINED
        if op > oend - 12 or ip > iend - 8:
            return DECLINED  # a match this close to either end breaks the format's end rules
        off = np.int64(src[ip]) | (np.int64(src[ip + 1]) << 8)
        ip += 2
        if off == 0 or off > op - obase:
            return DECLINED
        n = np.int64(token & 15)
        if n == 15:
            n, ip = _length(src, ip, iend, n)
            if n < 0:
                return DECLINED
        n += 4
        if n > oend - 5 - op:
            return DECLINED  # the last 5 output bytes are always literals
        m = op - off
        if off >= 8 and op + n + 8 <= dlen:  # each 8-byte piece reads only bytes already written
            for k in range(0, n, 8):
                _copy8(dst, op + k, dst, m + k)
        elif off >= n:
            copy_bytes(dst, op, dst, m, n)
        else:  # overlapping: the match repeats its last ``off`` bytes, byte by byte
            for k in range(n):
                dst[op + k] = dst[m + k]
        op += n
    return DECLINED


@njit(cache=True, nogil=True)
def blosc_frame(src, o, size, nbytes, vsize, dst, tmp):
    """Decode the blosc1 frame src[o:o+size] of ``nbytes`` bytes (values of ``vsize`` bytes).

    Returns 0: the bytes are in dst[0:nbytes]; 1: a stored ("memcpyed") frame, the bytes are
    src[o+16:o+16+nbytes], nothing copied; 2: the bytes are in tmp[0:nbytes] still byte-shuffled
    (one block of values of ``vsize`` bytes: byte k of value e at tmp[k * (nbytes // vsize) + e]),
    which the caller reads directly instead of paying an unshuffle pass; DECLINED: not LZ4,
    bit-shuffled, a layout blosc would refuse, or corrupt. dst and tmp hold >= nbytes bytes.
    """
    if size < _FRAME_HEADER or nbytes > dst.shape[0] or nbytes > tmp.shape[0]:
        return DECLINED
    flags = src[o + 2]
    ts = np.int64(src[o + 3])
    bs = _le32(src, o + 8)
    if src[o] != 2 or flags & 0x0C or _le32(src, o + 4) != nbytes or _le32(src, o + 12) != size:
        return DECLINED  # format version, bit-shuffle / future flags, sizes
    if nbytes == 0:
        return 0
    if ts < 1 or bs < 1 or bs > nbytes:
        return DECLINED
    if flags & 0x02:  # memcpyed: stored as is, unshuffled
        return 1 if size == nbytes + _FRAME_HEADER else DECLINED
    if (flags >> 5) != 1 or src[o + 1] != 1:
        return DECLINED  # only LZ4 (format 1, version 1)
    nblocks = (nbytes + bs - 1) // bs
    if nblocks > (size - _FRAME_HEADER) // 4:
        return DECLINED
    shuffle = (flags & 0x01) != 0 and ts > 1
    out = tmp if shuffle else dst
    for j in range(nblocks):
        b0 = j * bs
        bsize = min(bs, nbytes - b0)
        leftover = bsize < bs
        nsplit = ts if ((flags & 0x10) == 0 and ts <= _MAX_SPLITS and bsize // ts >= _MIN_SPLIT
                        and not leftover) else 1
        neb = bsize // nsplit
        if neb * nsplit != bsize:
            return DECLINED
        p = _le32(src, o + _FRAME_HEADER + 4 * j)  # block start, relative to the frame
        for s in range(nsplit):
            if p < 0 or p > size - 4:
                return DECLINED
            cb = _le32(src, o + p)
            p += 4
            if cb >= 2**31:
                return DECLINED  # negative as the int32 blosc reads
            if cb > size - p:
                return DECLINED
            d = b0 + s * neb
            if cb == neb:  # a stream that did not compress is stored
                copy_bytes(out, d, src, o + p, neb)
            elif lz4_block(src, o + p, o + p + cb, out, d, d + neb) != 0:
                return DECLINED
            p += cb
        if shuffle:
            if nblocks == 1 and ts == vsize and nbytes % ts == 0:
                return 2
            cnt = bsize // ts  # byte k of element e sits at k * cnt + e; a short tail stays put
            for e in range(cnt):
                for k in range(ts):
                    dst[b0 + e * ts + k] = tmp[b0 + k * cnt + e]
            for k in range(cnt * ts, bsize):
                dst[b0 + k] = tmp[b0 + k]
    return 0


# ---- zlib through ctypes -------------------------------------------------------------------------

_ULONG = np.dtype(f"u{ctypes.sizeof(ctypes.c_ulong)}")  # zlib's uLong (4 bytes on Windows)
_UNCOMPRESS = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                               ctypes.c_ulong)


@njit(cache=True, nogil=True)
def _inflate_rows(lo, hi, fn, buf, ids, chunk_off, chunk_len, nbytes, pool, pool_start, dlen, status):
    """zlib ``uncompress`` chunks ids[lo:hi], each into pool[pool_start[i]:+nbytes[i]]. status[i]
    = 0 when it gave exactly nbytes[i] bytes (Z_OK), else 1 (left to the Python path). zlib never
    writes past the dlen it is given, and dlen is the slot size."""
    for j in range(lo, hi):
        i = ids[j]
        dlen[i] = nbytes[i]
        r = fn(pool.ctypes.data + pool_start[i], dlen.ctypes.data + i * dlen.itemsize,
               buf.ctypes.data + chunk_off[i], chunk_len[i])
        status[i] = 0 if (r == 0 and dlen[i] == nbytes[i]) else 1


def _find_uncompress():
    """A CFUNCTYPE for zlib's uncompress, or None. Never raises: any trouble means 'use Python'."""
    if not HAVE_NUMBA:
        return None
    try:
        names = [ctypes.util.find_library("z"), ctypes.util.find_library("zlib")]
        if sys.platform.startswith("linux"):
            names.append("libz.so.1")
        for name in names:
            if not name:
                continue
            try:
                lib = ctypes.CDLL(name)
                return _UNCOMPRESS(ctypes.cast(lib.uncompress, ctypes.c_void_p).value)
            except (OSError, AttributeError):
                continue
    except Exception:  # pragma: no cover - find_library can fail in odd ways on odd systems
        pass
    return None


_zlib_state = []  # [] = not looked up yet; [fn or None] afterwards


def zlib_uncompress():
    """The checked zlib uncompress pointer (looked up and self-tested once), or None."""
    if not _zlib_state:
        fn = _find_uncompress()
        if fn is not None:
            try:
                import zlib
                want = np.arange(3000, dtype=np.uint16).tobytes()
                raw = np.frombuffer(bytearray(zlib.compress(want)), np.uint8)  # writable, as files map
                pool = np.zeros(len(want), np.uint8)
                status = np.ones(1, np.uint8)
                _inflate_rows(np.int64(0), np.int64(1), fn, raw, np.zeros(1, np.int64),
                              np.zeros(1, np.int64), np.array([len(raw)], np.int64),
                              np.array([len(want)], np.int64), pool, np.zeros(1, np.int64),
                              np.zeros(1, _ULONG), status)
                if status[0] != 0 or pool.tobytes() != want:
                    fn = None
            except Exception:
                fn = None
        _zlib_state.append(fn)
    return _zlib_state[0]


def inflate_all(buf, ids, chunk_off, chunk_len, nbytes, pool, pool_start, threads=None):
    """Compiled zlib pass over chunks ``ids`` on ``threads`` (parallel_for's); returns per-leaf
    status (1 = do it in Python), or None when no C zlib is usable here."""
    fn = zlib_uncompress()
    if fn is None:
        return None
    n = len(chunk_off)
    status = np.ones(n, np.uint8)
    parallel_for(_inflate_rows, len(ids), fn, buf, ids, chunk_off, chunk_len, nbytes, pool, pool_start,
                 np.zeros(n, _ULONG), status, threads=threads)
    return status
