"""Scalar float64 helpers shared by the CPU kernels: erf spans, the transfer function, the
whitened ray-Gaussian chord, exponential compositing."""
from __future__ import annotations

import math

import numpy as np

from ...jit import njit
from ..inputs.layout import (
    BG_DEPTH,
    DEPTH,
    LS_COLOR,
    LS_CONST,
    LS_PLANE,
    LS_RANGE,
    PAR_DENSITY,
    PAR_LOG,
    PAR_VMAX,
    PAR_VMIN,
    RAD,
    TR,
    TWO_OVER_SQRT_PI,
    VSUM,
    VWT,
    Kind,
)

INF = np.inf
SQRT_PI = math.sqrt(math.pi)

_jit = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")
# Per-pixel kernels: no allocation, so no reference counting. With it, numba increfs and decrefs
# (atomically) every array argument of every call, inlined or not: ~9 ns per array per call,
# measured at 35-45% of a particles frame.
_hot = dict(_jit, _nrt=False)
# The one-fog sampler (cpu.fog): fused multiply-adds and
# reciprocals, which move results by rounding only (no flag that assumes away NaN, Inf or the
# order of a sum). 1.2-1.3x on its loop. (Not the walk: its interval ends then move far
# enough to shift a surface hit against the GPU device.)
_hot_fused = dict(_hot, fastmath={"contract", "arcp", "nsz"})


def _erf_table(per=16, deg=8, umax=6.0):
    """Taylor coefficients of erf about the midpoint of each 1/per-wide cell of [0, umax), in the
    cell's local coordinate d in [-1/2, 1/2]: erf^(k)(m) = 2/sqrt(pi) (-1)^(k-1) H_{k-1}(m) e^{-m^2}
    (physicists' Hermite polynomials, by their recurrence). Degree 8 at 1/16: within 3.3e-16 of
    libm's erf (tests/kernels/test_render_particles.py), about 4x faster, and erf(6) rounds to 1 in float64."""
    n = int(umax * per)
    tab = np.zeros((n, deg + 1))
    for i in range(n):
        m = (i + 0.5) / per
        tab[i, 0] = math.erf(m)
        h0, h1 = 1.0, 2.0 * m  # H_0, H_1
        for k in range(1, deg + 1):
            hk = h0 if k == 1 else h1
            tab[i, k] = TWO_OVER_SQRT_PI * (-1) ** (k - 1) * hk * math.exp(-m * m) / math.factorial(k) / per ** k
            if k >= 2:
                h0, h1 = h1, 2.0 * m * h1 - 2.0 * (k - 1) * h0
    return tab


ERF_PER = 16.0
ERF_UMAX = 6.0
ERF_TAB = _erf_table()


@njit(**_hot)
def erf_fast(u):
    """erf(u) from ERF_TAB (see _erf_table); NaN stays NaN."""
    x = abs(u)
    if not x < ERF_UMAX:
        return math.copysign(1.0, u) if x == x else x
    f = x * ERF_PER
    i = int(f)
    d = f - i - 0.5
    c = ERF_TAB[i]
    d2 = d * d
    d4 = d2 * d2
    # Estrin's scheme: a shorter dependency chain than Horner
    p = (c[0] + c[1] * d + d2 * (c[2] + c[3] * d)
         + d4 * (c[4] + c[5] * d + d2 * (c[6] + c[7] * d) + d4 * c[8]))
    return math.copysign(p, u)


@njit(**_hot)
def erf_diff(u0, u1):
    """erf(u1) - erf(u0) for u0 <= u1 (see erf_span)."""
    return erf_span(u0, u1, u1 - u0)


