"""The Gaussian modes' GPU tables (particles, field, paper): the CPU frame's numpy groups turned
into float32 arrays ready for RGBA32F textures (plain numpy, no bpy/gpu).

Every table is folded into a 2-D RGBA texture gpu_layout.ROW_TEXELS texels wide (``fold``): a table of rows
of c columns puts row i in texels i * ceil(c / 4) ...; a 1-D table puts element k in texel k // 4,
channel k % 4 (``flat``). Integers travel as exact floats, so each must stay below 2^24
(``check_exact`` says where one does not; the device then draws that frame on the CPU).

Tables (name: rows x columns, what):
- g_rec (m x 8): centre (3), 1/sigma (3), this frame's weight w, and column 7: the tile lists'
  entry bound (particles, field) or w x volfac (paper's per-step extinction factor).
- g_aux (m x 8): colour (3), value (0 when NaN), value weight (1, or 0 when NaN), object.
- t_start (flat, tiles + 1): each screen tile's first entry.
- t_ent (entries x 4): Gaussian id and the 64-bit pixel mask in three exact pieces of 22, 22 and
  20 bits (bit b of the mask: piece b // 22, bit b % 22).
- Field mode also gets the leaf lookup its surfaces' normals need (mixture_normal): the core's
  walk tables (node_table, node_cells, cell_skip) and the cells' Gaussian lists c_start, c_items
  (flat).
"""
from __future__ import annotations

import numpy as np

from . import gpu_layout

MASK_BITS = 22
OVERFLOW_DEPTH = -2e10  # a pixel's Depth when its ray needed more hit slots than the shader has
fold, flat = gpu_layout.fold_rows, gpu_layout.fold_scalars  # importing this module registers its modes (end)


def mask_pieces(masks) -> np.ndarray:
    """(n,) int64 pixel masks -> (n, 3) exact floats of 22, 22 and 20 bits."""
    u = np.asarray(masks).astype(np.int64).view(np.uint64)
    lo = np.uint64((1 << MASK_BITS) - 1)
    return np.stack([u & lo, (u >> np.uint64(MASK_BITS)) & lo, u >> np.uint64(2 * MASK_BITS)],
                    -1).astype(np.float64)


def check_exact(**arrays):
    """None, or the name of the first integer array (or count) that floats cannot hold exactly."""
    for name, a in arrays.items():
        a = np.asarray(a)
        if a.size and (int(a.max()) >= gpu_layout.EXACT or int(a.min()) <= -gpu_layout.EXACT):
            return name
    return None


def gauss_tables(mode, gauss) -> dict:
    """g_rec and g_aux for a frame's Gaussians (packing.Gaussians); paper: column 7 = w x volfac."""
    from .scene import Mode

    rec = np.array(gauss.rec, np.float64)
    if mode == Mode.PAPER:
        rec[:, 7] = gauss.w * gauss.volfac
    val = np.asarray(gauss.val, np.float64)
    ok = ~np.isnan(val)
    aux = np.zeros((rec.shape[0], 8))
    aux[:, 0:3] = gauss.col
    aux[:, 3] = np.where(ok, val, 0.0)
    aux[:, 4] = ok
    aux[:, 5] = gauss.obj
    return {"g_rec": fold(rec), "g_aux": fold(aux)}


def tile_tables(start, items, masks) -> dict:
    """t_start and t_ent from the frame's screen-tile lists (_cpu_tiles)."""
    ent = np.zeros((max(1, len(items)), 4))
    ent[:len(items), 0] = items
    ent[:len(items), 1:] = mask_pieces(masks)
    return {"t_start": flat(start), "t_ent": fold(ent)}


def frame_tiles(frame):
    """(starts, ids, masks) the shader scans: the frame's own screen-tile lists (particles, field)
    or, for paper mode (whose CPU kernels walk the leaves), lists of the Gaussians with its
    weights built here once per frame; None when there are none (switched off, too many)."""
    from .device import screen_tiles
    from .packing import SET_K
    from .scene import Mode

    if int(frame.mode) != Mode.PAPER:
        a = frame.accel
        return None if a.t_start.shape[0] <= 1 else (a.t_start, a.t_items, a.t_mask)
    if not hasattr(frame, "gpu_tiles"):
        g = frame.gauss
        i2w = [np.linalg.inv(m) for m in frame.objects.w2i]
        t = screen_tiles(frame.cam, i2w, g.mu, g.inv, g.obj, g.w, frame.transfer.settings[SET_K])
        frame.gpu_tiles = None if t is None else t[:3]
    return frame.gpu_tiles


def unsupported(frame) -> str | None:
    """Why the GPU's Gaussian modes cannot draw this frame exactly (the device then draws it on
    the CPU), or None: lit volumes, no screen-tile lists (switched off or too many entries), or
    an index past the floats' exact range."""
    if (np.asarray(frame.objects.lit) != 0).any():
        return "lit volumes"
    if on_gpu(frame):  # the device checks the entries' count when it builds them
        return check_exact(gaussians=[frame.gauss.rec.shape[0]])
    tiles = frame_tiles(frame)
    if tiles is None:
        return "no screen-tile lists"
    return check_exact(tile_entries=tiles[0][-1:], gaussians=[frame.gauss.rec.shape[0]])


def on_gpu(frame):
    """Whether the device builds this frame's screen-tile lists itself (gpu/tiles.py): then
    they are not uploaded, and the entry bounds come in t_lb."""
    return getattr(frame, "tiles_on_gpu", False)


def overflow_tiles(depth, row0=0, col0=0):
    """The screen tiles (image rows (a, b), columns (c, d), clipped to the region drawn from row0,
    col0) holding a pixel whose Depth is OVERFLOW_DEPTH: the device draws those on the CPU."""
    from ._cpu_tiles import TILE

    rows, cols = np.nonzero(np.asarray(depth) == np.float32(OVERFLOW_DEPTH))
    nr, nc = np.shape(depth)
    out = []
    for ty, tx in sorted(set(zip(((rows + row0) // TILE).tolist(), ((cols + col0) // TILE).tolist()))):
        a, c = max(ty * TILE, row0), max(tx * TILE, col0)
        out.append(((a, min((ty + 1) * TILE, row0 + nr)), (c, min((tx + 1) * TILE, col0 + nc))))
    return out


def no_geometry(frame):
    """The Gaussian modes upload everything per frame (weights and entry bounds change with it)."""
    return gpu_layout.Tables({}, {})


def particles_frame(frame):
    """Common tables, the Gaussians and the screen-tile lists (particles, paper)."""
    t = gpu_layout.common_tables(frame)
    t.textures.update(gauss_tables(frame.mode, frame.gauss))
    if not on_gpu(frame):
        t.textures.update(tile_tables(*frame_tiles(frame)))
    return t


def field_frame(frame):
    """The particles' tables, the leaf lookup and the cells' Gaussian lists (surface normals)."""
    t = particles_frame(frame)
    a = frame.accel
    t.textures.update(gpu_layout.walk_tables(a))
    t.textures.update(gpu_layout.walk_frame(a))
    t.textures.update(c_start=flat(a.cell_start), c_items=flat(a.cell_items))
    return t


gpu_layout.MODE_TABLES["particles"] = (no_geometry, particles_frame)
gpu_layout.MODE_TABLES["field"] = (no_geometry, field_frame)
gpu_layout.MODE_TABLES["paper"] = (no_geometry, particles_frame)
