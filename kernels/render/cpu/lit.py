"""Lit volumes: the scene's lights (lights.pack) shade a volume sample by Blinn-Phong on the
gradient of its field (shade_sample; the modes compute the gradient: trilinear voxel differences
in reference mode, the mixture's analytic gradient in field mode), and, with shadows, by each
light's transmittance through the media. The transmittance comes from a per-frame grid of shadow
rays over each shadowed object's index box (shadow_grid: the same leaf walk and representation
as the frame: voxel samples in reference mode, the Gaussians' closed-form optical depth
otherwise), interpolated trilinearly at the sample: one shadow ray per sample would cost a
primary ray's work at every sample.
"""
from __future__ import annotations

import math

import numpy as np

from ...jit import njit, parallel_for
from ..inputs.layout import (
    CB,
    CG,
    CR,
    HQ,
    LEAF,
    LIGHT_KIND,
    PAR_VMAX,
    PAR_VMIN,
    SET_K,
    SET_LIT_THRESHOLD,
    SET_SHADING,
    SHG_DIMS,
    SHG_OFFSET,
    SHG_ORIGIN,
    SHG_SIZE,
    SHG_SPACING,
    TS,
    Kind,
    Shading,
)
from .per_mode import per_kernel
from .surface import POINT, SUN, brick_xyz, light_at, trilinear
from .vecmath import _hot, _jit, erf_span, sample_color, whitened_chord
from .walk import clip_interval, walk_object

SHADOW_POINTS = 32  # shadow grid points along an object's longest axis
SHADOW_STEP = 1.0   # reference mode: shadow ray sample spacing, voxels


@njit(**_hot)
def shadow_tau(grid, tau, nl, li, x, y, z):
    """Optical depth towards light li at index point x, y, z from an object's shadow grid (row
    grid: origin, spacing, dims, offset), trilinear, clamped to the grid."""
    s = grid[SHG_SPACING]
    n0, n1, n2 = int(grid[SHG_DIMS]), int(grid[SHG_DIMS + 1]), int(grid[SHG_DIMS + 2])
    off = int(grid[SHG_OFFSET])
    o0, o1, o2 = grid[SHG_ORIGIN], grid[SHG_ORIGIN + 1], grid[SHG_ORIGIN + 2]
    u = (min(max((x - o0) / s, 0.0), n0 - 1.0), min(max((y - o1) / s, 0.0), n1 - 1.0),
         min(max((z - o2) / s, 0.0), n2 - 1.0))
    i0, j0, k0 = min(int(u[0]), n0 - 2), min(int(u[1]), n1 - 2), min(int(u[2]), n2 - 2)
    ax, ay, az = u[0] - i0, u[1] - j0, u[2] - k0
    v = 0.0
    for di in range(2):
        wx = ax if di else 1.0 - ax
        for dj in range(2):
            wy = ay if dj else 1.0 - ay
            for dk in range(2):
                w = wx * wy * (az if dk else 1.0 - az)
                v += w * tau[off + (((i0 + di) * n1 + j0 + dj) * n2 + k0 + dk) * nl + li]
    return v


@njit(**_hot, inline="always")
def shine(c, sh):
    """c ** sh, by repeated squaring for the usual whole shininess (up to 128), else pow."""
    n = int(sh)
    if n != sh or n < 0 or n > 128:
        return c ** sh
    r = 1.0
    while n:
        if n & 1:
            r *= c
        c *= c
        n >>= 1
    return r


