"""The drawn Gaussians of one GaussianSet as the renderer keeps them, in two compiled passes over
its leaf groups (count, then fill at each group's place): float64 centres (group origin + offset,
exact), inverse sigmas, values, second-grid values, amplitudes, and each Gaussian's walk level and
box of that level's cells (accel's LEVEL_CELLS / LEVEL_SPAN rule); plus the bounds of the centres
and of the k-sigma supports. Dropped: a zero or non-finite sigma, centre or amplitude (never drawn).

The same arithmetic as the numpy passes it replaces (bit for bit), without their temporaries: at
10 M Gaussians those took 12 s of a 15 s scene sync and several float64 copies of every array."""
from __future__ import annotations

import math

import numpy as np

from ...jit import njit, parallel_for
from .layout import REC_INV, REC_LB, REC_MU, REC_SIZE, REC_W

_jit = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


@njit(**_jit)
def _gaussian(origins, gi, offsets, sigmas, amps, i):
    """Gaussian i of group gi: whether it is drawn, its centre (origin + offset, exact in float64),
    sigma and amplitude."""
    m0 = float(origins[gi, 0]) + float(offsets[i, 0])
    m1 = float(origins[gi, 1]) + float(offsets[i, 1])
    m2 = float(origins[gi, 2]) + float(offsets[i, 2])
    s0, s1, s2 = float(sigmas[i, 0]), float(sigmas[i, 1]), float(sigmas[i, 2])
    w = float(amps[i])
    ok = (s0 > 0.0 and s1 > 0.0 and s2 > 0.0 and math.isfinite(m0) and math.isfinite(m1)
          and math.isfinite(m2) and math.isfinite(w) and w != 0.0)
    return ok, (m0, m1, m2), (s0, s1, s2), w


@njit(**_jit)
def _counts(g0, g1, start, origins, offsets, sigmas, amps, cnt):
    """Drawn Gaussians per group: cnt[gi] for groups g0..g1-1."""
    for gi in range(g0, g1):
        c = 0
        for i in range(start[gi], start[gi + 1]):
            c += _gaussian(origins, np.int64(gi), offsets, sigmas, amps, i)[0]
        cnt[gi] = c


@njit(**_jit)
def _fill(g0, g1, start, first, origins, offsets, sigmas, amps, values, cvalues, k, max_level, level_cells,
          level_span, leaf, mu, inv, sig_out, val, cval, amp, lev, clo, chi, gbox):
    """Each group's drawn Gaussians at first[gi]...; gbox[gi] = (centre lo, centre hi, support lo,
    support hi) over them (+-inf when none). values / cvalues: empty when the set has none (NaN).
    With empty output arrays (mu), only gbox."""
    has_v = values.shape[0] > 0
    has_c = cvalues.shape[0] > 0
    write = mu.shape[0] > 0
    keep_sig = sig_out.shape[0] > 0
    for gi in range(g0, g1):
        for a in range(3):
            gbox[gi, 0, a] = np.inf
            gbox[gi, 1, a] = -np.inf
            gbox[gi, 2, a] = np.inf
            gbox[gi, 3, a] = -np.inf
        j = first[gi]
        for i in range(start[gi], start[gi + 1]):
            ok, ms, ss, w = _gaussian(origins, np.int64(gi), offsets, sigmas, amps, i)
            if not ok:
                continue
            for a in range(3):
                r = k * ss[a]
                gbox[gi, 0, a] = min(gbox[gi, 0, a], ms[a])
                gbox[gi, 1, a] = max(gbox[gi, 1, a], ms[a])
                gbox[gi, 2, a] = min(gbox[gi, 2, a], ms[a] - r)
                gbox[gi, 3, a] = max(gbox[gi, 3, a], ms[a] + r)
            if not write:
                continue
            v = float(values[i]) if has_v else np.nan
            val[j] = v
            cval[j] = float(cvalues[i]) if has_c else v * np.nan
            amp[j] = w
            big = 0
            for a in range(3):
                mu[j, a] = ms[a]
                inv[j, a] = 1.0 / ss[a]
                if keep_sig:
                    sig_out[j, a] = ss[a]
                r = k * ss[a]
                clo[j, a] = np.int64(math.floor(ms[a] - r + 0.5)) // leaf
                chi[j, a] = np.int64(math.floor(ms[a] + r + 0.5)) // leaf
                big = max(big, chi[j, a] - clo[j, a])
            # the first level whose cells (level_cells^level leaves) the leaf box spans at most
            # level_span - 1 apart per axis (accel's rule)
            level = 0
            c0, c1, c2 = clo[j, 0], clo[j, 1], clo[j, 2]
            h0, h1, h2 = chi[j, 0], chi[j, 1], chi[j, 2]
            while big >= level_span and level < max_level:
                level += 1
                d = np.int64(level_cells) ** level
                clo[j, 0], clo[j, 1], clo[j, 2] = c0 // d, c1 // d, c2 // d
                chi[j, 0], chi[j, 1], chi[j, 2] = h0 // d, h1 // d, h2 // d
                big = max(chi[j, 0] - clo[j, 0], chi[j, 1] - clo[j, 1], chi[j, 2] - clo[j, 2])
            lev[j] = level
            j += 1


