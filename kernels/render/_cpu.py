"""Numba CPU kernels (parallel over rows, nogil, cached). Imported lazily by CPUDevice so the
numba cache directory can be chosen first. Every pixel is computed independently, in float64,
so images are bitwise identical for any thread count.

Modes: 0 particles, 1 field, 2 paper, 3 reference.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

INF = np.inf
LEAF = 8.0
NODE = 128.0
NL = 16
SQRT_PI = math.sqrt(math.pi)
TWO_OVER_SQRT_PI = 2.0 / math.sqrt(math.pi)
BG_DEPTH = 1e10

_jit = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


@njit(**_jit)
def erf_diff(u0, u1):
    """erf(u1) - erf(u0) for u0 <= u1 (see erf_span)."""
    return erf_span(u0, u1, u1 - u0)


@njit(**_jit)
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


@njit(**_jit)
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


@njit(**_jit)
def tf_x(v, par):
    """Normalised TF coordinate in [0, 1]; NaN stays NaN."""
    if par[2] > 0.5:
        lo = math.log10(par[0])
        hi = math.log10(par[1])
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
        if par[1] > par[0]:
            x = (v - par[0]) / (par[1] - par[0])
        elif v != v:
            return v
        else:
            x = 1.0 if v >= par[1] else 0.0
    if x < 0.0:
        return 0.0
    if x > 1.0:
        return 1.0
    return x


@njit(**_jit)
def lut_at(lut, x, ch):
    """Linear interpolation of LUT channel ch at x in [0, 1]."""
    k = lut.shape[0]
    f = x * (k - 1)
    i = int(f)
    if i > k - 2:
        i = k - 2
    if i < 0:
        i = 0
    w = f - i
    return lut[i, ch] * (1.0 - w) + lut[i + 1, ch] * w


@njit(**_jit)
def slab(ox, oy, oz, dx, dy, dz, lx, ly, lz, hx, hy, hz, t0, t1):
    """NaN-free slab test: zero direction components are handled explicitly."""
    o = (ox, oy, oz)
    d = (dx, dy, dz)
    lo = (lx, ly, lz)
    hi = (hx, hy, hz)
    for k in range(3):
        if d[k] == 0.0:
            if o[k] < lo[k] or o[k] > hi[k]:
                return 1.0, 0.0
        else:
            inv = 1.0 / d[k]
            ta = (lo[k] - o[k]) * inv
            tb = (hi[k] - o[k]) * inv
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
    return t0, t1


@njit(**_jit)
def dda_axis(o, d, t, size, lo, hi):
    """Integer cell, step, t of the next boundary, t per cell along one axis."""
    c = int(math.floor((o + t * d) / size))
    if c < lo:
        c = lo
    if c > hi - 1:
        c = hi - 1
    if d > 0.0:
        return c, 1, ((c + 1) * size - o) / d, size / d
    if d < 0.0:
        return c, -1, (c * size - o) / d, -size / d
    return c, 0, INF, INF


@njit(**_jit)
def walk_object(ox, oy, oz, dx, dy, dz, nmin, ndims, noff, node_table, node_cells, cell_skip,
                obj, iv_ta, iv_tb, iv_obj, iv_cell, n, cap):
    """Hierarchical DDA (nodes of 128^3, then leaves of 8^3, integer cell indices) in q-space
    (q = index + 0.5); appends the non-empty, non-transparent leaf intervals front to back."""
    if ndims[0] == 0:
        return n
    qx, qy, qz = ox + 0.5, oy + 0.5, oz + 0.5
    t0, t1 = slab(qx, qy, qz, dx, dy, dz, nmin[0] * NODE, nmin[1] * NODE, nmin[2] * NODE,
                  (nmin[0] + ndims[0]) * NODE, (nmin[1] + ndims[1]) * NODE,
                  (nmin[2] + ndims[2]) * NODE, 0.0, INF)
    if not t0 < t1:
        return n
    t = t0
    cx, sx, mx, ex = dda_axis(qx, dx, t, NODE, nmin[0], nmin[0] + ndims[0])
    cy, sy, my, ey = dda_axis(qy, dy, t, NODE, nmin[1], nmin[1] + ndims[1])
    cz, sz, mz, ez = dda_axis(qz, dz, t, NODE, nmin[2], nmin[2] + ndims[2])
    while True:
        tn = min(mx, my, mz, t1)
        if tn > t:
            nid = node_table[noff + ((cx - nmin[0]) * ndims[1] + (cy - nmin[1])) * ndims[2] + (cz - nmin[2])]
            if nid >= 0:
                # leaf-level DDA inside this node over [t, tn]
                bx, by, bz = cx * NL, cy * NL, cz * NL
                lx, lsx, lmx, lex = dda_axis(qx, dx, t, LEAF, bx, bx + NL)
                ly, lsy, lmy, ley = dda_axis(qy, dy, t, LEAF, by, by + NL)
                lz, lsz, lmz, lez = dda_axis(qz, dz, t, LEAF, bz, bz + NL)
                u = t
                while True:
                    un = min(lmx, lmy, lmz, tn)
                    if un > u:
                        cid = node_cells[nid, ((lx - bx) * NL + (ly - by)) * NL + (lz - bz)]
                        if cid >= 0 and cell_skip[cid] == 0 and n < cap:
                            iv_ta[n] = u
                            iv_tb[n] = un
                            iv_obj[n] = obj
                            iv_cell[n] = cid
                            n += 1
                    if un >= tn:
                        break
                    if lmx <= lmy and lmx <= lmz:
                        lx += lsx
                        lmx += lex
                        if lx < bx or lx >= bx + NL:
                            break
                    elif lmy <= lmz:
                        ly += lsy
                        lmy += ley
                        if ly < by or ly >= by + NL:
                            break
                    else:
                        lz += lsz
                        lmz += lez
                        if lz < bz or lz >= bz + NL:
                            break
                    if un > u:
                        u = un
        if tn >= t1:
            break
        if mx <= my and mx <= mz:
            cx += sx
            mx += ex
            if cx < nmin[0] or cx >= nmin[0] + ndims[0]:
                break
        elif my <= mz:
            cy += sy
            my += ey
            if cy < nmin[1] or cy >= nmin[1] + ndims[1]:
                break
        else:
            cz += sz
            mz += ez
            if cz < nmin[2] or cz >= nmin[2] + ndims[2]:
                break
        if tn > t:
            t = tn
    return n


@njit(**_jit)
def composite(st, tau, r, g, b, v, ta, tb):
    """L += T c (1 - e^-tau) (expm1), T *= e^-tau; Value and median Depth bookkeeping.
    st = [T, Lr, Lg, Lb, depth, vsum, wsum, segs, done, ...]."""
    if tau <= 0.0:
        return
    T = st[0]
    w = -T * math.expm1(-tau)
    st[1] += w * r
    st[2] += w * g
    st[3] += w * b
    if v == v:
        st[5] += w * v
        st[6] += w
    Tn = T * math.exp(-tau)
    if st[4] == BG_DEPTH and Tn <= 0.5:
        f = math.log(T / 0.5) / tau if T > 0.5 else 0.0
        st[4] = ta + f * (tb - ta)
    st[0] = Tn


@njit(**_jit, inline="always")
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


@njit(**_jit)
def gather_hits(p0, p1, cov_obj, cov_cell, ncov, ro, rd, cell_start, cell_items, g_mu, g_inv,
                g_w, k2, h_s, h_e, h_ts, h_sa, h_pref, h_q, h_ha, h_id):
    """Gaussians of the covering leaves whose k-sigma ellipsoid meets the ray inside [p0, p1]."""
    nh = 0
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
            s = ts - hw
            e = ts + hw
            if s < p0:
                s = p0
            if e > p1:
                e = p1
            if not e > s:
                continue
            h_s[nh] = s
            h_e[nh] = e
            h_ts[nh] = ts
            h_sa[nh] = math.sqrt(0.5 * a)
            h_pref[nh] = math.exp(-0.5 * q) * math.sqrt(math.pi / (2.0 * a))
            h_q[nh] = 0.5 * q
            h_ha[nh] = 0.5 * a
            h_id[nh] = g
            nh += 1
    return nh


@njit(**_jit)
def seg_tau(h, ta, tb, h_ts, h_sa, h_pref, h_id, g_w, h_s, h_e):
    """Closed-form optical depth of hit h over [ta, tb] clipped to its support chord."""
    if ta < h_s[h]:
        ta = h_s[h]
    if tb > h_e[h]:
        tb = h_e[h]
    if not tb > ta:
        return 0.0
    sa = h_sa[h]
    ts = h_ts[h]
    return g_w[h_id[h]] * h_pref[h] * erf_span(sa * (ta - ts), sa * (tb - ts), sa * (tb - ta))


@njit(**_jit)
def depth_in_segment(st, tsum, a0, a1, act, nact, h_ts, h_sa, h_pref, h_id, g_w, h_s, h_e):
    """Median depth: where T crosses 0.5 inside [a0, a1], by bisection on the closed form."""
    T = st[0]
    if st[4] != BG_DEPTH or T * math.exp(-tsum) > 0.5:
        return
    target = math.log(T / 0.5) if T > 0.5 else 0.0
    lo = a0
    hi = a1
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        acc = 0.0
        for k in range(nact):
            acc += seg_tau(act[k], a0, mid, h_ts, h_sa, h_pref, h_id, g_w, h_s, h_e)
        if acc < target:
            lo = mid
        else:
            hi = mid
    st[4] = 0.5 * (lo + hi)


@njit(**_jit)
def particles_segment(st, ta, tb, act, nact, h_ts, h_sa, h_pref, h_id, g_w, g_col, g_val,
                      tau_max, tmp, h_s, h_e):
    """One event segment: closed form per active Gaussian; exact for one active Gaussian (or one
    colour); otherwise colour = tau-weighted mean, subdivided until tau <= tau_max."""
    if nact == 1:
        h = act[0]
        g = h_id[h]
        st[7] += 1
        tau = seg_tau(h, ta, tb, h_ts, h_sa, h_pref, h_id, g_w, h_s, h_e)
        depth_in_segment(st, tau, ta, tb, act, 1, h_ts, h_sa, h_pref, h_id, g_w, h_s, h_e)
        composite(st, tau, g_col[g, 0], g_col[g, 1], g_col[g, 2], g_val[g], ta, tb)
        return
    tsum = 0.0
    # colour spread = largest per-channel max - min over the active set: independent of their order
    cmin0 = cmin1 = cmin2 = INF
    cmax0 = cmax1 = cmax2 = -INF
    for k in range(nact):
        h = act[k]
        tk = seg_tau(h, ta, tb, h_ts, h_sa, h_pref, h_id, g_w, h_s, h_e)
        tmp[k] = tk
        tsum += tk
        g = h_id[h]
        cmin0 = min(cmin0, g_col[g, 0])
        cmax0 = max(cmax0, g_col[g, 0])
        cmin1 = min(cmin1, g_col[g, 1])
        cmax1 = max(cmax1, g_col[g, 1])
        cmin2 = min(cmin2, g_col[g, 2])
        cmax2 = max(cmax2, g_col[g, 2])
    spread = max(cmax0 - cmin0, cmax1 - cmin1, cmax2 - cmin2)
    st[7] += nact
    # mixing error ~ tau^2 x colour spread: subdivide until tau * spread <= tau_max
    nsub = 1
    if tau_max > 0.0 and tsum * spread > tau_max:
        nsub = min(int(math.ceil(tsum * spread / tau_max)), 1024)
    for s in range(nsub):
        if nsub > 1:
            a0 = ta + (tb - ta) * s / nsub
            a1 = ta + (tb - ta) * (s + 1) / nsub if s + 1 < nsub else tb
            tsum = 0.0
            for k in range(nact):
                tmp[k] = seg_tau(act[k], a0, a1, h_ts, h_sa, h_pref, h_id, g_w, h_s, h_e)
                tsum += tmp[k]
            st[7] += nact
        else:
            a0, a1 = ta, tb
        if tsum <= 0.0:
            continue
        r = 0.0
        gg = 0.0
        b = 0.0
        vs = 0.0
        vw = 0.0
        for k in range(nact):
            g = h_id[act[k]]
            w = tmp[k]
            r += w * g_col[g, 0]
            gg += w * g_col[g, 1]
            b += w * g_col[g, 2]
            if g_val[g] == g_val[g]:
                vs += w * g_val[g]
                vw += w
        composite(st, tsum, r / tsum, gg / tsum, b / tsum, vs / vw if vw > 0 else np.nan, a0, a1)
        if st[0] < st[9]:
            return


@njit(**_jit)
def sort_events(ev_t, ev_k, n, order):
    """Insertion sort of event indices by (t, Gaussian id, kind) -- exact ties keep a fixed
    order (3DGRT's t > t_last hazard)."""
    for i in range(n):
        order[i] = i
    for i in range(1, n):
        j = i
        cur = order[i]
        while j > 0:
            p = order[j - 1]
            if ev_t[p] < ev_t[cur] or (ev_t[p] == ev_t[cur] and ev_k[p] <= ev_k[cur]):
                break
            order[j] = p
            j -= 1
        order[j] = cur


@njit(**_jit)
def process_particles(st, p0, p1, nh, h_s, h_e, h_ts, h_sa, h_pref, h_id, g_w, g_col, g_val,
                      tau_max, ev_t, ev_k, order, act, pos, tmp, dense):
    if nh == 1:
        act[0] = 0
        particles_segment(st, h_s[0], h_e[0], act, 1, h_ts, h_sa, h_pref, h_id, g_w, g_col,
                          g_val, tau_max, tmp, h_s, h_e)
        return
    ne = 0
    for h in range(nh):
        ev_t[ne] = h_s[h]
        ev_k[ne] = h_id[h] * 2 + 1  # entry (key orders (t, id), exits before entries of same id)
        ne += 1
        ev_t[ne] = h_e[h]
        ev_k[ne] = h_id[h] * 2
        ne += 1
    if nh > dense:
        # many overlapping supports: one segment over the piece, subdivided by tau x spread
        # (same error bound as the sweep's mixed segments; cost ~nh per sub-segment, not nh^2)
        lo = h_s[0]
        hi = h_e[0]
        for h in range(nh):
            act[h] = h
            lo = min(lo, h_s[h])
            hi = max(hi, h_e[h])
        particles_segment(st, lo, hi, act, nh, h_ts, h_sa, h_pref, h_id, g_w, g_col, g_val,
                          tau_max, tmp, h_s, h_e)
        return
    sort_events(ev_t, ev_k, ne, order)
    nact = 0
    prev = ev_t[order[0]]
    for i in range(ne):
        e = order[i]
        t = ev_t[e]
        if t > prev and nact > 0:
            particles_segment(st, prev, t, act, nact, h_ts, h_sa, h_pref, h_id, g_w, g_col,
                              g_val, tau_max, tmp, h_s, h_e)
            if st[0] < st[9]:
                return
        h = e >> 1
        if e & 1 == 0:  # entry (event index even = entry, see construction order)
            pos[h] = nact
            act[nact] = h
            nact += 1
        else:
            k = pos[h]
            last = act[nact - 1]
            act[k] = last
            pos[last] = k
            nact -= 1
        prev = t


@njit(**_jit)
def sample_color(ob, s, x_idx, y_idx, z_idx, obj_kind, obj_tf, obj_ls, tf_lut, tf_par, out):
    """sigma_t and linear colour of object ob for field value s at index point x."""
    tfi = obj_tf[ob]
    par = tf_par[tfi]
    lut = tf_lut[tfi]
    if obj_kind[ob] == 1:  # level set: uniform opacity, colour by coordinate or constant
        occ = s
        if occ > 1.0:
            occ = 1.0
        if occ <= 0.0:
            out[0] = 0.0
            return
        out[0] = par[3] * occ
        ls = obj_ls[ob]
        if ls[0] > 0.5:
            out[1], out[2], out[3] = ls[8], ls[9], ls[10]
        else:
            c = ls[1] * x_idx + ls[2] * y_idx + ls[3] * z_idx + ls[4]
            x = (c - ls[5]) / (ls[6] - ls[5]) if ls[6] > ls[5] else 0.5
            x = min(max(x, 0.0), 1.0)
            out[1], out[2], out[3] = lut_at(lut, x, 0), lut_at(lut, x, 1), lut_at(lut, x, 2)
        out[4] = np.nan
        return
    x = tf_x(s, par)
    if x != x:
        out[0] = 0.0
        return
    a = lut_at(lut, x, 3)
    out[0] = par[3] * a
    out[1], out[2], out[3] = lut_at(lut, x, 0), lut_at(lut, x, 1), lut_at(lut, x, 2)
    out[4] = s


@njit(**_jit)
def process_samples(st, mode, p0, p1, ncov, cov_obj, cov_cell, ro, rd, obj_step, nh, h_s, h_e,
                    h_ts, h_q, h_ha, h_id, g_w, g_obj, bricks, cell_xyz, obj_kind, obj_tf, obj_ls,
                    tf_lut, tf_par, svals, sact, samp):
    """field (mode 1) / reference (mode 3): midpoint samples, exact exponential compositing.
    Each object's medium exists only inside its domain (field: union of supports; reference:
    its leaves); objects overlapping in a piece add extinction, colours tau-weighted."""
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
        sig = 0.0
        r = 0.0
        g = 0.0
        b = 0.0
        vs = 0.0
        vw = 0.0
        for c in range(ncov):
            ob = cov_obj[c]
            svals[c] = 0.0
            sact[c] = 0
        if mode == 1:
            for k in range(nh):
                if h_s[k] <= t and t <= h_e[k]:
                    gid = h_id[k]
                    d = t - h_ts[k]
                    ob = g_obj[gid]
                    for c in range(ncov):
                        if cov_obj[c] == ob:
                            svals[c] += g_w[gid] * math.exp(-(h_q[k] + h_ha[k] * d * d))
                            sact[c] = 1
            st[7] += nh
        for c in range(ncov):
            ob = cov_obj[c]
            x = ro[ob, 0] + t * rd[ob, 0]
            y = ro[ob, 1] + t * rd[ob, 1]
            z = ro[ob, 2] + t * rd[ob, 2]
            if mode == 3:
                cid = cov_cell[c]
                fx = x - (cell_xyz[cid, 0] * 8 - 1)
                fy = y - (cell_xyz[cid, 1] * 8 - 1)
                fz = z - (cell_xyz[cid, 2] * 8 - 1)
                fx = min(max(fx, 0.0), 8.999999)
                fy = min(max(fy, 0.0), 8.999999)
                fz = min(max(fz, 0.0), 8.999999)
                i0, j0, k0 = int(fx), int(fy), int(fz)
                ax, ay, az = fx - i0, fy - j0, fz - k0
                B = bricks[cid]
                c00 = B[i0, j0, k0] * (1 - ax) + B[i0 + 1, j0, k0] * ax
                c10 = B[i0, j0 + 1, k0] * (1 - ax) + B[i0 + 1, j0 + 1, k0] * ax
                c01 = B[i0, j0, k0 + 1] * (1 - ax) + B[i0 + 1, j0, k0 + 1] * ax
                c11 = B[i0, j0 + 1, k0 + 1] * (1 - ax) + B[i0 + 1, j0 + 1, k0 + 1] * ax
                val = (c00 * (1 - ay) + c10 * ay) * (1 - az) + (c01 * (1 - ay) + c11 * ay) * az
                if obj_kind[ob] == 1:  # SDF (world units) -> occupancy with a one-voxel ramp
                    val = 0.5 - val / obj_ls[ob, 7]
                svals[c] = val
                sact[c] = 1
                st[7] += 1
            if sact[c] == 0:
                continue
            sample_color(ob, svals[c], x, y, z, obj_kind, obj_tf, obj_ls, tf_lut, tf_par, samp)
            sg = samp[0]
            if sg > 0.0:
                sig += sg
                r += sg * samp[1]
                g += sg * samp[2]
                b += sg * samp[3]
                if samp[4] == samp[4]:
                    vs += sg * samp[4]
                    vw += sg
        if sig > 0.0:
            composite(st, sig * h, r / sig, g / sig, b / sig, vs / vw if vw > 0 else np.nan,
                      t - 0.5 * h, t + 0.5 * h)
            if st[0] < st[9]:
                return


@njit(**_jit)
def paper_piece(st, p0, p1, ncov, cov_obj, cov_cell, ro, rd, cell_start, cell_items, g_mu, g_inv,
                g_w, g_col, g_val, g_obj, g_volfac, k2, nsteps, max_depth):
    """The seed paper: closest hit (smallest entry, ties by id) entering at or after the current
    origin, fixed midpoint steps over its chord, A = rho dt / det(Sigma), C += T c A,
    T *= exp(-A), continue after its exit; overlapping Gaussians entered earlier are ignored."""
    while st[10] < max_depth and st[0] >= st[9]:
        best = -1
        bt0 = INF
        bt1 = 0.0
        tcur = max(st[11], p0)
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
                if t0 < tcur or t0 >= p1:
                    continue
                if t0 < bt0 or (t0 == bt0 and g < best):
                    bt0 = t0
                    bt1 = ts + hw
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
            T = st[0]
            st[1] += T * g_col[g, 0] * A
            st[2] += T * g_col[g, 1] * A
            st[3] += T * g_col[g, 2] * A
            if g_val[g] == g_val[g]:
                st[5] += T * A * g_val[g]
                st[6] += T * A
            st[0] = T * math.exp(-A)
            if st[4] == BG_DEPTH and st[0] <= 0.5:
                st[4] = t
        st[7] += nsteps
        st[10] += 1
        st[11] = bt1


@njit(parallel=True, **_jit)
def render_rows(mode, cam, row0, row1, w2i, nmin, ndims, noff, node_table, node_cells, cell_skip,
                cell_start, cell_items, g_mu, g_inv, g_w, g_col, g_val, g_obj, g_volfac,
                bricks, cell_xyz, obj_kind, obj_tf, obj_ls, obj_step, tf_lut, tf_par,
                settings, max_walk, max_hits, out_rgba, out_depth, out_value, out_segs):
    """Render rows [row0, row1) into out_* (indexed from 0 = row0).
    settings: [T_min, tau_max, k, bg_r, bg_g, bg_b, bg_a, paper_steps, paper_max_depth]."""
    W = int(cam[1])
    H = int(cam[2])
    ex, ey, offx, offy = cam[3], cam[4], cam[5], cam[6]
    n_obj = w2i.shape[0]
    tmin_T = settings[0]
    tau_max = settings[1]
    k2 = settings[2] * settings[2]
    bgr, bgg, bgb, bga = settings[3], settings[4], settings[5], settings[6]
    nsteps = int(settings[7])
    maxd = settings[8]
    dense = int(settings[9])
    for jr in prange(row1 - row0):
        j = row0 + jr
        iv_ta = np.empty(max_walk)
        iv_tb = np.empty(max_walk)
        iv_obj = np.empty(max_walk, np.int32)
        iv_cell = np.empty(max_walk, np.int32)
        srt = np.empty(max_walk, np.int64)
        bnd = np.empty(2 * max_walk)
        act_iv = np.empty(max_walk, np.int64)
        cov_obj = np.empty(max_walk, np.int32)
        cov_cell = np.empty(max_walk, np.int32)
        ro = np.empty((n_obj, 3))
        rd = np.empty((n_obj, 3))
        h_s = np.empty(max_hits)
        h_e = np.empty(max_hits)
        h_ts = np.empty(max_hits)
        h_sa = np.empty(max_hits)
        h_pref = np.empty(max_hits)
        h_q = np.empty(max_hits)
        h_ha = np.empty(max_hits)
        h_id = np.empty(max_hits, np.int64)
        ev_t = np.empty(2 * max_hits)
        ev_k = np.empty(2 * max_hits, np.int64)
        order = np.empty(2 * max_hits, np.int64)
        act = np.empty(max_hits, np.int64)
        pos = np.empty(max_hits, np.int64)
        tmp = np.empty(max_hits)
        svals = np.empty(max_walk)
        sact = np.empty(max_walk, np.int64)
        samp = np.empty(5)
        st = np.empty(12)
        segs = 0.0
        py = ((j + 0.5) / H - 0.5) * ey + offy
        for i in range(W):
            px = ((i + 0.5) / W - 0.5) * ex + offx
            if cam[0] < 0.5:
                dcx = cam[7] * px + cam[8] * py - cam[9]
                dcy = cam[10] * px + cam[11] * py - cam[12]
                dcz = cam[13] * px + cam[14] * py - cam[15]
                nrm = math.sqrt(dcx * dcx + dcy * dcy + dcz * dcz)
                dwx, dwy, dwz = dcx / nrm, dcy / nrm, dcz / nrm
                owx, owy, owz = cam[16], cam[17], cam[18]
            else:
                dwx, dwy, dwz = -cam[9], -cam[12], -cam[15]
                owx = cam[16] + px * cam[7] + py * cam[8]
                owy = cam[17] + px * cam[10] + py * cam[11]
                owz = cam[18] + px * cam[13] + py * cam[14]
            st[0] = 1.0
            st[1] = 0.0
            st[2] = 0.0
            st[3] = 0.0
            st[4] = BG_DEPTH
            st[5] = 0.0
            st[6] = 0.0
            st[7] = 0.0
            st[8] = 0.0
            st[9] = tmin_T
            st[10] = 0.0
            st[11] = -INF
            n = 0
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
                n = walk_object(ox, oy, oz, dx, dy, dz, nmin[ob], ndims[ob], noff[ob], node_table,
                                node_cells, cell_skip, ob, iv_ta, iv_tb, iv_obj, iv_cell, n, max_walk)
            if n > 0:
                # pieces: where the set of covering leaves (at most one per object) is constant
                if n_obj == 1:
                    npieces = n
                else:
                    srt[:n] = np.argsort(iv_ta[:n], kind="mergesort")
                    for q in range(n):
                        bnd[q] = iv_ta[q]
                        bnd[n + q] = iv_tb[q]
                    bs = np.sort(bnd[:2 * n])
                    npieces = 2 * n - 1
                ptr = 0
                nactiv = 0
                for pi in range(npieces):
                    if n_obj == 1:
                        p0 = iv_ta[pi]
                        p1 = iv_tb[pi]
                        ncov = 1
                        cov_obj[0] = iv_obj[pi]
                        cov_cell[0] = iv_cell[pi]
                    else:
                        p0 = bs[pi]
                        p1 = bs[pi + 1]
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
                            cov_obj[ncov] = iv_obj[act_iv[q]]
                            cov_cell[ncov] = iv_cell[act_iv[q]]
                            ncov += 1
                        if ncov == 0:
                            continue
                    if mode == 2:
                        paper_piece(st, p0, p1, ncov, cov_obj, cov_cell, ro, rd, cell_start,
                                    cell_items, g_mu, g_inv, g_w, g_col, g_val, g_obj, g_volfac,
                                    k2, nsteps, maxd)
                        if st[10] >= maxd:
                            break
                    elif mode == 3:
                        process_samples(st, mode, p0, p1, ncov, cov_obj, cov_cell, ro, rd,
                                        obj_step, 0, h_s, h_e, h_ts, h_q, h_ha, h_id, g_w, g_obj,
                                        bricks, cell_xyz, obj_kind, obj_tf, obj_ls, tf_lut, tf_par,
                                        svals, sact, samp)
                    else:
                        nh = gather_hits(p0, p1, cov_obj, cov_cell, ncov, ro, rd, cell_start,
                                         cell_items, g_mu, g_inv, g_w, k2, h_s, h_e, h_ts, h_sa,
                                         h_pref, h_q, h_ha, h_id)
                        if nh > 0:
                            if mode == 0:
                                process_particles(st, p0, p1, nh, h_s, h_e, h_ts, h_sa, h_pref,
                                                  h_id, g_w, g_col, g_val, tau_max, ev_t, ev_k,
                                                  order, act, pos, tmp, dense)
                            else:
                                process_samples(st, mode, p0, p1, ncov, cov_obj, cov_cell, ro,
                                                rd, obj_step, nh, h_s, h_e, h_ts, h_q, h_ha,
                                                h_id, g_w, g_obj, bricks, cell_xyz, obj_kind,
                                                obj_tf, obj_ls, tf_lut, tf_par, svals, sact, samp)
                    if st[0] < tmin_T:
                        break
            T = st[0]
            out_rgba[jr, i, 0] = st[1] + T * bgr * bga
            out_rgba[jr, i, 1] = st[2] + T * bgg * bga
            out_rgba[jr, i, 2] = st[3] + T * bgb * bga
            out_rgba[jr, i, 3] = (1.0 - T) + T * bga
            out_depth[jr, i] = st[4]
            out_value[jr, i] = st[5] / st[6] if st[6] > 0.0 else 0.0
            segs += st[7]
        out_segs[jr] = segs
