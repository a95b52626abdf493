"""The field of a Gaussian set evaluated on a lattice (a splat grid, as VTK's vtkGaussianSplatter
makes one): s(x) = sum_i v_i a_i g_i(x), the field mode's mixture (same k-sigma truncation), at the
centres of a lattice `spacing` voxels apart, stored as a sparse grid of 8^3 leaves that the voxel
renderer draws as it draws the source (trilinear, post-classified).

Why: a ray through the mixture meets every Gaussian whose support it crosses (about ten per leaf
it passes at Low, supports of 3 sigma = 1.8 leaves), and a sample of the field sums as many
terms; the splat grid holds the sum once, at the Gaussians' own scale, so a frame costs samples of
one lattice, fewer the coarser the LOD. The price is the lattice's interpolation error, measured
like every other error against the voxels.

Coarse voxel j stands at fine index position spacing * j + (spacing - 1) / 2 (the centre of the
fine voxels it covers); the grid's index-to-world says so. Voxels no support reaches stay inactive.
Per cell in parallel, each Gaussian's terms in the set's order: the result does not depend on the
thread count.
"""
from __future__ import annotations

import numpy as np

from ..jit import parallel_njit, prange
from ..vdb.griddata import GridData
from .error import DEFAULT_K, LUT_CELLS, _add_gaussian, axis_tables, gaussian_terms
from .error_pairs import _by_cell, _count_pairs, _fill_pairs, _lut_pairs, distinct_sigmas

SPACINGS = (1, 2, 4, 8)
STEP = 1.0  # a ray step of one lattice cell resolves the field: the lattice follows the Gaussians' scale
OFF = 1 << 20  # the cell key's offset (error_pairs._key)
MAX_CELLS = 1 << 22  # 8^3 cells of the lattice (16 GB of float64 sums would be far past it)
CHUNK = 8192  # cells summed at a time: bounds the pair lists (a few hundred a cell at High)


def auto_spacing(gset):
    """The lattice spacing that follows the LOD: the largest power of two (at most 8) with at
    least 1.2 lattice cells a sigma for the Gaussians that stand for 90% of the voxels (their
    smallest sigma, the 10% quantile over the voxels they stand for: Low 4 where its leaves are
    dense, 2 where many are partial; Medium and High 1). Weighted by voxels, not counted: a LOD's
    many small Gaussians on sparse edges would otherwise set the lattice for its few large ones
    that fill the volume."""
    sig = np.asarray(gset.sigmas, np.float64).reshape(-1, 3).min(axis=1)
    if len(sig) == 0:
        return 1
    vox = getattr(gset, "voxels", None)
    w = np.ones(len(sig)) if vox is None else np.maximum(np.asarray(vox, np.float64), 1.0)
    o = np.argsort(sig, kind="stable")
    cum = np.cumsum(w[o])
    s = float(sig[o][np.searchsorted(cum, 0.1 * cum[-1])]) / 1.2
    return int(max(sp for sp in SPACINGS if sp <= max(s, 1.0)))


@parallel_njit(cache=True)
def _cell_values(corg, cstart, pg, cent, sig, w, k, c2, sid, tq, te, hh, vals, masks):
    """Per cell, the mixture of its listed Gaussians at its 512 voxel centres, as float32 values
    and active masks (nonzero sums). hh >= 0: the axis terms from axis_tables' (c2, sid, tq, te,
    hh), the same bits as axis_terms."""
    k2 = k * k
    for c in prange(corg.shape[0]):
        acc = np.zeros(512)
        q = np.empty((3, 8))
        e = np.empty((3, 8))
        for p in range(cstart[c], cstart[c + 1]):
            gaussian_terms(c, pg[p], corg, cent, sig, k2, c2, sid, tq, te, hh, q, e)
            _add_gaussian(acc, w[pg[p]], k2, q, e)
        for wd in range(8):
            m = np.uint64(0)
            for b in range(64):
                v = acc[wd * 64 + b]
                vals[c, wd * 64 + b] = np.float32(v)
                if v != 0.0:
                    m |= np.uint64(1) << np.uint64(b)
            masks[c, wd] = m


