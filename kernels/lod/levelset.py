"""Level sets: keep only the voxels whose cell the zero crossing can enter.

For a distance function phi (world units, as OpenVDB stores level sets) the zero set can meet the
cell of voxel i only if |phi_i| <= half the cell diagonal = (sqrt(3)/2) dx. Voxels further out are
the rest of the narrow band, hidden behind (or inside) the surface, and are dropped before the
scheme runs, so every Gaussian covers shell voxels only. `band_width` (in voxels) tunes it.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit, parallel_for

DEFAULT_BAND_WIDTH = 0.5 * np.sqrt(3.0)
# Where the surface passes within 1 - band_width of a layer of voxel centres and its normal is
# near an axis, the band keeps that layer only: the signed distances there are all in
# [0, 1 - band_width) voxel, and their mixture never reaches 0. The field draws the level
# SURFACE_LEVEL voxel instead of 0 (kernels/render/cpu/surface.py).
SURFACE_LEVEL = 1.0 - DEFAULT_BAND_WIDTH


def voxel_size(index_to_world) -> float:
    m = np.asarray(index_to_world, np.float64)[:3, :3]
    return float(abs(np.linalg.det(m)) ** (1.0 / 3.0)) or 1.0


@njit(cache=True, inline="always")
def in_band(v, thr):
    """The band test, on float32 values and a float32 threshold (one definition for every pass)."""
    return abs(v) <= thr


def band_masks(masks, values, thr):
    """uint64 (N, 8): active voxels with |value| <= thr (a float32), leaves on threads."""
    out = np.zeros_like(masks)
    parallel_for(_band_rows, masks.shape[0], masks, values, thr, out)
    return out


@njit(cache=True, nogil=True)
def _band_rows(lo, hi, masks, values, thr, out):
    for i in range(lo, hi):
        for w in range(8):
            m = masks[i, w]
            if m == 0:
                continue
            r = np.uint64(0)
            for b in range(64):
                if (m >> np.uint64(b)) & np.uint64(1):
                    if in_band(values[i, w * 64 + b], thr):
                        r |= np.uint64(1) << np.uint64(b)
            out[i, w] = r


def surface_level(index_to_world) -> float:
    """SURFACE_LEVEL in the grid's units (its values' world units)."""
    return SURFACE_LEVEL * voxel_size(index_to_world)


def band_threshold(grid, band_width=DEFAULT_BAND_WIDTH) -> float:
    return float(band_width) * voxel_size(grid.index_to_world)
