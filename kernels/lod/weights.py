"""Sigmas and amplitudes of the two weightings.

sigma = sigma_scale * size_code, computed the same way here and in the decoder (bit-exact):
- "paper": sigma_scale = 1/2, size_code = 2 sigma on the half-voxel lattice:
    full blocks (dense-leaf blocks, 2^3 blocks, single voxels): sigma = edge/2 (code = edge);
    active-bbox Gaussians (Low leaves, variance clusters, tiles): the paper's
    sigma = (bboxMax - bboxMin)/2 with bboxMax/Min the extreme voxel *centres* (OpenVDB CoordBBox),
    clamped to >= 1/2 voxel per axis (code = max(edge - 1, 1)), the single-voxel radius the paper
    itself uses; without the clamp a one-voxel-thick leaf gets sigma = 0.
  amplitude = 1: the value is the peak.
- "field": sigma = f * edge per axis (f = 0.6 by default, code = edge); amplitude is the
  normalized kernel times the represented volume, a = V / ((2 pi)^{3/2} sx sy sz), so a lattice of
  blocks sums to the constant it stands for (ripple 0.33 % at f = 0.6; see rendering.md).
"""
from __future__ import annotations

import numpy as np

DEFAULT_SIGMA_FACTOR = 0.6
TWO_PI_32 = (2.0 * np.pi) ** 1.5


def size_codes(ext, kind, weights):
    ext = ext.astype(np.int32)
    if weights == "paper":
        bbox_rule = np.maximum(ext - 1, 1)
        return np.where((kind == 0)[:, None], bbox_rule, ext).astype(np.int32)
    return ext


def sigma_scale(weights, sigma_factor=DEFAULT_SIGMA_FACTOR) -> float:
    return 0.5 if weights == "paper" else float(sigma_factor)


def sigmas_from_codes(codes, scale):
    return (np.float64(scale) * codes.astype(np.float64)).astype(np.float32)


def amplitudes64(sigmas, voxels, weights):
    """The unrefined amplitudes in float64 (`amplitudes` is this cast to float32)."""
    if weights == "paper":
        return np.ones(len(voxels))
    s = sigmas.astype(np.float64)
    return voxels.astype(np.float64) / (TWO_PI_32 * s[:, 0] * s[:, 1] * s[:, 2])


def amplitudes(sigmas, voxels, weights, factors=None):
    """float32 amplitudes; `factors` (float64, from a refinement's quantized codes) multiply the
    float64 values before the cast, the same way in build_lod and in the decoder (bit-exact)."""
    a = amplitudes64(sigmas, voxels, weights)
    if factors is not None:
        a = a * factors
    return a.astype(np.float32)