@parallel_njit(cache=True)
def _fill_keys(lo, hi, start, keys):
    for g in prange(lo.shape[0]):
        n = start[g]
        for x in range(lo[g, 0], hi[g, 0] + 1):
            for y in range(lo[g, 1], hi[g, 1] + 1):
                for z in range(lo[g, 2], hi[g, 2] + 1):
                    keys[n] = ((x + OFF) << 42) | ((y + OFF) << 21) | (z + OFF)
                    n += 1


@parallel_njit(cache=True)
def _group_boxes(cent, sig, k, first, end):
    """Per group, the cells (index >> 3) its Gaussians' k-sigma boxes span: lo, hi (int64 (n, 3))."""
    n = first.shape[0]
    lo = np.empty((n, 3), np.int64)
    hi = np.empty((n, 3), np.int64)
    for i in prange(n):
        for a in range(3):
            lo[i, a] = np.iinfo(np.int64).max
            hi[i, a] = np.iinfo(np.int64).min
        for g in range(first[i], end[i]):
            for a in range(3):
                r = k * sig[g, a]
                lo[i, a] = min(lo[i, a], np.int64(np.ceil(cent[g, a] - r)) >> 3)
                hi[i, a] = max(hi[i, a], np.int64(np.floor(cent[g, a] + r)) >> 3)
    return lo, hi


def _cells(cent, sig, k, gstart):
    """The 8^3 cells (origins, int64 (n, 3), and keys, sorted by key) of the boxes that hold each
    group's supports (the voxel centres within k sigma, as the pair lists count them): a group's
    box, not each Gaussian's, so the list before de-duplication stays near the groups' count;
    cells no support reaches come out empty and are dropped. Also each non-empty group's
    Gaussians (first, end) and the cell x its box spans (lo, hi): what a chunk of cells gathers."""
    gstart = np.asarray(gstart, np.int64)
    full = np.diff(gstart) > 0
    first, end = gstart[:-1][full], gstart[1:][full]
    lo, hi = _group_boxes(cent, sig, float(k), first, end)
    cnt = np.prod(np.maximum(hi - lo + 1, 0).astype(np.float64), axis=1)
    if cnt.sum() > 16 * MAX_CELLS:
        raise ValueError(f"the splat grid's supports reach {cnt.sum():,.0f} cells "
                         f"(limit {16 * MAX_CELLS:,}): choose a coarser spacing")
    start = np.zeros(len(cnt) + 1, np.int64)
    np.cumsum(cnt.astype(np.int64), out=start[1:])
    keys = np.empty(int(start[-1]), np.int64)
    _fill_keys(lo, hi, start, keys)
    keys = np.unique(keys)
    if len(keys) > MAX_CELLS:
        raise ValueError(f"the splat grid would hold {len(keys):,} leaves (limit {MAX_CELLS:,}): "
                         "choose a coarser spacing")
    mask = (1 << 21) - 1
    corg = np.stack([(keys >> 42) - OFF, ((keys >> 21) & mask) - OFF, (keys & mask) - OFF], axis=1) * 8
    return corg.astype(np.int64), keys, (first, end, lo[:, 0], hi[:, 0])


def _axis_tables(cent, sig, k):
    """_cell_values' axis-table arguments (c2, sid, tq, te, hh): tables where every centre is on
    the half-voxel lattice with few distinct sigmas (spacing 1: every set build_lod makes), else
    none (hh = -1: exponentials)."""
    c2 = 2.0 * cent
    if len(cent) and np.array_equal(c2, np.round(c2)):
        u, few = distinct_sigmas(sig.astype(np.float32))
        tab = axis_tables(u, k) if few and np.array_equal(sig, sig.astype(np.float32)) else None
        if tab is not None:
            o = np.argsort(u)
            sid = o[np.searchsorted(u[o], sig)].astype(np.int32)
            return (c2.astype(np.int64), sid, *tab)
    return np.zeros((0, 3), np.int64), np.zeros((0, 3), np.int32), np.zeros((0, 0)), np.zeros((0, 0)), -1


def _chunk_pairs(cent, sig, k, corg, keys):
    """(cstart, pg): a chunk's cells' Gaussians (indices into cent), each cell's in increasing
    order, from a dense box of the chunk's cells when it is small, else by key search."""
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


def _centers(gset):
    """float64 (M, 3) index-space centres of a Gaussian set (duck-typed: group origins + offsets)."""
    counts = np.diff(np.asarray(gset.group_start, np.int64))
    origins = np.asarray(gset.group_origins, np.float64).reshape(-1, 3)
    return np.repeat(origins, counts, axis=0) + np.asarray(gset.offsets, np.float64)


