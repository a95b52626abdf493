"""Leaf -> Gaussians for the paper's spatial schemes (low, medium, high) and the variance
clustering, in parallel over leaves, count-then-fill so the output never depends on threads.

Two passes: `scan_leaves` reads every active value once (value range, NaN/Inf check, level-set
band, Gaussians per leaf), then `fill_gaussians` writes each leaf's Gaussians straight into the
output arrays from the leaf's offset (High without any intermediate; the other schemes through a
per-task scratch of boxes). Set mask bits are visited with count-trailing-zeros in voxel order, so
sums and min/max ties come out exactly as a plain 0..511 loop gives them.

Each Gaussian is described as a box of voxels in its leaf's local coordinates:
  c2   = lo + hi per axis (twice the local centre: the centre is on the half-voxel lattice)
  ext  = hi - lo + 1 per axis (the box edge in voxels)
  nvox = active voxels represented (<= prod(ext); equal for full blocks)
  val  = mean value of those voxels
  full_block = 0 "active bbox" (Low leaf, variance cluster): paper sigma = max((hi - lo)/2, 1/2)
               1 "full block" (dense-leaf block, 2^3 block, single voxel): paper sigma = ext/2
"""
from __future__ import annotations

import functools

import numpy as np
from numba.cpython.unsafe.numbers import trailing_zeros  # LLVM cttz: no public numba API

from ..jit import njit, parallel_for
from .levelset import in_band
from .weights import gaussian_shape, put_centre, put_shape

LOW, MEDIUM, HIGH, VARIANCE = 0, 1, 2, 3
SCHEME_CODES = {"low": LOW, "medium": MEDIUM, "high": HIGH, "variance": VARIANCE}


@njit(cache=True, inline="always")
def _unpack(mask_row, bits):
    n = np.int64(0)  # (a literal 0 would reach _leaf_emit as its own signature)
    for w in range(8):
        m = mask_row[w]
        for b in range(64):
            on = ((m >> np.uint64(b)) & np.uint64(1)) != 0
            bits[w * 64 + b] = on
            n += on
    return n


@njit(cache=True, inline="always")
def _put(write, k, c2, ext, nvox, val, full_block, lx, ly, lz, hx, hy, hz, n, s):
    if write:
        c2[k, 0] = lx + hx
        c2[k, 1] = ly + hy
        c2[k, 2] = lz + hz
        ext[k, 0] = hx - lx + 1
        ext[k, 1] = hy - ly + 1
        ext[k, 2] = hz - lz + 1
        nvox[k] = n
        val[k] = s / n
        full_block[k] = 0 if (n < (hx - lx + 1) * (hy - ly + 1) * (hz - lz + 1)) else 1


@njit(cache=True)
def _block(write, k, c2, ext, nvox, val, full_block, bits, vals, x0, y0, z0, e):
    """One e^3 block at (x0, y0, z0); all voxels known active (dense leaf or full 2^3 cell)."""
    s = 0.0
    for x in range(x0, x0 + e):
        for y in range(y0, y0 + e):
            for z in range(z0, z0 + e):
                s += vals[x * 64 + y * 8 + z]
    _put(write, k, c2, ext, nvox, val, full_block, x0, y0, z0, x0 + e - 1, y0 + e - 1, z0 + e - 1,
         e * e * e, s)
    if write:
        full_block[k] = 1