@njit(**_hot)
def erf_span(u0, u1, h):
    """erf(u1) - erf(u0) for u0 <= u1, given the span h = u1 - u0 computed exactly by the caller
    (sa * (t1 - t0): forming u1 - u0 after rounding loses short spans). Stable: a Taylor series about
    the midpoint for short spans (h * max(1, |m|) small: error ~ (h m)^6), erfc for same-sign tails."""
    m = 0.5 * (u0 + u1)
    if h * max(1.0, abs(m)) < 1e-2:
        m2 = m * m
        h2 = h * h
        series = 1.0 + (4.0 * m2 - 2.0) * h2 / 24.0 + (16.0 * m2 * m2 - 48.0 * m2 + 12.0) * h2 * h2 / 1920.0
        return TWO_OVER_SQRT_PI * h * math.exp(-m2) * series
    if u0 >= 0.0:
        return math.erfc(u0) - math.erfc(u1)
    if u1 <= 0.0:
        return math.erfc(-u1) - math.erfc(-u0)
    return math.erf(u1) - math.erf(u0)


@njit(**_hot)
def line_integral(ox, oy, oz, dx, dy, dz, t0, t1):
    """Integral over t in [t0, t1] of exp(-|o' + t d'|^2 / 2) (whitened ray): float64 reference
    used by the tests; the kernels inline the same steps."""
    a = dx * dx + dy * dy + dz * dz
    b = ox * dx + oy * dy + oz * dz
    ts = -b / a
    px, py, pz = ox + ts * dx, oy + ts * dy, oz + ts * dz
    q = px * px + py * py + pz * pz
    sa = math.sqrt(0.5 * a)
    return math.exp(-0.5 * q) * math.sqrt(math.pi / (2.0 * a)) * erf_span(sa * (t0 - ts), sa * (t1 - ts),
                                                                         sa * (t1 - t0))


@njit(**_hot)
def tf_x(v, par):
    """Normalised TF coordinate in [0, 1]; NaN stays NaN."""
    if par[PAR_LOG] > 0.5:
        lo = math.log10(par[PAR_VMIN])
        hi = math.log10(par[PAR_VMAX])
        if v > 0.0:
            lv = math.log10(v)
        elif v <= 0.0:
            lv = -INF
        else:
            return v
        if hi > lo:
            x = (lv - lo) / (hi - lo)
        else:
            x = 1.0 if lv >= hi else 0.0
    else:
        if par[PAR_VMAX] > par[PAR_VMIN]:
            x = (v - par[PAR_VMIN]) / (par[PAR_VMAX] - par[PAR_VMIN])
        elif v != v:
            return v
        else:
            x = 1.0 if v >= par[PAR_VMAX] else 0.0
    if x < 0.0:
        return 0.0
    if x > 1.0:
        return 1.0
    return x


@njit(**_hot, inline="always")
def lut_pos(lut, x):
    """Row and weight of x in [0, 1] for linear interpolation in lut."""
    k = lut.shape[0]
    f = x * (k - 1)
    i = int(f)
    if i > k - 2:
        i = k - 2
    if i < 0:
        i = 0
    return i, f - i


@njit(**_hot, inline="always")
def lut_rgb(lut, i, w, out):
    """out[1:4] = the interpolated colour at (row i, weight w)."""
    for c in range(3):
        out[1 + c] = lut[i, c] * (1.0 - w) + lut[i + 1, c] * w



@njit(**_hot)
def composite(st, tau, r, g, b, v, ta, tb):
    """L += T c (1 - e^-tau) (expm1), T *= e^-tau; Value and median Depth bookkeeping (st: the
    ray's state, see TR)."""
    if tau <= 0.0:
        return
    T = st[TR]
    em = math.expm1(-tau)
    w = -T * em
    st[RAD] += w * r
    st[RAD + 1] += w * g
    st[RAD + 2] += w * b
    if v == v:
        st[VSUM] += w * v
        st[VWT] += w
    Tn = T * (1.0 + em)  # exp(-tau), within an ulp of 1
    if st[DEPTH] == BG_DEPTH and Tn <= 0.5:
        f = math.log(T / 0.5) / tau if T > 0.5 else 0.0
        st[DEPTH] = ta + f * (tb - ta)
    st[TR] = Tn


