"""The Gaussian modes' GPU tables (particles, field, paper): the CPU frame's numpy groups turned
into float32 arrays ready for RGBA32F textures (plain numpy, no bpy/gpu).

Every table is folded into a 2-D RGBA texture gpu_layout.ROW_TEXELS texels wide (``fold``): a table of rows
of c columns puts row i in texels i * ceil(c / 4) ...; a 1-D table puts element k in texel k // 4,
channel k % 4 (``flat``). Integers travel as exact floats, so each must stay below 2^24
(``check_exact`` says where one does not; the device then draws that frame on the CPU).

Tables (name: rows x columns, what):
- g_rec (layout.GREC, 32 bytes per Gaussian, the only per-Gaussian table of unlit frames): centre
  (3) and the tile lists' entry bound (particles, field) or w x volfac (paper's per-step extinction
  factor); [1/sigma x, y, z as 18-bit floats with the object (4 bits) and "has a
  value" (1 bit) in two words (size_words), w, value (0 when NaN; field mode: the weight of the
  second mixture, packing.Gaussians.cw: surfaces' signed distance x w)]. A packed word's high half
  is a normal half float's bits (range checked), so the word is a normal float32 (never NaN,
  Inf or denormal) and survives upload and texelFetch bit for bit. Colours are not uploaded:
  the shader takes them from the transfer function's LUT at the value (level sets: ls_color;
  volumes coloured by a second grid: their colour map at gpu.tables_color's g_cval).
- t_start (flat, tiles + 1): each screen tile's first entry.
- t_ent (layout.TENT): Gaussian id and the 64-bit pixel mask in three exact pieces of 22, 22 and
  20 bits (MASK_BITS; bit b of the mask: piece b // 22, bit b % 22).
- g_grad (m x 4, particles mode with lit volumes, geometry: once per sync): the gradient at each
  Gaussian's centre of its object's other Gaussians' field and its own field weight
  (packing.Gaussians.grad, cpu.lit.lit_gradients); the shader adds its own part at the chord.
- Field mode also gets the leaf lookup its surfaces' normals need (mixture_normal): the core's
  walk tables (node_table, node_cells, cell_skip) and the cells' Gaussian lists c_start, c_items
  (flat).
"""
from __future__ import annotations

import numpy as np

from ..inputs.layout import (
    EXP_REBIAS,
    GREC_BOUND,
    GREC_MU,
    GREC_SIZE,
    GREC_VAL,
    GREC_W,
    GREC_WORDS,
    MANT_DROP,
    MASK_BITS,
    OVERFLOW_DEPTH,
    REC_INV,
    REC_LB,
    REC_MU,
    REC_W,
    SET_K,
    TENT_ID,
    TENT_MASK,
    TENT_SIZE,
    TILE,
)
from . import tables as gpu_layout

GAUSS_COLUMNS = {"g_rec": GREC_SIZE}  # the per-Gaussian tables and their float32 columns
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


def size_codes(inv) -> np.ndarray:
    """1/sigma (> 0) as 18-bit floats: a half float's 5-bit exponent and 13 mantissa bits
    (relative error <= 2^-14), rounded; as int64, the exponent valid where 1..30 (size_ok)."""
    f = np.asarray(inv, np.float32).view(np.uint32).astype(np.int64)
    return ((f + (1 << (MANT_DROP - 1))) >> MANT_DROP) - (EXP_REBIAS << 13)


def size_ok(codes) -> np.ndarray:
    e = np.asarray(codes) >> 13
    return (e >= 1) & (e <= 30)


def size_words(inv, flags) -> np.ndarray:
    """(m, 2) float32 words [x code >> 3 | y code >> 3, z code >> 3 | low bits]: the high half of
    each is a normal half float's bits, so the word is a normal float32; low bits: the codes'
    3 low bits each (x: 0-2, y: 3-5, z: 6-8), then flags (16-bit integers) << 9."""
    c = size_codes(inv)
    c = np.where(size_ok(c), c, 15 << 13).astype(np.uint32)  # out of range: 1.0
    hi = c >> np.uint32(3)
    low = (c[:, 0] & 7) | ((c[:, 1] & 7) << 3) | ((c[:, 2] & 7) << 6) | (np.asarray(flags, np.uint32) << 9)
    x = (hi[:, 0] << np.uint32(16)) | hi[:, 1]
    y = (hi[:, 2] << np.uint32(16)) | (low & np.uint32(0xFFFF))
    return np.stack([x, y], -1).astype(np.uint32).view(np.float32)


def bad_sizes(inv) -> np.ndarray:
    """(m,) whether a Gaussian's 1/sigma has a component the 18-bit floats do not hold."""
    return ~size_ok(size_codes(inv)).all(axis=-1)