@njit(cache=True)
def _leaf_emit(scheme, bits, nact, vals, write, pos, c2, ext, nvox, val, full_block, thr_sp, thr_v2,
               stack):
    """Emit (write=True) or count (write=False) the Gaussians of one leaf starting at pos."""
    k = pos
    if nact == 0:
        return 0
    dense = nact == 512
    if scheme == LOW:
        lx = ly = lz = 8
        hx = hy = hz = -1
        s = 0.0
        for i in range(512):
            if bits[i]:
                x, y, z = i >> 6, (i >> 3) & 7, i & 7
                lx, ly, lz = min(lx, x), min(ly, y), min(lz, z)
                hx, hy, hz = max(hx, x), max(hy, y), max(hz, z)
                s += vals[i]
        _put(write, k, c2, ext, nvox, val, full_block, lx, ly, lz, hx, hy, hz, nact, s)
        if write:
            full_block[k] = 0  # always the bbox rule, even for a dense leaf (a sphere either way)
        return 1
    if dense and (scheme == MEDIUM or scheme == HIGH):
        e = 4 if scheme == MEDIUM else 2
        for x0 in range(0, 8, e):
            for y0 in range(0, 8, e):
                for z0 in range(0, 8, e):
                    _block(write, k, c2, ext, nvox, val, full_block, bits, vals, x0, y0, z0, e)
                    k += 1
        return k - pos
    if scheme == HIGH:  # sparse: one Gaussian per active voxel, in voxel order
        for i in range(512):
            if bits[i]:
                x, y, z = i >> 6, (i >> 3) & 7, i & 7
                _put(write, k, c2, ext, nvox, val, full_block, x, y, z, x, y, z, 1, vals[i])
                k += 1
        return k - pos
    if scheme == MEDIUM:  # sparse: aligned 2^3 cells, full -> block, else its voxels singly
        for c in range(64):
            x0, y0, z0 = (c >> 4) * 2, ((c >> 2) & 3) * 2, (c & 3) * 2
            full = True
            for x in range(x0, x0 + 2):
                for y in range(y0, y0 + 2):
                    for z in range(z0, z0 + 2):
                        if not bits[x * 64 + y * 8 + z]:
                            full = False
            if full:
                _block(write, k, c2, ext, nvox, val, full_block, bits, vals, x0, y0, z0, np.int64(2))
                k += 1
            else:
                for x in range(x0, x0 + 2):
                    for y in range(y0, y0 + 2):
                        for z in range(z0, z0 + 2):
                            i = x * 64 + y * 8 + z
                            if bits[i]:
                                _put(write, k, c2, ext, nvox, val, full_block, x, y, z, x, y, z, 1,
                                     vals[i])
                                k += 1
        return k - pos
    # VARIANCE: recursive bisection of the active voxels, explicit stack (left half first);
    # per-node sums in arrays allocated once per leaf (allocating per node was most of the time)
    for a in range(3):
        stack[0, a] = 0
        stack[0, 3 + a] = 7
    top = 1
    sp = np.empty(3)
    sp2 = np.empty(3)
    var = np.empty(3)
    tlo = np.empty(3, np.int64)
    thi = np.empty(3, np.int64)
    while top > 0:
        top -= 1
        x0, y0, z0, x1, y1, z1 = (stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3],
                                  stack[top, 4], stack[top, 5])
        n = 0
        sv = 0.0
        sv2 = 0.0
        for a in range(3):
            sp[a], sp2[a], tlo[a], thi[a] = 0.0, 0.0, 8, -1
        for x in range(x0, x1 + 1):
            for y in range(y0, y1 + 1):
                for z in range(z0, z1 + 1):
                    i = x * 64 + y * 8 + z
                    if bits[i]:
                        n += 1
                        v = np.float64(vals[i])
                        sv += v
                        sv2 += v * v
                        sp[0] += x
                        sp[1] += y
                        sp[2] += z
                        sp2[0] += x * x
                        sp2[1] += y * y
                        sp2[2] += z * z
                        tlo[0], tlo[1], tlo[2] = min(tlo[0], x), min(tlo[1], y), min(tlo[2], z)
                        thi[0], thi[1], thi[2] = max(thi[0], x), max(thi[1], y), max(thi[2], z)
        if n == 0:
            continue
        for a in range(3):  # = sp2 / n - (sp / n) ** 2, bit for bit (numba squares by a multiply)
            m = sp[a] / n
            var[a] = sp2[a] / n - m * m
        spatial = var[0] + var[1] + var[2]
        mv = sv / n
        vvar = max(sv2 / n - mv * mv, 0.0)
        if n == 1 or (spatial <= thr_sp and vvar <= thr_v2):
            _put(write, k, c2, ext, nvox, val, full_block, tlo[0], tlo[1], tlo[2], thi[0], thi[1],
                 thi[2], n, sv)
            if write:
                full_block[k] = 0
            k += 1
            continue
        ax = 0  # axis of largest spatial variance; ties -> lowest axis
        for a in range(1, 3):
            if var[a] > var[ax]:
                ax = a
        if thi[ax] == tlo[ax]:  # cannot happen for n > 1, kept as a guard
            for a in range(3):
                if thi[a] > tlo[a]:
                    ax = a
                    break
        mid = (tlo[ax] + thi[ax] + 1) // 2  # bisect the tight bbox: both halves non-empty
        # right half pushed first so the left half is processed (and emitted) first
        for a in range(3):
            stack[top, a] = tlo[a]
            stack[top, 3 + a] = thi[a]
        stack[top, ax] = mid
        top += 1
        for a in range(3):
            stack[top, a] = tlo[a]
            stack[top, 3 + a] = thi[a]
        stack[top, 3 + ax] = mid - 1
        top += 1
    return k - pos


