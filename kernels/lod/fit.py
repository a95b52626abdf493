"""Least-squares amplitudes: the weights w_i = value_i x amplitude_i that bring the mixture closest
to the voxels (the same k-sigma truncated field, at the same voxel centres, as `field_error`).

The problem is min ||A w - b||^2 over the active voxels, A_ji = g_i(x_j) (unit-peak Gaussians, so
A >= 0), with w_i of the sign of value_i (amplitudes stay non-negative, so the opacity does).
Conjugate gradients on the normal equations get close fast (the single-voxel lattice's kernel
matrix has a condition number of ~30); after the sign clip, projected majorize-minimize (SART) steps

    w_i += omega * sum_j g_ij r_j / sum_j g_ij s1_j,   r = b - A w,   s1 = A 1,

then w_i is clipped to the allowed sign. diag(A^T A 1) >= A^T A because A >= 0, so the step never
increases the error for omega <= 1 and converges for omega < 2; it is exact in one step for an
isolated Gaussian and for a uniform residual over a partition of unity. One pass over the cells per
iteration (mixture, residual, per-pair sums); partial sums are per pair and reduced in pair order,
so the result does not depend on the thread count.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit, parallel_for
from .error_pairs import distinct_sigmas
from .mixture import (
    CELLS_PER_TASK,
    axis_tables,
    cell_residual,
    gaussian_terms,
    pair_voxels,
)

OMEGA = 1.6  # over-relaxation (< 2)
NONE, S1, SHARE = 0, 1, 2  # what a pass sums per pair beside A^T r (_pass)


@njit(cache=True, nogil=True)
def _pass_rows(lo, hi, corg, cmask, cref, cstart, pg, cent, sig, w, k, den, c2, sid, tq, te, hh, pnum, pden,
               cres, ones, most, sse, mx):
    """_pass' tasks lo..hi-1: CELLS_PER_TASK cells each, one set of scratch arrays."""
    nc, k2 = corg.shape[0], k * k
    for t in range(lo, hi):
        acc = np.empty(512)
        one = np.empty(512)
        act = np.empty(512, np.bool_)
        wg = np.empty(1)
        og = np.empty(1)
        vn = np.empty(8)
        vd = np.empty(8)
        qs = np.empty((most, 3, 8))
        es = np.empty((most, 3, 8))
        for c in range(t * CELLS_PER_TASK, min(nc, (t + 1) * CELLS_PER_TASK)):
            p0 = cstart[c]
            acc[:] = 0.0
            one[:] = 0.0
            for p in range(p0, cstart[c + 1]):
                g = pg[p]
                q, e = qs[p - p0], es[p - p0]
                gaussian_terms(c, g, corg, cent, sig, k2, c2, sid, tq, te, hh, q, e)
                wg[0], og[0] = w[g], ones[g]  # one: s1, or sum |w g|
                if den == NONE:
                    pair_voxels(q, e, k2, False, False, acc, wg, one, og)
                else:
                    pair_voxels(q, e, k2, False, True, acc, wg, one, og)
            act[:] = False
            res = cres[c]
            res[:] = 0.0
            sse[c], mx[c], _ = cell_residual(c, cmask, cref, acc, res, act)
            for i in range(512):  # res is 0 off the active voxels: so is what it is paired with
                if not act[i]:
                    one[i] = 0.0
                elif den == SHARE:
                    one[i] = res[i] * res[i] / one[i] if one[i] > 1e-30 else 0.0
            for p in range(p0, cstart[c + 1]):
                if den == NONE:
                    pnum[p] = pair_voxels(qs[p - p0], es[p - p0], k2, True, False, vn, res, vd, one)[0]
                    continue
                num, dsum = pair_voxels(qs[p - p0], es[p - p0], k2, True, True, vn, res, vd, one)
                pnum[p] = num
                pden[p] = dsum if den == S1 else dsum * abs(w[pg[p]])


