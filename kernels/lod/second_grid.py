"""A second grid of the same file (a colour grid: a fire's temperature beside its density) on the
Gaussians of the first: its value at each Gaussian, and its voxels in bricks for the reference mode.

A second grid's value at a voxel is what OpenVDB's getValue gives: the leaf's value where the
grid has a leaf there, else the value of the tile holding it, else the grid's background.

The Gaussian's own value is the mean of the first grid's voxels it stands for: the kept voxels
(active, in a level set's band) inside its box (schemes.py), every voxel of a tile's box. The
box is the Gaussian's own: centre on the half-voxel lattice, edge from its size code (the code is
the edge, or edge - 1 under the paper's bbox rule, and c2 = lo + hi has the parity of edge - 1, so
the edge is the one of code, code + 1 with that parity). The second value is the mean of the
second grid's voxels over the same voxels, summed in the same voxel order.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit, parallel_for
from .levelset import band_masks

_OFF = 1 << 20  # leaf coordinates are offset into 21 bits per axis for one int64 key


def _keys(origins):
    c = (np.asarray(origins, np.int64).reshape(-1, 3) >> 3) + _OFF
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]


@njit(cache=True, inline="always")
def _key(x, y, z):
    return (((x >> 3) + _OFF) << 42) | (((y >> 3) + _OFF) << 21) | ((z >> 3) + _OFF)


@njit(cache=True, inline="always")
def _find(skeys, key):
    """Position of key in the sorted keys, or -1."""
    i = np.searchsorted(skeys, key)
    if i < skeys.shape[0] and skeys[i] == key:
        return i
    return -1


class _Lookup:
    """A grid's leaves by key (sorted) and its tiles, for _value_at."""

    def __init__(self, grid):
        keys = _keys(grid.leaf_origins)
        order = np.argsort(keys, kind="stable")
        self.skeys = np.ascontiguousarray(keys[order])
        self.order = order.astype(np.int64)
        vals = grid.leaf_values
        self.values = np.ascontiguousarray(vals if vals is not None and len(vals)
                                           else np.zeros((1, 512), np.float32), np.float32)
        self.t_lo = np.ascontiguousarray(np.asarray(grid.tile_origins, np.int64).reshape(-1, 3))
        self.t_size = np.ascontiguousarray(np.asarray(grid.tile_sizes, np.int64).reshape(-1))
        self.t_val = np.ascontiguousarray(np.asarray(grid.tile_values, np.float64).reshape(-1))
        self.background = float(grid.background or 0.0)

    def args(self):
        return self.skeys, self.order, self.values, self.t_lo, self.t_size, self.t_val, self.background


@njit(cache=True)
def _value_at(x, y, z, skeys, order, values, t_lo, t_size, t_val, bg):
    li = _find(skeys, _key(x, y, z))
    if li >= 0:
        return np.float64(values[order[li], (x & 7) * 64 + (y & 7) * 8 + (z & 7)])
    for t in range(t_lo.shape[0]):
        s = t_size[t]
        if (t_lo[t, 0] <= x < t_lo[t, 0] + s and t_lo[t, 1] <= y < t_lo[t, 1] + s
                and t_lo[t, 2] <= z < t_lo[t, 2] + s):
            return t_val[t]
    return bg


def _box_means(lo, ext, kkeys, korder, kmasks, skeys, order, values, t_lo, t_size, t_val, bg, out):
    """out[g] = mean of the second grid over the kept voxels of the first inside box g (voxel
    order x, y, z; NaN when the box holds none), boxes on threads."""
    parallel_for(_box_mean_rows, lo.shape[0], lo, ext, kkeys, korder, kmasks, skeys, order, values,
                 t_lo, t_size, t_val, bg, out)


@njit(cache=True, nogil=True)
def _box_mean_rows(g0, g1, lo, ext, kkeys, korder, kmasks, skeys, order, values, t_lo, t_size,
                   t_val, bg, out):
    for g in range(g0, g1):
        s = 0.0
        n = 0
        for x in range(lo[g, 0], lo[g, 0] + ext[g, 0]):
            for y in range(lo[g, 1], lo[g, 1] + ext[g, 1]):
                for z in range(lo[g, 2], lo[g, 2] + ext[g, 2]):
                    li = _find(kkeys, _key(x, y, z))
                    if li < 0:
                        continue
                    word = kmasks[korder[li], x & 7]
                    if (word >> np.uint64((y & 7) * 8 + (z & 7))) & np.uint64(1):
                        s += _value_at(x, y, z, skeys, order, values, t_lo, t_size, t_val, bg)
                        n += 1
        out[g] = np.float32(s / n) if n else np.float32(np.nan)


def _fill_bricks(cell_xyz, skeys, order, values, t_lo, t_size, t_val, bg, out):
    """out[c] = the 10^3 voxels 8 cell - 1 .. 8 cell + 8 of the second grid (accel.BRICK), cells
    on threads."""
    parallel_for(_brick_rows, cell_xyz.shape[0], cell_xyz, skeys, order, values, t_lo, t_size,
                 t_val, bg, out)


@njit(cache=True, nogil=True)
def _brick_rows(lo, hi, cell_xyz, skeys, order, values, t_lo, t_size, t_val, bg, out):
    for c in range(lo, hi):
        for i in range(10):
            for j in range(10):
                for k in range(10):
                    out[c, i, j, k] = np.float32(_value_at(
                        cell_xyz[c, 0] * 8 - 1 + i, cell_xyz[c, 1] * 8 - 1 + j,
                        cell_xyz[c, 2] * 8 - 1 + k, skeys, order, values, t_lo, t_size, t_val, bg))


