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

import collections

import numpy as np

from ..jit import njit, parallel_for
from ..vdb.griddata import GridData
from .error_pairs import chunk_pairs, distinct_sigmas, group_boxes
from .mixture import _NO_LATTICE, DEFAULT_K, _eval_cells, axis_tables, mixture_chunks

SPACINGS = (1, 2, 4, 8)
STEP = 1.0  # a ray step of one lattice cell resolves the field: the lattice follows the Gaussians' scale
OFF = 1 << 20  # the cell key's offset (error_pairs._key)
MAX_CELLS = 1 << 22  # 8^3 cells of the lattice (16 GB of float64 sums would be far past it)
DENSE_CELLS = 1 << 27  # the cells' common box marked densely up to this many (128 MB of bools)
CHUNK = 8192  # cells summed at a time: bounds the pair lists (a few hundred a cell at High)


def auto_spacing(gset):
    """The lattice spacing that follows the LOD: the largest power of two (at most 8) with at
    least 1.2 lattice cells a sigma for the Gaussians that stand for 90% of the voxels (their
    smallest sigma, the 10% quantile over the voxels they stand for: Low 4 where its leaves are
    dense, 2 where many are partial; Medium and High 1). Weighted by voxels, not counted: a LOD's
    many small Gaussians on sparse edges would otherwise set the lattice for its few large ones
    that fill the volume."""
    sig = np.asarray(gset.sigmas).reshape(-1, 3)
    vox = getattr(gset, "voxels", None)
    vox = np.zeros(0, np.int64) if vox is None else np.asarray(vox)
    below, total = _weight_below(sig, vox, np.asarray(SPACINGS, np.float64))
    # the quantile q passes spacing sp (q / 1.2 >= sp) when the Gaussians below sp weigh < 10%
    return max(sp for sp, b in zip(SPACINGS, below) if sp == 1 or b < 0.1 * total)


@njit(cache=True)
def _weight_below(sigmas, vox, spacings):
    """The voxels (at least 1 a Gaussian; 1 each without vox) of the Gaussians whose smallest
    sigma / 1.2 is below each spacing, and of all: one pass, no sort (21 M sigmas at High, 4x
    MNI). Sums of whole numbers: exact in any order."""
    below = np.zeros(spacings.shape[0])
    total = 0.0
    for g in range(sigmas.shape[0]):
        m = min(np.float64(sigmas[g, 0]), np.float64(sigmas[g, 1]), np.float64(sigmas[g, 2])) / 1.2
        w = max(np.float64(vox[g]), 1.0) if vox.shape[0] else 1.0
        total += w
        for j in range(spacings.shape[0]):
            if m < spacings[j]:
                below[j] += w
    return below, total


def _fill_keys(lo, hi, start, keys):
    """keys[start[g]:start[g + 1]] = the keys of box g's cells (x, then y, then z), boxes on threads."""
    parallel_for(_box_rows, lo.shape[0], lo, hi, start, keys)


@njit(cache=True, nogil=True)
def _box_rows(g0, g1, lo, hi, start, keys):
    for g in range(g0, g1):
        n = start[g]
        for x in range(lo[g, 0], hi[g, 0] + 1):
            for y in range(lo[g, 1], hi[g, 1] + 1):
                for z in range(lo[g, 2], hi[g, 2] + 1):
                    keys[n] = ((x + OFF) << 42) | ((y + OFF) << 21) | (z + OFF)
                    n += 1


def _box_keys(lo, hi, dense=DENSE_CELLS):
    """The sorted keys of the cells in the union of the boxes [lo, hi] (int64 (n, 3)): marked in
    a dense array over their common box where it is small (no sort), else listed and
    de-duplicated."""
    if not len(lo):
        return np.zeros(0, np.int64)
    base = lo.min(axis=0)
    dims = hi.max(axis=0) - base + 1
    if np.prod(dims.astype(np.float64)) <= dense:
        occ = np.zeros(tuple(dims), np.bool_)
        _mark_boxes(lo, hi, base, occ)
        xyz = np.argwhere(occ) + base  # C order: x, then y, then z, the keys' order
        return ((xyz[:, 0] + OFF) << 42) | ((xyz[:, 1] + OFF) << 21) | (xyz[:, 2] + OFF)
    cnt = np.prod(np.maximum(hi - lo + 1, 0).astype(np.float64), axis=1)
    if cnt.sum() > 16 * MAX_CELLS:
        raise ValueError(f"the splat grid's supports reach {cnt.sum():,.0f} cells "
                         f"(limit {16 * MAX_CELLS:,}): choose a coarser spacing")
    start = np.zeros(len(cnt) + 1, np.int64)
    np.cumsum(cnt.astype(np.int64), out=start[1:])
    keys = np.empty(int(start[-1]), np.int64)
    _fill_keys(lo, hi, start, keys)
    return np.unique(keys)


@njit(cache=True)
def _mark_boxes(lo, hi, base, occ):
    for g in range(lo.shape[0]):
        for x in range(lo[g, 0] - base[0], hi[g, 0] - base[0] + 1):
            for y in range(lo[g, 1] - base[1], hi[g, 1] - base[1] + 1):
                for z in range(lo[g, 2] - base[2], hi[g, 2] - base[2] + 1):
                    occ[x, y, z] = True


Cells = collections.namedtuple("Cells", "corg keys first end xlo xhi")
Cells.__doc__ = """A splat lattice's 8^3 cells (origins int64 (n, 3), keys; sorted by key) and each
non-empty group's Gaussians [first, end) with the cell x its box spans [xlo, xhi]."""


