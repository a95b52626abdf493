"""build_lod: GridData (duck-typed) -> GaussianSet. Orchestration only; the work is in schemes.py
(per leaf), clustering.py (merge pass), weights.py (sigma/amplitude), levelset.py (band filter)."""
from __future__ import annotations

import copy

import numpy as np

from .. import lod_names
from . import clustering, levelset, mixture, schemes
from . import weights as W
from .adaptive import adaptive_rounds
from .gaussian_set import GaussianSet
from .gridprep import active_tiles, finite_grid, range_of
from .refine import refine_amplitudes

PRESETS, WEIGHTS = lod_names.PRESETS, lod_names.WEIGHTS
DEFAULTS = dict(
    sigma_factor=W.DEFAULT_SIGMA_FACTOR,  # field weights: sigma = f x block edge
    var_spatial=4.0,  # variance scheme: max spatial variance (voxel^2, summed over axes)
    var_value=0.05,  # variance scheme: max value std, as a fraction of the value range
    merge_tol=clustering.DEFAULT_MERGE_TOL,  # merge pass: max value std / value range
    merge_base="high",  # the spatial scheme the merged preset starts from
    merge_check=True,  # field weights: undo the merges the field cannot carry (clustering.py)
    band_width=levelset.DEFAULT_BAND_WIDTH,  # level sets: |phi| <= band_width x voxel size
    tolerance=lod_names.DEFAULT_TOLERANCE,  # adaptive: max field NRMSE over the active voxels
    max_error=0.0,  # adaptive: max |field - voxel| (value units); 0: no bound
)


def leaf_order(origins):
    """Leaves sorted by origin (x, then y, then z), so the output (and its encoding) is canonical.
    Many leaves: one int64 key each and a stable sort (files are nearly in this order, where that
    is ~10x faster than lexsort on three keys); lexsort for few leaves or a span over 21 bits."""
    o = np.asarray(origins, np.int32).reshape(-1, 3)
    if len(o) >= 1024:
        rel = [o[:, k].astype(np.int64) - o[:, k].min() for k in range(3)]  # min(axis=0) is slow
        if max(r.max() for r in rel) < 1 << 21:
            return np.argsort((rel[0] << 42) | (rel[1] << 21) | rel[2], kind="stable")
    return np.lexsort((o[:, 2], o[:, 1], o[:, 0])).astype(np.int64)


def _scan(K, grid, order, band_thr, code):
    """scan_leaves over the grid; when it meets NaN/Inf (or a tile does), over a sanitized copy.
    Returns (grid, nonfinite voxels, lo, hi, kept, counts, active tile indices)."""
    thr = np.float32(band_thr if band_thr is not None else 0.0)
    lo, hi, bad, kept, counts = K["scan"](grid.leaf_masks, grid.leaf_values, order,
                                          band_thr is not None, thr, code)
    t_act = active_tiles(grid)
    if not bad.any() and np.isfinite(np.asarray(grid.tile_values)[t_act]).all():
        return grid, 0, lo, hi, kept, counts, t_act
    grid, nonfinite = finite_grid(grid)  # NaN/Inf is no density: never let it reach a Gaussian
    lo, hi, _, kept, counts = K["scan"](grid.leaf_masks, grid.leaf_values, order,
                                        band_thr is not None, thr, code)
    return grid, nonfinite, lo, hi, kept, counts, active_tiles(grid)


def _tile_boxes(grid, t_act, band_thr):
    """Active tiles t_act, one box each (so no data is omitted), sorted by origin; level sets:
    only the tiles within the band. Returns (origins int32 (T, 3), box dict as in schemes.py, or
    None when T = 0)."""
    t_or = np.asarray(grid.tile_origins, np.int32).reshape(-1, 3)[t_act]
    if not len(t_or):
        return t_or, None
    t_val = np.asarray(grid.tile_values, np.float32)[t_act]
    t_sz = np.asarray(grid.tile_sizes, np.int64)[t_act]
    if band_thr is not None:
        sel = np.abs(t_val) <= band_thr
        t_or, t_val, t_sz = t_or[sel], t_val[sel], t_sz[sel]
    o = np.lexsort((t_or[:, 2], t_or[:, 1], t_or[:, 0]))
    t_or, t_val, s = t_or[o], t_val[o], t_sz[o]
    box = dict(c2=np.repeat((s - 1)[:, None], 3, 1).astype(np.int16),
               ext=np.repeat(s[:, None], 3, 1).astype(np.int16),
               nvox=np.minimum(s ** 3, np.iinfo(np.int32).max).astype(np.int32),
               val=t_val, full_block=np.zeros(len(s), np.uint8))
    return t_or, box


