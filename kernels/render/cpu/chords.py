"""The pieces of the particles/field sweeps (see cpu.gauss for the method): the hit record's
and the sweep state's columns, the entry queue ordered by (t, id), chord bounds and closed-form
optical depth, and closing an interval of overlapping chords; and the per-Gaussian ray test that
fills the queue."""
from __future__ import annotations

import math

import numpy as np

from ...jit import njit
from ..inputs.layout import (
    BG_DEPTH,
    CB,
    CEND,
    CG,
    CR,
    DEPTH,
    FA,
    FB,
    HA,
    HQ,
    HSTEP,
    IA,
    LAST,
    NH,
    NQ,
    NQS,
    PK,
    QH,
    REC_INV,
    REC_MU,
    REC_W,
    RHO,
    SA,
    SEGS,
    SQRT_HALF,
    SQRT_HALF_PI,
    TMIN,
    TR,
    TS,
    VAL,
    VW,
    C,
    E,
    S,
)
from ..scene.objects import Mode
from .vecmath import INF, _hot, composite, erf_fast, erf_span

# the hit record's columns (S .. CV, NF) and the sweep state's (NQ .. QH, IA .. CEND): layout
OVERFLOW = -1


@njit(**_hot, inline="always")
def _before(ta, ka, tb, kb):
    return ta < tb or (ta == tb and ka < kb)


@njit(**_hot, inline="always")
def _put(qt, qk, qh, j, t, key, h):
    qt[j] = t
    qk[j] = key
    qh[j] = h


@njit(**_hot, inline="always")
def queue_insert(qt, qk, qh, q0, n, t, key, h):
    """Insert into the queue qt/qk/qh[q0:n], kept sorted by (t, key), from its back; the key (the
    Gaussian id) is unique per ray, so the order is total and does not depend on discovery order.
    Entries arrive nearly in order (tile lists are sorted by a lower bound of the entry time, the
    walk goes front to back), so few move: cheaper than a heap, and popping is q0 += 1. The queue
    only grows at its back, so n <= the hits so far. Returns n + 1."""
    j = n
    while j > q0 and _before(t, key, qt[j - 1], qk[j - 1]):
        _put(qt, qk, qh, j, qt[j - 1], qk[j - 1], qh[j - 1])
        j -= 1
    _put(qt, qk, qh, j, t, key, h)
    return n + 1


@njit(**_hot, inline="always")
def entry_face(dx, dy, dz):
    """Face through which the walk entered a cell from the one at offset -(dx, dy, dz): 2a moving
    +a, 2a + 1 moving -a; -1 when that cell is not a face neighbour (first cell, gaps, edges)."""
    if dy == 0 and dz == 0:
        return 0 if dx == 1 else (1 if dx == -1 else -1)
    if dx == 0 and dz == 0:
        return 2 if dy == 1 else (3 if dy == -1 else -1)
    if dx == 0 and dy == 0:
        return 4 if dz == 1 else (5 if dz == -1 else -1)
    return -1


@njit(**_hot, inline="always")
def widen(cb, H, h):
    """Widen the colour bounds cb = (lo rgb, hi rgb) by hit h's colour."""
    for c in range(3):
        cb[c] = min(cb[c], H[h, CR + c])
        cb[3 + c] = max(cb[3 + c], H[h, CR + c])


@njit(**_hot, inline="always")
def reset_bounds(cb):
    for c in range(3):
        cb[c] = INF
        cb[3 + c] = -INF


@njit(**_hot, inline="always")
def spread_of(cb):
    return max(cb[3] - cb[0], cb[4] - cb[1], cb[5] - cb[2])


@njit(**_hot, inline="always")
def erf_at(H, h, t):
    """erf(u) of hit h at ray distance t clipped to its chord."""
    if t < H[h, S]:
        t = H[h, S]
    if t > H[h, E]:
        t = H[h, E]
    return erf_fast(H[h, SA] * (t - H[h, TS]))


