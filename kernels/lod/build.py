"""build_lod: GridData (duck-typed) -> GaussianSet. Orchestration only; the work is in schemes.py
(per leaf), clustering.py (merge pass), weights.py (sigma/amplitude), levelset.py (band filter)."""
from __future__ import annotations

import copy

import numpy as np
from numba import njit, prange

from . import clustering, levelset, schemes
from . import weights as W
from .gaussian_set import GaussianSet

# ordered: the paper's three spatial schemes, then the two clustering schemes
PRESETS = ("low", "medium", "high", "variance", "merged")
PRESET_LABELS = {"low": "Low", "medium": "Medium", "high": "High", "variance": "Variance",
                 "merged": "Merged"}
WEIGHTS = ("field", "paper")
DEFAULTS = dict(
    sigma_factor=W.DEFAULT_SIGMA_FACTOR,  # field weights: sigma = f x block edge
    var_spatial=4.0,  # variance scheme: max spatial variance (voxel^2, summed over axes)
    var_value=0.05,  # variance scheme: max value std, as a fraction of the value range
    merge_tol=clustering.DEFAULT_MERGE_TOL,  # merge pass: max value std / value range
    merge_base="high",  # the spatial scheme the merged preset starts from
    band_width=levelset.DEFAULT_BAND_WIDTH,  # level sets: |phi| <= band_width x voxel size
)


@njit(parallel=True, cache=True)
def _leaf_minmax(masks, values):
    n = masks.shape[0]
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    for i in prange(n):
        a, b = np.inf, -np.inf
        for w in range(8):
            m = masks[i, w]
            if m == 0:
                continue
            if m == np.uint64(0xFFFFFFFFFFFFFFFF):
                for k in range(64):
                    v = np.float64(values[i, w * 64 + k])
                    a, b = min(a, v), max(b, v)
                continue
            for k in range(64):
                if (m >> np.uint64(k)) & np.uint64(1):
                    v = np.float64(values[i, w * 64 + k])
                    a, b = min(a, v), max(b, v)
        lo[i], hi[i] = a, b
    return lo, hi


_leaf_minmax_serial = njit(cache=True)(_leaf_minmax.py_func)


def value_range(grid):
    """(min, max) over the active voxels, tiles included; (0, 0) for an empty grid."""
    lo, hi = [np.inf], [-np.inf]
    if len(grid.leaf_masks):
        f = _leaf_minmax_serial if len(grid.leaf_masks) < schemes.SERIAL_BELOW else _leaf_minmax
        a, b = f(grid.leaf_masks, grid.leaf_values)
        lo.append(a.min())
        hi.append(b.max())
    act = np.asarray(grid.tile_active, bool)
    if act.any():
        tv = np.asarray(grid.tile_values, np.float64)[act]
        lo.append(tv.min())
        hi.append(tv.max())
    a, b = min(lo), max(hi)
    return (0.0, 0.0) if a > b else (float(a), float(b))


def effective_masks(grid, level_set_band=True, band_width=levelset.DEFAULT_BAND_WIDTH):
    """The voxels the Gaussians must cover: all active ones, or the level-set shell."""
    if grid.grid_class == "level_set" and level_set_band and len(grid.leaf_masks):
        thr = levelset.band_threshold(grid, band_width)
        return levelset.band_masks(grid.leaf_masks, grid.leaf_values, np.float32(thr)), thr
    return grid.leaf_masks, None


def finite_grid(grid):
    """(grid, n): the grid itself when every active value is finite, else a copy whose NaN/Inf
    voxels and tiles are inactive (the caller's grid is untouched), with how many voxels that was."""
    from ..vdb.sanitize import count_nonfinite, sanitize_nonfinite

    if count_nonfinite(grid) == 0:
        return grid, 0
    clean = copy.copy(grid)
    return clean, sanitize_nonfinite(clean)