def build_lod(grid, preset=lod_names.DEFAULT, weights="field", *, level_set_band=True, merge=None,
              refine=0, **thresholds) -> GaussianSet:
    """refine: amplitude-refinement iterations (field weights, non-level-set grids; see refine.py).
    0 (default) keeps a_i = V_i / ((2 pi)^1.5 sx sy sz); 2 roughly halves the NRMSE at High LOD on
    real data at the cost of ~2 exact field evaluations per iteration. Paper weights: must be 0."""
    return finish(build_steps(grid, preset, weights, level_set_band=level_set_band, merge=merge,
                              refine=refine, **thresholds))


def finish(steps):
    """Run a generator of build steps to its end: what it returns."""
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


def build_steps(grid, preset=lod_names.DEFAULT, weights="field", *, level_set_band=True, merge=None,
                refine=0, **thresholds):
    """build_lod as a generator: the adaptive preset yields (round, figures) after each of its
    rounds (adaptive.adaptive_rounds); the others yield nothing. Returns the GaussianSet."""
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
    if preset == "adaptive":
        if weights != "field" or refine:
            raise ValueError("the adaptive preset fits field weights itself (no paper weights, "
                             "no refine)")
        for key in ("tolerance", "max_error"):
            if not (np.isfinite(float(p[key])) and float(p[key]) >= 0):
                raise ValueError(f"{key} must be finite and >= 0, not {p[key]!r}")
    is_ls = grid.grid_class == "level_set"
    base = p["merge_base"] if preset == "merged" else preset
    code = schemes.SCHEME_CODES.get(base, schemes.HIGH)  # adaptive: the scan's counts go unused
    paper, scale = weights == "paper", W.sigma_scale(weights, p["sigma_factor"])
    lo_ = np.asarray(grid.leaf_origins, np.int32).reshape(-1, 3)
    order = leaf_order(lo_)
    K = schemes.kernels(len(order))
    band_thr = None  # level sets: only the band where the zero crossing can be (levelset.py)
    if is_ls and level_set_band and len(grid.leaf_masks):
        band_thr = levelset.band_threshold(grid, p["band_width"])
    grid, nonfinite, lo, hi, kept, counts, t_act = _scan(K, grid, order, band_thr, code)
    vmin, vmax = range_of(lo, hi, np.asarray(grid.tile_values)[t_act])
    vr = vmax - vmin
    thr_sp, thr_v = float(p["var_spatial"]), float(p["var_value"] * vr)
    values = grid.leaf_values
    if code == schemes.VARIANCE:
        counts = K["count"](kept, values, order, code, thr_sp, thr_v * thr_v)
    starts = np.zeros(len(counts) + 1, np.int64)
    np.cumsum(counts, out=starts[1:])
    m_leaf = int(starts[-1])
    nz = counts > 0
    n_leaf = int(np.count_nonzero(nz))
    t_or, tbox = _tile_boxes(grid, t_act, band_thr)
    nt = len(t_or)
    origins = np.concatenate([lo_[order[nz]], t_or]) if nt else lo_[order[nz]]
    params = dict(p, preset=preset, base=base, level_set_band=bool(level_set_band and is_ls),
                  band_threshold=band_thr, value_min=vmin, value_max=vmax, merged=0,
                  nonfinite_voxels=nonfinite, refine=0)
    if preset == "adaptive":
        return (yield from adaptive_rounds(grid, kept, order, lo_, t_or, tbox, tolerance=p["tolerance"],
                                           max_error=p["max_error"], scale=scale,
                                           band=params["level_set_band"], params=params))

    if preset == "merged" or merge:  # the merge pass works on boxes; Gaussians after it
        box = dict(c2=np.empty((m_leaf, 3), np.int16), ext=np.empty((m_leaf, 3), np.int16),
                   nvox=np.empty(m_leaf, np.int32), val=np.empty(m_leaf, np.float32),
                   full_block=np.empty(m_leaf, np.uint8))
        K["boxes"](kept, values, order, starts, code, thr_sp, thr_v * thr_v, box["c2"],
                   box["ext"], box["nvox"], box["val"], box["full_block"])
        group = np.repeat(np.arange(n_leaf, dtype=np.int64), counts[nz])
        if nt:
            box = {k: np.concatenate([box[k], tbox[k]]) for k in box}
            group = np.concatenate([group, n_leaf + np.arange(nt, dtype=np.int64)])
        boxes = _Boxes(grid, origins, n_leaf, nt, paper, scale, weights, params)
        g_m, b_m, params["merged"], centres = clustering.merge_blocks(group, origins, n_leaf, box,
                                                                      vr, p["merge_tol"])
        if params["merged"] and p["merge_check"] and not paper and not is_ls:
            cells = clustering.merge_cells(group, origins, box, centres, scale, mixture.DEFAULT_K)
            near = _leaves_in(grid, cells[1])  # where the merges can change the field
            undo = clustering.field_checked_merge(
                cells, boxes.cell_errors(group, box, near), boxes.cell_errors(g_m, b_m, near),
                mixture.nrmse_denominator(False, vmin, vmax), p["merge_tol"], len(centres))
            params["merges_undone"] = int(undo.sum())
            if undo.any():
                exclude = np.zeros(len(group), bool)
                exclude[centres[undo]] = True
                g_m, b_m, params["merged"], _ = clustering.merge_blocks(
                    group, origins, n_leaf, box, vr, p["merge_tol"], exclude)
        gs = boxes.gaussian_set(g_m, b_m)
    else:  # leaves straight into the output, tiles after them
        out = W.new_gaussians(m_leaf + nt)
        K["fill"](kept, values, order, starts, code, thr_sp, thr_v * thr_v, paper, scale, out)
        if nt:
            W.boxes_to_gaussians(tbox["c2"], tbox["ext"], tbox["nvox"], tbox["val"], tbox["full_block"],
                                 0, paper, scale, out, m_leaf)
        gcount = np.concatenate([counts[nz], np.ones(nt, np.int64)]) if nt else counts[nz]
        gs = _gaussian_set(grid, origins, gcount, out, n_leaf, scale, weights, params)
    if refine and not is_ls and gs.count:

        info = refine_amplitudes(grid, gs, refine)
        params["refine"] = refine
        params["refine_sse"] = info["sse"]
    return gs


