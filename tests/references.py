"""Independent float64 references for the render tests: plain numpy, no numba, no traversal."""

import math

import numpy as np
from scipy.special import erf

from kernels.render import generate_rays


def closed_form_alpha(cam, gset, matrix_world, density, k=3.0):
    """Alpha per pixel of particles mode under a constant-alpha transfer function: Gaussians
    truncated at k sigma, rays from t = 0, each optical depth in closed form (erf)."""
    o, d = generate_rays(cam)
    w2i = np.linalg.inv(matrix_world)
    oi = o @ w2i[:3, :3].T + w2i[:3, 3]
    di = d @ w2i[:3, :3].T
    start = np.asarray(gset.group_start)
    mu = np.repeat(np.asarray(gset.group_origins, np.float64), np.diff(start), 0) + \
        np.asarray(gset.offsets, np.float64)
    sig = np.asarray(gset.sigmas, np.float64)
    amp = np.asarray(gset.amplitudes, np.float64)
    tau = np.zeros(len(o))
    for c0 in range(0, len(mu), 256):
        sl = slice(c0, c0 + 256)
        wo = (oi[:, None, :] - mu[None, sl]) / sig[None, sl]
        wd = di[:, None, :] / sig[None, sl]
        a = np.sum(wd * wd, -1)
        ts = -np.sum(wo * wd, -1) / a
        p = wo + ts[..., None] * wd
        q = np.sum(p * p, -1)
        hw = np.sqrt(np.maximum(k * k - q, 0.0) / a)
        t0 = np.maximum(ts - hw, 0.0)
        t1 = ts + hw
        sa = np.sqrt(0.5 * a)
        seg = np.where((q < k * k) & (t1 > t0),
                       np.exp(-0.5 * q) * np.sqrt(np.pi / (2 * a)) * (erf(sa * (t1 - ts)) - erf(sa * (t0 - ts))),
                       0.0)
        tau += (seg * amp[None, sl]).sum(1)
    return (-np.expm1(-density * tau)).reshape(cam.height, cam.width)


def quadrature_pixel(o, d, cs, sig, kap, col, t0, t1, k=3.0, n=40001):
    """One pixel (RGB, alpha) of the truncated mixture by fine quadrature over [t0, t1]: midpoint
    samples, exact exponential per step, colour = extinction-weighted mean of the Gaussians'."""
    sig = np.broadcast_to(sig, cs.shape)
    t = np.linspace(t0, t1, n)
    dt = t[1] - t[0]
    tm = t[:-1] + dt / 2
    x = o[None] + tm[:, None] * d[None]
    s_t = np.zeros(tm.size)
    c_t = np.zeros((tm.size, 3))
    for i in range(len(cs)):
        q = np.sum(((x - cs[i]) / sig[i]) ** 2, 1)
        g = np.where(q < k * k, np.exp(-q / 2), 0.0) * kap[i]
        s_t += g
        c_t += g[:, None] * col[i]
    tau = s_t * dt
    T = np.exp(-np.concatenate([[0], np.cumsum(tau)[:-1]]))
    w = T * -np.expm1(-tau)
    cc = np.where(s_t[:, None] > 0, c_t / np.maximum(s_t, 1e-300)[:, None], 0)
    return np.concatenate([(w[:, None] * cc).sum(0), [1 - np.exp(-tau.sum())]])


GPU_MIN_DB = 50.0  # the GPU device's images against the CPU device's (issue: PSNR >= 50 dB)


def psnr(a, b):
    """PSNR in dB of image a against b, peak 1 (inf when equal)."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)