@njit(cache=True, inline="always")
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True)
def _fast_count(mrow, scheme):
    """Gaussians of one leaf from its mask words alone (low/medium/high)."""
    n = 0
    full = True
    for w in range(8):
        n += _popcount(mrow[w])
        full = full and mrow[w] == np.uint64(0xFFFFFFFFFFFFFFFF)
    if n == 0:
        return 0
    if scheme == LOW:
        return 1
    if full:
        return 8 if scheme == MEDIUM else 64
    if scheme == HIGH:
        return n
    # MEDIUM: word w holds x = w; bit y*8+z. The aligned cell (x0, y0, z0) is full when the
    # 2x2 pattern (y0..y0+1, z0..z0+1) is set in words x0 and x0 + 1.
    k = 0
    for x0 in range(0, 8, 2):
        both = mrow[x0] & mrow[x0 + 1]
        for y0 in range(0, 8, 2):
            for z0 in range(0, 8, 2):
                pat = np.uint64(3) << np.uint64(y0 * 8 + z0)
                pat = pat | (pat << np.uint64(8))
                if (both & pat) == pat:
                    k += 1
                else:
                    k += _popcount(mrow[x0] & pat) + _popcount(mrow[x0 + 1] & pat)
    return k


FULL = np.uint64(0xFFFFFFFFFFFFFFFF)
FLT_MAX = np.float32(3.4028235e38)


def scan_leaves(masks, values, order, band, thr, scheme, threads=None):
    """The one full read of the active values. Leaf i of the canonical order is order[i]. Returns
    lo, hi: float64 per leaf (file order): min / max of its active values (NaN ignored, +-inf when
      none), what value_range reduces;
    bad: bool per i: an active value is NaN or +-Inf (the caller sanitizes and scans again);
    kept: uint64 (n, 8) per i: the voxels to cover (active, and in the level-set band if band);
    counts: int64 per i: Gaussians of the mask-only schemes (variance: see count_leaves)."""
    n = order.shape[0]
    lo = np.full(masks.shape[0], np.inf)
    hi = np.full(masks.shape[0], -np.inf)
    bad = np.zeros(n, np.bool_)
    kept = np.empty((n, 8), np.uint64)
    counts = np.zeros(n, np.int64)
    parallel_for(_scan_rows, n, masks, values, order, band, thr, np.int64(scheme), lo, hi,
                 bad, kept, counts, threads=threads)
    return lo, hi, bad, kept, counts


@njit(cache=True, nogil=True)
def _scan_rows(i0, i1, masks, values, order, band, thr, scheme, lo, hi, bad, kept, counts):
    for i in range(i0, i1):
        li = order[i]
        a = np.float32(np.inf)
        c = np.float32(-np.inf)
        nf = False
        for w in range(8):
            m = masks[li, w]
            r = np.uint64(0)
            while m:
                b = trailing_zeros(m)
                m &= m - np.uint64(1)
                v = values[li, w * 64 + b]
                a, c = min(a, v), max(c, v)
                nf |= not (abs(v) <= FLT_MAX)
                r |= np.uint64(in_band(v, thr)) << b
            kept[i, w] = r if band else masks[li, w]
        lo[li], hi[li], bad[i] = a, c, nf
        if scheme != VARIANCE:
            counts[i] = _fast_count(kept[i], scheme)


def count_leaves(kept, values, order, scheme, thr_sp, thr_v2, threads=None):
    """Gaussians per leaf of the variance scheme (its splits depend on the values)."""
    n = order.shape[0]
    counts = np.zeros(n, np.int64)
    # dummy outputs: counting writes nothing
    d8, d1 = np.zeros((1, 3), np.int16), np.zeros(1, np.int32)
    df, du = np.zeros(1, np.float32), np.zeros(1, np.uint8)
    parallel_for(_count_rows, n, kept, values, order, np.int64(scheme), thr_sp,
                 thr_v2, d8, d1, df, du, counts, threads=threads)
    return counts


@njit(cache=True, nogil=True)
def _count_rows(lo, hi, kept, values, order, scheme, thr_sp, thr_v2, d8, d1, df, du, counts):
    for i in range(lo, hi):
        bits = np.empty(512, np.bool_)
        nact = _unpack(kept[i], bits)
        stack = np.empty((64, 6), np.int64)
        counts[i] = _leaf_emit(scheme, bits, nact, values[order[i]], False, np.int64(0), d8, d8, d1, df, du,
                               thr_sp, thr_v2, stack)