@njit(**_hot, inline="always")
def chord_tau(H, h, a, b):
    """Closed-form optical depth of hit h over [a, b] clipped to its chord (short spans by the
    series in erf_span)."""
    if a < H[h, S]:
        a = H[h, S]
    if b > H[h, E]:
        b = H[h, E]
    if not b > a:
        return 0.0
    sa = H[h, SA]
    ts = H[h, TS]
    return H[h, C] * erf_span(sa * (a - ts), sa * (b - ts), sa * (b - a))


@njit(**_hot)
def median_depth(st, H, h, a, b, tsum):
    """Depth pass for a one-Gaussian interval: where T crosses 0.5, by bisection on the closed form."""
    T = st[TR]
    if st[DEPTH] != BG_DEPTH or T * math.exp(-tsum) > 0.5:
        return
    target = math.log(T / 0.5) if T > 0.5 else 0.0
    lo = a
    hi = b
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if chord_tau(H, h, a, mid) < target:
            lo = mid
        else:
            hi = mid
    st[DEPTH] = 0.5 * (lo + hi)


@njit(**_hot, inline="always")
def mix_add(H, h, tk, tsum, r, g, b, vs, vw):
    """The interval's sums (depth, depth-weighted colour and value, value weight) with member h's
    depth tk added."""
    return (tsum + tk, r + tk * H[h, CR], g + tk * H[h, CG], b + tk * H[h, CB], vs + tk * H[h, VAL],
            vw + tk * H[h, VW])


@njit(**_hot, inline="always")
def composite_mix(st, tsum, r, g, b, vs, vw, a, c):
    """Composite a tau-weighted colour and value sum over [a, c]."""
    composite(st, tsum, r / tsum, g / tsum, b / tsum, vs / vw if vw > 0 else np.nan, a, c)


@njit(**_hot)
def close_interval(st, H, mem, nm, a, b, spread, tau_max, keep, cb):
    """Composite the members' optical depth over [a, b] (see module doc). Moves the members still
    open at b to keep[:n] with their colour bounds in cb; returns n and their peak-density sum."""
    tsum = r = gg = bb = vs = vw = 0.0
    n = 0
    rho = 0.0
    reset_bounds(cb)
    for k in range(nm):
        h = mem[k]
        fb = erf_at(H, h, b)
        tk = H[h, C] * (fb - H[h, FA])
        H[h, FB] = H[h, FA]  # the erf at a, for the subdivisions
        H[h, FA] = fb
        tsum, r, gg, bb, vs, vw = mix_add(H, h, tk, tsum, r, gg, bb, vs, vw)
        if H[h, E] > b:
            keep[n] = h
            n += 1
            rho += H[h, PK]
            widen(cb, H, h)
    st[SEGS] += nm
    if not tsum > 0.0:
        return n, rho
    nsub = 1
    if nm > 1 and tau_max > 0.0 and tsum * spread > tau_max:
        nsub = min(int(math.ceil(tsum * spread / tau_max)), 1024)
    if nsub == 1:
        if nm == 1:
            median_depth(st, H, mem[0], a, b, tsum)
        composite_mix(st, tsum, r, gg, bb, vs, vw, a, b)
        return n, rho
    for s in range(nsub):
        # the same sums over each part, each member's erf carried part to part in FB
        a0 = a + (b - a) * s / nsub
        a1 = a + (b - a) * (s + 1) / nsub if s + 1 < nsub else b
        tsum = r = gg = bb = vs = vw = 0.0
        for k in range(nm):
            h = mem[k]
            if H[h, E] <= a0 or H[h, S] >= a1:
                continue
            f1 = H[h, FA] if s + 1 == nsub else erf_at(H, h, a1)
            tk = H[h, C] * (f1 - H[h, FB])
            H[h, FB] = f1
            tsum, r, gg, bb, vs, vw = mix_add(H, h, tk, tsum, r, gg, bb, vs, vw)
        st[SEGS] += nm
        if tsum > 0.0:
            composite_mix(st, tsum, r, gg, bb, vs, vw, a0, a1)
            if st[TR] < st[TMIN]:
                break
    return n, rho


BATCH = 32


