"""Numba CPU kernels (parallel over rows, nogil, cached). Imported lazily by CPUDevice so the
numba cache directory can be chosen first. Every pixel is computed independently, in float64,
so images are bitwise identical for any thread count.

Modes (scene.Mode): particles, field (cpu.gauss), paper, reference (here); level-set surfaces
in cpu.surface. The arguments come grouped as packing's named tuples (gauss: Gaussians,
objs: Objects, accel: Accel, xfer: Transfer, out: Output, scr: Scratch, hits: Hits).
"""
from __future__ import annotations

import math

import numpy as np

from ...jit import njit
from ...lod.levelset import SURFACE_LEVEL
from ..devices import modes
from ..devices.modes import LEAF_TILE_MODES, SCREEN_TILE_MODES
from ..inputs.layout import (
    BG_DEPTH,
    CAM_CLIP,
    CAM_EX,
    CAM_EY,
    CAM_H,
    CAM_KIND,
    CAM_OX,
    CAM_OY,
    CAM_POS,
    CAM_ROT,
    CAM_W,
    DEPTH,
    HIT,
    HIT_NORMAL,
    HIT_OB,
    NF,
    NFS,
    NQS,
    NST,
    PCUR,
    PDEPTH,
    RAD,
    SEGS,
    SET_BG,
    SET_K,
    SET_PAPER_DEPTH,
    SET_PAPER_STEPS,
    SET_TAU_MAX,
    SET_TMIN,
    TILE,
    TMIN,
    TR,
    VSUM,
    VWT,
)
from ..inputs.packing import Hits, Scratch
from .chords import OVERFLOW
from .fog import FOG_CHUNK, reference_fog
from .gauss import NB, trace_gauss, trace_tiles
from .per_mode import MODE_BITS, per_kernel, per_mode
from .pieces import lut_rows, paper_piece, reference_piece  # noqa: F401  (lut_rows: for device.py)
from .surface import mixture_normal, shade_hit
from .vecmath import INF, _hot, _jit, composite, erf_diff, erf_span, line_integral
from .walk import clip_interval, walk_object

# the launcher (cpu.launch) calls render_band; the tests reach the float64 helpers here too
__all__ = ["render_band", "composite", "erf_diff", "erf_span", "line_integral"]


@njit(**_hot)
def argsort_small(keys, idx, n):
    """idx[:n] = the stable argsort of keys[:n], by insertion (no allocation; the inputs are a few
    sorted runs, one per object, so the shifts stay short)."""
    for q in range(n):
        r = q
        while r > 0 and keys[idx[r - 1]] > keys[q]:
            idx[r] = idx[r - 1]
            r -= 1
        idx[r] = q


@njit(**_hot)
def sort_small(vals, n):
    """vals[:n] sorted in place, by insertion (see argsort_small)."""
    for q in range(1, n):
        v = vals[q]
        r = q
        while r > 0 and vals[r - 1] > v:
            vals[r] = vals[r - 1]
            r -= 1
        vals[r] = v


@njit(**_hot)
def merged_pieces(n, iv_ta, iv_tb, srt, bnd):
    """Several objects: the interval boundaries sorted (pieces between them have a constant set
    of covering leaves, at most one per object); returns the piece count."""
    argsort_small(iv_ta, srt, n)
    for q in range(n):
        bnd[q] = iv_ta[q]
        bnd[n + q] = iv_tb[q]
    sort_small(bnd, 2 * n)
    return 2 * n - 1


def piece(mode, st, p0, p1, ncov, gauss, objs, accel, xfer, scr, k2, nsteps, maxd):
    """One piece [p0, p1) of a ray over its ncov covering leaves (scr.cov_obj, scr.cov_cell):
    sampled from the voxels (reference_piece) or the Gaussians (paper_piece); true when the ray
    has its paper-mode depth."""


