"""Texture-ready float32 tables for the GPU device, from a CPU frame's packed groups (plain numpy,
no bpy/gpu: the GPU glue uploads what these functions return).

Layout rules (common.glsl reads them):
- A table is a 2-D RGBA32F texture ROW_TEXELS wide. ``fold_rows`` puts row i of an (n, c) table
  at texels i * ceil(c / 4) ..; ``fold_scalars`` puts element e of a 1-D table in component e % 4
  of texel e // 4. A texel t sits at (t % ROW_TEXELS, t // ROW_TEXELS).
- Integers go up as exact floats (|v| < 2^24, checked): ids, counts, cell coordinates, flags.
- The voxel bricks ((n, 10, 10, 10), one-voxel apron) go in one 3-D R32F atlas, ``ATLAS_SLOTS``
  slots per axis at most; brick b sits at slot (b % sx, b // sx % sy, b // (sx * sy)), its voxel
  [i, j, k] at texel (10 sx' + i, 10 sy' + j, 10 sz' + k) (numpy's last axis is the texture's x).
- Per mode, the mode table (at the end) holds (geometry tables, frame tables): two functions of
  a frame returning Tables; geometry is uploaded once per sync, frame tables once per frame key.
- The records' fields (frame, objects, ...) are declared in layout.py, which the shaders get as
  #defines too.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..inputs.layout import (
    BRICK,
    FR_CAM,
    FR_SET,
    FR_SIZE,
    LUT_SIZE,
    MAX_OBJ,
    OBJ_KIND,
    OBJ_LEVEL,
    OBJ_LIT,
    OBJ_LS,
    OBJ_NCLIP,
    OBJ_NODE_DIMS,
    OBJ_NODE_MIN,
    OBJ_NODE_OFF,
    OBJ_REF,
    OBJ_SH_GRID,
    OBJ_SIZE,
    OBJ_STEP,
    OBJ_TEXELS,
    OBJ_TF,
    OBJ_W2I,
    OBJ_WALK_SCALE,
    ROW_TEXELS,
    SHG_DIMS,
    SHG_OFFSET,
    SHG_SIZE,
)

EXACT = float(1 << 24)
ATLAS_MAX = 2040  # 3-D texture side used at most (OpenGL guarantees 2048)
ATLAS_SLOTS = ATLAS_MAX // BRICK
# {name: float32 (H, ROW_TEXELS, 4) table, (n, LUT_TEXELS, 4) LUTs or (Z, Y, X) atlas},
# {name: int push constant}
Tables = namedtuple("Tables", "textures ints")


def _exact(a, what):
    a = np.asarray(a)
    if a.size and np.abs(a).max() >= EXACT:
        raise ValueError(f"{what}: values up to {np.abs(a).max()} do not fit a float32 exactly")
    return a.astype(np.float32)


def fold_scalars(a, what="table"):
    """1-D -> (H, ROW_TEXELS, 4) float32, element e in texel e // 4, component e % 4."""
    a = np.asarray(a).ravel()
    texels = max(1, -(-a.size // 4))
    h = -(-texels // ROW_TEXELS)
    out = np.zeros(h * ROW_TEXELS * 4, np.float32)
    out[:a.size] = a
    return out.reshape(h, ROW_TEXELS, 4)


def texels_per_row(c):
    return max(1, -(-int(c) // 4))


def fold_rows(a, what="table"):
    """(n, c) -> (H, ROW_TEXELS, 4) float32; row i at texels i * ceil(c / 4) .. (see above)."""
    a = np.asarray(a, np.float64)
    a = a[:, None] if a.ndim == 1 else a.reshape(a.shape[0], -1)
    n, c = a.shape
    per = texels_per_row(c)
    flat = np.zeros((max(n, 1), per * 4), np.float32)
    flat[:n, :c] = a
    return fold_scalars(flat.ravel(), what)


def brick_atlas(bricks):
    """(n, 10, 10, 10) bricks -> ((Z, Y, X) float32 atlas, (sx, sy, sz) slots)."""
    b = np.asarray(bricks, np.float32)
    n = b.shape[0]
    sx = min(n, ATLAS_SLOTS)
    sy = min(-(-n // sx), ATLAS_SLOTS)
    sz = -(-n // (sx * sy))
    if sz > ATLAS_SLOTS:
        raise ValueError(f"{n} voxel bricks do not fit one 3-D texture ({ATLAS_SLOTS ** 3} at most)")
    full = np.zeros((sx * sy * sz, BRICK, BRICK, BRICK), np.float32)
    full[:n] = b
    # [slot z, slot y, slot x, i, j, k] -> atlas [z = 10 sz + k, y = 10 sy + j, x = 10 sx + i]
    g = full.reshape(sz, sy, sx, BRICK, BRICK, BRICK).transpose(0, 5, 1, 4, 2, 3)
    return np.ascontiguousarray(g.reshape(sz * BRICK, sy * BRICK, sx * BRICK)), (sx, sy, sz)


def frame_table(frame):
    """The camera and settings as one scalar table (layout.FR)."""
    fr = np.zeros(FR_SIZE)
    fr[FR_CAM:FR_CAM + frame.cam.size] = frame.cam
    fr[FR_SET:FR_SET + frame.transfer.settings.size] = frame.transfer.settings
    return fold_scalars(fr.astype(np.float32))


def object_rows(frame):
    """Per object its layout.OBJ row (OBJ_TEXELS texels: w2i rows 0-2, kind, transfer row, step,
    shading, ls, clip count, node grid, reference point, a signed-distance surface's
    single-layer level (packing.Objects.sdf, cbg; 0: none), shadow grid), then its clip
    half-spaces (one texel each). Returns (table, texels per object)."""
    o, a = frame.objects, frame.accel
    n = o.w2i.shape[0]
    if n > MAX_OBJ:
        raise ValueError(f"the GPU device draws at most {MAX_OBJ} objects, not {n}")
    nclip = o.clip.shape[1]
    rows = np.zeros((n, OBJ_SIZE + 4 * nclip))
    rows[:, OBJ_W2I:OBJ_W2I + 12] = o.w2i[:, :3, :].reshape(n, 12)
    rows[:, OBJ_KIND], rows[:, OBJ_TF], rows[:, OBJ_STEP], rows[:, OBJ_LIT] = o.kind, o.tf, o.step, o.lit
    rows[:, OBJ_LS:OBJ_LS + o.ls.shape[1]] = o.ls
    rows[:, OBJ_NCLIP] = nclip
    rows[:, OBJ_NODE_MIN:OBJ_NODE_MIN + 3] = a.node_min[:n]
    rows[:, OBJ_NODE_OFF] = a.node_off[:n]
    rows[:, OBJ_NODE_DIMS:OBJ_NODE_DIMS + 3] = a.node_dims[:n]
    rows[:, OBJ_WALK_SCALE] = a.walk_scale[:n]
    if o.ref.shape[0] >= n:
        rows[:, OBJ_REF:OBJ_REF + 3] = o.ref[:n]
    rows[:, OBJ_LEVEL] = np.where(o.sdf[:n] != 0, o.cbg[:n], 0.0)
    rows[:, OBJ_SH_GRID:OBJ_SH_GRID + SHG_SIZE] = np.asarray(o.sh_grid[:n])
    rows[:, OBJ_SIZE:] = o.clip.reshape(n, -1)
    _exact(rows[:, OBJ_NODE_MIN:OBJ_WALK_SCALE + 1], "object node grids")
    _exact(rows[:, OBJ_SH_GRID + SHG_DIMS:OBJ_SH_GRID + SHG_OFFSET + 1], "shadow grid sizes")
    return fold_rows(rows, "objects"), OBJ_TEXELS + nclip


def transfer_tables(frame):
    """LUTs (one texture row of LUT_SIZE texels per transfer function), their parameters
    (one texel each, layout.PAR) and the lights (two texels each, layout.LIGHT_ROW)."""
    x = frame.transfer
    lut = np.asarray(x.lut, np.float32)
    if lut.shape[1] != LUT_SIZE:
        raise ValueError(f"transfer tables of {lut.shape[1]} rows; the GPU device reads {LUT_SIZE}")
    return {"tf_lut": np.ascontiguousarray(lut), "tf_par": fold_rows(x.par),
            "lights": fold_rows(x.lights)}, x.lights.shape[0]


def common_tables(frame):
    """What every mode reads per frame: frame (camera, settings), objects, transfer, lights and
    the lit volumes' optical depths towards each light (sh_tau, scalars, light fastest)."""
    objs, per_obj = object_rows(frame)
    tex, n_lights = transfer_tables(frame)
    tex.update(frame=frame_table(frame), objs=objs, sh_tau=fold_scalars(frame.objects.sh_tau))
    return Tables(tex, {"n_obj": int(frame.objects.w2i.shape[0]), "obj_texels": per_obj,
                        "n_lights": int(n_lights)})


def walk_tables(accel):
    """The leaf hierarchy (geometry): node table and node -> cell table, scalars."""
    return {"node_table": fold_scalars(_exact(accel.node_table, "node table")),
            "node_cells": fold_scalars(_exact(accel.node_cells, "node cells"))}


def walk_frame(accel):
    """This frame's empty-space skips per cell (1: skip), scalars."""
    return {"cell_skip": fold_scalars(np.asarray(accel.cell_skip, np.float32))}


# -- reference mode -------------------------------------------------------------------------------
def reference_geometry(frame):
    """Voxel atlas (with the colour grids' bricks after the grid's: gpu.tables_color), the leaf
    hierarchy and each cell's [x, y, z] in leaves (once per sync)."""
    a = frame.accel
    color = a.cbricks.shape == a.bricks.shape  # (else a placeholder: no colour grid)
    atlas, (sx, sy, _) = brick_atlas(np.concatenate([a.bricks, a.cbricks]) if color else a.bricks)
    tex = walk_tables(a)
    tex["atlas"] = atlas
    tex["cells"] = fold_rows(_exact(a.cell_xyz, "cell coordinates"))
    ints = {"atlas_sx": sx, "atlas_sy": sy}
    if color:  # cell c's colour brick: c + cbrick0
        ints["cbrick0"] = a.bricks.shape[0]
    return Tables(tex, ints)


def reference_frame(frame):
    """The common tables and the cells' skips."""
    t = common_tables(frame)
    t.textures.update(walk_frame(frame.accel))
    return t


MODE_TABLES = {"reference": (reference_geometry, reference_frame)}


def nbytes(tables):
    return int(sum(a.nbytes for a in tables.textures.values()))

