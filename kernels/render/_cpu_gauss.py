"""Particles and field modes: each ray tests every Gaussian once and sweeps its chords in
(t, id) order, streaming behind its candidate list so early termination still saves the work.
Candidates come from the frame's screen tile (trace_tiles, ordered by a lower bound of the entry
time: see _cpu_tiles) or, when there are no tile lists, from the leaf walk (trace_gauss).

Why the walk is exact and complete: it visits leaf cells front to back and each cell lists the
Gaussians whose support box meets it. A Gaussian met in a cell was already tested if its box also
covers the previous cell visited for its object (the cells of a box along a line are consecutive),
so it is skipped there. A chord enters at a point inside its box, hence inside a listed cell the ray
visits at or before that time: once the cells entered before t are visited, every chord entering
before t is known, and the events before t can be swept.

Only entries are queued (sorted by (t, id)); exits need no events. Particles: chords
overlapping one another form a cluster that ends at the latest exit of its members, so the next
entry at or after that ends it (non-overlapping supports are exact). Within a cluster an interval
closes at an entry when an upper bound of its optical depth x colour spread (sum of the members'
peak densities x length x spread) would pass tau_max; the members still open carry over. A closed
interval gets each member's closed-form optical depth, C (erf(u_b) - erf(u_a)), with erf(u_a)
cached from the member's entry or the previous boundary (one erf per member and boundary); its
colour is their tau-weighted mean, subdivided until tau x spread <= tau_max (one colour or one
member: exact).
Field: midpoint samples on a uniform grid along the ray; each active Gaussian's value is carried
from sample to sample by two multiplications (exp(-a(t+h)^2) = exp(-a t^2) r, r *= exp(-2 a h^2)),
and it leaves the active set at the first sample past its exit.
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import njit
from ._cpu_lit import shade_sample
from ._cpu_math import (
    BG_DEPTH,
    DEPTH,
    HIT,
    HIT_NORMAL,
    INF,
    SEGS,
    TMIN,
    TR,
    _hot,
    add_sample,
    composite,
    composite_sample,
    erf_fast,
    erf_span,
    sample_color,
)
from ._cpu_surface import surface_hit
from ._cpu_tiles import TILE
from .scene import Mode

# hit record columns (float64): chord [S, E], closest approach TS, sqrt(a/2) SA, C = peak x
# sqrt(pi / 2a), Q/2 HQ, a/2 HA, peak PK; particles: erf at the member's last boundary FA (and a
# running one, FB), colour, value (0 when NaN) and value weight (0 when NaN); field keeps V, R,
# RC, EX (value, ratios, exit) and, for lit volumes, the gradient's terms GA (3) + t GB (3) by
# active slot (sweep_field)
S, E, TS, SA, C, HQ, HA, PK, FA, FB, CR, CG, CB, VAL, VW = range(15)
V, R, RC, EX, GA, GB = 8, 9, 10, 11, 12, 15
NF = 18
SQRT_HALF = math.sqrt(0.5)
SQRT_HALF_PI = math.sqrt(0.5 * math.pi)
# g_rec columns: centre (3), 1/sigma (3), extinction weight, and (tile lists) the entry bound
LB = 7
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


# per-ray sweep state: qs (int64) and fs (float64) columns
NQ, NACT, NM, NH, ISAMP, QH = range(6)  # queue: [QH, NQ)
BATCH = 32
IA, LAST, RHO, HSTEP, CEND = range(5)


@njit(**_hot)
def sweep_start(mode, qs, fs, cb, rd, obj_step):
    """Empty queue, no hits; field samples at t_i = (i + 1/2) h from the ray origin, h the finest
    object step along this ray."""
    for c in range(6):
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
def chord(g, ox, oy, oz, dx, dy, dz, g_rec, k2, tn, tf):
    """The exact ray/support test of Gaussian g (object-index-space ray), without branches: s, e,
    ts, aa, qq, ra, pk (chord clipped to the ray's [tn, tf], closest approach, |d'|^2, its squared
    distance, 1 / |d'|, peak density); a miss has s >= e. One division and two roots."""
    ix, iy, iz = g_rec[g, 3], g_rec[g, 4], g_rec[g, 5]
    wx, wy, wz = (ox - g_rec[g, 0]) * ix, (oy - g_rec[g, 1]) * iy, (oz - g_rec[g, 2]) * iz
    vx, vy, vz = dx * ix, dy * iy, dz * iz
    aa = vx * vx + vy * vy + vz * vz
    bb = wx * vx + wy * vy + wz * vz
    ia = 1.0 / aa
    ts = -bb * ia
    px, py, pz = wx + ts * vx, wy + ts * vy, wz + ts * vz
    qq = px * px + py * py + pz * pz
    ra = math.sqrt(ia)
    hw = math.sqrt(max(k2 - qq, 0.0)) * ra
    s = max(ts - hw, tn) if qq < k2 else INF
    pk = g_rec[g, 6] * math.exp(-0.5 * min(qq, k2))
    return s, min(ts + hw, tf), ts, aa, qq, ra, pk


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
def test_one(g, ox, oy, oz, dx, dy, dz, g_rec, k2, tn, tf, H, hid, ev_t, ev_k, ev_h, qs):
    """Gaussian g's test (chord); a hit gets a record in H and an entry event. Returns OVERFLOW
    when H is full."""
    s, e, ts, aa, qq, ra, pk = chord(g, ox, oy, oz, dx, dy, dz, g_rec, k2, tn, tf)
    if not e > s:
        return 0
    nh = qs[NH]
    if nh >= H.shape[0]:
        return OVERFLOW
    qs[NQ] = add_hit(H, hid, ev_t, ev_k, ev_h, qs[QH], qs[NQ], nh, g, s, e, ts, aa, qq, ra, pk)
    qs[NH] = nh + 1
    return 0


@njit(**_hot)
def sweep_particles(horizon, st, qs, fs, H, hid, ev_t, ev_h, mem, keep, cb, g_col, g_val, tau_max):
    """Particles: consume the entries before horizon, and close the cluster when it ends before
    it (see module doc). Returns 1 once the ray is opaque (early termination)."""
    q0, nq, nm = qs[QH], qs[NQ], qs[NM]
    a, last_t, rho, cend = fs[IA], fs[LAST], fs[RHO], fs[CEND]
    done = 0
    while q0 < nq and ev_t[q0] < horizon:
        t = ev_t[q0]
        h = ev_h[q0]
        q0 += 1
        if t < last_t:
            t = last_t  # a chord found late by rounding: starts where the sweep is
        if nm > 0:
            if t >= cend:  # the cluster ended before this entry
                close_interval(st, H, mem, nm, a, cend, spread_of(cb), tau_max, keep, cb)
                if st[TR] < st[TMIN]:
                    done = 1
                    break
                nm = 0
            elif t > last_t and last_t > a:
                spread = spread_of(cb)
                if rho * (t - a) * spread > tau_max:
                    nm, rho = close_interval(st, H, mem, nm, a, last_t, spread, tau_max, keep, cb)
                    if st[TR] < st[TMIN]:
                        done = 1
                        break
                    for k in range(nm):  # the members still open carry over
                        mem[k] = keep[k]
                    a = last_t
        if nm == 0:
            a = t
            rho = 0.0
            cend = t
            reset_bounds(cb)
        # a new member: its colour, value and erf at entry (FA) into its record
        g = hid[h]
        H[h, CR] = g_col[g, 0]
        H[h, CG] = g_col[g, 1]
        H[h, CB] = g_col[g, 2]
        v = g_val[g]
        H[h, VAL] = v if v == v else 0.0
        H[h, VW] = 1.0 if v == v else 0.0
        H[h, FA] = erf_fast(H[h, SA] * (H[h, S] - H[h, TS]))
        widen(cb, H, h)
        mem[nm] = h
        nm += 1
        rho += H[h, PK]
        cend = max(cend, H[h, E])
        last_t = t
    if done == 0 and nm > 0 and cend <= horizon:  # no entry before its end is left to find
        close_interval(st, H, mem, nm, a, cend, spread_of(cb), tau_max, keep, cb)
        done = 1 if st[TR] < st[TMIN] else 0
        nm = 0
        last_t = cend
    qs[QH], qs[NM] = q0, nm
    fs[IA], fs[LAST], fs[RHO], fs[CEND] = a, last_t, rho, cend
    return done


@njit(**_hot, inline="always")
def _move_slot(H, act, k, j, glit):
    act[k] = act[j]
    H[k, V] = H[j, V]
    H[k, R] = H[j, R]
    H[k, RC] = H[j, RC]
    H[k, EX] = H[j, EX]
    if glit:
        for c in range(6):
            H[k, GA + c] = H[j, GA + c]


@njit(**_hot)
def mixture_hit(st, ob, th, ti, hstep, ro, rd, obj_ls, lut, acc):
    """Object ob's surface at th, inside the sample at ti: the volumes of that sample composite
    over [ti - hstep / 2, th], then the hit with the outward normal -grad(mixture) at th, summed
    is left for render_pixels to take from the Gaussians around the hit (mixture_normal): the
    ray's active set is only a tube around it."""
    if acc[0] > 0.0 and th > ti - 0.5 * hstep:
        sig = acc[0]
        composite(st, sig * (th - (ti - 0.5 * hstep)), acc[1] / sig, acc[2] / sig, acc[3] / sig,
                  acc[4] / acc[5] if acc[5] > 0 else np.nan, ti - 0.5 * hstep, th)
    x = ro[ob, 0] + th * rd[ob, 0]
    y = ro[ob, 1] + th * rd[ob, 1]
    z = ro[ob, 2] + th * rd[ob, 2]
    surface_hit(st, ob, th, 0.0, 0.0, 0.0, obj_ls, lut, x, y, z)
    st[HIT] = HIT_NORMAL  # the normal is still to be found


@njit(**_hot)
def sweep_field(horizon, st, qs, fs, H, hid, ev_t, ev_h, act, g_rec, g_obj, ro, rd, obj_kind, obj_tf,
                obj_ls, tf_lut, tf_par, svals, sact, samp, acc, sprev, objs, xfer, wr, sgrad):
    """Field: the samples before horizon (see module doc). Returns 1 once the ray is opaque.
    Surfaces (obj_kind 2): the mixture's first rise through 0.5 between samples (sprev: the
    object's previous sample value and index), placed by the secant; the volumes composite up to
    it and the ray ends there (mixture_hit). Lit volumes (objs.lit): each sample is shaded on the
    mixture's analytic gradient, sum_g -V_g (x - mu_g) / sigma_g^2 (sgrad per object; wr the
    world ray; _cpu_lit)."""
    q0, nq, nact, isamp = qs[QH], qs[NQ], qs[NACT], qs[ISAMP]
    obj_lit = objs.lit
    glit = False
    for ob in range(obj_lit.shape[0]):
        glit = glit or obj_lit[ob] != 0
    hstep = fs[HSTEP]
    cend = fs[CEND]
    n_obj = ro.shape[0]
    done = 0
    while True:
        ti = (isamp + 0.5) * hstep
        if not ti < horizon:
            break
        while q0 < nq and ev_t[q0] <= ti:
            h = ev_h[q0]
            q0 += 1
            # the active chords' V, R, RC, EX live in H's rows by active slot (not by hit), so the
            # per-sample loop below reads them contiguously
            k = nact
            act[k] = h
            nact += 1
            d = ti - H[h, TS]
            ha = H[h, HA]
            H[k, V] = g_rec[hid[h], 6] * math.exp(-(H[h, HQ] + ha * d * d))
            H[k, R] = math.exp(-ha * (2.0 * d * hstep + hstep * hstep))
            H[k, RC] = math.exp(-2.0 * ha * hstep * hstep)
            H[k, EX] = H[h, E]
            if glit:  # grad of this Gaussian at t: -V (GA + t GB), x - mu = o - mu + t d
                g = hid[h]
                ob = g_obj[g]
                for c in range(3):
                    i2 = g_rec[g, 3 + c] * g_rec[g, 3 + c]
                    H[k, GA + c] = i2 * (ro[ob, c] - g_rec[g, c])
                    H[k, GB + c] = i2 * rd[ob, c]
            cend = max(cend, H[h, E])
        if nact > 0 and ti >= cend:
            nact = 0  # every active chord has ended
        if nact == 0:
            if q0 == nq or not ev_t[q0] < horizon:
                # nothing known ahead: resume at the first sample not before the horizon
                if horizon < INF:
                    isamp = max(isamp, int(math.ceil(horizon / hstep - 0.5)))
                break
            isamp = max(isamp + 1, int(math.ceil(ev_t[q0] / hstep - 0.5)))
            continue
        k = 0
        if glit:
            for ob in range(n_obj):
                sgrad[ob, 0] = sgrad[ob, 1] = sgrad[ob, 2] = 0.0
        if n_obj == 1 and glit:
            sv = 0.0
            gx = gy = gz = 0.0
            while k < nact:
                if H[k, EX] <= ti:
                    nact -= 1
                    _move_slot(H, act, k, nact, glit)
                    continue
                v = H[k, V]
                sv += v
                gx -= v * (H[k, GA] + ti * H[k, GB])
                gy -= v * (H[k, GA + 1] + ti * H[k, GB + 1])
                gz -= v * (H[k, GA + 2] + ti * H[k, GB + 2])
                H[k, V] *= H[k, R]
                H[k, R] *= H[k, RC]
                k += 1
            svals[0] = sv
            sact[0] = 1
            sgrad[0, 0], sgrad[0, 1], sgrad[0, 2] = gx, gy, gz
        elif n_obj == 1:  # the sum in a register (svals[ob] += ... would store on every term)
            sv = 0.0
            while k < nact:
                if H[k, EX] <= ti:  # ended before this sample: drop it
                    nact -= 1
                    _move_slot(H, act, k, nact, glit)
                    continue
                sv += H[k, V]
                H[k, V] *= H[k, R]
                H[k, R] *= H[k, RC]
                k += 1
            svals[0] = sv
            sact[0] = 1
        else:
            for ob in range(n_obj):
                svals[ob] = 0.0
                sact[ob] = 0
            while k < nact:
                if H[k, EX] <= ti:
                    nact -= 1
                    _move_slot(H, act, k, nact, glit)
                    continue
                ob = g_obj[hid[act[k]]]
                v = H[k, V]
                svals[ob] += v
                sact[ob] = 1
                if glit:
                    for c in range(3):
                        sgrad[ob, c] -= v * (H[k, GA + c] + ti * H[k, GB + c])
                H[k, V] *= H[k, R]
                H[k, R] *= H[k, RC]
                k += 1
        st[SEGS] += nact
        acc[:] = 0.0
        best = -1
        bt = INF
        for ob in range(n_obj):
            if sact[ob] == 0:
                continue
            if obj_kind[ob] == 2:
                sv = svals[ob]
                prev = sprev[ob, 0] if sprev[ob, 1] == isamp - 1 else 0.0  # none active: 0
                sprev[ob, 0] = sv
                sprev[ob, 1] = isamp
                if sv >= 0.5 and prev < 0.5:
                    th = ti - hstep + (0.5 - prev) / (sv - prev) * hstep
                    if th < bt:
                        bt = th
                        best = ob
                continue
            x = ro[ob, 0] + ti * rd[ob, 0]
            y = ro[ob, 1] + ti * rd[ob, 1]
            z = ro[ob, 2] + ti * rd[ob, 2]
            sample_color(ob, svals[ob], x, y, z, obj_kind, obj_tf, obj_ls, tf_lut, tf_par, samp)
            if obj_lit[ob] != 0 and samp[0] > 0.0:
                shade_sample(samp, ob, sgrad[ob, 0], sgrad[ob, 1], sgrad[ob, 2], x, y, z, wr, ti,
                             objs, xfer.lights, xfer.settings, tf_par[obj_tf[ob]])
            add_sample(acc, samp)
        if best >= 0:
            mixture_hit(st, best, bt, ti, hstep, ro, rd, obj_ls, tf_lut[obj_tf[best]], acc)
            done = 1
            break
        isamp += 1
        if acc[0] > 0.0:
            composite_sample(st, acc, ti, hstep)
            if st[TR] < st[TMIN]:
                done = 1
                break
    qs[QH], qs[NACT], qs[ISAMP] = q0, nact, isamp
    fs[CEND] = cend
    return done


@njit(**_hot, inline="always")
def sweep(mode, horizon, st, gauss, objs, xfer, scr, hits, tau_max):
    if mode == Mode.PARTICLES:
        return sweep_particles(horizon, st, scr.qs, scr.fs, hits.rec, hits.hid, hits.ev_t, hits.ev_h,
                               hits.mem, hits.act, scr.cb, gauss.col, gauss.val, tau_max)
    return sweep_field(horizon, st, scr.qs, scr.fs, hits.rec, hits.hid, hits.ev_t, hits.ev_h,
                       hits.act, gauss.rec, gauss.obj, scr.ro, scr.rd, objs.kind, objs.tf, objs.ls,
                       xfer.lut, xfer.par, scr.svals, scr.sact, scr.samp, scr.acc, scr.sprev, objs, xfer,
                       scr.wr, scr.sgrad)


@njit(**_hot)
def trace_gauss(mode, st, n, gauss, objs, accel, xfer, scr, hits, k2, tn, tf, tau_max):
    """One ray, particles or field, over the n leaf cells visited, in scr.srt order (the chords
    clipped to the ray's [tn, tf] and their object's clip interval scr.rclip[ob]). Returns 0, or
    OVERFLOW when more hits than hits.rec's rows are needed (the caller grows and retries)."""
    ro, rd, rclip, lastc, qs = scr.ro, scr.rd, scr.rclip, scr.lastc, scr.qs
    H, hid, ev_t, ev_k, ev_h = hits.rec, hits.hid, hits.ev_t, hits.ev_k, hits.ev_h
    g_rec, g_sph, g_clo, g_chi, obj_ref = gauss.rec, gauss.sph, gauss.clo, gauss.chi, objs.ref
    cell_xyz, cell_start, cell_items = accel.cell_xyz, accel.cell_start, accel.cell_items
    face_start, face_items = accel.face_start, accel.face_items
    sweep_start(mode, qs, scr.fs, scr.cb, rd, objs.step)
    for w in range(lastc.shape[0]):
        lastc[w, 0] = -(1 << 62)
    for q in range(n):
        # --- 1. test the Gaussians first met in cell q (of walk grid w: a level of object ob)
        iv = scr.srt[q]
        w = scr.iv_obj[iv]
        ob = accel.walk_obj[w]
        cid = scr.iv_cell[iv]
        ox, oy, oz = ro[ob, 0], ro[ob, 1], ro[ob, 2]
        dx, dy, dz = rd[ob, 0], rd[ob, 1], rd[ob, 2]
        tno, tfo = max(tn, rclip[ob, 0]), min(tf, rclip[ob, 1])
        ox32 = np.float32(ox - obj_ref[ob, 0])
        oy32 = np.float32(oy - obj_ref[ob, 1])
        oz32 = np.float32(oz - obj_ref[ob, 2])
        dx32, dy32, dz32 = np.float32(dx), np.float32(dy), np.float32(dz)
        dd32 = dx32 * dx32 + dy32 * dy32 + dz32 * dz32
        near = ox32 * ox32 + oy32 * oy32 + oz32 * oz32 < 1e8  # float32 good to ~1e-3 voxel
        cx, cy, cz = cell_xyz[cid, 0], cell_xyz[cid, 1], cell_xyz[cid, 2]
        lx, ly, lz = lastc[w, 0], lastc[w, 1], lastc[w, 2]
        f = entry_face(cx - lx, cy - ly, cz - lz)
        if f >= 0:  # came from the face neighbour: only the Gaussians that start here
            lst = face_items
            j0 = face_start[6 * cid + f]
            j1 = face_start[6 * cid + f + 1]
        else:
            lst = cell_items
            j0 = cell_start[cid]
            j1 = cell_start[cid + 1]
        for j in range(j0, j1):
            g = lst[j]
            if g_rec[g, 6] == 0.0:
                continue
            if f < 0 and (g_clo[g, 0] <= lx and lx <= g_chi[g, 0] and g_clo[g, 1] <= ly
                          and ly <= g_chi[g, 1] and g_clo[g, 2] <= lz and lz <= g_chi[g, 2]):
                continue  # its box covers the previous cell: tested there
            # cheap rejection on a 16-byte bounding sphere (float32 near the object's
            # reference point, radius widened for the rounding); survivors: the exact test
            if near:
                cxp = (g_sph[g, 1] - oy32) * dz32 - (g_sph[g, 2] - oz32) * dy32
                cyp = (g_sph[g, 2] - oz32) * dx32 - (g_sph[g, 0] - ox32) * dz32
                czp = (g_sph[g, 0] - ox32) * dy32 - (g_sph[g, 1] - oy32) * dx32
                if cxp * cxp + cyp * cyp + czp * czp > g_sph[g, 3] * dd32:
                    continue
            if test_one(g, ox, oy, oz, dx, dy, dz, g_rec, k2, tno, tfo, H, hid, ev_t, ev_k, ev_h,
                        qs) != 0:
                return OVERFLOW
        lastc[w, 0] = cx
        lastc[w, 1] = cy
        lastc[w, 2] = cz
        # --- 2. sweep what is complete before the next cell's entry
        horizon = scr.iv_ta[scr.srt[q + 1]] if q + 1 < n else INF
        if sweep(mode, horizon, st, gauss, objs, xfer, scr, hits, tau_max):
            return 0
    return 0


NB = 32  # candidates tested per block (trace_tiles)


@njit(**_hot, inline="always")
def test_block(cand, nc, ro, rd, g_rec, g_obj, k2, tn, tf, blk, rclip):
    """The tests (chord) of candidates cand[:nc] into blk[c] = s, e, ts, aa, qq, ra, pk, apart
    from the queue insertion: no branch then waits on a candidate's division and roots (together
    they cost ~18% more on dense volumes)."""
    one = ro.shape[0] == 1
    for c in range(nc):
        g = cand[c]
        ob = 0 if one else g_obj[g]
        (blk[c, 0], blk[c, 1], blk[c, 2], blk[c, 3], blk[c, 4], blk[c, 5],
         blk[c, 6]) = chord(g, ro[ob, 0], ro[ob, 1], ro[ob, 2], rd[ob, 0], rd[ob, 1], rd[ob, 2],
                            g_rec, k2, max(tn, rclip[ob, 0]), min(tf, rclip[ob, 1]))


@njit(**_hot)
def trace_tiles(mode, st, i, j, t0, t1, gauss, objs, accel, xfer, scr, hits, k2, tn, tf, tau_max):
    """One ray (pixel i, j), particles or field, over its screen tile's list accel.t_items[t0:t1]
    (ordered by the lower bound of each support's entry, gauss.rec[g, LB]: see _cpu_tiles), in blocks
    of NB candidates (the entries with the pixel's mask bit), the chords clipped to the ray's
    [tn, tf]. Returns 0 or OVERFLOW."""
    qs, fs, cand, blk = scr.qs, scr.fs, scr.cand, scr.blk
    H, hid, ev_t, ev_k, ev_h = hits.rec, hits.hid, hits.ev_t, hits.ev_k, hits.ev_h
    t_items, t_mask, g_rec = accel.t_items, accel.t_mask, gauss.rec
    sweep_start(mode, qs, fs, scr.cb, scr.rd, objs.step)
    swept = 0
    bit = (j % TILE) * TILE + i % TILE
    q = t0
    while True:
        nc = 0
        while q < t1 and nc < NB:
            cand[nc] = t_items[q]
            nc += (t_mask[q] >> bit) & 1
            q += 1
        if nc == 0:
            break
        lbg = g_rec[cand[0], LB]
        # sweep after BATCH new hits, up to the block's earliest entry
        if qs[NH] >= swept + BATCH and ((qs[QH] < qs[NQ] and ev_t[qs[QH]] < lbg)
                                        or (qs[NM] > 0 and fs[CEND] <= lbg)):
            swept = qs[NH]
            if sweep(mode, lbg, st, gauss, objs, xfer, scr, hits, tau_max):
                return 0
        test_block(cand, nc, scr.ro, scr.rd, g_rec, gauss.obj, k2, tn, tf, blk, scr.rclip)
        nh = qs[NH]
        nq = qs[NQ]
        q0 = qs[QH]
        for c in range(nc):
            if not blk[c, 1] > blk[c, 0]:
                continue
            if nh >= H.shape[0]:
                return OVERFLOW
            nq = add_hit(H, hid, ev_t, ev_k, ev_h, q0, nq, nh, cand[c], blk[c, 0], blk[c, 1],
                         blk[c, 2], blk[c, 3], blk[c, 4], blk[c, 5], blk[c, 6])
            nh += 1
        qs[NH] = nh
        qs[NQ] = nq
    sweep(mode, INF, st, gauss, objs, xfer, scr, hits, tau_max)
    return 0