def gauss_tables(mode, gauss) -> dict:
    """g_rec for a frame's Gaussians (packing.Gaussians); paper: GREC_BOUND = w x volfac."""
    from ..scene.objects import Mode

    rec = np.asarray(gauss.rec, np.float64)
    m = rec.shape[0]
    val = np.asarray(gauss.val, np.float64)
    ok = ~np.isnan(val)
    out = np.zeros((m, GREC_SIZE), np.float32)
    out[:, GREC_MU:GREC_MU + 3] = rec[:, REC_MU:REC_MU + 3]
    out[:, GREC_BOUND] = gauss.w * gauss.volfac if mode == Mode.PAPER else rec[:, REC_LB]
    # (a size beyond the codes' range reads as 1: only weight-0 Gaussians, see unsupported)
    out[:, GREC_WORDS:GREC_WORDS + 2] = size_words(rec[:, REC_INV:REC_INV + 3],
                                                   np.asarray(gauss.obj, np.int64) | (ok.astype(np.int64) << 4))
    out[:, GREC_W] = rec[:, REC_W]
    out[:, GREC_VAL] = np.where(ok, val, 0.0)
    if mode == Mode.FIELD and np.shape(gauss.cw) == (m,):  # the field reads no values
        out[:, GREC_VAL] = gauss.cw
    return {"g_rec": fold(out)}


def bytes_per_gaussian() -> int:
    """The GPU scene's bytes per Gaussian: every per-Gaussian table's texels x 16 (RGBA32F)."""
    return sum(16 * gpu_layout.texels_per_row(c) for c in GAUSS_COLUMNS.values())


def tile_tables(start, items, masks) -> dict:
    """t_start and t_ent from the frame's screen-tile lists (cpu.tiles)."""
    ent = np.zeros((max(1, len(items)), TENT_SIZE))
    ent[:len(items), TENT_ID] = items
    ent[:len(items), TENT_MASK:TENT_MASK + 3] = mask_pieces(masks)
    return {"t_start": flat(start), "t_ent": fold(ent)}


def frame_tiles(frame):
    """(starts, ids, masks) the shader scans: the frame's own screen-tile lists (particles, field)
    or, for paper mode (whose CPU kernels walk the leaves), lists of the Gaussians with its
    weights built here once per frame; None when there are none (switched off, too many)."""
    from ..cpu.tiles import screen_tiles
    from ..devices.frame import NOT_BUILT
    from ..devices.frame_setup import MAX_TILE_ENTRIES
    from ..devices.modes import spec

    if spec(frame.mode).screen_tiles:
        a = frame.accel
        return None if a.t_start.shape[0] <= 1 else (a.t_start, a.t_items, a.t_mask)
    if frame.gpu_tiles is NOT_BUILT:
        g = frame.gauss
        i2w = [np.linalg.inv(m) for m in frame.objects.w2i]
        t = screen_tiles(frame.cam, i2w, g.mu, g.inv, g.obj, g.w, frame.transfer.settings[SET_K],
                         MAX_TILE_ENTRIES)
        frame.gpu_tiles = None if t is None else t[:3]
    return frame.gpu_tiles


def unsupported(frame) -> str | None:
    """Why the GPU's Gaussian modes cannot draw this frame exactly (the device then draws it on
    the CPU), or None: no screen-tile lists (switched off or too many entries), or an index past
    the floats' exact range, or a 1/sigma beyond the size codes."""
    rec = frame.gauss.rec
    if (bad_sizes(rec[:, REC_INV:REC_INV + 3]) & (rec[:, REC_W] != 0)).any():
        return "a Gaussian too small or large for the GPU's size codes"
    if on_gpu(frame):  # the device checks the entries' count when it builds them
        return check_exact(gaussians=[frame.gauss.rec.shape[0]])
    tiles = frame_tiles(frame)
    if tiles is None:
        return "no screen-tile lists"
    return check_exact(tile_entries=tiles[0][-1:], gaussians=[frame.gauss.rec.shape[0]])


def on_gpu(frame):
    """Whether the device builds this frame's screen-tile lists itself (gpu/tiles.py): then
    they are not uploaded, and the entry bounds come in t_lb."""
    return frame.tiles_elsewhere


def overflow_tiles(depth, row0=0, col0=0):
    """The screen tiles (image rows (a, b), columns (c, d), clipped to the region drawn from row0,
    col0) holding a pixel whose Depth is OVERFLOW_DEPTH: the device draws those on the CPU."""
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


def lit(frame):
    """Whether the frame draws a lit volume (the shaders are then compiled with LIT)."""
    return bool((np.asarray(frame.objects.lit) != 0).any())


def particles_geometry(frame):
    """Lit volumes' centre gradients (g_grad), which change only with the sync; none unlit."""
    if not lit(frame):
        return no_geometry(frame)
    return gpu_layout.Tables({"g_grad": fold(frame.gauss.grad)}, {})


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


gpu_layout.MODE_TABLES["particles"] = (particles_geometry, particles_frame)
gpu_layout.MODE_TABLES["field"] = (no_geometry, field_frame)
gpu_layout.MODE_TABLES["paper"] = (no_geometry, particles_frame)