@per_mode(piece)
def _piece(mode):
    if modes.spec(mode).draws == modes.VOXELS:
        def voxels(mode, st, p0, p1, ncov, gauss, objs, accel, xfer, scr, k2, nsteps, maxd):
            reference_piece(st, p0, p1, ncov, scr.cov_obj, scr.cov_cell, scr.ro, scr.rd, objs.step,
                            accel.bricks, accel.cell_xyz, objs.kind, objs.tf, objs.ls, xfer.lut,
                            xfer.par, scr.samp, scr.acc, scr.sprev, objs, xfer, scr.wr, accel.cbricks)
            return False
        return voxels

    def gaussians(mode, st, p0, p1, ncov, gauss, objs, accel, xfer, scr, k2, nsteps, maxd):
        cov_obj = scr.cov_obj
        for c in range(ncov):  # walk grid -> its object
            cov_obj[c] = accel.walk_obj[cov_obj[c]]
        paper_piece(st, p0, p1, ncov, cov_obj, scr.cov_cell, scr.ro, scr.rd, accel.cell_start,
                    accel.cell_items, gauss.mu, gauss.inv, gauss.w, gauss.col, gauss.val,
                    gauss.obj, gauss.volfac, k2, nsteps, maxd, scr.rclip)
        return st[PDEPTH] >= maxd
    return gaussians


@njit(**_hot)
def trace_pieces(mode, st, n, gauss, objs, accel, xfer, scr, k2, nsteps, maxd):
    """paper / reference: piece by piece over the covering leaves."""
    one = accel.walk_obj.shape[0] == 1  # one object's leaves: the intervals are the pieces
    iv_ta, iv_tb, srt, act_iv = scr.iv_ta, scr.iv_tb, scr.srt, scr.act_iv
    cov_obj, cov_cell = scr.cov_obj, scr.cov_cell
    npieces = n if one else merged_pieces(n, iv_ta, iv_tb, srt, scr.bnd)
    ptr = 0
    nactiv = 0
    for pi in range(npieces):
        if one:
            p0 = iv_ta[pi]
            p1 = iv_tb[pi]
            ncov = 1
            cov_obj[0] = scr.iv_obj[pi]
            cov_cell[0] = scr.iv_cell[pi]
        else:
            p0 = scr.bnd[pi]
            p1 = scr.bnd[pi + 1]
            if not p1 > p0:
                continue
            q = 0
            while q < nactiv:  # drop finished intervals, keep order
                if iv_tb[act_iv[q]] <= p0:
                    for r in range(q, nactiv - 1):
                        act_iv[r] = act_iv[r + 1]
                    nactiv -= 1
                else:
                    q += 1
            while ptr < n and iv_ta[srt[ptr]] <= p0:
                if iv_tb[srt[ptr]] > p0:
                    act_iv[nactiv] = srt[ptr]
                    nactiv += 1
                ptr += 1
            ncov = 0
            for q in range(nactiv):
                cov_obj[ncov] = scr.iv_obj[act_iv[q]]
                cov_cell[ncov] = scr.iv_cell[act_iv[q]]
                ncov += 1
            if ncov == 0:
                continue
        if piece(mode, st, p0, p1, ncov, gauss, objs, accel, xfer, scr, k2, nsteps, maxd):
            return
        if st[TR] < st[TMIN] or st[HIT] > 0.0:
            return


@njit(**_hot, inline="always")
def trace_walk(mode, st, n, gauss, objs, accel, xfer, scr, hits, k2, t_near, t_far, tau_max):
    """Particles/field over the leaf cells the walk visited (several objects: by entry time)."""
    argsort_small(scr.iv_ta, scr.srt, n)  # by entry time (one object: already in order)
    return trace_gauss(mode, st, n, gauss, objs, accel, xfer, scr, hits, k2, t_near, t_far, tau_max)


def trace_ray(mode, tiled, st, n, i, j, ta, tb, gauss, objs, accel, xfer, scr, hits, k2, nsteps, maxd,
              t_near, t_far, tau_max):
    """One ray of pixel (i, j) through what its n walked leaf intervals (or, ``tiled``, its
    screen tile's list accel.t_items[ta:tb]) hold, as ``mode`` draws it; 0, or OVERFLOW when
    hits needs more rows."""


