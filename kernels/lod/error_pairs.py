"""The field error's pair lists (mixture.py): which leaf cells each Gaussian's k-sigma box meets
(sorted cell keys, or a chunk's dense cell box), counted then filled on threads, grouped by cell
with a counting sort; and the groups' reach in cells (the chunks' Gaussians are gathered by
error_lattice.gather_split)."""
from __future__ import annotations

import numpy as np

from ..jit import njit, parallel_for

_OFF = np.int64(1 << 20)
LUT_CELLS = 1 << 22  # a chunk's dense cell box (int32) up to 16 MB


@njit(cache=True, inline="always")
def _key(x, y, z):
    return ((x + _OFF) << np.int64(42)) | ((y + _OFF) << np.int64(21)) | (z + _OFF)


@njit(cache=True)
def _find(keys, key):
    i = np.searchsorted(keys, key)
    if i < keys.shape[0] and keys[i] == key:
        return i
    return -1


@njit(cache=True, inline="always")
def _box(g, cent, sig, k, a):
    """Gaussian g's k-sigma box along axis a in voxels: (first, last) index."""
    r = k * sig[g, a]
    return np.int64(np.ceil(cent[g, a] - r)), np.int64(np.floor(cent[g, a] + r))


@njit(cache=True)
def _cells_of(g, cent, sig, k, keys, corg, out, pos, write):
    ix0, ix1 = _box(g, cent, sig, k, 0)
    iy0, iy1 = _box(g, cent, sig, k, 1)
    iz0, iz1 = _box(g, cent, sig, k, 2)
    if ix0 > ix1 or iy0 > iy1 or iz0 > iz1:
        return 0
    vol = ((ix1 >> 3) - (ix0 >> 3) + 1) * ((iy1 >> 3) - (iy0 >> 3) + 1) * ((iz1 >> 3) - (iz0 >> 3) + 1)
    n = 0
    if vol <= keys.shape[0]:
        for x in range(ix0 >> 3, (ix1 >> 3) + 1):
            for y in range(iy0 >> 3, (iy1 >> 3) + 1):
                for z in range(iz0 >> 3, (iz1 >> 3) + 1):
                    j = _find(keys, _key(x, y, z))
                    if j >= 0:
                        if write:
                            out[pos + n] = j
                        n += 1
    else:  # huge support (big tiles): test every cell
        for j in range(keys.shape[0]):
            if (corg[j, 0] + 7 >= ix0 and corg[j, 0] <= ix1 and corg[j, 1] + 7 >= iy0
                    and corg[j, 1] <= iy1 and corg[j, 2] + 7 >= iz0 and corg[j, 2] <= iz1):
                if write:
                    out[pos + n] = j
                n += 1
    return n


@njit(cache=True)
def _lut_cells_of(g, cent, sig, k, lut, lmin, out, pos, write):
    """_cells_of with the cells' indices in a dense box lut (cell lmin + (i, j, l) -> index or -1):
    the same cells in the same order (x, then y, then z: the key order)."""
    ix0, ix1 = _box(g, cent, sig, k, 0)
    iy0, iy1 = _box(g, cent, sig, k, 1)
    iz0, iz1 = _box(g, cent, sig, k, 2)
    if ix0 > ix1 or iy0 > iy1 or iz0 > iz1:
        return 0
    n = 0
    for x in range(max(ix0 >> 3, lmin[0]), min(ix1 >> 3, lmin[0] + lut.shape[0] - 1) + 1):
        for y in range(max(iy0 >> 3, lmin[1]), min(iy1 >> 3, lmin[1] + lut.shape[1] - 1) + 1):
            for z in range(max(iz0 >> 3, lmin[2]), min(iz1 >> 3, lmin[2] + lut.shape[2] - 1) + 1):
                j = lut[x - lmin[0], y - lmin[1], z - lmin[2]]
                if j >= 0:
                    if write:
                        out[pos + n] = j
                    n += 1
    return n


@njit(cache=True, nogil=True)
def _lut_count_rows(lo, hi, cent, sig, k, lut, lmin, start):
    """start[g + 1] = Gaussian g's cells in the dense box lut, for g in lo..hi-1."""
    dummy = np.zeros(1, np.int32)
    for g in range(lo, hi):
        start[g + 1] = _lut_cells_of(g, cent, sig, k, lut, lmin, dummy, 0, False)


@njit(cache=True, nogil=True)
def _lut_fill_rows(lo, hi, cent, sig, k, lut, lmin, start, pc):
    for g in range(lo, hi):
        _lut_cells_of(g, cent, sig, k, lut, lmin, pc, start[g], True)


def _lut_pairs(cent, sig, k, lut, lmin):
    """The pairs of a chunk of cells (lut: its cells' box): per Gaussian start, cell of each pair."""
    m = cent.shape[0]
    start = np.zeros(m + 1, np.int64)
    parallel_for(_lut_count_rows, m, cent, sig, k, lut, lmin, start)
    np.cumsum(start, out=start)
    pc = np.empty(start[m], np.int32)
    parallel_for(_lut_fill_rows, m, cent, sig, k, lut, lmin, start, pc)
    return start, pc


