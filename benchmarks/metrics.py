"""Image error metrics and display helpers for the benchmark report (numpy + scikit-image).

Images are GAUSSVDB 'Combined' passes: float (H, W, 4), scene-linear, premultiplied alpha, row 0 =
bottom. Errors are computed in LINEAR space on the premultiplied RGB (the image composited over
black), with data range 1 (emission-absorption radiance never exceeds the brightest colormap entry).
"""
from __future__ import annotations

import itertools
import math

import numpy as np


def _rgb(img):
    return np.clip(np.asarray(img, np.float64)[..., :3], 0.0, None)


def image_errors(ref, img) -> dict:
    """psnr (dB, data range 1; None when the images are identical), ssim (scikit-image, per channel
    mean, data range 1), max_abs_error, rmse, brightness (img's summed RGB over ref's); all on linear
    premultiplied RGB."""
    from skimage.metrics import structural_similarity

    a, b = _rgb(ref), _rgb(img)
    mse = float(np.mean((a - b) ** 2))
    psnr = None if mse == 0 else 10.0 * math.log10(1.0 / mse)
    win = min(7, min(a.shape[:2]) // 2 * 2 - 1)
    ssim = float(structural_similarity(a, b, channel_axis=2, data_range=1.0, win_size=max(win, 3)))
    sa = float(a.sum())
    return {"psnr": psnr, "ssim": ssim, "max_abs_error": float(np.max(np.abs(a - b))), "rmse": math.sqrt(mse),
            "brightness": float(b.sum()) / sa if sa > 0 else None}


def covered_pixels(img) -> int:
    """Pixels a render drew something on (alpha > 0): what its work is counted against."""
    return int(np.count_nonzero(img[..., 3] > 0))


def to_display(img, max_side=256) -> np.ndarray:
    """uint8 sRGB (H, W, 3), top row first, composited over black, downsampled to <= max_side."""
    from kernels.render.scene.colormaps import linear_to_srgb

    a = _rgb(img)[::-1]
    step = max(1, math.ceil(max(a.shape[:2]) / max_side))
    if step > 1:
        h, w = (a.shape[0] // step) * step, (a.shape[1] // step) * step
        a = a[:h, :w].reshape(h // step, step, w // step, step, 3).mean((1, 3))
    return (np.clip(linear_to_srgb(np.clip(a, 0, 1)), 0, 1) * 255 + 0.5).astype(np.uint8)


def time_to_reach(curve, psnr):
    """Cycles time to reach ``psnr`` from [(seconds, psnr), ...] sorted by samples: log-linear
    interpolation between the bracketing points. Returns (seconds, how) with how 'interpolated',
    'below_first' (the first sample count already beats it: the first time is an upper bound) or
    'not_reached' (None)."""
    pts = [(t, p) for t, p in curve if p is not None and t > 0]
    if not pts or psnr is None:
        return None, "not_reached"
    if pts[0][1] >= psnr:
        return pts[0][0], "below_first"
    for (t0, p0), (t1, p1) in itertools.pairwise(pts):
        if p0 < psnr <= p1:
            f = (psnr - p0) / (p1 - p0) if p1 > p0 else 1.0
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0))), "interpolated"
    return None, "not_reached"
