"""The inputs of the GPU's own screen-tile lists (glsl/tiles.glsl, the float32 twin of
_cpu_tiles.gauss_footprints + tile_counts + tile_fill), plain numpy:

- tl_g (m x 8, gpu_layout.fold_rows): centre (3), 1/sigma (3), this frame's weight, object.
- tl_par (flat): W, H, ex, ey, offx, offy, ortho, k, then per object its camera matrix (3 x 4,
  _cpu_tiles.tile_camera) and spectral norm, 16 values each.

The lists the shaders build have the uploaded lists' layout (gpu_layout_gauss.tile_tables:
t_start, t_ent) plus t_lb, each Gaussian's float32 entry bound in texel g (x)."""
from __future__ import annotations

import numpy as np

from . import gpu_layout

PAR_OBJ = 2  # texels of tl_par before the first object's
OBJ_TEXELS = 4


def tile_grid(frame):
    """(ntx, nty): the frame's screen tiles across and down."""
    from ._cpu_tiles import TILE

    return -(-int(frame.cam[1]) // TILE), -(-int(frame.cam[2]) // TILE)


def tile_inputs(frame) -> dict:
    """tl_g and tl_par for a frame's Gaussians (its weights) and camera."""
    from ._cpu_tiles import tile_camera
    from .packing import SET_K

    g = frame.gauss
    cam = np.asarray(frame.cam, np.float64)
    i2w = [np.linalg.inv(m) for m in frame.objects.w2i]
    cmat, onorm = tile_camera(cam, i2w)
    rec = np.zeros((g.mu.shape[0], 8))
    rec[:, 0:3], rec[:, 3:6], rec[:, 6], rec[:, 7] = g.mu, g.inv, g.w, g.obj
    par = np.zeros((PAR_OBJ + OBJ_TEXELS * len(i2w)) * 4)
    par[:8] = (cam[1], cam[2], cam[3], cam[4], cam[5], cam[6], cam[0] > 0.5,
               frame.transfer.settings[SET_K])
    for j in range(len(i2w)):
        o = (PAR_OBJ + OBJ_TEXELS * j) * 4
        par[o:o + 12] = cmat[j].ravel()
        par[o + 12] = onorm[j]
    return {"tl_g": gpu_layout.fold_rows(rec), "tl_par": gpu_layout.fold_scalars(par)}


def starts(counts) -> np.ndarray:
    """Per-tile entry counts (the GPU's, read back) -> the exclusive prefix sum (tiles + 1)."""
    out = np.zeros(np.size(counts) + 1, np.int64)
    np.cumsum(np.asarray(counts, np.int64).ravel(), out=out[1:])
    return out


def cpu_lists(frame):
    """The fallback when the GPU's lists do not fit its textures: the CPU's lists (_cpu_tiles.
    screen_tiles) as the same three tables; None when those pass MAX_TILE_ENTRIES too."""
    from ._cpu_tiles import screen_tiles
    from .frame_setup import MAX_TILE_ENTRIES
    from .gpu_layout_gauss import tile_tables
    from .packing import SET_K

    g = frame.gauss
    i2w = [np.linalg.inv(m) for m in frame.objects.w2i]
    t = screen_tiles(frame.cam, i2w, g.mu, g.inv, g.obj, g.w, frame.transfer.settings[SET_K],
                     MAX_TILE_ENTRIES)
    if t is None:
        return None
    out = tile_tables(*t[:3])
    out["t_lb"] = gpu_layout.fold_rows(np.asarray(t[3], np.float64))
    return out