@njit(**_hot, inline="always")
def shade_sample(samp, ob, gx, gy, gz, x, y, z, wr, t, objs, lights, settings, par):
    """Blinn-Phong on a lit volume sample of object ob (samp: sigma_t, rgb, value from
    sample_color; the rgb is replaced): gx, gy, gz the field's index-space gradient at index point
    x, y, z; wr the world ray (origin, direction), t the sample's distance along it. Below the
    gradient threshold (a fraction of the transfer function's value range per voxel) the
    emission colour stays; the normal is -gradient (the medium's outside), in world space."""
    rng = par[PAR_VMAX] - par[PAR_VMIN]
    if not rng > 0.0:
        rng = 1.0
    thr = settings[SET_LIT_THRESHOLD] * rng
    if not gx * gx + gy * gy + gz * gz > thr * thr:
        return
    M = objs.w2i[ob]
    nx = -(M[0, 0] * gx + M[1, 0] * gy + M[2, 0] * gz)
    ny = -(M[0, 1] * gx + M[1, 1] * gy + M[2, 1] * gz)
    nz = -(M[0, 2] * gx + M[1, 2] * gy + M[2, 2] * gz)
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not nn > 0.0:
        return
    inn = 1.0 / nn
    nx, ny, nz = nx * inn, ny * inn, nz * inn
    dx, dy, dz = wr[3], wr[4], wr[5]
    px, py, pz = wr[0] + t * dx, wr[1] + t * dy, wr[2] + t * dz
    ka, kd, ks, sh = (settings[SET_SHADING], settings[SET_SHADING + 1], settings[SET_SHADING + 2],
                      settings[SET_SHADING + 3])
    cr, cg, cb = samp[1], samp[2], samp[3]
    r, g, b = ka * cr, ka * cg, ka * cb
    nl = lights.shape[0]
    shadows = objs.lit[ob] == Shading.LIT_SHADOWS
    for k in range(nl):
        ok, lx, ly, lz, er, eg, eb, _ = light_at(lights, k, px, py, pz, dx, dy, dz)
        ndl = nx * lx + ny * ly + nz * lz
        if not ok or ndl <= 0.0:
            continue
        if shadows:
            tr = math.exp(-shadow_tau(objs.sh_grid[ob], objs.sh_tau, nl, k, x, y, z))
            er, eg, eb = er * tr, eg * tr, eb * tr
        hx, hy, hz = lx - dx, ly - dy, lz - dz
        hn = math.sqrt(hx * hx + hy * hy + hz * hz)
        spec = 0.0
        if hn > 0.0 and ks > 0.0:
            spec = ks * shine(max(nx * hx + ny * hy + nz * hz, 0.0) / hn, sh)
        r += er * (kd * ndl * cr + spec)
        g += eg * (kd * ndl * cg + spec)
        b += eb * (kd * ndl * cb + spec)
    samp[1], samp[2], samp[3] = r, g, b


@njit(**_hot, inline="always")
def lit_member(H, h, g, gauss, objs, xfer, scr):
    """A lit volume's chord in particles mode: its colour shaded once, at the chord's closest
    approach to the centre (shade_sample), on the mixture's gradient there: the Gaussian's own
    (analytic) plus its neighbours', taken at its centre (gauss.grad, per sync)."""
    ob = gauss.obj[g]
    ts = H[h, TS]
    ro, rd = scr.ro, scr.rd
    x, y, z = ro[ob, 0] + ts * rd[ob, 0], ro[ob, 1] + ts * rd[ob, 1], ro[ob, 2] + ts * rd[ob, 2]
    ix, iy, iz = gauss.inv[g, 0], gauss.inv[g, 1], gauss.inv[g, 2]
    ux, uy, uz = (x - gauss.mu[g, 0]) * ix, (y - gauss.mu[g, 1]) * iy, (z - gauss.mu[g, 2]) * iz
    e = -gauss.grad[g, 3] * math.exp(-H[h, HQ])  # HQ: half the whitened distance at TS
    samp = scr.samp
    samp[1], samp[2], samp[3] = H[h, CR], H[h, CG], H[h, CB]
    shade_sample(samp, ob, gauss.grad[g, 0] + e * ux * ix, gauss.grad[g, 1] + e * uy * iy,
                 gauss.grad[g, 2] + e * uz * iz, x, y, z, scr.wr, ts, objs, xfer.lights,
                 xfer.settings, xfer.par[objs.tf[ob]])
    H[h, CR], H[h, CG], H[h, CB] = samp[1], samp[2], samp[3]


def shade_member(mode, H, h, g, gauss, objs, xfer, scr):
    """A new member's shading where its volume is lit (lit_member); nothing in a plain frame."""


