"""The render kernels' inputs, grouped by what they describe, and the plain-numpy code that packs a
RenderScene and a frame's set-up into them. Free of numba so that every device shares it: the CPU
kernels take these named tuples as arguments (numba passes them without allocation), a GPU device
packs the same groups into its buffers or textures.

Arrays that may be empty (no Gaussians, no voxel bricks, no tile lists) get one dummy row, so the
kernels never see a zero-length array they would have to special-case.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ...lod.levelset import surface_level
from ..devices import modes
from ..scene import clip, lights
from . import gauss_pack
from .layout import (
    LS_COLOR,
    LS_CONST,
    LS_PLANE,
    LS_RANGE,
    LS_SIZE,
    LS_VOXEL,
    PAR_LOG,
    PAR_VMAX,
    PAR_VMIN,
    REC_SIZE,
    REC_W,
    SET_BG,
    SET_K,
    SET_LIT_THRESHOLD,
    SET_PAPER_DEPTH,
    SET_PAPER_STEPS,
    SET_SHADING,
    SET_SIZE,
    SET_TAU_MAX,
    SET_TMIN,
    SHG_SIZE,
    Kind,
    Shading,
)

# Per Gaussian (index space, all objects one after the other). rec: what the per-ray test reads,
# one 64-byte row each: centre, 1/sigma, this frame's extinction weight w, the entry bound (tile
# lists); sph: a float32 bounding sphere near obj_ref; clo/chi: the leaf-cell box of its support;
# cw: the field weight of the colour grid's mixture ((colour value - its background) x amplitude;
# objects coloured by a second grid, Objects.ctf, and surfaces' signed distance x amplitude,
# Objects.sdf; one dummy row when no object is);
# grad: lit volumes in particles mode, the gradient of the other Gaussians' field at its centre
# and its own field weight (value x amplitude), one dummy row otherwise.
Gaussians = namedtuple("Gaussians", "mu inv w col val obj volfac rec sph clo chi cw grad")
# Per object: world -> index matrix, kind (layout.Kind), its transfer function's row, level-set
# colouring (ls, layout.LS), sample step in voxels, clip half-spaces (clip.pack), the float32
# reference point of the bounding spheres, shading (layout.Shading: volumes only, see
# pack_objects) and the lit volumes' shadow grids (sh_grid rows, layout.SHG; sh_tau: the optical depth
# towards each light at each grid point, light fastest; cpu.lit) and, for a volume coloured by a
# second grid, its colour map's transfer-function row (-1: coloured by its own values) and that
# grid's background (its value where no Gaussian is: the field adds it to the colour mixture);
# sdf: 1 for a surface whose Gaussians carry signed distances (their mixture is carried as the
# colour mixture is; cbg: its single-layer level, levelset.surface_level: cpu.surface.field_crossing).
Objects = namedtuple("Objects", "w2i kind tf ls step clip ref lit sh_grid sh_tau ctf cbg sdf")
# Acceleration: the leaf hierarchy (node grids, node -> cell tables: per object its leaves, then
# the grids of coarser cells that hold the larger Gaussians), the cells' Gaussian lists (and per
# entry face), this frame's empty-space skips, voxel bricks (reference mode), the longest walk,
# this frame's screen-tile lists (starts, ids, pixel masks), per walk grid its object and cell
# size in leaves, and the colour grids' voxel bricks on the same cells (reference mode; one
# dummy brick when no object has a colour grid), and per cell this frame's transparent sub-blocks
# (clear_bits; reference mode, else one zero).
Accel = namedtuple("Accel", "node_min node_dims node_off node_table node_cells cell_skip cell_start "
                            "cell_items face_start face_items cell_xyz bricks max_walk t_start "
                            "t_items t_mask walk_obj walk_scale cbricks node_box clear")
# Transfer functions (rows: the scene's, then each object's own), lights (lights.pack) and the
# scalar settings (pack_settings).
Transfer = namedtuple("Transfer", "lut par lights settings")
# The passes of the rows being drawn: rgba, depth, value (float32, the kernels round their float64)
# and segments per row (float64).
Output = namedtuple("Output", "rgba depth value segs")

# The CPU kernels' per-thread buffers (render_band allocates them): the leaf walk's intervals
# (entry, exit, object, cell), their order and boundaries, the active intervals and a piece's
# covering leaves (paper, reference), the ray per object (index space) and its clip interval, the
# walk's last cell per object, per-object sample sums, one sample and its sums, colour bounds,
# the ray state, the sweep state, a block of tile candidates and their tests, surfaces' previous
# sample per object, the world ray (origin, direction), lit volumes' field gradient per object,
# the colour grids' mixture per object and the one-fog sampler's chunk of values (cpu.fog).
Scratch = namedtuple("Scratch", "iv_ta iv_tb iv_obj iv_cell srt bnd act_iv cov_obj cov_cell ro rd "
                                "rclip lastc svals sact samp acc cb st qs fs cand blk sprev wr sgrad "
                                "cvals fog")
# Per-ray hits (particles, field), grown on demand: records, Gaussian ids, the entry queue (times,
# keys, hits), the active set (field; particles: the members carried over), the members.
Hits = namedtuple("Hits", "rec hid ev_t ev_k ev_h act mem")

def pack_settings(scene) -> np.ndarray:
    """layout.SET: T_min, tau_max, k, background rgba, paper_steps, paper_max_depth, Blinn-Phong
    shading (ambient, diffuse, specular, shininess), lit volumes' gradient threshold."""
    bg = np.asarray(scene.background, np.float64).ravel()
    out = np.zeros(SET_SIZE)
    out[SET_TMIN] = max(float(scene.transmittance_min), 0.0)
    out[SET_TAU_MAX] = float(scene.tau_max)
    out[SET_K] = float(scene.support_k)
    out[SET_BG:SET_BG + 4] = np.concatenate([bg, [1.0] * (4 - bg.size)])[:4]
    out[SET_PAPER_STEPS] = float(scene.paper_steps)
    out[SET_PAPER_DEPTH] = float(scene.paper_max_depth)
    out[SET_SHADING:SET_SHADING + 4] = [float(v) for v in scene.shading]
    out[SET_LIT_THRESHOLD] = float(scene.lit_threshold)
    return out