@per_kernel(trace_ray)
def _trace_ray(mode, variant):
    if variant.one_fog:  # one fog volume in Emission, a linear transfer function (launch.kernel_code)
        def fog(mode, tiled, st, n, i, j, ta, tb, gauss, objs, accel, xfer, scr, hits, k2, nsteps, maxd,
                t_near, t_far, tau_max):
            tf = objs.tf[0]
            reference_fog(st, n, scr.iv_ta, scr.iv_tb, scr.iv_cell, scr.ro, scr.rd, objs.step[0],
                          accel.bricks, accel.cell_xyz, xfer.lut[tf], xfer.par[tf], accel.clear,
                          scr.fog)
            return 0
        return fog

    if modes.spec(mode).pieces:
        def pieces(mode, tiled, st, n, i, j, ta, tb, gauss, objs, accel, xfer, scr, hits, k2, nsteps, maxd,
                   t_near, t_far, tau_max):
            trace_pieces(mode, st, n, gauss, objs, accel, xfer, scr, k2, nsteps, maxd)
            return 0
        return pieces

    def gaussians(mode, tiled, st, n, i, j, ta, tb, gauss, objs, accel, xfer, scr, hits, k2, nsteps, maxd,
                  t_near, t_far, tau_max):
        if tiled:
            return trace_tiles(mode, st, i, j, ta, tb, gauss, objs, accel, xfer, scr, hits, k2, t_near,
                               t_far, tau_max)
        return trace_walk(mode, st, n, gauss, objs, accel, xfer, scr, hits, k2, t_near, t_far, tau_max)
    return gaussians


def gauss_normal(mode, st, ro, rd, accel, gauss, objs):
    """A field-mode surface hit's normal, from the Gaussians around it (surface.mixture_normal);
    the other modes' hits come with theirs."""


@per_mode(gauss_normal)
def _gauss_normal(mode):
    if modes.spec(mode).field and modes.spec(mode).surfaces:
        def field(mode, st, ro, rd, accel, gauss, objs):
            if st[HIT] == HIT_NORMAL:
                mixture_normal(st, ro, rd, accel.node_min, accel.node_dims, accel.node_off,
                               accel.node_table, accel.node_cells, accel.cell_start, accel.cell_items,
                               gauss.rec, gauss.cw, objs.sdf[int(st[HIT_OB])],
                               objs.cbg[int(st[HIT_OB])] / SURFACE_LEVEL)
        return field

    def others(mode, st, ro, rd, accel, gauss, objs):
        pass
    return others


def surface_shade(mode, st, w2i, lights, settings, owx, owy, owz, dwx, dwy, dwz):
    """A surface hit's shading (surface.shade_hit); nothing in a plain frame, which has none."""


@per_kernel(surface_shade)
def _surface_shade(mode, variant):
    if variant.plain:
        def none(mode, st, w2i, lights, settings, owx, owy, owz, dwx, dwy, dwz):
            pass
        return none

    def shade(mode, st, w2i, lights, settings, owx, owy, owz, dwx, dwy, dwz):
        if st[HIT] > 0.0:
            shade_hit(st, w2i[int(st[HIT_OB])], lights, settings, owx, owy, owz, dwx, dwy, dwz)
    return shade


@njit(**_jit)
def ray_scratch(cap):
    """Per-ray hit arrays for trace_gauss, room for cap hits (packing.Hits)."""
    return Hits(np.empty((cap, NF)), np.empty(cap, np.int64), np.empty(cap), np.empty(cap, np.int64),
                np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64))


