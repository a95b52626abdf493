"""A frame's set-up arrays, made by the CPU device's begin_frame from the synced scene: the
Gaussians' per-frame weights and colours, the second mixture's weights, the cells' empty-space
skips, the screen-tile lists and the lit volumes' shadow grids. What a mode needs of them its
entry in modes.py says (field, draws, screen_tiles)."""
from __future__ import annotations

import numpy as np

from ..inputs import packing
from ..inputs.accel import tile_budget
from ..inputs.layout import LS_COLOR, LS_CONST, LS_PLANE, LS_RANGE, Kind
from ..scene.transfer import range_alpha
from .modes import VOXELS

MAX_TILE_ENTRIES = 24_000_000  # screen-tile list entries per frame (id + pixel mask: 288 MB)


def gauss_weights(acc, field, tfs, obj_tf, obj_kind, obj_ls, obj_ctf=None):
    """Per-Gaussian extinction scale (particles/paper: density * alpha(v) * a; level sets:
    density * a) and colour (a volume coloured by a second grid: its colour map at the
    second grid's value), or with ``field`` the field weights (v * a; level sets: a)."""
    from ..cpu.pieces import lut_rows  # (numba: loaded once the cache folder is chosen)

    A = acc
    m = A.g_val.shape[0]
    w = np.zeros(m)
    col = np.zeros((m, 3))
    for k in range(len(obj_tf)):
        s = slice(A.g_first[k], A.g_first[k + 1])
        if s.stop == s.start:
            continue
        t = tfs[obj_tf[k]]
        v, a = A.g_val[s], A.g_amp[s]
        if field:
            w[s] = a if obj_kind[k] else np.nan_to_num(v) * a
            continue
        if obj_kind[k]:
            w[s] = t.density * a
            ls = obj_ls[k]
            if ls[LS_CONST] > 0.5:
                col[s] = ls[LS_COLOR:LS_COLOR + 3]
            else:
                c = A.g_mu[s] @ ls[LS_PLANE:LS_PLANE + 3] + ls[LS_PLANE + 3]
                lo, hi = ls[LS_RANGE], ls[LS_RANGE + 1]
                x = (c - lo) / (hi - lo) if hi > lo else np.full(c.shape, 0.5)
                lut_rows(t.lut, x, col[s])
        else:
            rgba = np.empty((v.shape[0], 4))
            lut_rows(t.lut, np.where(np.isnan(v), np.nan, t.normalize(v)), rgba)
            w[s] = t.density * rgba[:, 3] * a
            col[s] = rgba[:, :3]
            if obj_ctf is not None and obj_ctf[k] >= 0:
                ct, cv = tfs[obj_ctf[k]], A.g_cval[s]
                lut_rows(ct.lut, np.where(np.isnan(cv), np.nan, ct.normalize(cv)), rgba)
                col[s] = rgba[:, :3]
    return w, col


def color_weights(acc, objects):
    """The second mixture's field weights (second value x amplitude): the volumes coloured by a
    grid (less its background objects.cbg, the mixture where no Gaussian is, as the reference's
    voxels), the surfaces' signed distances (Objects.sdf); zero elsewhere; None if none."""
    sel = np.flatnonzero((objects.ctf >= 0) | (objects.sdf != 0))
    if not sel.size:
        return None
    A = acc
    cw = np.zeros(A.g_val.shape[0])
    for k in sel:
        s = slice(A.g_first[k], A.g_first[k + 1])
        cv = A.g_cval[s]
        cw[s] = np.where(np.isnan(cv), 0.0, cv - objects.cbg[k] * (objects.ctf[k] >= 0)) * A.g_amp[s]
    return cw


