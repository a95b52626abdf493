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

from ..jit import parallel_njit, prange
from .error import cell_mixture, cell_residual, pair_sums

OMEGA = 1.6  # over-relaxation (< 2)


@parallel_njit(cache=True)
def _pass(corg, cmask, cref, cstart, pg, cent, sig, w, k, with_den, pnum, pden, cres):
    """Residual at every active voxel of every cell into cres (0 elsewhere); per pair
    pnum = sum g r and, with with_den, pden = sum g s1; else pden = the pair's share of the SSE,
    sum |w g| r^2 / sum_k |w_k g_k| (each voxel's error split among the Gaussians that make its
    field). Returns the per-cell SSE and max |r|."""
    nc = corg.shape[0]
    k2 = k * k
    sse = np.zeros(nc)
    mx = np.zeros(nc)
    ones = np.ones(w.shape[0]) if with_den else np.abs(w)
    for c in prange(nc):
        acc = np.zeros(512)
        one = np.zeros(512)
        q = np.empty((3, 8))
        e = np.empty((3, 8))
        cell_mixture(c, corg, cstart, pg, cent, sig, w, k2, acc, q, e)
        cell_mixture(c, corg, cstart, pg, cent, sig, ones, k2, one, q, e)  # s1, or sum |w g|
        act = np.zeros(512, np.bool_)
        res = cres[c]
        for i in range(512):
            res[i] = 0.0
        sse[c], mx[c], _ = cell_residual(c, cmask, cref, acc, res, act)
        if not with_den:
            for i in range(512):
                if act[i]:
                    one[i] = res[i] * res[i] / one[i] if one[i] > 1e-30 else 0.0
        for p in range(cstart[c], cstart[c + 1]):
            g = pg[p]
            num, den = pair_sums(c, g, corg, cent, sig, k2, 1.0, q, e, act, res, one)
            pnum[p] = num
            pden[p] = den if with_den else den * abs(w[g])
    return sse, mx


def _run(st, w, cref, with_den, pnum, pden, cres):
    return _pass(st["corg"], st["cmask"], cref, st["cstart"], st["pg"], st["cent"], st["sig"], w,
                 st["k"], with_den, pnum, pden, cres)


def fit_weights(st, w, sign, cg_steps, mm_steps, omega=OMEGA):
    """Improve the weights w (float64; a new array is returned): cg_steps of conjugate gradients
    on the normal equations (Jacobi-preconditioned by diag(A^T A 1), unconstrained), the sign clip,
    then mm_steps projected MM steps, each monotone, and a last pass that only measures.
    st: error.pair_lists output; sign: +1 / -1 / 0 per Gaussian (0: the weight stays 0).
    Returns (w, per-cell residuals (C, 512), per-cell SSE, per-cell max |r|, per-Gaussian share of
    the SSE)."""
    w = np.array(w, np.float64)
    m, npair = len(w), len(st["pg"])
    pnum, pden = np.empty(npair), np.empty(npair)
    cres = np.empty((len(st["corg"]), 512))
    pw = np.repeat(st["cw"], np.diff(st["cstart"]))  # big tiles count (edge/8)^3 voxels each

    def at(v):  # per-Gaussian sums of per-pair values, in pair order
        return np.bincount(st["pg"], weights=v * pw, minlength=m)

    free = sign != 0
    _run(st, w, st["cref"], True, pnum, pden, cres)
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
            _run(st, p, zero, False, pnum, pden, cres)
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
        sse, mx = _run(st, w, st["cref"], False, pnum, pden, cres)
        if it == mm_steps:
            break
        w = w + omega * dinv * at(pnum)
    return w, cres, sse, mx, at(pden)
