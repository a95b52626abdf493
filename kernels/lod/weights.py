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

from ..jit import njit, parallel_for

DEFAULT_SIGMA_FACTOR = 0.6
TWO_PI_32 = (2.0 * np.pi) ** 1.5


def size_codes(ext, full_block, weights):
    ext = ext.astype(np.int32)
    if weights == "paper":
        bbox_rule = np.maximum(ext - 1, 1)
        return np.where((full_block == 0)[:, None], bbox_rule, ext).astype(np.int32)
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


_BLOCKS = 64  # blocks of rows field_amplitudes_match checks on threads


@njit(cache=True, nogil=True)
def _match_rows(lo, hi, sigmas, voxels, amps, first, tvox, bad):
    """bad[b] for the blocks b in lo..hi-1: a row of block b whose amplitude differs."""
    n = amps.shape[0]
    for b in range(lo, hi):
        for j in range(b * n // _BLOCKS, (b + 1) * n // _BLOCKS):
            v = np.float64(voxels[j]) if j < first else tvox[j - first]
            s = TWO_PI_32 * np.float64(sigmas[j, 0]) * np.float64(sigmas[j, 1]) * np.float64(sigmas[j, 2])
            if np.float32(v / s) != amps[j]:
                bad[b] = True
                break


def field_amplitudes_match(sigmas, voxels, amps, first, tvox):
    """Whether amps are exactly the unrefined field amplitudes (amplitudes64 cast to float32,
    the same operations) of sigmas and the voxel counts: voxels below row ``first``, the true
    counts tvox (float64, GaussianSet.true_voxels) from there on."""
    bad = np.zeros(_BLOCKS, np.bool_)
    parallel_for(_match_rows, _BLOCKS, sigmas, voxels, amps, np.int64(first), tvox, bad)
    return not bad.any()


# ---- compiled writer: what build_lod uses. Same float64 operations in the same order as the numpy
# functions above (which the decoder uses), so both give the same bits.
def new_gaussians(m):
    """Empty output arrays for m Gaussians: (offsets, codes, sigmas, amplitudes, voxels, values)."""
    return (np.empty((m, 3), np.float32), np.empty((m, 3), np.int32), np.empty((m, 3), np.float32),
            np.empty(m, np.float32), np.empty(m, np.int32), np.empty(m, np.float32))


@njit(cache=True, inline="always")
def gaussian_shape(ex, ey, ez, full_block, vox, paper, scale):
    """Size codes, sigmas and amplitude of a box: edge e per axis, full_block (see schemes.py), vox =
    the voxels it stands for (float64: a 4096^3 tile does not fit int32)."""
    bbox_rule = paper and full_block == 0
    cx = max(ex - 1, 1) if bbox_rule else ex
    cy = max(ey - 1, 1) if bbox_rule else ey
    cz = max(ez - 1, 1) if bbox_rule else ez
    sx = np.float32(scale * np.float64(cx))
    sy = np.float32(scale * np.float64(cy))
    sz = np.float32(scale * np.float64(cz))
    if paper:
        amp = np.float32(1.0)
    else:
        amp = np.float32(vox / (TWO_PI_32 * np.float64(sx) * np.float64(sy) * np.float64(sz)))
    return cx, cy, cz, sx, sy, sz, amp


@njit(cache=True, inline="always")
def put_centre(out, j, c2x, c2y, c2z, value):
    """Offset and value of row j of out = (offsets, codes, sigmas, amplitudes, voxels, values);
    c2 = twice the centre offset (the half-voxel lattice)."""
    offsets, values = out[0], out[5]
    offsets[j, 0] = np.float32(c2x) * np.float32(0.5)
    offsets[j, 1] = np.float32(c2y) * np.float32(0.5)
    offsets[j, 2] = np.float32(c2z) * np.float32(0.5)
    values[j] = value


@njit(cache=True, inline="always")
def put_shape(out, j0, j1, shape, nvox):
    """Rows j0..j1-1 of the same shape (from gaussian_shape) and voxel count: one tight loop."""
    codes, sigmas, amps, voxels = out[1], out[2], out[3], out[4]
    cx, cy, cz, sx, sy, sz, amp = shape
    for j in range(j0, j1):
        codes[j, 0], codes[j, 1], codes[j, 2] = cx, cy, cz
        sigmas[j, 0], sigmas[j, 1], sigmas[j, 2] = sx, sy, sz
        amps[j] = amp
        voxels[j] = nvox


@njit(cache=True)
def boxes_to_gaussians(c2, ext, nvox, val, full_block, first_tile, paper, scale, out, at):
    """Boxes -> Gaussians at out rows at, at + 1, ... (values: the boxes' means; a level set's:
    level_set_distances); boxes from first_tile on are tiles, whose
    true volume (up to 4096^3) does not fit nvox. Serial: tiles are few, and the merge pass that
    precedes it for merged boxes costs ~30x more."""
    for k in range(c2.shape[0]):
        if k >= first_tile:
            vox = np.float64(ext[k, 0]) * np.float64(ext[k, 1]) * np.float64(ext[k, 2])
        else:
            vox = np.float64(nvox[k])
        shape = gaussian_shape(ext[k, 0], ext[k, 1], ext[k, 2], full_block[k], vox, paper, scale)
        put_centre(out, at + k, c2[k, 0], c2[k, 1], c2[k, 2], val[k])
        put_shape(out, at + k, at + k + 1, shape, nvox[k])


def level_set_distances(out):
    """A level set's Gaussians (out as new_gaussians gives it, filled): the means written as their
    values are the mean signed distances of the voxels each stands for, returned; the values
    become 1, the occupancy of the shell (what the field and the shells draw)."""
    dist = out[5].copy()
    out[5][:] = 1.0
    return dist


# -- amplitude factors (refinement, adaptive fit) as the compact encoding stores them ------------
QSTEPS = 256  # factor quantization: 2^(c / QSTEPS), relative step 0.27 %
CMIN = -16 * QSTEPS  # smallest non-zero factor 2^-16; below it the factor is 0


def quantize_factors(f):
    """Amplitude factors -> integer codes c (f = 2^(c / QSTEPS)); codes below CMIN mean f = 0."""
    f = np.asarray(f, np.float64)
    c = np.full(f.shape, CMIN - 1, np.int64)
    pos = f >= 2.0 ** (CMIN / QSTEPS)
    c[pos] = np.rint(np.log2(f[pos]) * QSTEPS).astype(np.int64)
    return c


def factors_from_codes(c):
    c = np.asarray(c, np.int64)
    return np.where(c < CMIN, 0.0, np.exp2(c.astype(np.float64) / QSTEPS))
