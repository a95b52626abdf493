"""Bit-packed streams of the compact encoding (encoding.py), a 64-bit word at a time.

A stream of n unsigned values of `width` bits is the little-endian bit stream value 0 first, least
significant bit first, in ceil(n width / 8) bytes (np.packbits' bitorder="little" of the bits;
the last byte padded with 0). Values wider than `width` keep their low `width` bits. Written in
uint64 words (a value may straddle two) and read back as bytes: the same bytes on any host.

`leaf_ranges` and `leaf_streams` make the per-Gaussian streams of the leaf groups straight from
the set's arrays (no per-Gaussian int64 or float64 copies): the ranges and modes first, then
every stream in one pass.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit, parallel_for

_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)


@njit(cache=True, inline="always")
def _put(words, pos, v, width, mask):
    """OR v's low `width` bits (mask) in at bit pos of zeroed words (one spare word at the end);
    returns pos + width. All uint64 (a mix with int64 would go through float64), and without a
    branch: the bits spilling into the next word are v >> (64 - pos % 64), 0 at a word's start
    (a data-dependent branch there cost 5x)."""
    v &= mask
    wi = pos >> np.uint64(6)
    sh = pos & np.uint64(63)
    words[wi] |= v << sh
    words[wi + np.uint64(1)] |= (v >> np.uint64(1)) >> (np.uint64(63) - sh)
    return pos + width


@njit(cache=True, inline="always")
def _mask(width):
    return _ALL if width >= 64 else (np.uint64(1) << np.uint64(width)) - np.uint64(1)


@njit(cache=True, inline="always")
def _get(words, pos, width):
    wi = pos >> 6
    sh = pos & 63
    v = words[wi] >> np.uint64(sh)
    if sh + width > 64:
        v |= words[wi + 1] << np.uint64(64 - sh)
    if width < 64:
        v &= (np.uint64(1) << np.uint64(width)) - np.uint64(1)
    return v


def _words(bits):
    """Zeroed words for a stream of `bits` bits, plus one spare (a straddling write's end)."""
    return np.zeros((bits + 63) // 64 + 1, np.uint64)


def _bytes(words, bits):
    """The stream's ceil(bits / 8) bytes (little-endian words, whatever the host)."""
    return words.astype("<u8").view(np.uint8)[:(bits + 7) // 8].copy()


@njit(cache=True)
def _pack(vals, width, words):
    pos = np.uint64(0)
    w, m = np.uint64(width), _mask(width)
    for i in range(vals.shape[0]):
        pos = _put(words, pos, vals[i], w, m)


@njit(cache=True)
def _unpack(words, width, n, out):
    pos = 0
    for i in range(n):
        out[i] = np.int64(_get(words, pos, width))
        pos += width


def pack(vals, width):
    """Unsigned ints -> little-endian bit stream of `width` bits each (uint8)."""
    vals = np.asarray(vals).ravel()
    if width == 0 or len(vals) == 0:
        return np.zeros(0, np.uint8)
    bits = len(vals) * int(width)
    words = _words(bits)
    _pack(vals.astype(np.uint64), int(width), words)
    return _bytes(words, bits)


def unpack(buf, width, n):
    """pack's values back, as int64 (n of them, `width` bits each)."""
    if width == 0 or n == 0:
        return np.zeros(n, np.int64)
    buf = np.asarray(buf, np.uint8)
    nw = (n * int(width) + 63) // 64 + 1
    raw = np.zeros(nw * 8, np.uint8)
    raw[:len(buf)] = buf[:nw * 8]
    out = np.empty(n, np.int64)
    _unpack(raw.view("<u8").astype(np.uint64), int(width), n, out)
    return out


_BLOCKS = 64


@njit(cache=True, inline="always")
def _c2(off):
    """2 x offset as an int, and whether that is exact (the half-voxel lattice)."""
    o = np.float64(off)
    h = np.rint(o * 2.0)
    return np.int64(h) if h * 0.5 == o else np.int64(0), h * 0.5 == o


def leaf_ranges(offsets, codes, vox, ml):
    """Over the first ml Gaussians: (min, max) of c2 = 2 x offset, whether every centre is on
    the half-voxel lattice, (min, max) of the stored size codes (a sphere stores one), spheres,
    Gaussians whose voxels differ from the product of their codes, and the largest such count
    (-1: none). Per block of Gaussians on threads, blocks reduced here: exact in any order."""
    r = np.zeros((_BLOCKS, 8), np.int64)
    parallel_for(_range_blocks, _BLOCKS, offsets, codes, vox, np.int64(ml), r)
    return (r[:, 0].min(), r[:, 1].max(), r[:, 2].sum() == 0, r[:, 3].min(), r[:, 4].max(),
            r[:, 5].sum(), r[:, 6].sum(), r[:, 7].max())


@njit(cache=True, nogil=True)
def _range_blocks(b0, b1, offsets, codes, vox, ml, r):
    """leaf_ranges' figures of blocks b0..b1-1 (of _BLOCKS) into rows of r."""
    big, small = np.iinfo(np.int64).max, np.iinfo(np.int64).min
    for b in range(b0, b1):
        lo, hi, slo, shi, bad, nsph, nexp, vmax = big, small, big, small, 0, 0, 0, -1
        for j in range(b * ml // _BLOCKS, (b + 1) * ml // _BLOCKS):
            for a in range(3):
                h, exact = _c2(offsets[j, a])
                bad += not exact
                lo, hi = min(lo, h), max(hi, h)
            c0, c1, c2 = np.int64(codes[j, 0]), np.int64(codes[j, 1]), np.int64(codes[j, 2])
            if c0 == c1 and c1 == c2:
                nsph += 1
                slo, shi = min(slo, c0), max(shi, c0)
            else:
                slo, shi = min(slo, min(c0, min(c1, c2))), max(shi, max(c0, max(c1, c2)))
            v = np.int64(vox[j])
            if v != c0 * c1 * c2:
                nexp += 1
                vmax = max(vmax, v)
        r[b, 0], r[b, 1], r[b, 2], r[b, 3] = lo, hi, bad, slo
        r[b, 4], r[b, 5], r[b, 6], r[b, 7] = shi, nsph, nexp, vmax


@njit(cache=True)
def _fill_streams(offsets, codes, vox, ml, cmin, w_c, smin, w_s, flags, w_v, centre, sizes,
                  sflags, vflags, vexp):
    z = np.uint64(0)
    one = np.uint64(1)
    m_c, m_s, m_v = _mask(w_c), _mask(w_s), _mask(w_v)
    wc, ws, wv = np.uint64(w_c), np.uint64(w_s), np.uint64(w_v)
    rec = 3 * w_c <= 64  # a centre's three values as one record: one write, not three
    w3, m3 = np.uint64(3 * w_c), _mask(3 * w_c)
    pc = ps = pv = z
    for j in range(ml):
        if w_c and rec:
            r = z
            for a in range(3):
                r |= (np.uint64(_c2(offsets[j, a])[0] - cmin) & m_c) << (wc * np.uint64(a))
            pc = _put(centre, pc, r, w3, m3)
        elif w_c:
            for a in range(3):
                pc = _put(centre, pc, np.uint64(_c2(offsets[j, a])[0] - cmin), wc, m_c)
        c0, c1, c2 = np.int64(codes[j, 0]), np.int64(codes[j, 1]), np.int64(codes[j, 2])
        sph = c0 == c1 and c1 == c2
        if w_s:
            ps = _put(sizes, ps, np.uint64(c0 - smin), ws, m_s)
            if not sph:
                ps = _put(sizes, ps, np.uint64(c1 - smin), ws, m_s)
                ps = _put(sizes, ps, np.uint64(c2 - smin), ws, m_s)
        if flags & 1:
            _put(sflags, np.uint64(j), one if sph else z, one, one)
        v = np.int64(vox[j])
        if flags & 2 and v != c0 * c1 * c2:
            _put(vflags, np.uint64(j), one, one, one)
            if w_v:
                pv = _put(vexp, pv, np.uint64(v), wv, m_v)


def leaf_streams(offsets, codes, vox, ml, cmin, w_c, smin, w_s, nsph, sphere_flags, nexp, w_v,
                 explicit):
    """The leaf Gaussians' streams as bytes: centre (c2 - cmin, 3 each), sizes (codes - smin:
    one for a sphere, three else), sphere flags (if sphere_flags), explicit-voxel flags and
    counts (if explicit); the same bytes as pack() of each stream."""
    bits = (3 * ml * w_c, (nsph + 3 * (ml - nsph)) * w_s, ml, ml, nexp * w_v)
    out = [_words(b) for b in bits]
    _fill_streams(offsets, codes, vox, ml, cmin, w_c, smin, w_s,
                  int(sphere_flags) | 2 * int(explicit), max(w_v, 0), *out)
    return [_bytes(w, b) for w, b in zip(out, bits)]