@njit(**_hot)
def render_pixels(p0, jr0, j0, nr, c0, c1, mode, cam, gauss, objs, accel, xfer, out, scr, hits):
    """Pixels p0.. of the band of nr output rows from jr0 (image row j0) and image columns
    [c0, c1) (output column i - c0), tile by tile (see render_band); no allocation, no reference
    counting (see cpu.vecmath._hot). Returns -1, or the pixel whose ray needs more hit rows than
    hits has. Rays run over [clip start, clip end] along the view axis (cam[CAM_CLIP:]); each object's
    part of a ray is further cut to its clip half-spaces objs.clip[ob] (scr.rclip[ob], clip.py)."""
    W = int(cam[CAM_W])
    Hh = int(cam[CAM_H])
    ex, ey, offx, offy = cam[CAM_EX], cam[CAM_EY], cam[CAM_OX], cam[CAM_OY]
    clip0, clip1 = cam[CAM_CLIP], cam[CAM_CLIP + 1]
    w2i = objs.w2i
    n_obj = w2i.shape[0]
    settings = xfer.settings
    tmin_T = settings[SET_TMIN]
    tau_max = settings[SET_TAU_MAX]
    k2 = settings[SET_K] * settings[SET_K]
    bgr, bgg, bgb, bga = (settings[SET_BG], settings[SET_BG + 1], settings[SET_BG + 2],
                          settings[SET_BG + 3])
    nsteps = int(settings[SET_PAPER_STEPS])
    maxd = settings[SET_PAPER_DEPTH]
    t_start = accel.t_start
    tiled = (mode & MODE_BITS) in SCREEN_TILE_MODES and t_start.shape[0] > 1
    culled = (mode & MODE_BITS) in LEAF_TILE_MODES and t_start.shape[0] > 1  # leaves per tile
    ntx = (W + TILE - 1) // TILE
    w0 = min(c1, (c0 // TILE + 1) * TILE) - c0  # the first tile column's part of [c0, c1)
    st, ro, rd, rclip, sprev = scr.st, scr.ro, scr.rd, scr.rclip, scr.sprev
    # pixel p0's tile (its first column x0, width tw) and place (qi, qj) in it; then stepped
    # pixel by pixel (integer divisions per pixel cost as much as a culled pixel's work)
    if p0 < nr * w0:
        x0, tw, q = c0, w0, p0
    else:
        k = (p0 - nr * w0) // (nr * TILE)
        x0 = (c0 // TILE + 1 + k) * TILE
        tw = min(TILE, c1 - x0)
        q = p0 - nr * w0 - k * nr * TILE
    qj, qi = q // tw, q % tw
    bg = (bgr * bga, bgg * bga, bgb * bga, bga)
    for p in range(p0, nr * (c1 - c0)):
        if qi == tw:
            qi = 0
            qj += 1
            if qj == nr:
                qj = 0
                x0 += tw
                tw = min(TILE, c1 - x0)
        jr = jr0 + qj
        j = j0 + qj
        i = x0 + qi
        qi += 1
        tl = (j // TILE) * ntx + i // TILE
        if culled and t_start[tl + 1] == t_start[tl]:  # no leaf projects here: the background
            io = i - c0
            out.rgba[jr, io, 0], out.rgba[jr, io, 1], out.rgba[jr, io, 2] = bg[0], bg[1], bg[2]
            out.rgba[jr, io, 3] = bg[3]
            out.depth[jr, io] = BG_DEPTH
            out.value[jr, io] = 0.0
            continue
        py = ((j + 0.5) / Hh - 0.5) * ey + offy
        px = ((i + 0.5) / W - 0.5) * ex + offx
        # R = cam[CAM_ROT:][:9] row-major: R[r, c] at CAM_ROT + 3 r + c (columns: camera x, y, z)
        if cam[CAM_KIND] < 0.5:
            dcx = cam[CAM_ROT] * px + cam[CAM_ROT + 1] * py - cam[CAM_ROT + 2]
            dcy = cam[CAM_ROT + 3] * px + cam[CAM_ROT + 4] * py - cam[CAM_ROT + 5]
            dcz = cam[CAM_ROT + 6] * px + cam[CAM_ROT + 7] * py - cam[CAM_ROT + 8]
            nrm = math.sqrt(dcx * dcx + dcy * dcy + dcz * dcz)
            dwx, dwy, dwz = dcx / nrm, dcy / nrm, dcz / nrm
            owx, owy, owz = cam[CAM_POS], cam[CAM_POS + 1], cam[CAM_POS + 2]
            t_near, t_far = clip0 * nrm, clip1 * nrm  # the view-axis distances along this ray
        else:
            dwx, dwy, dwz = -cam[CAM_ROT + 2], -cam[CAM_ROT + 5], -cam[CAM_ROT + 8]
            owx = cam[CAM_POS] + px * cam[CAM_ROT] + py * cam[CAM_ROT + 1]
            owy = cam[CAM_POS + 1] + px * cam[CAM_ROT + 3] + py * cam[CAM_ROT + 4]
            owz = cam[CAM_POS + 2] + px * cam[CAM_ROT + 6] + py * cam[CAM_ROT + 7]
            t_near, t_far = clip0, clip1
        ta, tb = (t_start[tl], t_start[tl + 1]) if tiled else (0, 0)  # the tile's list
        n = tb - ta
        walk = not tiled
        for ob in range(n_obj):
            M = w2i[ob]
            ox = M[0, 0] * owx + M[0, 1] * owy + M[0, 2] * owz + M[0, 3]
            oy = M[1, 0] * owx + M[1, 1] * owy + M[1, 2] * owz + M[1, 3]
            oz = M[2, 0] * owx + M[2, 1] * owy + M[2, 2] * owz + M[2, 3]
            dx = M[0, 0] * dwx + M[0, 1] * dwy + M[0, 2] * dwz
            dy = M[1, 0] * dwx + M[1, 1] * dwy + M[1, 2] * dwz
            dz = M[2, 0] * dwx + M[2, 1] * dwy + M[2, 2] * dwz
            ro[ob, 0], ro[ob, 1], ro[ob, 2] = ox, oy, oz
            rd[ob, 0], rd[ob, 1], rd[ob, 2] = dx, dy, dz
            rclip[ob, 0], rclip[ob, 1] = clip_interval(objs.clip[ob], owx, owy, owz, dwx, dwy, dwz)
            if walk:
                n = walk_object(ox, oy, oz, dx, dy, dz, max(t_near, rclip[ob, 0]),
                                min(t_far, rclip[ob, 1]), accel.node_min[ob], accel.node_dims[ob],
                                accel.node_off[ob], accel.node_table, accel.node_cells,
                                accel.node_box, accel.cell_skip, ob, scr.iv_ta, scr.iv_tb, scr.iv_obj, scr.iv_cell,
                                n, accel.max_walk, np.int64(1))  # (not a literal 1: one signature)
        for w in range(n_obj, accel.walk_obj.shape[0] if walk else 0):  # the coarse levels' grids
            ob = accel.walk_obj[w]
            n = walk_object(ro[ob, 0], ro[ob, 1], ro[ob, 2], rd[ob, 0], rd[ob, 1], rd[ob, 2],
                            max(t_near, rclip[ob, 0]), min(t_far, rclip[ob, 1]), accel.node_min[w],
                            accel.node_dims[w], accel.node_off[w], accel.node_table,
                            accel.node_cells, accel.node_box, accel.cell_skip, w, scr.iv_ta, scr.iv_tb, scr.iv_obj,
                            scr.iv_cell, n, accel.max_walk, accel.walk_scale[w])
        wr = scr.wr
        wr[0], wr[1], wr[2], wr[3], wr[4], wr[5] = owx, owy, owz, dwx, dwy, dwz
        st[TR] = 1.0
        st[RAD] = 0.0
        st[RAD + 1] = 0.0
        st[RAD + 2] = 0.0
        st[DEPTH] = BG_DEPTH
        st[VSUM] = 0.0
        st[VWT] = 0.0
        st[SEGS] = 0.0
        st[HIT] = 0.0
        st[TMIN] = tmin_T
        st[PDEPTH] = 0.0
        st[PCUR] = -INF
        for ob in range(n_obj):
            sprev[ob, 0] = 0.0
            sprev[ob, 1] = np.nan
        if n > 0 and trace_ray(mode, tiled, st, n, i, j, ta, tb, gauss, objs, accel, xfer, scr, hits, k2,
                               nsteps, maxd, t_near, t_far, tau_max) == OVERFLOW:
            return p
        gauss_normal(mode, st, ro, rd, accel, gauss, objs)
        surface_shade(mode, st, w2i, xfer.lights, settings, owx, owy, owz, dwx, dwy, dwz)
        Tr = st[TR]
        io = i - c0
        out.rgba[jr, io, 0] = st[RAD] + Tr * bgr * bga
        out.rgba[jr, io, 1] = st[RAD + 1] + Tr * bgg * bga
        out.rgba[jr, io, 2] = st[RAD + 2] + Tr * bgb * bga
        out.rgba[jr, io, 3] = (1.0 - Tr) + Tr * bga
        out.depth[jr, io] = st[DEPTH]
        out.value[jr, io] = st[VSUM] / st[VWT] if st[VWT] > 0.0 else 0.0
        out.segs[jr] += st[SEGS]
    return -1


@njit(**_jit)
def new_scratch(mw, n_obj, n_walk):
    """A thread's Scratch (packing.Scratch, by field name) for walks of up to mw leaf intervals,
    n_obj objects and n_walk walk grids."""
    return Scratch(iv_ta=np.empty(mw), iv_tb=np.empty(mw), iv_obj=np.empty(mw, np.int32),
                   iv_cell=np.empty(mw, np.int32), srt=np.empty(mw, np.int64), bnd=np.empty(2 * mw),
                   act_iv=np.empty(mw, np.int64), cov_obj=np.empty(mw, np.int32),
                   cov_cell=np.empty(mw, np.int32), ro=np.empty((n_obj, 3)), rd=np.empty((n_obj, 3)),
                   rclip=np.empty((n_obj, 2)), lastc=np.empty((n_walk, 3), np.int64),
                   svals=np.empty(n_obj), sact=np.empty(n_obj, np.int64), samp=np.empty(5),
                   acc=np.empty(6), cb=np.empty(6), st=np.empty(NST), qs=np.empty(NQS, np.int64),
                   fs=np.empty(NFS), cand=np.empty(NB, np.int64), blk=np.empty((16, NB)),
                   sprev=np.empty((n_obj, 5)), wr=np.empty(6), sgrad=np.empty((n_obj, 3)),
                   cvals=np.empty(n_obj), fog=np.empty(FOG_CHUNK))


@njit(**_jit, inline="always")
def render_band(jr0, j0, nr, c0, c1, mode, cam, gauss, objs, accel, xfer, out):
    """nr image rows from j0 (output rows from jr0), columns [c0, c1), within one row of screen
    tiles, one tile after the other, so a tile's candidate list and the Gaussians it names stay
    in cache for its pixels (row by row, a 512-wide image cycles through 64 tiles' lists). The
    scratch arrays, then render_pixels (grown and resumed when a ray needs more hit rows). Inlined
    into each mode's band kernel (cpu.launch): one compiled function less a mode."""
    scr = new_scratch(accel.max_walk, objs.w2i.shape[0], accel.walk_obj.shape[0])
    cap = np.int64(256)  # (not a literal: ray_scratch compiles once)
    hits = ray_scratch(cap)
    out.segs[jr0:jr0 + nr] = 0.0
    p = np.int64(0)  # (not the literal 0: render_pixels would compile twice)
    while True:
        p = render_pixels(p, jr0, j0, nr, c0, c1, mode, cam, gauss, objs, accel, xfer, out, scr, hits)
        if p < 0:
            return
        cap *= 2  # more Gaussians on ray p than this band's scratch holds: grow, redo it
        hits = ray_scratch(cap)
