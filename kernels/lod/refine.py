"""Amplitude refinement for "field" weights: a few preconditioned Richardson iterations on the
collocation system s(x_j) = v_j at the active voxel centres.

With field weights the mixture is a partition of unity in the interior of the active region, but a
boundary voxel has no neighbours outside (partial mass: s ~ v/2 on a face) and sharp gradients are
smoothed. Each iteration evaluates the mixture exactly at every active voxel centre (same k-sigma
truncation and leaf-structured evaluation as `field_error`), forms the residual r_j = v_j - s(x_j),
and moves every Gaussian's weight w_i = value_i x amplitude_i by

    dw_i = a0_i * rbar_i,   rbar_i = sum_j psi_ij r_j / sum_j psi_ij,   psi_ij = g_i(x_j)^p

a0_i the unrefined amplitude (so a uniform residual is corrected in one step, by partition of unity)
and psi a narrowed copy of the Gaussian (sigma / sqrt(p), p = 4): for a single voxel it is ~ the value
at its own centre, for a block ~ the mean over its voxels. Only amplitudes change (values stay the
means the transfer function classifies), as a factor f_i = a_i / a0_i clamped to [0, FMAX], so
opacity stays non-negative; the factor is quantized to 2^(c / 256) (c integer; 0 stays 0) so the compact
encoding stores it exactly. Per-pair partial sums are computed per cell and reduced in pair order:
the result does not depend on the thread count.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit, parallel_for
from .mixture import DEFAULT_K, axis_terms, cell_mixture, cell_residual, pair_voxels, setup
from .weights import amplitudes64, factors_from_codes, quantize_factors

FMAX = 8.0  # largest amplitude factor (an isolated voxel needs ~3.4 at sigma = 0.6 voxel)
POWER = 4.0  # psi = g^POWER


@njit(cache=True, nogil=True)
def _residual_rows(lo, hi, corg, cmask, cref, cstart, pg, cent, sig, w, k, power, pnum, pden, sse):
    k2 = k * k
    for c in range(lo, hi):
        acc = np.zeros(512)
        q = np.empty((3, 8))
        e = np.empty((3, 8))
        cell_mixture(c, corg, cstart, pg, cent, sig, w, k2, acc, q, e)
        res = np.zeros(512)
        act = np.zeros(512, np.bool_)
        sse[c] = cell_residual(c, cmask, cref, acc, res, act)[0]
        on = act.astype(np.float64)  # the active voxels' weight 1 (res is 0 elsewhere)
        vn = np.empty(8)
        vd = np.empty(8)
        for p in range(cstart[c], cstart[c + 1]):
            # psi = g^power: the Gaussian narrowed to sigma / sqrt(power), cut at k2 / power
            axis_terms(c, pg[p], corg, cent, sig, power, k2 / power, q, e)
            pnum[p], pden[p] = pair_voxels(q, e, k2 / power, True, True, vn, res, vd, on)


def _residual_pairs(corg, cmask, cref, cstart, pg, cent, sig, w, k, power, pnum, pden):
    """Per cell the summed squared residual at its active voxels; per pair pnum = sum psi r and
    pden = sum psi over its cell's active voxels (psi = g^power)."""
    sse = np.zeros(corg.shape[0])
    parallel_for(_residual_rows, corg.shape[0], corg, cmask, cref, cstart, pg, cent, sig, w,
                 np.float64(k), np.float64(power), pnum, pden, sse)
    return sse


def refine_amplitudes(grid, gset, iterations=2, omega=1.0, k=DEFAULT_K, fmax=FMAX, st=None):
    """Refine gset.amplitudes in place (field weights, non-level-set grids). Returns a dict with the
    RMSE at the active voxel centres before each iteration and after the last one."""
    if gset.weights != "field":
        raise ValueError("amplitude refinement is for field weights only")
    m = gset.count
    if iterations <= 0 or m == 0:
        return dict(iterations=0, rmse=[])
    if st is None:
        st = setup(grid, gset, k)
    a0 = amplitudes64(gset.sigmas, gset.true_voxels(), "field")
    v = gset.values.astype(np.float64)
    f = np.ones(m)
    ok = v != 0
    npair = len(st["pg"])
    pnum = np.empty(npair)
    pden = np.empty(npair)
    hist = []
    for it in range(iterations + 1):
        w = v * a0 * f
        sse = _residual_pairs(st["corg"], st["cmask"], st["cref"], st["cstart"], st["pg"],
                              st["cent"], st["sig"], w, st["k"], POWER, pnum, pden)
        hist.append(float(np.sum(sse * st["cw"])))
        if it == iterations:
            break
        num = np.bincount(st["pg"], weights=pnum, minlength=m)
        den = np.bincount(st["pg"], weights=pden, minlength=m)
        upd = ok & (den > 0)
        rbar = np.zeros(m)
        rbar[upd] = num[upd] / den[upd]
        f[upd] = np.clip(f[upd] + omega * rbar[upd] / v[upd], 0.0, fmax)
    codes = quantize_factors(f)
    gset.amplitudes = (a0 * factors_from_codes(codes)).astype(np.float32)
    return dict(iterations=iterations, sse=hist)
