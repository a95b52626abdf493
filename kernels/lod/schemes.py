"""Leaf -> Gaussian boxes for the paper's spatial schemes (low, medium, high) and the variance
clustering, one leaf per numba task, count-then-fill so the output never depends on threads.

Each Gaussian is described as a box of voxels in its leaf's local coordinates:
  c2   = lo + hi per axis (twice the local centre: the centre is on the half-voxel lattice)
  ext  = hi - lo + 1 per axis (the box edge in voxels)
  nvox = active voxels represented (<= prod(ext); equal for full blocks)
  val  = mean value of those voxels
  kind = 0 "active bbox" (Low leaf, variance cluster): paper sigma = max((hi - lo)/2, 1/2)
         1 "full block" (dense-leaf block, 2^3 block, single voxel): paper sigma = ext/2
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

LOW, MEDIUM, HIGH, VARIANCE = 0, 1, 2, 3
SCHEME_CODES = {"low": LOW, "medium": MEDIUM, "high": HIGH, "variance": VARIANCE}


@njit(cache=True, inline="always")
def _unpack(mask_row, bits):
    n = 0
    for w in range(8):
        m = mask_row[w]
        for b in range(64):
            on = ((m >> np.uint64(b)) & np.uint64(1)) != 0
            bits[w * 64 + b] = on
            n += on
    return n


@njit(cache=True, inline="always")
def _put(write, k, c2, ext, nvox, val, kind, lx, ly, lz, hx, hy, hz, n, s):
    if write:
        c2[k, 0] = lx + hx
        c2[k, 1] = ly + hy
        c2[k, 2] = lz + hz
        ext[k, 0] = hx - lx + 1
        ext[k, 1] = hy - ly + 1
        ext[k, 2] = hz - lz + 1
        nvox[k] = n
        val[k] = s / n
        kind[k] = 0 if (n < (hx - lx + 1) * (hy - ly + 1) * (hz - lz + 1)) else 1


@njit(cache=True)
def _block(write, k, c2, ext, nvox, val, kind, bits, vals, x0, y0, z0, e):
    """One e^3 block at (x0, y0, z0); all voxels known active (dense leaf or full 2^3 cell)."""
    s = 0.0
    for x in range(x0, x0 + e):
        for y in range(y0, y0 + e):
            for z in range(z0, z0 + e):
                s += vals[x * 64 + y * 8 + z]
    _put(write, k, c2, ext, nvox, val, kind, x0, y0, z0, x0 + e - 1, y0 + e - 1, z0 + e - 1,
         e * e * e, s)
    if write:
        kind[k] = 1


@njit(cache=True)
def _leaf_emit(scheme, bits, nact, vals, write, pos, c2, ext, nvox, val, kind, thr_sp, thr_v2,
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
        _put(write, k, c2, ext, nvox, val, kind, lx, ly, lz, hx, hy, hz, nact, s)
        if write:
            kind[k] = 0  # always the bbox rule, even for a dense leaf (a sphere either way)
        return 1
    if dense and (scheme == MEDIUM or scheme == HIGH):
        e = 4 if scheme == MEDIUM else 2
        for x0 in range(0, 8, e):
            for y0 in range(0, 8, e):
                for z0 in range(0, 8, e):
                    _block(write, k, c2, ext, nvox, val, kind, bits, vals, x0, y0, z0, e)
                    k += 1
        return k - pos
    if scheme == HIGH:  # sparse: one Gaussian per active voxel, in voxel order
        for i in range(512):
            if bits[i]:
                x, y, z = i >> 6, (i >> 3) & 7, i & 7
                _put(write, k, c2, ext, nvox, val, kind, x, y, z, x, y, z, 1, vals[i])
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
                _block(write, k, c2, ext, nvox, val, kind, bits, vals, x0, y0, z0, 2)
                k += 1
            else:
                for x in range(x0, x0 + 2):
                    for y in range(y0, y0 + 2):
                        for z in range(z0, z0 + 2):
                            i = x * 64 + y * 8 + z
                            if bits[i]:
                                _put(write, k, c2, ext, nvox, val, kind, x, y, z, x, y, z, 1,
                                     vals[i])
                                k += 1
        return k - pos
    # VARIANCE: recursive bisection of the active voxels, explicit stack (left half first)
    top = 0
    for a in range(3):
        stack[0, a] = 0
        stack[0, 3 + a] = 7
    top = 1
    while top > 0:
        top -= 1
        blo = stack[top, 0:3].copy()
        bhi = stack[top, 3:6].copy()
        n = 0
        sp = np.zeros(3)
        sp2 = np.zeros(3)
        sv = 0.0
        sv2 = 0.0
        tlo = np.full(3, 8, np.int64)
        thi = np.full(3, -1, np.int64)
        for x in range(blo[0], bhi[0] + 1):
            for y in range(blo[1], bhi[1] + 1):
                for z in range(blo[2], bhi[2] + 1):
                    i = x * 64 + y * 8 + z
                    if bits[i]:
                        n += 1
                        v = np.float64(vals[i])
                        sv += v
                        sv2 += v * v
                        p0, p1, p2 = x, y, z
                        sp[0] += p0
                        sp[1] += p1
                        sp[2] += p2
                        sp2[0] += p0 * p0
                        sp2[1] += p1 * p1
                        sp2[2] += p2 * p2
                        tlo[0], tlo[1], tlo[2] = min(tlo[0], x), min(tlo[1], y), min(tlo[2], z)
                        thi[0], thi[1], thi[2] = max(thi[0], x), max(thi[1], y), max(thi[2], z)
        if n == 0:
            continue
        var = sp2 / n - (sp / n) ** 2
        spatial = var[0] + var[1] + var[2]
        mv = sv / n
        vvar = max(sv2 / n - mv * mv, 0.0)
        if n == 1 or (spatial <= thr_sp and vvar <= thr_v2):
            _put(write, k, c2, ext, nvox, val, kind, tlo[0], tlo[1], tlo[2], thi[0], thi[1],
                 thi[2], n, sv)
            if write:
                kind[k] = 0
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


@njit(parallel=True, cache=True)
def count_leaves(masks, values, order, scheme, thr_sp, thr_v2):
    n = order.shape[0]
    counts = np.zeros(n, np.int64)
    if scheme != VARIANCE:
        for i in prange(n):
            counts[i] = _fast_count(masks[order[i]], scheme)
        return counts
    d8 = np.zeros((1, 3), np.int16)
    d1 = np.zeros(1, np.int32)
    df = np.zeros(1, np.float32)
    du = np.zeros(1, np.uint8)
    for i in prange(n):
        li = order[i]
        bits = np.empty(512, np.bool_)
        nact = _unpack(masks[li], bits)
        stack = np.empty((64, 6), np.int64)
        counts[i] = _leaf_emit(scheme, bits, nact, values[li], False, 0, d8, d8, d1, df, du,
                               thr_sp, thr_v2, stack)
    return counts


@njit(parallel=True, cache=True)
def fill_leaves(masks, values, order, starts, scheme, thr_sp, thr_v2, c2, ext, nvox, val, kind):
    n = order.shape[0]
    for i in prange(n):
        li = order[i]
        bits = np.empty(512, np.bool_)
        nact = _unpack(masks[li], bits)
        stack = np.empty((64, 6), np.int64)
        _leaf_emit(scheme, bits, nact, values[li], True, starts[i], c2, ext, nvox, val, kind,
                   thr_sp, thr_v2, stack)


# serial twins (prange runs as range): small grids skip the parallel region, whose start-up costs
# tens of ms when the other core is busy. Same code, same results.
SERIAL_BELOW = 4096  # leaves
count_leaves_serial = njit(cache=True)(count_leaves.py_func)
fill_leaves_serial = njit(cache=True)(fill_leaves.py_func)


def leaf_boxes(masks, values, order, scheme, thr_sp=0.0, thr_v2=0.0):
    """Run a scheme over the leaves in `order`. Returns (counts per leaf, dict of box arrays)."""
    code = SCHEME_CODES[scheme] if isinstance(scheme, str) else int(scheme)
    if len(order) < SERIAL_BELOW:
        count_leaves, fill_leaves = count_leaves_serial, fill_leaves_serial
    else:
        count_leaves, fill_leaves = _count_par, _fill_par
    counts = count_leaves(masks, values, order, code, float(thr_sp), float(thr_v2))
    starts = np.zeros(len(counts) + 1, np.int64)
    np.cumsum(counts, out=starts[1:])
    m = int(starts[-1])
    out = dict(c2=np.empty((m, 3), np.int16), ext=np.empty((m, 3), np.int16),
               nvox=np.empty(m, np.int32), val=np.empty(m, np.float32), kind=np.empty(m, np.uint8))
    fill_leaves(masks, values, order, starts, code, float(thr_sp), float(thr_v2), out["c2"],
                out["ext"], out["nvox"], out["val"], out["kind"])
    return counts, out


_count_par, _fill_par = count_leaves, fill_leaves
