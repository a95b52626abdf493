"""Reference mode's common case in tight loops: a single fog volume, Emission shading, coloured
by its own grid through a linear transfer function (no level set, lights, second grid or log
scale). It samples the points and composites the model of cpu.pieces.reference_piece (midpoints
of equal steps per leaf interval, trilinear, post-classified, exact exponential) to rounding, but
keeps the ray's state in registers, walks every interval of the ray in one call (a call per piece
with every table group as arguments cost more than its samples), scales the table position once
per ray and absorbs by an inline series (a libm call cost as much as the rest of a sample).
An interval is taken in chunks of up to FOG_CHUNK samples, first all their values, then their
compositing: the value loop's iterations are independent, so their brick reads overlap, which a
single loop's data-dependent branches (skipped sub-blocks, transparent samples) prevented
(MNI 17-19% and the Mantaflow grids 5-11% faster on one thread at steps 1-0.25)."""
from __future__ import annotations

import math

from ...jit import njit
from ..inputs.layout import (
    BG_DEPTH,
    BRICK_HI,
    DEPTH,
    PAR_DENSITY,
    PAR_VMAX,
    PAR_VMIN,
    RAD,
    SEGS,
    TMIN,
    TR,
    VSUM,
    VWT,
)
from .surface import trilinear
from .vecmath import _hot, _hot_fused

FOG_CHUNK = 32  # samples whose values are taken before they are composited (Scratch.fog)

# the series of 1 - exp(-x) = sum c_k x^(k + 1), c_k = (-1)^k / (k + 1)!, to 12 terms
C0, C1, C2, C3, C4, C5, C6, C7, C8, C9, C10, C11 = ((-1.0) ** k / math.factorial(k + 1) for k in range(12))


@njit(**_hot, inline="always")
def absorbed(tau):
    """1 - exp(-tau) for tau > 0 to double precision: below 1/16 by its Taylor series (the
    remainder under 1e-16 relative) in Estrin's order (fewer dependent steps than Horner's),
    inline, since a libm call cost as much as the rest of a sample; above, by expm1."""
    if tau < 0.0625:
        x2 = tau * tau
        x4 = x2 * x2
        q0 = (C0 + C1 * tau) + (C2 + C3 * tau) * x2
        q1 = (C4 + C5 * tau) + (C6 + C7 * tau) * x2
        q2 = (C8 + C9 * tau) + (C10 + C11 * tau) * x2
        return tau * ((q0 + q1 * x4) + q2 * (x4 * x4))
    return -math.expm1(-tau)


@njit(**_hot)
def equal_steps(p0, p1, dt):
    """(count, length) of the equal steps of at most dt over [p0, p1], as the general sampler
    divides it (cpu.pieces.reference_piece): compiled on its own without fastmath (numba's
    inlining would give it the caller's flags), so that a reciprocal never changes a count."""
    ns = int(math.ceil((p1 - p0) / dt))
    if ns < 1:
        ns = 1
    return ns, (p1 - p0) / ns


@njit(**_hot_fused)
def reference_fog(st, n, iv_ta, iv_tb, iv_cell, ro, rd, step, bricks, cell_xyz, lut, par, clear, vals):
    """Composite the n leaf intervals (iv_ta, iv_tb, iv_cell, front to back) of object 0's ray
    (index-space origin ro[0], direction rd[0]) into st; step: the object's step in voxels,
    lut/par its transfer function's table and parameters; clear: per cell its sub-blocks whose
    samples are all transparent (packing.clear_bits), skipped unread: they would add nothing;
    vals: room for FOG_CHUNK sample values (NaN: skipped or no medium)."""
    ox, oy, oz = ro[0, 0], ro[0, 1], ro[0, 2]
    dx, dy, dz = rd[0, 0], rd[0, 1], rd[0, 2]
    dt = step / math.sqrt(dx * dx + dy * dy + dz * dz)
    lo, hi, a_scale = par[PAR_VMIN], par[PAR_VMAX], par[PAR_DENSITY]
    kmax = lut.shape[0] - 1
    scale = kmax / (hi - lo) if hi > lo else 0.0
    T, r, g, b = st[TR], st[RAD], st[RAD + 1], st[RAD + 2]
    vsum, vwt, depth, tmin = st[VSUM], st[VWT], st[DEPTH], st[TMIN]
    segs = 0
    for pi in range(n):
        p0 = iv_ta[pi]
        p1 = iv_tb[pi]
        cid = iv_cell[pi]
        ns, h = equal_steps(p0, p1, dt)
        clr = clear[cid]
        if clr == -1:  # every sub-block transparent: the samples are counted, not taken
            segs += ns
            continue
        cxyz = cell_xyz[cid]
        B = bricks[cid]
        # the interval's start in the leaf's brick, its samples clamped as cpu.surface.brick_xyz does
        bx = ox + p0 * dx - (cxyz[0] * 8 - 1)
        by = oy + p0 * dy - (cxyz[1] * 8 - 1)
        bz = oz + p0 * dz - (cxyz[2] * 8 - 1)
        c0 = 0
        while c0 < ns:
            c1 = min(ns, c0 + FOG_CHUNK)
            for i in range(c0, c1):
                u = (i + 0.5) * h
                fx = min(max(bx + u * dx, 0.0), BRICK_HI)
                fy = min(max(by + u * dy, 0.0), BRICK_HI)
                fz = min(max(bz + u * dz, 0.0), BRICK_HI)
                if clr != 0 and (clr >> ((min(int(fx) >> 1, 3) * 4 + min(int(fy) >> 1, 3)) * 4
                                         + min(int(fz) >> 1, 3))) & 1:
                    vals[i - c0] = math.nan  # a transparent sub-block (bricks.sub_max)
                else:
                    vals[i - c0] = trilinear(B, fx, fy, fz)
            for i in range(c0, c1):
                segs += 1
                val = vals[i - c0]
                if val != val:
                    continue  # skipped, or NaN: no medium
                # the transfer function's table position (cpu.vecmath.tf_x, lut_pos), scaled once per ray
                if hi > lo:
                    f = (val - lo) * scale
                else:
                    f = kmax if val >= hi else 0.0
                if f < 0.0:
                    f = 0.0
                elif f > kmax:
                    f = kmax
                k = int(f)
                if k > kmax - 1:
                    k = kmax - 1
                w = f - k
                sig = a_scale * (lut[k, 3] * (1.0 - w) + lut[k + 1, 3] * w)
                tau = sig * h
                if not tau > 0.0:
                    continue
                a = absorbed(tau)
                wt = T * a
                r += wt * (lut[k, 0] * (1.0 - w) + lut[k + 1, 0] * w)
                g += wt * (lut[k, 1] * (1.0 - w) + lut[k + 1, 1] * w)
                b += wt * (lut[k, 2] * (1.0 - w) + lut[k + 1, 2] * w)
                vsum += wt * val
                vwt += wt
                Tn = T * (1.0 - a)
                if depth == BG_DEPTH and Tn <= 0.5:  # the median depth (cpu.vecmath.composite)
                    fr = math.log(T / 0.5) / tau if T > 0.5 else 0.0
                    depth = p0 + (i + 0.5) * h - 0.5 * h + fr * h
                T = Tn
                if T < tmin:
                    break
            if T < tmin:
                break
            c0 = c1
        if T < tmin:
            break
    st[TR], st[RAD], st[RAD + 1], st[RAD + 2] = T, r, g, b
    st[VSUM], st[VWT], st[DEPTH] = vsum, vwt, depth
    st[SEGS] += segs