def _gaussian_set(grid, origins, gcount, out, n_leaf, scale, weights, params):
    gstart = np.zeros(len(origins) + 1, np.int64)
    np.cumsum(gcount, out=gstart[1:])
    dist = W.level_set_distances(out) if grid.grid_class == "level_set" else None
    offsets, codes, sig, amp, vox, vals = out
    return GaussianSet(
        group_origins=origins, group_start=gstart, offsets=offsets, sigmas=sig, values=vals,
        amplitudes=amp, voxels=vox, grid_class=grid.grid_class, lod=params["preset"],
        weights=weights, index_to_world=np.asarray(grid.index_to_world, np.float64),
        background=float(grid.background), n_leaf_groups=n_leaf, size_codes=codes,
        sigma_scale=scale, params=params, distances=dist)


class _Boxes:
    """The merge pass's boxes -> Gaussians, and their field error per leaf cell."""

    def __init__(self, grid, origins, n_leaf, nt, paper, scale, weights, params):
        self.grid, self.origins, self.n_leaf, self.nt = grid, origins, n_leaf, nt
        self.paper, self.scale = paper, scale
        self.weights, self.params = weights, params

    def gaussian_set(self, group, box):
        origins, n_leaf = self.origins, self.n_leaf
        used = np.bincount(group, minlength=len(origins)) > 0
        if not used.all():  # a leaf whose blocks all went into neighbours' merged Gaussians
            remap = np.cumsum(used) - 1
            group = remap[group]
            n_leaf = int(used[:n_leaf].sum())
            origins = origins[used]
        gcount = np.bincount(group, minlength=len(origins))
        out = W.new_gaussians(len(group))
        W.boxes_to_gaussians(box["c2"], box["ext"], box["nvox"], box["val"], box["full_block"],
                             len(group) - self.nt, self.paper, self.scale, out, 0)
        return _gaussian_set(self.grid, origins, gcount, out, n_leaf, self.scale, self.weights,
                             self.params)

    def cell_errors(self, group, box, leaves):
        return mixture.cell_errors(leaves, self.gaussian_set(group, box))


def _leaves_in(grid, keys):
    """A copy of grid with only the leaves whose cell keys (mixture.cell_keys) are in keys, and no
    tiles."""
    lo = np.asarray(grid.leaf_origins, np.int64).reshape(-1, 3)
    sel = np.isin(mixture.cell_keys(lo >> 3), keys)
    sub = copy.copy(grid)
    sub.leaf_origins = np.asarray(grid.leaf_origins)[sel]
    sub.leaf_masks = np.asarray(grid.leaf_masks)[sel]
    sub.leaf_values = np.asarray(grid.leaf_values)[sel]
    sub.tile_active = np.zeros(len(grid.tile_active), bool)
    return sub