@per_kernel(shade_member)
def _shade_member(mode, variant):
    if variant.plain:
        def none(mode, H, h, g, gauss, objs, xfer, scr):
            pass
        return none

    def shade(mode, H, h, g, gauss, objs, xfer, scr):
        if objs.lit[gauss.obj[g]] != Shading.EMISSION:
            lit_member(H, h, g, gauss, objs, xfer, scr)
    return shade


@njit(**_hot)
def voxel_tau(ob, ta, tb, cid, ro, rd, h, accel, objs, xfer, samp):
    """Reference mode: object ob's optical depth over [ta, tb] of a ray (index space ro, rd;
    world t) inside leaf cell cid, by midpoint voxel samples h apart (world)."""
    n = max(1, int(math.ceil((tb - ta) / h)))
    hh = (tb - ta) / n
    B = accel.bricks[cid]
    cxyz = accel.cell_xyz[cid]
    tau = 0.0
    for i in range(n):
        t = ta + (i + 0.5) * hh
        x, y, z = ro[0] + t * rd[0], ro[1] + t * rd[1], ro[2] + t * rd[2]
        fx, fy, fz = brick_xyz(cxyz, x, y, z)
        sample_color(ob, trilinear(B, fx, fy, fz), x, y, z, objs.kind, objs.tf, objs.ls, xfer.lut,
                     xfer.par, samp)
        tau += samp[0] * hh
    return tau


@njit(**_hot)
def gauss_tau(ob, ta, tb, cid, lastc, ro, rd, gauss, wext, accel, k2):
    """Field/particles: the closed-form optical depth over the ray's [ta, tb] of the Gaussians
    first met in leaf cell cid (extinction weights wext): each counts once, whole, in the first
    cell of its support the ray visits (skipped where its support box covers the previous cell
    visited, lastc, as the primary walk does)."""
    lx, ly, lz = lastc[0], lastc[1], lastc[2]
    tau = 0.0
    for j in range(accel.cell_start[cid], accel.cell_start[cid + 1]):
        g = accel.cell_items[j]
        if wext[g] == 0.0:
            continue
        if (gauss.clo[g, 0] <= lx and lx <= gauss.chi[g, 0] and gauss.clo[g, 1] <= ly
                and ly <= gauss.chi[g, 1] and gauss.clo[g, 2] <= lz and lz <= gauss.chi[g, 2]):
            continue
        ts, a, q = whitened_chord(ro[0], ro[1], ro[2], rd[0], rd[1], rd[2], gauss.mu, gauss.inv, g)
        if q >= k2:
            continue
        hw = math.sqrt((k2 - q) / a)
        t0, t1 = max(ts - hw, ta), min(ts + hw, tb)
        if not t1 > t0:
            continue
        sa = math.sqrt(0.5 * a)
        tau += wext[g] * math.exp(-0.5 * q) * math.sqrt(math.pi / (2.0 * a)) * erf_span(
            sa * (t0 - ts), sa * (t1 - ts), sa * (t1 - t0))
    return tau


