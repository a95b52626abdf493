"""A compute shader's declaration (``Program``: its GLSL files, #defines, images, samplers, push
constants, work group), built once here for both backends that run the GLSL of kernels/render/gpu/glsl:

- Blender's ``gpu`` module (gaussvdb_addon/gpu/compute.py ``create_info``): each field becomes a
  ``GPUShaderCreateInfo`` call, the source is ``source(program)`` (the create-info dialect: no
  ``#version``, no layouts);
- plain OpenGL 4.3 (benchmarks/gl_backend.py, on moderngl): ``glsl_430(program)``, the same source
  behind a header that declares what the create-info declares.

Both take the same Program, so they cannot drift. This module imports nothing of the package at
load time (the standalone backend loads it by path, with no numba): ``mode_program`` and
``tiles_program`` import the layout when called.
"""
from __future__ import annotations

import json
import os
from collections import namedtuple

GLSL_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "glsl")
GROUP = 8  # a mode's work group: GROUP x GROUP pixels
TILES_GROUP = 64  # the tile lists' passes: invocations per work group (one Gaussian or entry each)
CORE_INTS = ("row0", "col0", "nrows", "ncols", "n_obj", "obj_texels", "n_lights")
# files: the sources in order; defines: ((name, value), ...); images: ((name, format, kind,
# qualifiers), ...) and samplers: ((name, kind), ...) at slots 0, 1, ...; ints: the INT push
# constants; local_size: (x, y)
Program = namedtuple("Program", "files defines images samplers ints local_size")
OUTPUTS = (("out_rgba", "RGBA32F", "FLOAT_2D", ("WRITE",)), ("out_dv", "RGBA32F", "FLOAT_2D", ("WRITE",)))
# The screen-tile lists' passes (gaussvdb_addon/gpu/tiles.py runs them; glsl/tiles.glsl):
# stage -> (samplers, images (name, format, kind, qualifiers), ints)
ATOMIC = ("R32UI", "UINT_2D_ATOMIC", ("READ", "WRITE"))
TILE_STAGES = {
    "FOOT": (("tl_g", "tl_par"), (("tl_box", "RGBA32F", "FLOAT_2D", ("WRITE",)),
                                  ("t_lb", "RGBA32F", "FLOAT_2D", ("WRITE",)), ("cnt",) + ATOMIC), ("n_g",)),
    "FILL": (("tl_box", "t_start"), (("cnt",) + ATOMIC, ("t_raw", "RGBA32F", "FLOAT_2D", ("WRITE",)),
                                     ("t_tile", "RGBA32F", "FLOAT_2D", ("WRITE",))), ("n_g", "ntx")),
    "SORT": (("t_start", "t_lb", "t_raw", "t_tile"), (("t_ent", "RGBA32F", "FLOAT_2D", ("WRITE",)),),
             ("n_ent",)),
}


def texture_kind(a) -> str:
    """How a table travels: (Z, Y, X) float32 as a 'FLOAT_3D' R32F texture (the voxel atlas),
    anything else (H, W, 4) as a 'FLOAT_2D' RGBA32F one."""
    return "FLOAT_3D" if a.ndim == 3 and str(a.dtype) == "float32" and a.shape[-1] != 4 else "FLOAT_2D"


def object_cap(n) -> int:
    """The per-object arrays' size a shader is compiled for: the power of two >= n objects
    (small arrays stay in registers; one object's are no arrays at all), at most MAX_OBJ."""
    from ..inputs.layout import MAX_OBJ

    cap = 1
    while cap < n:
        cap *= 2
    return min(cap, MAX_OBJ)


def mode_program(mode, glsl, defines, kinds, ints) -> Program:
    """A mode's shader: glsl its file(s) (between common.glsl + color.glsl and main.glsl),
    defines its extra #defines (names), kinds {table: texture_kind} (samplers, sorted by name),
    ints {push constant: value} (CORE_INTS first; n_obj sizes the per-object arrays).
    Work group GROUP x GROUP (``on_renderer`` narrows it where a renderer needs)."""
    from ..inputs.layout import glsl_defines

    files = (glsl,) if isinstance(glsl, str) else tuple(glsl)
    defs = tuple(glsl_defines(object_cap(ints["n_obj"])).items())
    defs += ((f"MODE_{mode}", "1"),) + tuple((d, "1") for d in defines)
    names = tuple(sorted(kinds))
    return Program(("common.glsl", "color.glsl") + files + ("main.glsl",), defs, OUTPUTS,
                   tuple((n, kinds[n]) for n in names),
                   CORE_INTS + tuple(sorted(set(ints) - set(CORE_INTS))), (GROUP, GROUP))