def build_lod(grid, preset="medium", weights="field", *, level_set_band=True, merge=None,
              refine=0, **thresholds) -> GaussianSet:
    """refine: amplitude-refinement iterations (field weights, non-level-set grids; see refine.py).
    0 (default) keeps a_i = V_i / ((2 pi)^1.5 sx sy sz); 2 roughly halves the NRMSE at High LOD on
    real data at the cost of ~2 exact field evaluations per iteration. Paper weights: must be 0."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {PRESETS}")
    if weights not in WEIGHTS:
        raise ValueError(f"unknown weights {weights!r}; choose one of {WEIGHTS}")
    bad = set(thresholds) - set(DEFAULTS)
    if bad:
        raise TypeError(f"unknown thresholds {sorted(bad)}; known: {sorted(DEFAULTS)}")
    refine = int(refine or 0)
    if refine < 0:
        raise ValueError("refine must be >= 0")
    if refine and weights == "paper":
        raise ValueError("refine is for field weights; the paper's weights stay as written")
    p = dict(DEFAULTS, **thresholds)
    grid, nonfinite = finite_grid(grid)  # NaN/Inf is no density: never let it reach a Gaussian
    is_ls = grid.grid_class == "level_set"
    vmin, vmax = value_range(grid)
    vr = vmax - vmin
    masks, band_thr = effective_masks(grid, level_set_band, p["band_width"])

    # leaves, sorted by origin so the output (and its encoding) is canonical
    lo_ = np.asarray(grid.leaf_origins, np.int32).reshape(-1, 3)
    order = np.lexsort((lo_[:, 2], lo_[:, 1], lo_[:, 0])).astype(np.int64)
    base = p["merge_base"] if preset == "merged" else preset
    thr_v = p["var_value"] * vr
    counts, box = schemes.leaf_boxes(masks, grid.leaf_values, order, base,
                                     p["var_spatial"], thr_v * thr_v)
    nz = counts > 0
    leaf_groups = lo_[order[nz]]
    group = np.repeat(np.arange(int(nz.sum()), dtype=np.int64), counts[nz])
    n_leaf = len(leaf_groups)

    # active tiles: one Gaussian each (so no data is omitted); level sets: only near zero
    t_or = np.asarray(grid.tile_origins, np.int32).reshape(-1, 3)
    t_sz = np.asarray(grid.tile_sizes, np.int64)
    t_val = np.asarray(grid.tile_values, np.float32)
    t_sel = np.asarray(grid.tile_active, bool).copy()
    if band_thr is not None:
        t_sel &= np.abs(t_val) <= band_thr
    t_idx = np.nonzero(t_sel)[0]
    t_idx = t_idx[np.lexsort((t_or[t_idx, 2], t_or[t_idx, 1], t_or[t_idx, 0]))]
    nt = len(t_idx)
    origins = np.concatenate([leaf_groups, t_or[t_idx]]).astype(np.int32)
    if nt:
        s = t_sz[t_idx]
        tbox = dict(c2=np.repeat((s - 1)[:, None], 3, 1).astype(np.int16),
                    ext=np.repeat(s[:, None], 3, 1).astype(np.int16),
                    nvox=np.minimum(s ** 3, np.iinfo(np.int32).max).astype(np.int32),
                    val=t_val[t_idx], kind=np.zeros(nt, np.uint8))
        box = {k: np.concatenate([box[k], tbox[k]]) for k in box}
        group = np.concatenate([group, n_leaf + np.arange(nt, dtype=np.int64)])

    n_merged = 0
    if preset == "merged" or merge:
        group, box, n_merged = clustering.merge_blocks(group, origins, n_leaf, box, vr,
                                                       p["merge_tol"])
        used = np.bincount(group, minlength=len(origins)) > 0
        if not used.all():  # a leaf whose blocks all went into neighbours' merged Gaussians
            remap = np.cumsum(used) - 1
            group = remap[group]
            n_leaf = int(used[:n_leaf].sum())
            origins = origins[used]

    gcount = np.bincount(group, minlength=len(origins))
    gstart = np.zeros(len(origins) + 1, np.int64)
    np.cumsum(gcount, out=gstart[1:])
    codes = W.size_codes(box["ext"], box["kind"], weights)
    scale = W.sigma_scale(weights, p["sigma_factor"])
    sig = W.sigmas_from_codes(codes, scale)
    vox_true = box["nvox"].astype(np.float64)
    if nt:  # tile volumes can exceed int32 (4096^3): amplitudes from the true count
        tmask = group >= n_leaf
        e = box["ext"][tmask].astype(np.float64)
        vox_true[tmask] = e[:, 0] * e[:, 1] * e[:, 2]
    amp = W.amplitudes(sig, vox_true, weights)
    vals = np.ones(len(group), np.float32) if is_ls else box["val"].astype(np.float32)
    params = dict(p, preset=preset, base=base, level_set_band=bool(level_set_band and is_ls),
                  band_threshold=band_thr, value_min=vmin, value_max=vmax, merged=n_merged,
                  nonfinite_voxels=nonfinite)
    gs = GaussianSet(
        group_origins=origins, group_start=gstart,
        offsets=(box["c2"].astype(np.float32) * np.float32(0.5)), sigmas=sig, values=vals,
        amplitudes=amp, voxels=box["nvox"].astype(np.int32), grid_class=grid.grid_class,
        lod=preset, weights=weights,
        index_to_world=np.asarray(grid.index_to_world, np.float64),
        background=float(grid.background), n_leaf_groups=n_leaf, size_codes=codes,
        sigma_scale=scale, params=params)
    if refine and not is_ls and gs.count:
        from .refine import refine_amplitudes

        info = refine_amplitudes(grid, gs, refine)
        params["refine"] = refine
        params["refine_sse"] = info["sse"]
    else:
        params["refine"] = 0
    return gs