@njit(**_jit)
def ray_tau(voxels, px, py, pz, dx, dy, dz, tmax, gauss, wext, objs, accel, xfer, iv_ta, iv_tb,
            iv_obj, iv_cell, ro, rd, lastc, samp):
    """Optical depth of the volumes (kind 0) along the world ray p + t d, t in [0, tmax], each
    cut to its clip half-spaces; over every walk grid (an object's leaves, then the coarser
    levels that list its wider Gaussians: each Gaussian is in one grid only)."""
    k2 = xfer.settings[SET_K] ** 2
    tau = 0.0
    for w in range(accel.walk_obj.shape[0]):
        ob = accel.walk_obj[w]
        if objs.kind[ob] != Kind.FOG:
            continue
        M = objs.w2i[ob]
        for c in range(3):
            ro[c] = M[c, 0] * px + M[c, 1] * py + M[c, 2] * pz + M[c, 3]
            rd[c] = M[c, 0] * dx + M[c, 1] * dy + M[c, 2] * dz
        c0, c1 = clip_interval(objs.clip[ob], px, py, pz, dx, dy, dz)
        c0, c1 = max(0.0, c0), min(tmax, c1)
        n = walk_object(ro[0], ro[1], ro[2], rd[0], rd[1], rd[2], c0, c1,
                        accel.node_min[w], accel.node_dims[w], accel.node_off[w],
                        accel.node_table, accel.node_cells, accel.node_box, accel.cell_skip, w,
                        iv_ta, iv_tb,
                        iv_obj, iv_cell, 0, accel.max_walk, accel.walk_scale[w])
        h = SHADOW_STEP / math.sqrt(rd[0] ** 2 + rd[1] ** 2 + rd[2] ** 2)  # world length
        lastc[:] = -(1 << 62)
        for q in range(n):
            cid = iv_cell[q]
            if voxels:
                tau += voxel_tau(ob, iv_ta[q], iv_tb[q], cid, ro, rd, h, accel, objs, xfer, samp)
            else:
                tau += gauss_tau(ob, c0, c1, cid, lastc, ro, rd, gauss, wext, accel, k2)
                lastc[0], lastc[1], lastc[2] = (accel.cell_xyz[cid, 0], accel.cell_xyz[cid, 1],
                                                accel.cell_xyz[cid, 2])
    return tau


def shadow_grid(voxels, pts_ob, pts, i2w, gauss, wext, objs, accel, xfer, out):
    """out[p, l] = the optical depth from grid point p (index point pts[p] of object pts_ob[p])
    towards light l, through every volume of the frame."""
    parallel_for(_shadow_grid, pts.shape[0], voxels, pts_ob, pts, i2w, gauss, wext, objs, accel,
                 xfer, out)


@njit(**_jit)
def _shadow_grid(p0, p1, voxels, pts_ob, pts, i2w, gauss, wext, objs, accel, xfer, out):
    lights = xfer.lights
    mw = accel.max_walk  # one ray's scratch, written before it is read
    iv_ta, iv_tb = np.empty(mw), np.empty(mw)
    iv_obj, iv_cell = np.empty(mw, np.int32), np.empty(mw, np.int32)
    ro, rd, lastc, samp = np.empty(3), np.empty(3), np.empty(3, np.int64), np.empty(5)
    for p in range(p0, p1):
        A = i2w[pts_ob[p]]
        x, y, z = pts[p, 0], pts[p, 1], pts[p, 2]
        wx = A[0, 0] * x + A[0, 1] * y + A[0, 2] * z + A[0, 3]
        wy = A[1, 0] * x + A[1, 1] * y + A[1, 2] * z + A[1, 3]
        wz = A[2, 0] * x + A[2, 1] * y + A[2, 2] * z + A[2, 3]
        for k in range(lights.shape[0]):
            # the headlight shines along each view ray: no single direction to shadow it by
            if lights[k, LIGHT_KIND] != SUN and lights[k, LIGHT_KIND] != POINT:
                out[p, k] = 0.0
                continue
            ok, lx, ly, lz, _, _, _, dist = light_at(lights, k, wx, wy, wz, 0.0, 0.0, 0.0)
            out[p, k] = ray_tau(voxels, wx, wy, wz, lx, ly, lz, dist, gauss, wext, objs, accel,
                                xfer, iv_ta, iv_tb, iv_obj, iv_cell, ro, rd, lastc, samp) if ok else 0.0


def centre_gradients(cstart, pg, cg_start, cg_items, mu, inv, fw, k2, out):
    """Particles mode's lit volumes: out[g] = (the gradient at g's centre of the field of the other
    Gaussians of its object, g's own field weight). Cells c (those holding a centre): their pairs
    pg[cstart[c]:cstart[c + 1]] (every Gaussian whose k-sigma box meets the cell) and the
    Gaussians centred there, cg_items[cg_start[c]:cg_start[c + 1]]."""
    parallel_for(_centre_gradients, cstart.shape[0] - 1, cstart, pg, cg_start, cg_items, mu, inv, fw,
                 float(k2), out)