def transfer_functions(scene, tf, resample):
    """The frame's transfer functions (the scene's first, then each object's own, resampled to
    the kernels' table size) and each object's row among them."""
    tfs = [tf]
    obj_tf = np.zeros(len(scene.objects), np.int32)
    for k, o in enumerate(scene.objects):
        if o.tf is not None:
            tfs.append(o.tf)
            obj_tf[k] = len(tfs) - 1
    return [resample(t) for t in tfs], obj_tf


def color_functions(scene, tfs, resample):
    """Append the colour maps of the volumes coloured by a second grid (RenderObject.color_tf)
    to the frame's transfer functions ``tfs``; returns each object's row (-1: none)."""
    obj_ctf = np.full(len(scene.objects), -1, np.int32)
    for k, o in enumerate(scene.objects):
        if o.color_tf is not None and not o.is_level_set:
            tfs.append(resample(o.color_tf))
            obj_ctf[k] = len(tfs) - 1
    return obj_ctf


def pack_transfer(scene, tfs) -> Transfer:
    lut = np.ascontiguousarray(np.stack([t.lut.astype(np.float64) for t in tfs]))
    par = np.stack([t.packed() for t in tfs])
    return Transfer(lut, par, lights.pack(scene.lights), pack_settings(scene))


def pack_objects(scene, obj_tf, w2i, coord_range, voxel_world, obj_ref, obj_ctf=None) -> Objects:
    """ls rows (layout.LS): CONST 1 for a constant colour (rgb in COLOR), else 0 and a colormap
    over the world coordinate PLANE . (x, y, z, 1) of index points across RANGE; VOXEL the
    voxel's world size. Level sets are surfaces where the mode draws them (modes: surfaces; else
    shells); only volumes are lit, where the mode has lights. The shadow grids are the device's to
    fill (no_shadows until then).
    obj_ctf: color_functions' rows (None: no object coloured by a second grid)."""
    objs = scene.objects
    n = len(objs)
    spec = modes.spec(scene.mode)
    kind = np.array([(Kind.SURFACE if o.surface and spec.surfaces else Kind.SHELL)
                     if o.is_level_set else Kind.FOG for o in objs], np.int32)
    ls = np.zeros((n, LS_SIZE))
    axes = {"x": 0, "y": 1, "z": 2}
    for k, o in enumerate(objs):
        c = o.level_set_color
        if isinstance(c, str):
            ax = axes[c.lower()]
            ls[k, LS_CONST] = 0.0
            ls[k, LS_PLANE:LS_PLANE + 4] = o.matrix_world[ax]
            ls[k, LS_RANGE:LS_RANGE + 2] = coord_range[k, ax]
        else:
            ls[k, LS_CONST] = 1.0
            ls[k, LS_COLOR:LS_COLOR + 3] = np.asarray(c, np.float64)[:3]
        ls[k, LS_VOXEL] = voxel_world[k]
    step = np.full(n, float(scene.step))
    lit = np.array([(Shading.LIT_SHADOWS if o.shadows else Shading.LIT)
                    if o.shading == "lit" and not o.is_level_set and spec.lights
                    else Shading.EMISSION for o in objs], np.int32)
    ctf = np.full(max(n, 1), -1, np.int32) if obj_ctf is None else np.asarray(obj_ctf, np.int32)
    cbg = np.zeros(max(n, 1))
    sdf = np.zeros(max(n, 1), np.int32)
    for k, o in enumerate(objs):
        if ctf[k] >= 0:
            cbg[k] = float(getattr(o.gaussians, "color_background", 0.0) or 0.0)
        sdf[k] = kind[k] == Kind.SURFACE and getattr(o.gaussians, "distances", None) is not None
        if sdf[k]:
            cbg[k] = surface_level(o.gaussians.index_to_world)
    return Objects(w2i, kind, obj_tf, ls, step, clip.pack(objs), obj_ref, lit, *no_shadows(n), ctf,
                   cbg, sdf)