def _pass(corg, cmask, cref, cstart, pg, cent, sig, w, k, den, c2, sid, tq, te, hh, pnum, pden,
          cres):
    """Residual at every active voxel of every cell into cres (0 elsewhere); per pair
    pnum = sum g r and pden: with den = S1 sum g s1, with den = SHARE the pair's share of the SSE,
    sum |w g| r^2 / sum_k |w_k g_k| (each voxel's error split among the Gaussians that make its
    field), with den = NONE nothing (the second mixture is not made). Returns the per-cell SSE
    and max |r|. Each pair's axis terms are made once (from axis_tables' tables when hh >= 0) and
    kept for their three uses: they were most of the cost."""
    nc = corg.shape[0]
    sse = np.zeros(nc)
    mx = np.zeros(nc)
    ones = np.ones(w.shape[0]) if den == S1 else np.abs(w)
    most = max(1, int(np.diff(cstart).max())) if nc else 1  # the most pairs a cell has
    parallel_for(_pass_rows, -(-nc // CELLS_PER_TASK), corg, cmask, cref, cstart, pg, cent, sig, w,
                 np.float64(k), np.int64(den), c2, sid, tq, te, np.int64(hh), pnum, pden, cres, ones,
                 np.int64(most), sse, mx)
    return sse, mx


COMPUTED = (np.zeros((0, 3), np.int64), np.zeros((0, 3), np.int64), np.zeros((0, 0)), np.zeros((0, 0)),
            -1)


def axis_lattice(cent, sig, k):
    """_pass' table arguments (c2, sid, tq, te, hh): centres on the half-voxel lattice with few
    distinct sigmas (every set the presets make) read their axis terms from axis_tables (the same
    bits); otherwise COMPUTED (hh = -1): they are computed."""
    c2 = 2.0 * cent
    u, few = distinct_sigmas(sig)
    tables = axis_tables(u, k) if few and len(u) and np.array_equal(c2, np.round(c2)) else None
    if tables is None:
        return COMPUTED
    order = np.argsort(u)
    sid = order[np.searchsorted(u[order], sig)]
    return c2.astype(np.int64), sid.astype(np.int64), *tables


def _run(st, w, cref, den, pnum, pden, cres):
    return _pass(st["corg"], st["cmask"], cref, st["cstart"], st["pg"], st["cent"], st["sig"], w,
                 st["k"], den, *st["tables"], pnum, pden, cres)


def fit_weights(st, w, sign, cg_steps, mm_steps, omega=OMEGA):
    """Improve the weights w (float64; a new array is returned): cg_steps of conjugate gradients
    on the normal equations (Jacobi-preconditioned by diag(A^T A 1), unconstrained), the sign clip,
    then mm_steps projected MM steps, each monotone, and a last pass that only measures.
    st: mixture.pair_lists output (plus, optionally, axis_lattice's tables as "tables"); sign:
    +1 / -1 / 0 per Gaussian (0: the weight stays 0).
    Returns (w, per-cell residuals (C, 512), per-cell SSE, per-cell max |r|, per-Gaussian share of
    the SSE)."""
    w = np.array(w, np.float64)
    if "tables" not in st:
        st = dict(st, tables=axis_lattice(st["cent"], st["sig"], st["k"]))
    m, npair = len(w), len(st["pg"])
    pnum, pden = np.empty(npair), np.empty(npair)
    cres = np.empty((len(st["corg"]), 512))
    pw = np.repeat(st["cw"], np.diff(st["cstart"]))  # big tiles count (edge/8)^3 voxels each

    def at(v):  # per-Gaussian sums of per-pair values, in pair order
        return np.bincount(st["pg"], weights=v * pw, minlength=m)

    free = sign != 0
    _run(st, w, st["cref"], S1, pnum, pden, cres)
    d = at(pden)
    dinv = np.where(free & (d > 0), 1.0 / np.where(d > 0, d, 1.0), 0.0)
    g = at(pnum)  # A^T (b - A w)
    if cg_steps:
        zero = np.zeros_like(st["cref"])
        z = dinv * g
        p, rz = z.copy(), float(g @ z)
        for _ in range(cg_steps):
            if rz <= 0:
                break
            _run(st, p, zero, NONE, pnum, pden, cres)
            q = -at(pnum)  # A^T A p
            pq = float(p @ q)
            if pq <= 0:
                break
            a = rz / pq
            w += a * p
            g -= a * q
            z = dinv * g
            rz, rz_old = float(g @ z), rz
            p = z + (rz / rz_old) * p
    for it in range(mm_steps + 1):
        w = np.where(sign > 0, np.maximum(w, 0.0), np.where(sign < 0, np.minimum(w, 0.0), 0.0))
        sse, mx = _run(st, w, st["cref"], SHARE if it == mm_steps else NONE, pnum, pden, cres)
        if it == mm_steps:
            break
        w = w + omega * dinv * at(pnum)
    return w, cres, sse, mx, at(pden)
