"""The thin part that calls Blender's ``gpu`` module: compute shaders assembled from the GLSL files
(kernels/render/gpu/glsl: common + the mode's file + main), numpy tables uploaded as textures, one
dispatch per band of rows, the passes read back. Every function here must run inside a GPU
context (context.run)."""
from __future__ import annotations

import numpy as np

from ...kernels.render.gpu import assembly as asm

GLSL_DIR = asm.GLSL_DIR
GROUP = asm.GROUP  # work group: GROUP x GROUP pixels
_SHADERS = {}  # Program -> compiled shader, per process


def group(spec):
    """The work group's side for a mode on this renderer (assembly.group_side)."""
    import gpu

    return asm.group_side(spec.defines, gpu.platform.renderer_get())


_kind = asm.texture_kind


def create_info(program):
    """A glsl_assembly.Program as Blender's create-info (the standalone backend declares the same
    Program as GLSL 4.30: assembly.glsl_430)."""
    import gpu

    info = gpu.types.GPUShaderCreateInfo()
    for slot, (name, fmt, kind, qual) in enumerate(program.images):
        info.image(slot, fmt, kind, name, qualifiers=set(qual))
    for slot, (name, kind) in enumerate(program.samplers):
        info.sampler(slot, kind, name)
    for name in program.ints:
        info.push_constant("INT", name)
    for name, value in program.defines:
        info.define(name, value)
    info.local_group_size(*program.local_size)
    info.compute_source(asm.source(program))
    return info


def compiled(program):
    """The program's shader (compiled once per process)."""
    import gpu

    sh = _SHADERS.get(program)
    if sh is None:
        sh = _SHADERS[program] = gpu.shader.create_from_info(create_info(program))
    return sh


def shader(mode, spec, textures, ints):
    """The mode's shader for these tables (assembly.mode_program on this renderer)."""
    import gpu

    program = asm.mode_program(mode, spec.glsl, spec.defines,
                               {n: _kind(a) for n, a in textures.items()}, ints)
    return compiled(asm.on_renderer(program, gpu.platform.renderer_get()))


def upload(textures):
    """{name: float32 array} -> {name: GPUTexture}: (H, W, 4) as RGBA32F 2-D, (Z, Y, X) as R32F 3-D."""
    import gpu

    out = {}
    limit = gpu.capabilities.max_texture_size_get()
    for name, a in textures.items():
        a = np.ascontiguousarray(a, np.float32)
        if _kind(a) == "FLOAT_2D" and max(a.shape[:2]) > limit:
            raise ValueError(f"the scene's {name} table needs a {a.shape[1]}x{a.shape[0]} texture; "
                             f"this GPU takes {limit} at most (use the CPU device)")
        buf = gpu.types.Buffer("FLOAT", a.size, a.reshape(-1))
        if _kind(a) == "FLOAT_3D":
            out[name] = gpu.types.GPUTexture((a.shape[2], a.shape[1], a.shape[0]), format="R32F", data=buf)
        else:
            out[name] = gpu.types.GPUTexture((a.shape[1], a.shape[0]), format="RGBA32F", data=buf)
    return out


def dispatch(sh, textures, ints, rows, cols, out=None, side=GROUP):
    """Draw rows [r0, r1) x columns [c0, c1) into (new, or the given) output textures;
    returns (rgba, dv) textures (nr x nc). side: the shader's work group (group(spec))."""
    import gpu

    (r0, r1), (c0, c1) = rows, cols
    nr, nc = r1 - r0, c1 - c0
    if out is None or out[0].width != nc or out[0].height != nr:
        out = (gpu.types.GPUTexture((nc, nr), format="RGBA32F"),
               gpu.types.GPUTexture((nc, nr), format="RGBA32F"))
    sh.bind()
    for name, tex in textures.items():
        sh.uniform_sampler(name, tex)
    sh.image("out_rgba", out[0])
    sh.image("out_dv", out[1])
    vals = dict(ints, row0=r0, col0=c0, nrows=nr, ncols=nc)
    for name, v in vals.items():
        try:
            sh.uniform_int(name, int(v))
        except ValueError:  # a push constant this mode never reads: the compiler dropped it
            pass
    gpu.compute.dispatch(sh, -(-nc // side), -(-nr // side), 1)
    return out


def read(tex):
    """A RGBA32F texture's pixels, (h, w, 4) float32."""
    buf = tex.read()
    buf.dimensions = tex.width * tex.height * 4
    return np.frombuffer(buf, np.float32).reshape(tex.height, tex.width, 4).copy()