def no_shadows(n):
    """sh_grid, sh_tau for n objects without shadow grids (dims 0)."""
    return np.zeros((max(n, 1), SHG_SIZE)), np.zeros(1)


NO_GRAD = np.zeros((1, 4))  # Gaussians.grad where no lit volume is drawn in particles mode


def empty_gaussians() -> Gaussians:
    """One dummy Gaussian of weight 0 (reference mode, or objects without Gaussians)."""
    z3 = np.zeros((1, 3))
    zc = np.zeros((1, 3), np.int64)
    return Gaussians(z3, z3, np.zeros(1), np.zeros((1, 3)), np.zeros(1), np.zeros(1, np.int32),
                     np.zeros(1), np.zeros((1, REC_SIZE)), np.zeros((1, 4), np.float32), zc, zc, np.zeros(1),
                     NO_GRAD)


def pack_gaussians(acc, w, col, rec, cw=None, grad=None) -> Gaussians:
    """The synced Gaussians with this frame's weights w and colours col; rec: the device's
    test records (layout.REC), rewritten here (centre and 1/sigma kept from sync, REC_W = w); cw:
    the colour grids' field weights (None: no object coloured by a second grid); grad: lit
    particles' (m, 4) gradients (see Gaussians), or None."""
    if acc.g_mu.shape[0] == 0:
        return empty_gaussians()
    rec[:, REC_W] = w
    sph = acc.g_sph if acc.g_sph.shape[0] else np.zeros((1, 4), np.float32)
    return Gaussians(acc.g_mu, acc.g_inv, w, col, acc.g_val, acc.g_obj, acc.g_volfac, rec, sph,
                     acc.g_clo, acc.g_chi, np.zeros(1) if cw is None else cw,
                     NO_GRAD if grad is None else grad)


def test_records(acc):
    """(m, REC_SIZE) rows for the per-ray Gaussian test: centre and 1/sigma filled, weight and entry
    bound per frame (pack_gaussians, the tile lists)."""
    return gauss_pack.test_records(acc.g_mu, acc.g_inv)


NO_TILES = (np.zeros(1, np.int64), np.zeros(1, np.int32), np.zeros(1, np.int64))


