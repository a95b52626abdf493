"""The inputs of the GPU's own screen-tile lists (glsl/tiles.glsl, the float32 twin of
cpu.tiles.gauss_footprints + tile_counts + tile_fill), plain numpy:

- tl_g (gpu_layout.fold_rows, layout.TLG): centre (3), 1/sigma (3), this frame's weight, object.
- tl_par (flat): layout.TLP (W, H, ex, ey, offx, offy, ortho, k), then per object layout.TLO (its
  camera matrix (3 x 4, cpu.tiles.tile_camera) and spectral norm).

The lists the shaders build have the uploaded lists' layout (gpu.tables_gauss.tile_tables:
t_start, t_ent) plus t_lb, each Gaussian's float32 entry bound in texel g (x)."""
from __future__ import annotations

import numpy as np

from ..inputs.layout import (
    CAM_EX,
    CAM_EY,
    CAM_H,
    CAM_KIND,
    CAM_OX,
    CAM_OY,
    CAM_W,
    SET_K,
    TILE,
    TLG_INV,
    TLG_MU,
    TLG_OBJ,
    TLG_SIZE,
    TLG_W,
    TLO_CMAT,
    TLO_NORM,
    TLO_SIZE,
    TLP_EX,
    TLP_EY,
    TLP_H,
    TLP_K,
    TLP_ORTHO,
    TLP_OX,
    TLP_OY,
    TLP_SIZE,
    TLP_W,
)
from . import tables as gpu_layout


def tile_grid(frame):
    """(ntx, nty): the frame's screen tiles across and down."""
    return -(-int(frame.cam[CAM_W]) // TILE), -(-int(frame.cam[CAM_H]) // TILE)


def tile_inputs(frame) -> dict:
    """tl_g and tl_par for a frame's Gaussians (its weights) and camera."""
    from ..cpu.tiles import tile_camera

    g = frame.gauss
    cam = np.asarray(frame.cam, np.float64)
    i2w = [np.linalg.inv(m) for m in frame.objects.w2i]
    cmat, onorm = tile_camera(cam, i2w)
    rec = np.zeros((g.mu.shape[0], TLG_SIZE))
    rec[:, TLG_MU:TLG_MU + 3], rec[:, TLG_INV:TLG_INV + 3] = g.mu, g.inv
    rec[:, TLG_W], rec[:, TLG_OBJ] = g.w, g.obj
    par = np.zeros(TLP_SIZE + TLO_SIZE * len(i2w))
    par[TLP_W], par[TLP_H] = cam[CAM_W], cam[CAM_H]
    par[TLP_EX], par[TLP_EY], par[TLP_OX], par[TLP_OY] = cam[CAM_EX], cam[CAM_EY], cam[CAM_OX], cam[CAM_OY]
    par[TLP_ORTHO] = cam[CAM_KIND] > 0.5
    par[TLP_K] = frame.transfer.settings[SET_K]
    for j in range(len(i2w)):
        o = TLP_SIZE + TLO_SIZE * j
        par[o + TLO_CMAT:o + TLO_CMAT + 12] = cmat[j].ravel()
        par[o + TLO_NORM] = onorm[j]
    return {"tl_g": gpu_layout.fold_rows(rec), "tl_par": gpu_layout.fold_scalars(par)}


def starts(counts) -> np.ndarray:
    """Per-tile entry counts (the GPU's, read back) -> the exclusive prefix sum (tiles + 1)."""
    out = np.zeros(np.size(counts) + 1, np.int64)
    np.cumsum(np.asarray(counts, np.int64).ravel(), out=out[1:])
    return out


def cpu_lists(frame):
    """The fallback when the GPU's lists do not fit its textures: the CPU's lists (cpu.tiles.
    screen_tiles) as the same three tables; None when those pass MAX_TILE_ENTRIES too."""
    from ..cpu.tiles import screen_tiles
    from ..devices.frame_setup import MAX_TILE_ENTRIES
    from .tables_gauss import tile_tables

    g = frame.gauss
    i2w = [np.linalg.inv(m) for m in frame.objects.w2i]
    t = screen_tiles(frame.cam, i2w, g.mu, g.inv, g.obj, g.w, frame.transfer.settings[SET_K],
                     MAX_TILE_ENTRIES)
    if t is None:
        return None
    out = tile_tables(*t[:3])
    out["t_lb"] = gpu_layout.fold_rows(np.asarray(t[3], np.float64))
    return out