@njit(**_hot, inline="always")
def whitened_chord(ox, oy, oz, dx, dy, dz, g_mu, g_inv, g):
    """Ray o + t d against Gaussian g in its whitened frame: (t*, a = |d'|^2, Qmin), with Qmin from
    the closest-point vector (never c - b^2/a, which cancels far from the origin)."""
    ix, iy, iz = g_inv[g, 0], g_inv[g, 1], g_inv[g, 2]
    wx, wy, wz = (ox - g_mu[g, 0]) * ix, (oy - g_mu[g, 1]) * iy, (oz - g_mu[g, 2]) * iz
    vx, vy, vz = dx * ix, dy * iy, dz * iz
    a = vx * vx + vy * vy + vz * vz
    ts = -(wx * vx + wy * vy + wz * vz) / a
    px, py, pz = wx + ts * vx, wy + ts * vy, wz + ts * vz
    return ts, a, px * px + py * py + pz * pz



@njit(**_hot)
def sample_color(ob, s, x_idx, y_idx, z_idx, obj_kind, obj_tf, obj_ls, tf_lut, tf_par, out):
    """sigma_t and linear colour of object ob for field value s at index point x."""
    tfi = obj_tf[ob]
    par = tf_par[tfi]
    lut = tf_lut[tfi]
    if obj_kind[ob] == Kind.SHELL:  # uniform opacity, colour by coordinate or constant
        occ = s
        if occ > 1.0:
            occ = 1.0
        if occ <= 0.0:
            out[0] = 0.0
            return
        out[0] = par[PAR_DENSITY] * occ
        ls = obj_ls[ob]
        if ls[LS_CONST] > 0.5:
            out[1], out[2], out[3] = ls[LS_COLOR], ls[LS_COLOR + 1], ls[LS_COLOR + 2]
        else:
            c = ls[LS_PLANE] * x_idx + ls[LS_PLANE + 1] * y_idx + ls[LS_PLANE + 2] * z_idx + ls[LS_PLANE + 3]
            lo, hi = ls[LS_RANGE], ls[LS_RANGE + 1]
            x = (c - lo) / (hi - lo) if hi > lo else 0.5
            x = min(max(x, 0.0), 1.0)
            i, w = lut_pos(lut, x)
            lut_rgb(lut, i, w, out)
        out[4] = np.nan
        return
    x = tf_x(s, par)
    if x != x:
        out[0] = 0.0
        return
    i, w = lut_pos(lut, x)
    out[0] = par[PAR_DENSITY] * (lut[i, 3] * (1.0 - w) + lut[i + 1, 3] * w)
    lut_rgb(lut, i, w, out)
    out[4] = s


@njit(**_hot, inline="always")
def recolor(ob, cv, obj_ctf, tf_lut, tf_par, out):
    """A volume coloured by a second grid (obj_ctf[ob] >= 0): the sample's colour from its colour
    map at the second grid's value cv (NaN: black); its extinction and value stay the first
    grid's."""
    c = obj_ctf[ob]
    if c < 0 or not out[0] > 0.0:
        return
    x = tf_x(cv, tf_par[c])
    if x != x:
        out[1] = out[2] = out[3] = 0.0
        return
    lut = tf_lut[c]
    i, w = lut_pos(lut, x)
    lut_rgb(lut, i, w, out)


@njit(**_hot, inline="always")
def add_sample(acc, samp):
    """Add one object's sample (sigma_t, rgb, value) to acc = (sigma, r, g, b, vsum, vweight)."""
    sg = samp[0]
    if sg > 0.0:
        acc[0] += sg
        acc[1] += sg * samp[1]
        acc[2] += sg * samp[2]
        acc[3] += sg * samp[3]
        if samp[4] == samp[4]:
            acc[4] += sg * samp[4]
            acc[5] += sg


@njit(**_hot, inline="always")
def composite_sample(st, acc, t, h):
    """Composite the accumulated sample at t over a step h (colours sigma-weighted)."""
    sig = acc[0]
    if sig > 0.0:
        composite(st, sig * h, acc[1] / sig, acc[2] / sig, acc[3] / sig,
                  acc[4] / acc[5] if acc[5] > 0 else np.nan, t - 0.5 * h, t + 0.5 * h)