@njit(cache=True, nogil=True)
def _count_rows(lo, hi, cent, sig, k, keys, corg, cnt):
    dummy = np.zeros(1, np.int64)
    for g in range(lo, hi):
        cnt[g] = _cells_of(g, cent, sig, k, keys, corg, dummy, 0, False)


def _count_pairs(cent, sig, k, keys, corg):
    """Per Gaussian, the cells (of keys / corg) its k-sigma box meets."""
    cnt = np.zeros(cent.shape[0], np.int64)
    parallel_for(_count_rows, cent.shape[0], cent, sig, k, keys, corg, cnt)
    return cnt


@njit(cache=True, nogil=True)
def _fill_rows(lo, hi, cent, sig, k, keys, corg, start, out):
    for g in range(lo, hi):
        _cells_of(g, cent, sig, k, keys, corg, out, start[g], True)


def _fill_pairs(cent, sig, k, keys, corg, start, out):
    """Gaussian g's cells into out[start[g]:], in key order."""
    parallel_for(_fill_rows, cent.shape[0], cent, sig, k, keys, corg, start, out)


@njit(cache=True, nogil=True)
def _group_box_rows(lo, hi, origins, gstart, offsets, sigmas, o, s, k, glo, ghi):
    for i in range(lo, hi):
        for a in range(3):
            glo[i, a] = np.iinfo(np.int64).max
            ghi[i, a] = np.iinfo(np.int64).min
        for g in range(gstart[i], gstart[i + 1]):
            for a in range(3):
                c = (np.float64(origins[i, a]) + np.float64(offsets[g, a]) - o) / s
                r = k * (np.float64(sigmas[g, a]) / s)
                glo[i, a] = min(glo[i, a], np.int64(np.ceil(c - r)) >> 3)
                ghi[i, a] = max(ghi[i, a], np.int64(np.floor(c + r)) >> 3)


def group_boxes(origins, gstart, offsets, sigmas, o, s, k):
    """Per group, the cells (index >> 3) its Gaussians' k-sigma boxes span, as _cells_of finds
    them (lo, hi: int64 (groups, 3); lo > hi for an empty group), on a lattice of spacing s whose
    voxel j stands at s j + o (splat.py; s = 1, o = 0: the voxels themselves, the same bits)."""
    n = gstart.shape[0] - 1
    lo = np.empty((n, 3), np.int64)
    hi = np.empty((n, 3), np.int64)
    parallel_for(_group_box_rows, n, origins, gstart, offsets, sigmas, np.float64(o),
                 np.float64(s), np.float64(k), lo, hi)
    return lo, hi


@njit(cache=True)
def _by_cell(start, pc, ncell):
    """Gaussian g's cells pc[start[g]:start[g + 1]] -> (cstart, pg): the pairs grouped by cell,
    each cell's Gaussians in increasing order (a counting sort: stable, as argsort was)."""
    cstart = np.zeros(ncell + 1, np.int64)
    for p in range(pc.shape[0]):
        cstart[pc[p] + 1] += 1
    for c in range(ncell):
        cstart[c + 1] += cstart[c]
    pos = cstart[:-1].copy()
    pg = np.empty(pc.shape[0], np.int32)
    for g in range(start.shape[0] - 1):
        for p in range(start[g], start[g + 1]):
            c = pc[p]
            pg[pos[c]] = g
            pos[c] += 1
    return cstart, pg


@njit(cache=True)
def distinct_sigmas(sig, most=64):
    """The distinct values of sig (float32 (m, 3)) as float64, and False past ``most`` of them."""
    u = np.empty(most)
    n = 0
    for g in range(sig.shape[0]):
        for a in range(3):
            v = np.float64(sig[g, a])
            j = 0
            while j < n and u[j] != v:
                j += 1
            if j == n:
                if n == most:
                    return u[:n], False
                u[n] = v
                n += 1
    return u[:n], True


def chunk_pairs(cent, sig, k, corg, keys):
    """(cstart, pg): the Gaussians (indices into cent) of a chunk of cells, each cell's in
    increasing order, from a dense box of the chunk's cells when it is small, else by key search."""
    lmin = corg.min(0) >> 3
    dims = (corg.max(0) >> 3) - lmin + 1
    if np.prod(dims) <= LUT_CELLS:
        lut = np.full(tuple(dims), -1, np.int32)
        rel = (corg >> 3) - lmin
        lut[rel[:, 0], rel[:, 1], rel[:, 2]] = np.arange(len(corg), dtype=np.int32)
        start, pc = _lut_pairs(cent, sig, k, lut, lmin)
    else:
        cnt = _count_pairs(cent, sig, k, keys, corg)
        start = np.zeros(len(cnt) + 1, np.int64)
        np.cumsum(cnt, out=start[1:])
        pc = np.empty(int(start[-1]), np.int32)
        _fill_pairs(cent, sig, k, keys, corg, start, pc)
    return _by_cell(start, pc, len(corg))