def pack_accel(acc, cell_skip, tiles=NO_TILES, voxels=False, xfer=None) -> Accel:
    """acc: the synced Gaussian (or, voxels=True, voxel) acceleration; tiles: (starts, ids,
    masks), or NO_TILES for the leaf walk; xfer: (objects' transfer rows, Transfer), for
    clear_bits."""
    if voxels:
        cell_start, cell_items = np.zeros(2, np.int64), np.zeros(1, np.int32)
        face_start, face_items = np.zeros(7, np.int64), np.zeros(1, np.int32)
        bricks, cell_xyz = acc.bricks, acc.cell_xyz
        cbricks = getattr(acc, "cbricks", None)
        clear = clear_bits(acc.sub_max, acc.cell_obj, *xfer) if xfer is not None and acc.n_cells else None
    else:
        clear = None
        cell_start, cell_items = acc.cell_start, acc.cell_items
        face_start, face_items = acc.face_start, acc.face_items
        if cell_items.size == 0:  # no Gaussians, or no lists (the screen tiles need none)
            cell_items = face_items = np.zeros(1, np.int32)
        bricks = cbricks = np.zeros((1, 10, 10, 10), np.float32)
        cell_xyz = acc.cell_xyz if acc.cell_xyz.size else np.zeros((1, 3), np.int64)
    if cbricks is None:
        cbricks = np.zeros((1, 10, 10, 10), np.float32)
    return Accel(acc.node_min, acc.node_dims, acc.node_off, acc.node_table, acc.node_cells,
                 cell_skip, cell_start, cell_items, face_start, face_items, cell_xyz, bricks,
                 acc.max_walk, *tiles, acc.walk_obj, acc.walk_scale, cbricks,
                 node_boxes(acc.node_cells, cell_skip), np.zeros(1, np.int64) if clear is None else clear)


def clear_bits(sub_max, cell_obj, obj_tf, xfer, chunk=1 << 14):
    """int64 per cell: bit (sx * 4 + sy) * 4 + sz set where every sample of that sub-block
    (bricks.sub_max) is transparent under its object's transfer function, so that the one-fog
    sampler (cpu.fog) skips it and draws the same image: with a linear table whose first alpha is
    0, a value v <= lo (hi <= lo: v < hi) takes alpha 0. The bound widens the sub-block's max by
    the trilinear interpolation's rounding (a few ulps of it; 32 here, and an underflow's), so no
    sample that would have drawn is skipped; a max of 0 needs none (weights >= 0: a sum of
    values <= 0 rounds to <= 0). Objects with other tables get no bits."""
    thr = np.full(len(obj_tf), -np.inf)
    le = np.zeros(len(obj_tf), bool)  # v == thr is transparent too
    for k, row in enumerate(obj_tf):
        lo, hi = xfer.par[row, PAR_VMIN], xfer.par[row, PAR_VMAX]
        if xfer.par[row, PAR_LOG] < 0.5 and xfer.lut[row, 0, 3] == 0.0:
            thr[k], le[k] = (lo, True) if hi > lo else (hi, False)
    bit = np.left_shift(np.uint64(1), np.arange(sub_max.shape[1], dtype=np.uint64))
    out = np.zeros(sub_max.shape[0], np.uint64)
    for a in range(0, sub_max.shape[0], chunk):  # in chunks: a (cells, 64) temporary per step
        vm = sub_max[a:a + chunk].astype(np.float64)
        ob = cell_obj[a:a + chunk]
        with np.errstate(invalid="ignore"):
            vm = vm + 32.0 * np.finfo(np.float64).eps * np.abs(vm) + np.where(vm == 0.0, 0.0, 1e-300)
            ok = (vm < thr[ob, None]) | ((vm == thr[ob, None]) & le[ob, None])
        out[a:a + chunk] = np.bitwise_or.reduce(np.where(ok, bit, np.uint64(0)), axis=1)
    return out.view(np.int64)


def node_boxes(node_cells, cell_skip):
    """int64 (nodes, 6): per node, the box [lo, hi) (cells, from the node's corner) of its cells
    that this frame draws (listed and not skipped); lo = hi = 0 where none is."""
    nl = round(node_cells.shape[1] ** (1 / 3))
    drawn = node_cells >= 0
    if cell_skip.shape[0] and drawn.any():
        drawn[drawn] = cell_skip[node_cells[drawn]] == 0
    drawn = drawn.reshape(-1, nl, nl, nl)
    box = np.zeros((drawn.shape[0], 6), np.int64)
    for a, other in enumerate(((2, 3), (1, 3), (1, 2))):
        occ = drawn.any(axis=other)  # (nodes, nl): which cell planes along axis a are drawn
        has = occ.any(axis=1)
        box[has, a] = np.argmax(occ[has], axis=1)
        box[has, a + 3] = nl - np.argmax(occ[has, ::-1], axis=1)
    return box
