"""Reference and paper modes along one ray: the pieces of the voxel walk sampled trilinearly
(reference_piece) or as the paper's sorted Gaussian samples (paper_piece), and lut_rows."""
from __future__ import annotations

import math

import numpy as np

from ...jit import njit, parallel_for
from ..inputs.layout import (
    BG_DEPTH,
    BRICK_HI,
    DEPTH,
    LS_VOXEL,
    PCUR,
    PDEPTH,
    RAD,
    SEGS,
    TMIN,
    TR,
    VSUM,
    VWT,
    Kind,
    Shading,
)
from .lit import shade_sample
from .surface import brick_xyz, sdf_crossing, surface_hit, trilinear, trilinear_grad
from .vecmath import (
    INF,
    _hot,
    _jit,
    add_sample,
    composite,
    composite_sample,
    lut_pos,
    recolor,
    sample_color,
    whitened_chord,
)


def lut_rows(lut, x, out):
    """out[n] = the first out.shape[1] columns of lut interpolated at x[n] in [0, 1] (clamped; NaN:
    zeros): the per-frame colours and opacities of every Gaussian, in parallel."""
    parallel_for(_lut_rows, x.shape[0], lut, x, out)


@njit(**_jit)
def _lut_rows(n0, n1, lut, x, out):
    for n in range(n0, n1):
        xn = x[n]
        if xn != xn:
            out[n, :] = 0.0
            continue
        i, w = lut_pos(lut, min(max(xn, 0.0), 1.0))
        for c in range(out.shape[1]):
            out[n, c] = lut[i, c] * (1.0 - w) + lut[i + 1, c] * w


@njit(**_hot)
def reference_piece(st, p0, p1, ncov, cov_obj, cov_cell, ro, rd, obj_step, bricks, cell_xyz,
                    obj_kind, obj_tf, obj_ls, tf_lut, tf_par, samp, acc, sprev, objs, xfer, wr, cbricks):
    """reference: trilinear voxel samples at midpoints, exact exponential compositing. Each
    object's medium exists only inside its leaves; objects overlapping in a piece add extinction,
    colours tau-weighted. Surfaces (Kind.SURFACE): the first sign change of the trilinear signed
    distance from + to - between samples (sprev: the object's previous one), refined by bisection;
    a ray that starts inside (a clip or the camera's cut) hits at its start. The volumes composite
    up to the hit, which ends the ray (surface_hit). Lit volumes: shaded on the voxels' gradient
    (trilinear central differences, cpu.lit); wr: the world ray. Volumes coloured by a second
    grid (objs.ctf) take the colour from its bricks (cbricks, the same cells), sampled alike."""
    dt = INF
    for c in range(ncov):
        ob = cov_obj[c]
        dn = math.sqrt(rd[ob, 0] ** 2 + rd[ob, 1] ** 2 + rd[ob, 2] ** 2)
        step = obj_step[ob] / dn  # world length of `step` voxels along this ray
        if step < dt:
            dt = step
    n = int(math.ceil((p1 - p0) / dt))
    if n < 1:
        n = 1
    h = (p1 - p0) / n
    for i in range(n):
        t = p0 + (i + 0.5) * h
        acc[:] = 0.0
        best = -1
        bt = INF
        for c in range(ncov):
            ob = cov_obj[c]
            x = ro[ob, 0] + t * rd[ob, 0]
            y = ro[ob, 1] + t * rd[ob, 1]
            z = ro[ob, 2] + t * rd[ob, 2]
            cid = cov_cell[c]
            fx = x - (cell_xyz[cid, 0] * 8 - 1)
            fy = y - (cell_xyz[cid, 1] * 8 - 1)
            fz = z - (cell_xyz[cid, 2] * 8 - 1)
            fx = min(max(fx, 0.0), BRICK_HI)
            fy = min(max(fy, 0.0), BRICK_HI)
            fz = min(max(fz, 0.0), BRICK_HI)
            i0, j0, k0 = int(fx), int(fy), int(fz)
            ax, ay, az = fx - i0, fy - j0, fz - k0
            B = bricks[cid]
            c00 = B[i0, j0, k0] * (1 - ax) + B[i0 + 1, j0, k0] * ax
            c10 = B[i0, j0 + 1, k0] * (1 - ax) + B[i0 + 1, j0 + 1, k0] * ax
            c01 = B[i0, j0, k0 + 1] * (1 - ax) + B[i0 + 1, j0, k0 + 1] * ax
            c11 = B[i0, j0 + 1, k0 + 1] * (1 - ax) + B[i0 + 1, j0 + 1, k0 + 1] * ax
            val = (c00 * (1 - ay) + c10 * ay) * (1 - az) + (c01 * (1 - ay) + c11 * ay) * az
            if obj_kind[ob] == Kind.SURFACE:
                th = sdf_crossing(sprev, ob, val, t, p0, h, ro, rd, B, cell_xyz[cid])
                if th < bt:
                    bt = th
                    best = c
                continue
            if obj_kind[ob] == Kind.SHELL:  # SDF (world units) -> occupancy with a one-voxel ramp
                val = 0.5 - val / obj_ls[ob, LS_VOXEL]
            st[SEGS] += 1
            sample_color(ob, val, x, y, z, obj_kind, obj_tf, obj_ls, tf_lut, tf_par, samp)
            if objs.ctf[ob] >= 0:
                recolor(ob, trilinear(cbricks[cid], fx, fy, fz), objs.ctf, tf_lut, tf_par, samp)
            if objs.lit[ob] != Shading.EMISSION and samp[0] > 0.0:
                gx, gy, gz = trilinear_grad(B, fx, fy, fz)
                shade_sample(samp, ob, gx, gy, gz, x, y, z, wr, t, objs, xfer.lights, xfer.settings,
                             tf_par[obj_tf[ob]])
            add_sample(acc, samp)
        if best >= 0:
            ob = cov_obj[best]
            B = bricks[cov_cell[best]]
            cxyz = cell_xyz[cov_cell[best]]
            x = ro[ob, 0] + bt * rd[ob, 0]
            y = ro[ob, 1] + bt * rd[ob, 1]
            z = ro[ob, 2] + bt * rd[ob, 2]
            fx, fy, fz = brick_xyz(cxyz, x, y, z)
            gx, gy, gz = trilinear_grad(B, fx, fy, fz)
            if acc[0] > 0.0 and bt > t - 0.5 * h:  # the volumes before the hit in this sample
                sig = acc[0]
                composite(st, sig * (bt - (t - 0.5 * h)), acc[1] / sig, acc[2] / sig, acc[3] / sig,
                          acc[4] / acc[5] if acc[5] > 0 else np.nan, t - 0.5 * h, bt)
            surface_hit(st, ob, bt, gx, gy, gz, obj_ls, tf_lut[obj_tf[ob]], x, y, z)
            return
        if acc[0] > 0.0:
            composite_sample(st, acc, t, h)
            if st[TR] < st[TMIN]:
                return