@njit(**_hot)
def sweep_start(mode, qs, fs, cb, rd, obj_step):
    """Empty queue, no hits; field samples at t_i = (i + 1/2) h from the ray origin, h the finest
    object step along this ray."""
    for c in range(NQS):
        qs[c] = 0
    fs[IA] = 0.0
    fs[LAST] = 0.0
    fs[RHO] = 0.0
    fs[CEND] = -INF
    reset_bounds(cb)
    if mode == Mode.FIELD:
        h = INF
        for ob in range(rd.shape[0]):
            dn = math.sqrt(rd[ob, 0] ** 2 + rd[ob, 1] ** 2 + rd[ob, 2] ** 2)
            h = min(h, obj_step[ob] / dn)
        fs[HSTEP] = h


@njit(**_hot, inline="always")
def chord_of(mx, my, mz, ix, iy, iz, ox, oy, oz, dx, dy, dz, k2, t_near, t_far):
    """The exact ray/support test of a Gaussian centred at m with 1/sigma i (object-index-space
    ray), without branches: s, e, ts, aa, qq, ra (chord clipped to the ray's [t_near, t_far], closest
    approach, |d'|^2, its squared distance, 1 / |d'|); a miss has s >= e. One division and two
    roots."""
    wx, wy, wz = (ox - mx) * ix, (oy - my) * iy, (oz - mz) * iz
    vx, vy, vz = dx * ix, dy * iy, dz * iz
    aa = vx * vx + vy * vy + vz * vz
    bb = wx * vx + wy * vy + wz * vz
    ia = 1.0 / aa
    ts = -bb * ia
    px, py, pz = wx + ts * vx, wy + ts * vy, wz + ts * vz
    qq = px * px + py * py + pz * pz
    ra = math.sqrt(ia)
    hw = math.sqrt(max(k2 - qq, 0.0)) * ra
    s = max(ts - hw, t_near) if qq < k2 else INF
    return s, min(ts + hw, t_far), ts, aa, qq, ra


@njit(**_hot, inline="always")
def chord(g, ox, oy, oz, dx, dy, dz, g_rec, k2, t_near, t_far):
    """chord_of for Gaussian g's record in g_rec."""
    return chord_of(g_rec[g, REC_MU], g_rec[g, REC_MU + 1], g_rec[g, REC_MU + 2], g_rec[g, REC_INV],
                    g_rec[g, REC_INV + 1], g_rec[g, REC_INV + 2], ox, oy, oz, dx, dy, dz, k2, t_near, t_far)


@njit(**_hot, inline="always")
def peak(g, g_rec, qq, k2):
    """Peak density of Gaussian g along a ray passing at squared distance qq (in its sigmas):
    only for hits (an exponential per candidate cost ~15% of the test)."""
    return g_rec[g, REC_W] * math.exp(-0.5 * min(qq, k2))


@njit(**_hot, inline="always")
def add_hit(H, hid, ev_t, ev_k, ev_h, q0, nq, nh, g, s, e, ts, aa, qq, ra, pk):
    """Hit nh's record in H and its entry event; returns the queue's new end."""
    H[nh, S] = s
    H[nh, E] = e
    H[nh, TS] = ts
    H[nh, SA] = SQRT_HALF * aa * ra
    H[nh, HQ] = 0.5 * qq
    H[nh, HA] = 0.5 * aa
    H[nh, PK] = pk
    H[nh, C] = pk * SQRT_HALF_PI * ra
    hid[nh] = g
    return queue_insert(ev_t, ev_k, ev_h, q0, nq, s, np.int64(g), nh)


@njit(**_hot, inline="always")
def test_one(g, ox, oy, oz, dx, dy, dz, g_rec, k2, t_near, t_far, H, hid, ev_t, ev_k, ev_h, qs):
    """Gaussian g's test (chord); a hit gets a record in H and an entry event. Returns OVERFLOW
    when H is full."""
    s, e, ts, aa, qq, ra = chord(g, ox, oy, oz, dx, dy, dz, g_rec, k2, t_near, t_far)
    if not e > s:
        return 0
    pk = peak(g, g_rec, qq, k2)
    nh = qs[NH]
    if nh >= H.shape[0]:
        return OVERFLOW
    qs[NQ] = add_hit(H, hid, ev_t, ev_k, ev_h, qs[QH], qs[NQ], nh, g, s, e, ts, aa, qq, ra, pk)
    qs[NH] = nh + 1
    return 0