def spheres(mu, inv, ref, obj, k, sph, volfac):
    """Per Gaussian: its bounding sphere for the kernels' cheap rejection, float32 centre relative
    to its object's reference point ref[obj] and squared radius k sigma_max widened by a margin for
    the float32 rounding; and the paper's volume factor 1/det(Sigma) = (prod 1/sigma)^2."""
    parallel_for(_spheres, mu.shape[0], mu, inv, ref, obj, float(k), sph, volfac)


@njit(**_jit)
def _spheres(g0, g1, mu, inv, ref, obj, k, sph, volfac):
    for g in range(g0, g1):
        ob = obj[g]
        for a in range(3):
            sph[g, a] = np.float32(mu[g, a] - ref[ob, a])
        rad = k / min(min(inv[g, 0], inv[g, 1]), inv[g, 2])
        rad = rad * 1.001 + 0.01
        sph[g, 3] = np.float32(rad * rad)
        p = inv[g, 0] * inv[g, 1] * inv[g, 2]
        volfac[g] = p * p


def test_records(mu, inv):
    """(m, REC_SIZE) rows for the per-ray Gaussian test (layout.REC): centre and 1/sigma, then the weight and entry
    bound (zero here: set per frame). One parallel pass: at 22 M Gaussians the numpy version's
    column copies took 5 s, most of it first touches of the fresh rows."""
    rec = np.empty((mu.shape[0], REC_SIZE))
    parallel_for(_test_records, mu.shape[0], mu, inv, rec)
    return rec


@njit(**_jit)
def _test_records(g0, g1, mu, inv, rec):
    for g in range(g0, g1):
        for a in range(3):
            rec[g, REC_MU + a] = mu[g, a]
            rec[g, REC_INV + a] = inv[g, a]
        rec[g, REC_W] = 0.0
        rec[g, REC_LB] = 0.0