@njit(**_hot)
def paper_piece(st, p0, p1, ncov, cov_obj, cov_cell, ro, rd, cell_start, cell_items, g_mu, g_inv,
                g_w, g_col, g_val, g_obj, g_volfac, k2, nsteps, max_depth, rclip):
    """The seed paper: closest hit (smallest entry, ties by id) entering at or after the current
    origin, fixed midpoint steps over its chord, A = rho dt / det(Sigma), C += T c A,
    T *= exp(-A), continue after its exit; overlapping Gaussians entered earlier are ignored.
    Chords are cut to their object's clip interval rclip[ob] (clip.py)."""
    while st[PDEPTH] < max_depth and st[TR] >= st[TMIN]:
        best = -1
        bt0 = INF
        bt1 = 0.0
        tcur = max(st[PCUR], p0)
        for c in range(ncov):
            ob = cov_obj[c]
            cid = cov_cell[c]
            ox, oy, oz = ro[ob, 0], ro[ob, 1], ro[ob, 2]
            dx, dy, dz = rd[ob, 0], rd[ob, 1], rd[ob, 2]
            for j in range(cell_start[cid], cell_start[cid + 1]):
                g = cell_items[j]
                if g_w[g] == 0.0:
                    continue
                ts, a, q = whitened_chord(ox, oy, oz, dx, dy, dz, g_mu, g_inv, g)
                if q >= k2:
                    continue
                hw = math.sqrt((k2 - q) / a)
                t0 = ts - hw
                t1 = ts + hw
                if t0 < rclip[ob, 0]:
                    t0 = rclip[ob, 0]
                if t1 > rclip[ob, 1]:
                    t1 = rclip[ob, 1]
                if t0 < tcur or t0 >= p1 or not t1 > t0:
                    continue
                if t0 < bt0 or (t0 == bt0 and g < best):
                    bt0 = t0
                    bt1 = t1
                    best = g
        if best < 0:
            return
        g = best
        ob = g_obj[g]
        ox, oy, oz = ro[ob, 0], ro[ob, 1], ro[ob, 2]
        dx, dy, dz = rd[ob, 0], rd[ob, 1], rd[ob, 2]
        dt = (bt1 - bt0) / nsteps
        for s in range(nsteps):
            t = bt0 + (s + 0.5) * dt
            ux = (ox + t * dx - g_mu[g, 0]) * g_inv[g, 0]
            uy = (oy + t * dy - g_mu[g, 1]) * g_inv[g, 1]
            uz = (oz + t * dz - g_mu[g, 2]) * g_inv[g, 2]
            rho = math.exp(-0.5 * (ux * ux + uy * uy + uz * uz))
            A = g_w[g] * rho * dt * g_volfac[g]
            T = st[TR]
            st[RAD] += T * g_col[g, 0] * A
            st[RAD + 1] += T * g_col[g, 1] * A
            st[RAD + 2] += T * g_col[g, 2] * A
            if g_val[g] == g_val[g]:
                st[VSUM] += T * A * g_val[g]
                st[VWT] += T * A
            st[TR] = T * math.exp(-A)
            if st[DEPTH] == BG_DEPTH and st[TR] <= 0.5:
                st[DEPTH] = t
        st[SEGS] += nsteps
        st[PDEPTH] += 1
        st[PCUR] = bt1