@njit(cache=True)
def _high_leaf(mrow, vals, k, paper, scale, out):
    """HIGH written directly: a dense leaf as 64 2^3 blocks, else one Gaussian per voxel; centres
    and values per Gaussian, then the shape (the same for the whole leaf) in one loop."""
    k0 = k
    dense = True
    for w in range(8):
        dense = dense and mrow[w] == FULL
    if dense:
        for x0 in range(0, 8, 2):
            for y0 in range(0, 8, 2):
                for z0 in range(0, 8, 2):
                    s = 0.0
                    for x in range(x0, x0 + 2):
                        for y in range(y0, y0 + 2):
                            for z in range(z0, z0 + 2):
                                s += vals[x * 64 + y * 8 + z]
                    put_centre(out, k, 2 * x0 + 1, 2 * y0 + 1, 2 * z0 + 1, np.float32(s / 8))
                    k += 1
        put_shape(out, k0, k, gaussian_shape(2, 2, 2, 1, 8.0, paper, scale), 8)
        return
    for w in range(8):
        m = mrow[w]
        while m:
            b = trailing_zeros(m)
            m &= m - np.uint64(1)
            put_centre(out, k, 2 * w, 2 * (b >> 3), 2 * (b & 7), vals[w * 64 + b])
            k += 1
    put_shape(out, k0, k, gaussian_shape(1, 1, 1, 1, 1.0, paper, scale), 1)


CHUNK = 32  # leaves per parallel task: one set of scratch arrays per task, not per leaf


def fill_gaussians(kept, values, order, starts, scheme, thr_sp, thr_v2, paper, scale, out,
                   threads=None):
    """Every leaf's Gaussians into out (see weights.new_gaussians) at rows starts[i]..., each
    with the mean of its voxels as its value (a level set's: weights.level_set_distances)."""
    n = order.shape[0]
    parallel_for(_fill_tasks, (n + CHUNK - 1) // CHUNK, kept, values, order, starts, np.int64(scheme),
                 thr_sp, thr_v2, paper, scale, out, threads=threads)


@njit(cache=True, nogil=True)
def _fill_tasks(lo, hi, kept, values, order, starts, scheme, thr_sp, thr_v2, paper, scale, out):
    n = order.shape[0]
    for t in range(lo, hi):
        bits = np.empty(512, np.bool_)
        stack = np.empty((64, 6), np.int64)
        c2 = np.empty((512, 3), np.int16)
        ext = np.empty((512, 3), np.int16)
        nvox = np.empty(512, np.int32)
        val = np.empty(512, np.float32)
        full_block = np.empty(512, np.uint8)
        for i in range(t * CHUNK, min(n, t * CHUNK + CHUNK)):
            if starts[i + 1] == starts[i]:
                continue
            if scheme == HIGH:
                _high_leaf(kept[i], values[order[i]], starts[i], paper, scale, out)
                continue
            nact = _unpack(kept[i], bits)
            cnt = _leaf_emit(scheme, bits, nact, values[order[i]], True, np.int64(0), c2, ext, nvox, val,
                             full_block, thr_sp, thr_v2, stack)
            for q in range(cnt):
                shape = gaussian_shape(ext[q, 0], ext[q, 1], ext[q, 2], full_block[q],
                                       np.float64(nvox[q]), paper, scale)
                put_centre(out, starts[i] + q, c2[q, 0], c2[q, 1], c2[q, 2], val[q])
                put_shape(out, starts[i] + q, starts[i] + q + 1, shape, nvox[q])


def fill_boxes(kept, values, order, starts, scheme, thr_sp, thr_v2, c2, ext, nvox, val, full_block,
               threads=None):
    """Every leaf's boxes (for the merge pass, which works on boxes)."""
    parallel_for(_box_rows, order.shape[0], kept, values, order, starts, np.int64(scheme),
                 thr_sp, thr_v2, c2, ext, nvox, val, full_block, threads=threads)


@njit(cache=True, nogil=True)
def _box_rows(lo, hi, kept, values, order, starts, scheme, thr_sp, thr_v2, c2, ext, nvox, val,
              full_block):
    for i in range(lo, hi):
        bits = np.empty(512, np.bool_)
        nact = _unpack(kept[i], bits)
        stack = np.empty((64, 6), np.int64)
        _leaf_emit(scheme, bits, nact, values[order[i]], True, starts[i], c2, ext, nvox, val, full_block,
                   thr_sp, thr_v2, stack)


# Small grids run on the calling thread alone (threads=1): helper threads would cost more than
# they save, and on a busy machine the last chunk can wait a time slice for one. Same kernels,
# same results.
SERIAL_BELOW = 4096  # leaves
_PAR = dict(scan=scan_leaves, count=count_leaves, fill=fill_gaussians, boxes=fill_boxes)
_SER = {k: functools.partial(f, threads=1) for k, f in _PAR.items()}


def kernels(n_leaves):
    """The scheme kernels, on the calling thread alone for small grids."""
    return _SER if n_leaves < SERIAL_BELOW else _PAR
