"""A GPU frame as a file: the numpy tables the GPU device uploads for a frame, its shaders'
declarations (glsl_assembly.Program) and the CPU device's image, in one ``.npz`` that a machine
with numpy and OpenGL 4.3 draws and times with no Blender and no numba
(benchmarks/gl_backend.py). Plain numpy here; the GPU device (gaussvdb_addon/gpu/device.py) takes
its per-frame tables and defines from ``frame_tables`` and ``frame_defines`` too.

A case file holds (all arrays, no pickles):
- ``case.json``: a JSON string: mode, ints (push constants), program (the mode's shader), the
  views (name, width, height), tiles (whether the GPU builds the screen-tile lists, their grid
  per view, the passes' programs), what the tables cost on the GPU, the scene's description;
- ``t.NAME``: a table every view uploads; ``VIEW.t.NAME``: a table of one view (the camera);
- ``tiles.tl_g``, ``tiles.tl_par`` (per view ``VIEW.tiles.tl_par``): the tile lists' inputs;
- ``VIEW.cpu``: the CPU device's Combined pass where saved, compact (``pack_image``: float32
  rounded to CPU_BITS of its 23 mantissa bits, its four bytes stored as four planes, which the
  compression takes far better; ``unpack_image`` or gl_backend.Case.cpu reads it back). The view's
  ``cpu_floor_db`` in case.json is the rounding's PSNR against the exact image: the PSNR a run
  measures against it is the true one wherever that is well below (16 bits: about 130 dB).
"""
from __future__ import annotations

import json

import numpy as np

from ..inputs.layout import CAM_H, CAM_W
from . import assembly as asm
from . import tables as gpu_layout
from . import tables_color, tables_gauss, tables_tiles

TILE_LISTS = ("t_start", "t_ent", "t_lb")  # the GPU-built lists the mode's shader samples
CPU_BITS = 16  # the CPU image's mantissa bits kept (relative error <= 2**-17)


def pack_image(img, bits=CPU_BITS):
    """(H, W, C) float32 -> (4, H*W*C) uint8: each value rounded to ``bits`` mantissa bits
    (to nearest; finite values only), its bytes as four planes (little-endian: low byte first)."""
    a = np.ascontiguousarray(img, np.float32)
    u = a.view(np.uint32).copy()
    drop = 23 - int(bits)
    if drop > 0:
        u = (u + np.uint32(1 << (drop - 1))) & ~np.uint32((1 << drop) - 1)
    return np.ascontiguousarray(u.view(np.uint8).reshape(-1, 4).T)


def unpack_image(planes, shape):
    """pack_image's inverse (the rounded values), as float32 of ``shape``."""
    p = np.asarray(planes)
    if p.dtype == np.float32:  # (a case saved before the images were packed)
        return p.reshape(shape)
    return np.ascontiguousarray(p.T).view(np.float32).reshape(shape)


def psnr(a, b):
    """PSNR in dB (peak 1) of two images, inf where equal."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def frame_tables(frame, name):
    """The mode's per-frame tables (gpu_layout.MODE_TABLES) with the colour grids' (Tables)."""
    t = gpu_layout.MODE_TABLES[name][1](frame)
    t.textures.update(tables_color.frame_tables(frame))
    return t


def frame_defines(frame, tables) -> tuple:
    """The #defines a frame adds to its mode's: GPU_TILES (lists built on the GPU), LIT, the
    colour grids' (for these table names)."""
    return ((("GPU_TILES",) if tables_gauss.on_gpu(frame) else ())
            + (("LIT",) if tables_gauss.lit(frame) else ()) + tables_color.defines(tables))


def frame_case(frame, name, spec):
    """({table: array}, {int: value}, Program, tile inputs or None) of a frame the GPU device
    draws (its fallback said None): what it uploads and the mode's shader. spec: the device's
    ModeSpec (glsl, defines)."""
    geo = gpu_layout.MODE_TABLES[name][0](frame)
    fr = frame_tables(frame, name)
    tables = dict(geo.textures, **fr.textures)
    ints = {k: int(v) for k, v in dict(geo.ints, **fr.ints).items()}
    tiles = None
    kinds = {n: asm.texture_kind(a) for n, a in tables.items()}
    if tables_gauss.on_gpu(frame):
        tiles = tables_tiles.tile_inputs(frame)
        kinds.update((n, "FLOAT_2D") for n in TILE_LISTS)
    program = asm.mode_program(name, spec.glsl, tuple(spec.defines) + frame_defines(frame, tables),
                               kinds, ints)
    return tables, ints, program, tiles


def view_name(width, height) -> str:
    return f"{int(width)}x{int(height)}"


def save(path, views, meta):
    """One case file from its views: [(frame, name, spec, cpu Combined or None), ...] of one
    scene at several image sizes (the tables they share stored once, the CPU image packed where
    given); meta: the scene's description."""
    arrays, shared, info = {}, None, dict(meta, views=[])
    for frame, name, spec, cpu in views:
        tables, ints, program, tiles = frame_case(frame, name, spec)
        v = view_name(frame.width, frame.height)
        ntx, nty = tables_tiles.tile_grid(frame) if tiles is not None else (0, 0)
        view = {"name": v, "width": int(frame.cam[CAM_W]), "height": int(frame.cam[CAM_H]),
                "ntx": ntx, "nty": nty}
        info["views"].append(view)
        if shared is None:
            shared = dict(tables, **({"tiles.tl_g": tiles["tl_g"]} if tiles else {}))
            info.update(mode=name, ints=ints, program=asm.to_json(program),
                        gaussians=int(frame.gauss.mu.shape[0]), on_gpu_tiles=tiles is not None,
                        tile_programs={s: asm.to_json(asm.tiles_program(s)) for s in asm.TILE_STAGES}
                        if tiles is not None else {},
                        table_bytes=int(sum(a.nbytes for a in tables.values())))
            arrays.update((n if n.startswith("tiles.") else "t." + n, a) for n, a in shared.items())
        elif asm.to_json(program) != info["program"] or ints != info["ints"]:
            raise ValueError(f"view {v}: another shader or push constants than the first view's")
        for n, a in tables.items():
            if not np.array_equal(a, shared[n]):
                arrays[f"{v}.t.{n}"] = a
        if tiles is not None:
            arrays[f"{v}.tiles.tl_par"] = tiles["tl_par"]
        if cpu is not None:
            cpu = np.asarray(cpu, np.float32)
            arrays[f"{v}.cpu"] = packed = pack_image(cpu)
            view["cpu_floor_db"] = psnr(unpack_image(packed, cpu.shape), cpu)
    arrays["case.json"] = np.array(json.dumps(info))
    np.savez_compressed(path, **arrays)
