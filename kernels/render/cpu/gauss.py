"""Particles and field modes: each ray tests every Gaussian once and sweeps its chords in
(t, id) order, streaming behind its candidate list so early termination still saves the work.
Candidates come from the frame's screen tile (trace_tiles, ordered by a lower bound of the entry
time: see cpu.tiles) or, when there are no tile lists, from the leaf walk (trace_gauss).

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

from ...jit import njit
from ..devices import modes
from ..inputs.layout import (
    CB,
    CEND,
    CG,
    CR,
    CV,
    EX,
    FA,
    GA,
    GB,
    HA,
    HQ,
    HSTEP,
    IA,
    ISAMP,
    LAST,
    NACT,
    NH,
    NM,
    NQ,
    PK,
    QH,
    RC,
    REC_INV,
    REC_LB,
    REC_MU,
    REC_W,
    RHO,
    SA,
    SEGS,
    TILE,
    TMIN,
    TR,
    TS,
    VAL,
    VW,
    E,
    Kind,
    R,
    S,
    Shading,
    V,
)
from .chords import (
    BATCH,
    OVERFLOW,
    add_hit,
    chord,
    chord_of,
    close_interval,
    entry_face,
    peak,
    reset_bounds,
    spread_of,
    sweep_start,
    test_one,
    widen,
)
from .lit import shade_member, shade_sample
from .per_mode import per_mode
from .surface import field_crossing, mixture_hit
from .vecmath import INF, _hot, add_sample, composite_sample, erf_fast, recolor, sample_color


@njit(**_hot)
def sweep_particles(mode, horizon, st, qs, fs, H, hid, ev_t, ev_h, mem, keep, cb, g_col, g_val,
                    tau_max, gauss, objs, xfer, scr):
    """Particles: consume the entries before horizon, and close the cluster when it ends before
    it (see module doc). Returns 1 once the ray is opaque (early termination). Lit volumes'
    members are shaded as they enter (lit_member)."""
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
        shade_member(mode, H, h, g, gauss, objs, xfer, scr)
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
def _move_slot(H, act, k, j, glit, gcol):
    act[k] = act[j]
    H[k, V] = H[j, V]
    H[k, R] = H[j, R]
    H[k, RC] = H[j, RC]
    H[k, EX] = H[j, EX]
    if glit:
        for c in range(6):
            H[k, GA + c] = H[j, GA + c]
    if gcol:
        H[k, CV] = H[j, CV]


@njit(**_hot)
def sweep_field(horizon, st, qs, fs, H, hid, ev_t, ev_h, act, g_rec, g_obj, ro, rd, obj_kind, obj_tf,
                obj_ls, tf_lut, tf_par, svals, sact, samp, acc, sprev, objs, xfer, wr, sgrad, g_cw,
                cvals):
    """Field: the samples before horizon (see module doc). Returns 1 once the ray is opaque.
    Surfaces (Kind.SURFACE): the first crossing between samples (cpu.surface.field_crossing;
    sprev: the object's previous sample level and index); the volumes composite up to it and the
    ray ends there (mixture_hit). With signed distances (objs.sdf) their mixture is carried as a
    colour grid's is (CV, g_cw, cvals). Lit volumes (objs.lit): each sample is shaded on the
    mixture's analytic gradient, sum_g -V_g (x - mu_g) / sigma_g^2 (sgrad per object; wr the
    world ray; cpu.lit). Volumes coloured by a second grid (objs.ctf): its mixture, with the
    weights g_cw on the same Gaussians, is carried beside the field (CV) and summed per object
    (cvals); plus that grid's background (objs.cbg), it is the colour map's value."""
    q0, nq, nact, isamp = qs[QH], qs[NQ], qs[NACT], qs[ISAMP]
    obj_lit = objs.lit
    obj_ctf = objs.ctf
    glit = False
    for ob in range(obj_lit.shape[0]):
        glit = glit or obj_lit[ob] != Shading.EMISSION
    gcol = False  # a second mixture carried: colour grids, surfaces' signed distances
    for ob in range(obj_ctf.shape[0]):
        gcol = gcol or obj_ctf[ob] >= 0 or objs.sdf[ob] != 0
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
            H[k, V] = g_rec[hid[h], REC_W] * math.exp(-(H[h, HQ] + ha * d * d))
            if gcol:
                H[k, CV] = g_cw[hid[h]] * math.exp(-(H[h, HQ] + ha * d * d))
            H[k, R] = math.exp(-ha * (2.0 * d * hstep + hstep * hstep))
            H[k, RC] = math.exp(-2.0 * ha * hstep * hstep)
            H[k, EX] = H[h, E]
            if glit:  # grad of this Gaussian at t: -V (GA + t GB), x - mu = o - mu + t d
                g = hid[h]
                ob = g_obj[g]
                for c in range(3):
                    i2 = g_rec[g, REC_INV + c] * g_rec[g, REC_INV + c]
                    H[k, GA + c] = i2 * (ro[ob, c] - g_rec[g, REC_MU + c])
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
        if n_obj == 1 and glit and not gcol:
            sv = 0.0
            gx = gy = gz = 0.0
            while k < nact:
                if H[k, EX] <= ti:
                    nact -= 1
                    _move_slot(H, act, k, nact, glit, gcol)
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
        elif n_obj == 1 and not gcol:  # the sum in a register (svals[ob] += ... would store on every term)
            sv = 0.0
            while k < nact:
                if H[k, EX] <= ti:  # ended before this sample: drop it
                    nact -= 1
                    _move_slot(H, act, k, nact, glit, gcol)
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
                cvals[ob] = 0.0
            while k < nact:
                if H[k, EX] <= ti:
                    nact -= 1
                    _move_slot(H, act, k, nact, glit, gcol)
                    continue
                ob = g_obj[hid[act[k]]]
                v = H[k, V]
                svals[ob] += v
                sact[ob] = 1
                if glit:
                    for c in range(3):
                        sgrad[ob, c] -= v * (H[k, GA + c] + ti * H[k, GB + c])
                if gcol:
                    cvals[ob] += H[k, CV]
                    H[k, CV] *= H[k, R]
                H[k, V] *= H[k, R]
                H[k, R] *= H[k, RC]
                k += 1
        st[SEGS] += nact
        acc[:] = 0.0
        best = -1
        bt = INF
        for ob in range(n_obj):
            if obj_kind[ob] == Kind.SURFACE:  # at every sample: a passage through the shell may end here
                th = field_crossing(sprev, ob, isamp, ti, hstep, svals[ob], cvals[ob], objs.sdf[ob],
                                    objs.cbg[ob])
                if th < bt:
                    bt = th
                    best = ob
                continue
            if sact[ob] == 0:
                continue
            x = ro[ob, 0] + ti * rd[ob, 0]
            y = ro[ob, 1] + ti * rd[ob, 1]
            z = ro[ob, 2] + ti * rd[ob, 2]
            sample_color(ob, svals[ob], x, y, z, obj_kind, obj_tf, obj_ls, tf_lut, tf_par, samp)
            if gcol:
                recolor(ob, cvals[ob] + objs.cbg[ob], obj_ctf, tf_lut, tf_par, samp)
            if obj_lit[ob] != Shading.EMISSION and samp[0] > 0.0:
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


def sweep(mode, horizon, st, gauss, objs, xfer, scr, hits, tau_max):
    """The queued chords up to ``horizon``, composited as ``mode`` draws them (sweep_particles
    or sweep_field: per_mode compiles one); true when the ray is done."""


@per_mode(sweep)
def _sweep(mode):
    if modes.spec(mode).field:
        def field(mode, horizon, st, gauss, objs, xfer, scr, hits, tau_max):
            return sweep_field(horizon, st, scr.qs, scr.fs, hits.rec, hits.hid, hits.ev_t, hits.ev_h,
                               hits.act, gauss.rec, gauss.obj, scr.ro, scr.rd, objs.kind, objs.tf, objs.ls,
                               xfer.lut, xfer.par, scr.svals, scr.sact, scr.samp, scr.acc, scr.sprev, objs,
                               xfer, scr.wr, scr.sgrad, gauss.cw, scr.cvals)
        return field

    def particles(mode, horizon, st, gauss, objs, xfer, scr, hits, tau_max):
        return sweep_particles(mode, horizon, st, scr.qs, scr.fs, hits.rec, hits.hid, hits.ev_t,
                               hits.ev_h, hits.mem, hits.act, scr.cb, gauss.col, gauss.val, tau_max,
                               gauss, objs, xfer, scr)
    return particles


@njit(**_hot)
def trace_gauss(mode, st, n, gauss, objs, accel, xfer, scr, hits, k2, t_near, t_far, tau_max):
    """One ray, particles or field, over the n leaf cells visited, in scr.srt order (the chords
    clipped to the ray's [t_near, t_far] and their object's clip interval scr.rclip[ob]). Returns 0, or
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
        t_near_ob, t_far_ob = max(t_near, rclip[ob, 0]), min(t_far, rclip[ob, 1])
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
            if g_rec[g, REC_W] == 0.0:
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
            if test_one(g, ox, oy, oz, dx, dy, dz, g_rec, k2, t_near_ob, t_far_ob, H, hid, ev_t, ev_k, ev_h,
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
def test_block(cand, nc, ro, rd, g_rec, g_obj, k2, t_near, t_far, blk, rclip):
    """The tests (chord) of candidates cand[:nc] into blk[0:6, c] = s, e, ts, aa, qq, ra (the peak
    is taken for hits only, as they are queued), apart from the queue insertion: no branch then
    waits on a candidate's division and roots. One object: the candidates' records are gathered
    into blk[8:14] first, so the tests run over the block in SIMD lanes (the same operations:
    the same bits; 1.1-1.15x a dense Low frame)."""
    if ro.shape[0] == 1:
        for c in range(nc):
            for k in range(6):  # centre and 1/sigma (REC_INV = REC_MU + 3)
                blk[8 + k, c] = g_rec[cand[c], REC_MU + k]
        ox, oy, oz, dx, dy, dz = ro[0, 0], ro[0, 1], ro[0, 2], rd[0, 0], rd[0, 1], rd[0, 2]
        t_near_ob, t_far_ob = max(t_near, rclip[0, 0]), min(t_far, rclip[0, 1])
        for c in range(nc):
            (blk[0, c], blk[1, c], blk[2, c], blk[3, c], blk[4, c],
             blk[5, c]) = chord_of(blk[8, c], blk[9, c], blk[10, c], blk[11, c], blk[12, c],
                                   blk[13, c], ox, oy, oz, dx, dy, dz, k2, t_near_ob, t_far_ob)
        return
    for c in range(nc):
        g = cand[c]
        ob = g_obj[g]
        (blk[0, c], blk[1, c], blk[2, c], blk[3, c], blk[4, c],
         blk[5, c]) = chord(g, ro[ob, 0], ro[ob, 1], ro[ob, 2], rd[ob, 0], rd[ob, 1], rd[ob, 2],
                            g_rec, k2, max(t_near, rclip[ob, 0]), min(t_far, rclip[ob, 1]))


@njit(**_hot)
def trace_tiles(mode, st, i, j, t0, t1, gauss, objs, accel, xfer, scr, hits, k2, t_near, t_far, tau_max):
    """One ray (pixel i, j), particles or field, over its screen tile's list accel.t_items[t0:t1]
    (ordered by the lower bound of each support's entry, gauss.rec[g, REC_LB]: see cpu.tiles), in blocks
    of NB candidates (the entries with the pixel's mask bit), the chords clipped to the ray's
    [t_near, t_far]. Returns 0 or OVERFLOW."""
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
        lbg = g_rec[cand[0], REC_LB]
        # sweep after BATCH new hits, up to the block's earliest entry
        if qs[NH] >= swept + BATCH and ((qs[QH] < qs[NQ] and ev_t[qs[QH]] < lbg)
                                        or (qs[NM] > 0 and fs[CEND] <= lbg)):
            swept = qs[NH]
            if sweep(mode, lbg, st, gauss, objs, xfer, scr, hits, tau_max):
                return 0
        test_block(cand, nc, scr.ro, scr.rd, g_rec, gauss.obj, k2, t_near, t_far, blk, scr.rclip)
        nh = qs[NH]
        nq = qs[NQ]
        q0 = qs[QH]
        for c in range(nc):
            if not blk[1, c] > blk[0, c]:
                continue
            if nh >= H.shape[0]:
                return OVERFLOW
            nq = add_hit(H, hid, ev_t, ev_k, ev_h, q0, nq, nh, cand[c], blk[0, c], blk[1, c],
                         blk[2, c], blk[3, c], blk[4, c], blk[5, c],
                         peak(cand[c], g_rec, blk[4, c], k2))
            nh += 1
        qs[NH] = nh
        qs[NQ] = nq
    sweep(mode, INF, st, gauss, objs, xfer, scr, hits, tau_max)
    return 0