def _cells(gset, s, k):
    """The Cells of the boxes that hold each group's supports (the lattice centres within k sigma,
    as the pair lists count them): a group's box, not each Gaussian's, so the list before
    de-duplication stays near the groups' count; cells no support reaches come out empty and are
    dropped."""
    gstart = np.asarray(gset.group_start, np.int64)
    origins = np.asarray(gset.group_origins).reshape(-1, 3)
    lo, hi = group_boxes(origins, gstart, np.asarray(gset.offsets), np.asarray(gset.sigmas),
                          (s - 1) / 2.0, float(s), k)
    full = np.diff(gstart) > 0
    first, end, lo, hi = gstart[:-1][full], gstart[1:][full], lo[full], hi[full]
    keys = _box_keys(lo, hi)
    if len(keys) > MAX_CELLS:
        raise ValueError(f"the splat grid would hold {len(keys):,} leaves (limit {MAX_CELLS:,}): "
                         "choose a coarser spacing")
    mask = (1 << 21) - 1
    corg = np.stack([(keys >> 42) - OFF, ((keys >> 21) & mask) - OFF, (keys & mask) - OFF], axis=1) * 8
    return Cells(corg.astype(np.int64), keys, first, end, lo[:, 0], hi[:, 0])


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


def _geometry(gset, s, wv):
    """Centres and sigmas in lattice units (float64 (M, 3)) and weights value x amplitude of a
    Gaussian set (duck-typed: group origins + offsets)."""
    counts = np.diff(np.asarray(gset.group_start, np.int64))
    origins = np.asarray(gset.group_origins, np.float64).reshape(-1, 3)
    cent = (np.repeat(origins, counts, axis=0) + np.asarray(gset.offsets, np.float64) - (s - 1) / 2.0) / s
    sig = np.asarray(gset.sigmas, np.float64) / s
    return cent, sig, wv * np.asarray(gset.amplitudes, np.float64)


_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], np.int64)
_NO_REF = np.zeros((1, 512), np.float32)  # _eval_cells' reference: no voxel is active (cmask 0)


def _chunks(gset, s, wv, k, cells, chunk):
    """Per chunk of cells (sorted by key, so by x): (a, b, _eval_cells' arguments after corg,
    cmask, cref). On the voxel lattice (spacing 1), the field error's own evaluation
    (mixture.mixture_chunks: its lattice classes and axis tables); coarser, the Gaussians of the
    groups whose boxes reach the chunk's x span, in the set's order, on pair lists."""
    chunk = max(1, int(chunk))
    if s == 1 and hasattr(gset, "n_leaf_groups"):
        yield from mixture_chunks(cells.keys, cells.corg, gset, k, chunk, values=wv)
        return
    cent, sig, w = _geometry(gset, s, wv)
    tab = _axis_tables(cent, sig, k)
    corg = cells.corg
    for a in range(0, len(corg), chunk):
        b = min(len(corg), a + chunk)
        sel = (cells.xlo <= corg[b - 1, 0] >> 3) & (cells.xhi >= corg[a, 0] >> 3)
        idx = _ranges(cells.first[sel], cells.end[sel])
        cstart, pg = chunk_pairs(cent[idx], sig[idx], k, corg[a:b], cells.keys[a:b])
        ctab = tab if tab[-1] < 0 else (tab[0][idx], tab[1][idx], *tab[2:])
        yield a, b, (cstart, pg, cent[idx], sig[idx], w[idx], k, *ctab, *_NO_LATTICE)


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
    if values is None:
        ls = getattr(gset, "grid_class", None) == "level_set"
        values = np.ones(len(gset.sigmas)) if ls else gset.values
    wv = np.asarray(values)  # float32 stays so (read as float64 per Gaussian)
    if wv.dtype.kind != "f":
        wv = wv.astype(np.float64)
    if not np.isfinite(wv).all():
        wv = np.nan_to_num(wv)
    kk = float(k)
    cells = _cells(gset, s, kk)
    corg = cells.corg
    n = len(corg)
    vals = np.empty((n, 512), np.float32)
    masks = np.empty((n, 8), np.uint64)
    for a, b, args in _chunks(gset, s, wv, kk, cells, chunk):
        _eval_cells(corg[a:b], np.zeros((b - a, 8), np.uint64), _NO_REF, *args, vals[a:b], masks[a:b])
    keep = masks.any(axis=1)
    if not keep.all():
        corg, vals, masks = corg[keep], vals[keep], masks[keep]
    if background:
        vals += np.float32(background)
    m = np.asarray(getattr(gset, "index_to_world", np.eye(4)), np.float64) @ lattice_to_index(s)
    nact = int(_POPCOUNT[masks.view(np.uint8)].sum())
    lo = corg.min(axis=0) if len(corg) else np.zeros(3, np.int64)
    hi = corg.max(axis=0) + 7 if len(corg) else -np.ones(3, np.int64)
    return GridData(name=name or "splat", grid_class="fog_volume", value_type="float",
                    background=float(background),
                    file_version=0, compression="none", half=False, index_to_world=m,
                    leaf_origins=corg.astype(np.int32), leaf_masks=masks, leaf_values=vals,
                    tile_origins=np.zeros((0, 3), np.int32), tile_sizes=np.zeros(0, np.int32),
                    tile_values=np.zeros(0, np.float32), tile_active=np.zeros(0, bool),
                    active_voxels=nact, bbox_min=lo.astype(np.int64), bbox_max=hi.astype(np.int64))