def _ranges(first, end):
    """The concatenated index ranges [first[i], end[i]) (int64), in order."""
    cnt = end - first
    if not len(cnt):
        return np.zeros(0, np.int64)
    return np.repeat(first - np.concatenate([[0], np.cumsum(cnt)[:-1]]), cnt) + np.arange(cnt.sum())


def lattice_to_index(spacing):
    """float64 (4, 4): lattice index -> the set's index space (coarse voxel j at spacing x j +
    (spacing - 1) / 2)."""
    m = np.diag([float(spacing)] * 3 + [1.0])
    m[:3, 3] = (spacing - 1) / 2.0
    return m


def splat_grid(gset, spacing=None, k=DEFAULT_K, name=None, values=None, background=0.0, chunk=CHUNK):
    """The field of gset, sum_i values_i a_i g_i(x) (values: default the set's own, NaN as 0;
    level sets: 1, their occupancy), on a lattice of `spacing` voxels (None: auto_spacing) as a
    GridData of class fog_volume whose active voxels (those a support reaches) hold
    background + that sum; index_to_world maps lattice indices to the set's world. A second
    grid's mixture (field mode's colour grid) is values = its values - background. ``chunk``:
    cells summed at a time (bounds the memory; any value gives the same grid)."""
    s = auto_spacing(gset) if spacing is None else int(spacing)
    if s not in SPACINGS:
        raise ValueError(f"spacing must be one of {SPACINGS}, not {spacing!r}")
    o = (s - 1) / 2.0
    cent = (_centers(gset) - o) / s
    sig = np.asarray(gset.sigmas, np.float64) / s
    if values is None:
        ls = getattr(gset, "grid_class", None) == "level_set"
        values = np.ones(len(sig)) if ls else gset.values
    w = np.nan_to_num(np.asarray(values, np.float64)) * np.asarray(gset.amplitudes, np.float64)
    kk = float(k)
    corg, keys, (first, end, glo, ghi) = _cells(cent, sig, kk, gset.group_start)
    n = len(corg)
    vals = np.empty((n, 512), np.float32)
    masks = np.empty((n, 8), np.uint64)
    tab = _axis_tables(cent, sig, kk)
    # a chunk of cells (sorted by key, so by x) at a time, with the Gaussians of the groups whose
    # boxes reach its x span in the set's order: each cell sums what one list over all would
    chunk = max(1, int(chunk))
    for a in range(0, n, chunk):
        b = min(n, a + chunk)
        sel = (glo <= corg[b - 1, 0] >> 3) & (ghi >= corg[a, 0] >> 3)
        idx = _ranges(first[sel], end[sel])
        cstart, pg = _chunk_pairs(cent[idx], sig[idx], kk, corg[a:b], keys[a:b])
        ctab = tab if tab[-1] < 0 else (tab[0][idx], tab[1][idx], *tab[2:])
        _cell_values(corg[a:b], cstart, pg, cent[idx], sig[idx], w[idx], kk, *ctab, vals[a:b], masks[a:b])
    keep = masks.any(axis=1)
    corg, vals, masks = corg[keep], vals[keep], masks[keep]
    if background:
        vals += np.float32(background)
    m = np.asarray(getattr(gset, "index_to_world", np.eye(4)), np.float64) @ lattice_to_index(s)
    nact = int(np.unpackbits(masks.view(np.uint8)).sum()) if len(masks) else 0
    lo = corg.min(axis=0) if len(corg) else np.zeros(3, np.int64)
    hi = corg.max(axis=0) + 7 if len(corg) else -np.ones(3, np.int64)
    return GridData(name=name or "splat", grid_class="fog_volume", value_type="float",
                    background=float(background),
                    file_version=0, compression="none", half=False, index_to_world=m,
                    leaf_origins=corg.astype(np.int32), leaf_masks=masks, leaf_values=vals,
                    tile_origins=np.zeros((0, 3), np.int32), tile_sizes=np.zeros(0, np.int32),
                    tile_values=np.zeros(0, np.float32), tile_active=np.zeros(0, bool),
                    active_voxels=nact, bbox_min=lo.astype(np.int64), bbox_max=hi.astype(np.int64))