@njit(**_jit)
def _centre_gradients(c0, c1, cstart, pg, cg_start, cg_items, mu, inv, fw, k2, out):
    for c in range(c0, c1):
        for a in range(cg_start[c], cg_start[c + 1]):
            g = cg_items[a]
            x, y, z = mu[g, 0], mu[g, 1], mu[g, 2]
            gx = gy = gz = 0.0
            for b in range(cstart[c], cstart[c + 1]):
                j = pg[b]
                if j == g or fw[j] == 0.0:
                    continue
                ux = (x - mu[j, 0]) * inv[j, 0]
                uy = (y - mu[j, 1]) * inv[j, 1]
                uz = (z - mu[j, 2]) * inv[j, 2]
                q = ux * ux + uy * uy + uz * uz
                if q > k2:
                    continue
                e = -fw[j] * math.exp(-0.5 * q)
                gx += e * ux * inv[j, 0]
                gy += e * uy * inv[j, 1]
                gz += e * uz * inv[j, 2]
            out[g, 0], out[g, 1], out[g, 2], out[g, 3] = gx, gy, gz, fw[g]


def lit_gradients(mu, inv, fw, first, k):
    """(m, 4) Gaussians.grad for the Gaussians of every object (first: each object's first row):
    centre_gradients over the leaf cells holding their centres, pairs as the field error lists
    them (kernels.lod.mixture.pair_lists: each Gaussian in every cell its k-sigma box meets)."""
    from ...lod.mixture import cell_keys, pair_lists

    out = np.zeros((mu.shape[0], 4))
    for ob in range(len(first) - 1):
        s = slice(int(first[ob]), int(first[ob + 1]))
        if s.stop == s.start:
            continue
        m = mu[s]
        cells = np.floor((m + 0.5) / LEAF).astype(np.int64)  # a voxel's centre sits at its index
        keys = cell_keys(cells)
        ukeys, where = np.unique(keys, return_inverse=True)
        corg = np.empty((len(ukeys), 3), np.int64)
        corg[where] = cells * LEAF
        sig = 1.0 / inv[s]
        lists = pair_lists(dict(keys=ukeys, corg=corg), m, sig, k)
        order = np.argsort(where, kind="stable")
        cg_start = np.zeros(len(ukeys) + 1, np.int64)
        np.cumsum(np.bincount(where, minlength=len(ukeys)), out=cg_start[1:])
        part = np.zeros((s.stop - s.start, 4))
        centre_gradients(lists["cstart"], lists["pg"], cg_start, order, np.ascontiguousarray(m),
                         np.ascontiguousarray(inv[s]), np.ascontiguousarray(fw[s]), float(k) ** 2,
                         part)
        out[s] = part
    return out


def shadow_points(index_box, lit, n, nl):
    """The shadow grids' rows (Objects.sh_grid: origin, spacing, dims, offset into sh_tau) of the
    n objects, and their points (index space) with the object of each: SHADOW_POINTS along the
    longest axis of each shadowed lit volume's index box (Shading.LIT_SHADOWS), half a voxel out."""
    grid = np.zeros((n, SHG_SIZE))
    pts, owner = [], []
    off = 0
    for k in np.flatnonzero(lit == Shading.LIT_SHADOWS):
        lo, hi = index_box[k]
        lo, hi = lo - 0.5, hi + 0.5
        s = max(float(np.max(hi - lo)) / (SHADOW_POINTS - 1), 1e-6)
        dims = np.maximum(np.ceil((hi - lo) / s).astype(np.int64) + 1, 2)
        axes = [lo[c] + s * np.arange(dims[c]) for c in range(3)]
        p = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        grid[k, SHG_ORIGIN:SHG_ORIGIN + 3], grid[k, SHG_SPACING] = lo, s
        grid[k, SHG_DIMS:SHG_DIMS + 3], grid[k, SHG_OFFSET] = dims, off * nl
        pts.append(p)
        owner.append(np.full(p.shape[0], k, np.int32))
        off += p.shape[0]
    return grid, np.concatenate(pts), np.concatenate(owner)