def cell_skip(spec, acc, w, tfs, obj_tf, obj_kind):
    """Per leaf cell, 1 where nothing in it can show: voxels whose value range the transfer
    function makes transparent, Gaussians of zero weight, or (field) a summed field bounded to
    transparent values; surfaces are never skipped."""
    c = acc.n_cells
    if c == 0:
        return np.zeros(1, np.uint8)
    if spec.draws == VOXELS:
        skip = np.zeros(c, np.uint8)
        cell_obj = acc.cell_obj
        for k in range(len(obj_tf)):
            sel = cell_obj == k
            t = tfs[obj_tf[k]]
            if obj_kind[k] == Kind.SURFACE:
                continue
            if obj_kind[k]:
                skip[sel] = t.density <= 0
            else:
                skip[sel] = (range_alpha(t, acc.brick_lo[sel], acc.brick_hi[sel]) <= 0) | (t.density <= 0)
        return skip
    items = acc.cell_items
    starts = acc.cell_start[:-1]
    if not spec.field:
        mx = np.maximum.reduceat(np.abs(w[items]), starts)
        return (mx <= 0).astype(np.uint8)
    # field: bound the summed field per cell: [sum of negative weights, sum of positive]
    wi = w[items]
    lo = np.add.reduceat(np.minimum(wi, 0.0), starts)
    hi = np.add.reduceat(np.maximum(wi, 0.0), starts)
    cobj = acc.g_obj[items[starts]]
    skip = np.zeros(c, np.uint8)
    for k in range(len(obj_tf)):
        sel = cobj == k
        t = tfs[obj_tf[k]]
        if obj_kind[k] == Kind.SURFACE:
            skip[sel] = hi[sel] <= 0
        elif obj_kind[k]:
            skip[sel] = (t.density <= 0) | (hi[sel] <= 0)
        else:
            skip[sel] = (range_alpha(t, lo[sel], hi[sel]) <= 0) | (t.density <= 0)
    return skip


def screen_tiles(spec, scene, camera, acc, g_w, enabled=True, elsewhere=False):
    """Per-frame screen-tile lists for the modes that draw from them (cpu.tiles): starts, ids,
    pixel masks and each Gaussian's entry bound; or empty arrays and no bounds (the kernels then
    walk the leaf hierarchy) when the mode has none or the lists would pass accel.tile_budget (a
    camera inside a dense volume puts every support near the eye plane in every tile).
    ``enabled`` False: none (the leaf walk); ``elsewhere``: the caller builds the lists (empty
    arrays, zero bounds: no leaf walk either)."""
    from ..cpu import tiles as _cpu_tiles  # (numba: loaded once the cache folder is chosen)

    none = packing.NO_TILES + (None,)
    m = acc.g_mu.shape[0]
    if not enabled or m == 0 or not spec.screen_tiles:
        return none
    if elsewhere:
        return packing.NO_TILES + (np.zeros(m),)
    i2w = [np.asarray(o.matrix_world, np.float64) for o in scene.objects]
    tiles = _cpu_tiles.screen_tiles(camera.packed(), i2w, acc.g_mu, acc.g_inv, acc.g_obj, g_w,
                                    float(scene.support_k), tile_budget(m, MAX_TILE_ENTRIES))
    return none if tiles is None else tiles


def shadow_grids(voxels, scene, index_box, objects, gauss, wext, accel, transfer):
    """The shadowed lit volumes' grids of optical depth towards each light (cpu.lit): points
    SHADOW_POINTS along each object's longest index axis (index_box: the objects' index boxes),
    shadow rays through the voxels (``voxels``) or the Gaussians with the particles' extinction
    weights ``wext`` (closed form). The objects with them."""
    from ..cpu import lit as _cpu_lit

    grid, pts, owner = _cpu_lit.shadow_points(index_box, objects.lit, len(scene.objects),
                                              transfer.lights.shape[0])
    nl = transfer.lights.shape[0]
    tau = np.zeros((pts.shape[0], nl))
    i2w = np.stack([np.asarray(o.matrix_world, np.float64) for o in scene.objects])
    _cpu_lit.shadow_grid(voxels, owner, pts, i2w, gauss, wext, objects, accel, transfer, tau)
    return objects._replace(sh_grid=grid, sh_tau=tau.ravel())