def sample(grid, ijk):
    """The grid's values (float64) at integer index points (K, 3), as getValue gives them."""
    p = np.ascontiguousarray(np.asarray(ijk, np.int64).reshape(-1, 3))
    look = _Lookup(grid).args()
    return np.array([_value_at(x, y, z, *look) for x, y, z in p], np.float64)


def gaussian_boxes(gs):
    """(lo int64 (M, 3) absolute index, edge int64 (M, 3)) of every Gaussian's box."""
    m = gs.count
    origins = np.repeat(np.asarray(gs.group_origins, np.int64).reshape(-1, 3),
                        np.diff(np.asarray(gs.group_start, np.int64)), axis=0)
    c2 = np.rint(2.0 * np.asarray(gs.offsets, np.float64)[:m]).astype(np.int64)
    codes = gs.size_codes
    if codes is None:
        codes = np.rint(np.asarray(gs.sigmas, np.float64) / float(gs.sigma_scale))
    codes = np.asarray(codes, np.int64)[:m]
    ext = np.where((codes - c2 - 1) % 2 == 0, codes, codes + 1)
    return origins + (c2 - ext + 1) // 2, ext


def kept_masks(gs, grid):
    """The voxels ``gs`` covers of its grid: the active ones, or a level set's band as build_lod
    kept it (its threshold is in gs.params)."""
    thr = (gs.params or {}).get("band_threshold")
    if (gs.params or {}).get("level_set_band") and thr is not None:
        return band_masks(grid.leaf_masks, grid.leaf_values, np.float32(thr))
    return grid.leaf_masks


def second_values(gs, grid, second):
    """float32 (M,): the second grid's value at each Gaussian of ``gs`` (built from ``grid``),
    from the same voxels and in the same order as the Gaussian's own value."""
    m = gs.count
    out = np.empty(m, np.float32)
    if m == 0:
        return out
    lo, ext = gaussian_boxes(gs)
    look = _Lookup(second)
    n_leaf = int(np.asarray(gs.group_start)[gs.n_leaf_groups]) if gs.n_leaf_groups else 0
    if n_leaf:
        masks = kept_masks(gs, grid)
        kkeys = _keys(grid.leaf_origins)
        korder = np.argsort(kkeys, kind="stable")
        _box_means(np.ascontiguousarray(lo[:n_leaf]), np.ascontiguousarray(ext[:n_leaf]),
                   np.ascontiguousarray(kkeys[korder]), korder.astype(np.int64),
                   np.ascontiguousarray(masks, np.uint64), *look.args(), out[:n_leaf])
    for g in range(n_leaf, m):  # a tile stands for all its voxels
        out[g] = np.float32(_region_mean(look, lo[g], ext[g]))
    return out


def attach(gs, grid, second):
    """Carry the second grid on ``gs``: its values (second_values) and its background (what the
    field's colour mixture is away from the Gaussians). Returns gs."""
    gs.color_values = second_values(gs, grid, second)
    gs.color_background = float(second.background or 0.0)
    return gs


def _region_mean(look, lo, ext):
    """Mean of the second grid over the box [lo, lo + ext): its leaves inside, its tiles' overlap,
    the background for the rest (a tile's box may hold up to 4096^3 voxels)."""
    hi = lo + ext
    total = float(np.prod(ext.astype(np.float64)))
    s, covered = 0.0, 0.0
    org = ((look.skeys[:, None] >> np.array([42, 21, 0])) & ((1 << 21) - 1)) - _OFF
    org = org * 8
    inside = np.all((org >= lo) & (org + 8 <= hi), axis=1)
    if inside.any():
        s += float(look.values[look.order[inside]].astype(np.float64).sum())
        covered += 512.0 * int(inside.sum())
    for t in range(look.t_lo.shape[0]):
        a = np.maximum(look.t_lo[t], lo)
        b = np.minimum(look.t_lo[t] + look.t_size[t], hi)
        if np.all(b > a):
            n = float(np.prod((b - a).astype(np.float64)))
            s += n * look.t_val[t]
            covered += n
    s += (total - covered) * look.background
    return s / total


def object_bricks(objects, cell_obj, cell_xyz):
    """The colour grids' bricks (n_cells, 10, 10, 10) on the reference mode's cells (cell_obj:
    each cell's object) of the RenderObjects with a color_grid, zeros on the others' cells; None
    when no object has one."""
    if not any(o.color_grid is not None for o in objects) or not len(cell_obj):
        return None
    out = np.zeros((len(cell_obj), 10, 10, 10), np.float32)
    for k, o in enumerate(objects):
        sel = np.flatnonzero(cell_obj == k)
        if o.color_grid is not None and sel.size:
            out[sel] = second_bricks(np.asarray(cell_xyz)[sel], o.color_grid)
    return out


def second_bricks(cell_xyz, second):
    """float32 (n, 10, 10, 10): the second grid's voxels around each leaf cell (reference mode)."""
    cells = np.ascontiguousarray(np.asarray(cell_xyz, np.int64).reshape(-1, 3))
    out = np.empty((cells.shape[0], 10, 10, 10), np.float32)
    if cells.shape[0]:
        _fill_bricks(cells, *_Lookup(second).args(), out)
    return out