def tiles_program(stage) -> Program:
    """One pass of the screen-tile lists (TILE_STAGES), TILES_GROUP invocations per group."""
    from ..inputs.layout import glsl_defines

    samplers, images, ints = TILE_STAGES[stage]
    return Program(("tiles.glsl",), ((f"STAGE_{stage}", "1"),) + tuple(glsl_defines().items()),
                   tuple(images), tuple((n, "FLOAT_2D") for n in samplers), tuple(ints),
                   (TILES_GROUP, 1))


def group_side(defines, renderer) -> int:
    """A mode's work-group side: GROUP, or 1 for modes marked ONE_PER_GROUP on llvmpipe (the pixels
    it runs together share one loop budget, glsl/common.glsl's loops_cut, and the Gaussian modes'
    divergent loops spend it at the pace of the slowest pixel)."""
    names = {d[0] if isinstance(d, (tuple, list)) else d for d in defines}
    return 1 if "ONE_PER_GROUP" in names and "llvmpipe" in renderer else GROUP


def on_renderer(program, renderer) -> Program:
    """The program with the work group this renderer runs a mode's shader with (group_side)."""
    if program.local_size[1] == 1:  # (a tile-list pass: one row of invocations everywhere)
        return program
    side = group_side(program.defines, renderer)
    return program._replace(local_size=(side, side))


def source(program, glsl_dir=GLSL_DIR) -> str:
    """The program's GLSL body: its files joined (the create-info dialect)."""
    parts = []
    for name in program.files:
        with open(os.path.join(glsl_dir, name), encoding="utf-8") as f:
            parts.append(f.read())
    return "\n".join(parts)


_IMAGE_TYPE = {"FLOAT_2D": "image2D", "UINT_2D_ATOMIC": "uimage2D"}
_SAMPLER_TYPE = {"FLOAT_2D": "sampler2D", "FLOAT_3D": "sampler3D"}
_ACCESS = {("WRITE",): "writeonly ", ("READ",): "readonly ", ("READ", "WRITE"): ""}


def glsl_430_header(program) -> str:
    """What Blender's create-info declares, as plain GLSL 4.30: the #defines, the images and
    samplers at their slots' bindings, the push constants as uniforms, the work group."""
    lines = ["#version 430"]
    lines += [f"#define {n} {v}" for n, v in program.defines]
    lines.append("layout(local_size_x = %d, local_size_y = %d) in;" % tuple(program.local_size))
    for slot, (name, fmt, kind, qual) in enumerate(program.images):
        access = _ACCESS[tuple(sorted(qual))]
        lines.append(f"layout(binding = {slot}, {fmt.lower()}) uniform {access}{_IMAGE_TYPE[kind]} {name};")
    for slot, (name, kind) in enumerate(program.samplers):
        lines.append(f"layout(binding = {slot}) uniform {_SAMPLER_TYPE[kind]} {name};")
    lines += [f"uniform int {n};" for n in program.ints]
    return "\n".join(lines) + "\n"


def glsl_430(program, glsl_dir=GLSL_DIR) -> str:
    """The whole standalone compute shader: glsl_430_header, then source."""
    return glsl_430_header(program) + "#line 1\n" + source(program, glsl_dir)


def to_json(program) -> str:
    return json.dumps(program._asdict())


def from_json(text) -> Program:
    d = json.loads(text)
    return Program(tuple(d["files"]), tuple(tuple(x) for x in d["defines"]),
                   tuple((n, f, k, tuple(q)) for n, f, k, q in d["images"]),
                   tuple(tuple(x) for x in d["samplers"]), tuple(d["ints"]), tuple(d["local_size"]))
