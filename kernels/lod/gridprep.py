"""Grid preparation shared by the LOD builders and the field error: the voxels Gaussians must
cover (all active ones, or a level set's shell), a NaN/Inf-free view of the grid, and the value
range over the active voxels and tiles."""
from __future__ import annotations

import copy

import numpy as np

from . import levelset, schemes


def range_of(lo, hi, tile_values):
    """(min, max) from the per-leaf lo/hi of scan_leaves and the active tiles' values; (0, 0)
    when there is nothing."""
    tv = np.asarray(tile_values, np.float64)
    lo_ = [np.inf] + ([lo.min()] if len(lo) else []) + ([tv.min()] if len(tv) else [])
    hi_ = [-np.inf] + ([hi.max()] if len(hi) else []) + ([tv.max()] if len(tv) else [])
    a, b = min(lo_), max(hi_)
    return (0.0, 0.0) if a > b else (float(a), float(b))


def active_tiles(grid):
    """Indices of the active tiles (cheap when there are none)."""
    if not len(grid.tile_values):
        return np.zeros(0, np.int64)
    return np.flatnonzero(np.asarray(grid.tile_active, bool))


def value_range(grid):
    """(min, max) over the active voxels, tiles included; (0, 0) for an empty grid."""
    n = len(grid.leaf_masks)
    lo = hi = np.zeros(0)
    if n:
        lo, hi, *_ = schemes.kernels(n)["scan"](grid.leaf_masks, grid.leaf_values,
                                                np.arange(n, dtype=np.int64), False,
                                                np.float32(0), schemes.LOW)
    return range_of(lo, hi, np.asarray(grid.tile_values)[active_tiles(grid)])


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