def _bounds(start, origins, offsets, sigmas, amps, k, chunk=1 << 20):
    """drawn's bounds in numpy, group runs of about ``chunk`` Gaussians at a time: the same
    tests, sums and products in float64 as _gaussian and _fill (so the same numbers), without
    compiling _fill for a frame that needs only the box (a reference frame's sync)."""
    lo_c, hi_c = np.full(3, np.inf), np.full(3, -np.inf)
    lo_s, hi_s = lo_c.copy(), hi_c.copy()
    ng = start.shape[0] - 1
    g = 0
    while g < ng:
        g2 = min(ng, max(g + 1, int(np.searchsorted(start, start[g] + chunk, side="right")) - 1))
        i0, i1 = int(start[g]), int(start[g2])
        gid = np.repeat(np.arange(g, g2), np.diff(start[g:g2 + 1]))
        mu = origins[gid].astype(np.float64) + offsets[i0:i1].astype(np.float64)
        sg = sigmas[i0:i1].astype(np.float64)
        w = amps[i0:i1].astype(np.float64)
        ok = (sg > 0.0).all(1) & np.isfinite(mu).all(1) & np.isfinite(w) & (w != 0.0)
        mu, r = mu[ok], k * sg[ok]
        lo_c = np.minimum(lo_c, mu.min(0, initial=np.inf))
        hi_c = np.maximum(hi_c, mu.max(0, initial=-np.inf))
        lo_s = np.minimum(lo_s, (mu - r).min(0, initial=np.inf))
        hi_s = np.maximum(hi_s, (mu + r).max(0, initial=-np.inf))
        g = g2
    return None if not np.isfinite(lo_c).all() else ((lo_c, hi_c), (lo_s, hi_s))


def drawn(gs, k, max_level, level_cells, level_span, leaf, sigmas=False, arrays=True):
    """The drawn Gaussians of set gs (None: none) as a dict of arrays (see module doc): mu, inv,
    val, cval (its second grid: a level set's distances, else its colour values; NaN without),
    amp, lev, clo, chi, sig (with sigmas, else empty), and bounds ((centre lo, hi), (support lo,
    hi)) or None when none is drawn. Without arrays, {"bounds": ...} alone."""
    start = np.asarray(gs.group_start, np.int64) if gs is not None else np.zeros(1, np.int64)
    m = int(start[-1]) if start.size else 0
    if m == 0:
        start = np.zeros(1, np.int64)
    origins = np.asarray(gs.group_origins, np.int64).reshape(-1, 3) if m else np.zeros((0, 3), np.int64)
    offsets = np.asarray(gs.offsets)[:m] if m else np.zeros((0, 3), np.float32)
    sig_in = np.asarray(gs.sigmas)[:m] if m else np.zeros((0, 3), np.float32)
    amps = np.asarray(gs.amplitudes)[:m] if m else np.zeros(0, np.float32)
    values = getattr(gs, "values", None) if m else None
    values = np.zeros(0) if values is None else np.asarray(values)[:m]
    second = "distances" if getattr(gs, "grid_class", "") == "level_set" else "color_values"
    cvalues = getattr(gs, second, None) if m else None
    cvalues = np.zeros(0) if cvalues is None else np.asarray(cvalues)[:m]
    if not arrays:
        return {"bounds": _bounds(start, origins, offsets, sig_in, amps, float(k))}
    cnt = np.zeros(start.shape[0] - 1, np.int64)
    parallel_for(_counts, cnt.shape[0], start, origins, offsets, sig_in, amps, cnt)
    first = np.zeros(cnt.shape[0] + 1, np.int64)
    np.cumsum(cnt, out=first[1:])
    n = int(first[-1])
    out = dict(mu=np.empty((n, 3)), inv=np.empty((n, 3)), val=np.empty(n), cval=np.empty(n),
               amp=np.empty(n), lev=np.empty(n, np.int64), clo=np.empty((n, 3), np.int64),
               chi=np.empty((n, 3), np.int64), sig=np.empty((n if sigmas else 0, 3)))
    gbox = np.empty((start.shape[0] - 1, 4, 3))
    parallel_for(_fill, gbox.shape[0], start, first, origins, offsets, sig_in, amps, values, cvalues,
                 float(k), np.int64(max_level), np.int64(level_cells), np.int64(level_span),
                 np.int64(leaf), out["mu"], out["inv"], out["sig"], out["val"], out["cval"], out["amp"],
                 out["lev"], out["clo"], out["chi"], gbox)
    lo = gbox[:, 0].min(0, initial=np.inf)
    out["bounds"] = None if not np.isfinite(lo).all() else (
        (lo, gbox[:, 1].max(0)), (gbox[:, 2].min(0), gbox[:, 3].max(0)))
    return out
