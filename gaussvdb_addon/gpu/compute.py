"""The thin part that calls Blender's ``gpu`` module: compute shaders assembled from the GLSL files
(kernels/render/glsl: common + the mode's file + main), numpy tables uploaded as textures, one
dispatch per band of rows, the passes read back. Every function here must run inside a GPU
context (context.run)."""
from __future__ import annotations

import os

import numpy as np

from ...kernels.render import gpu_layout, layout

GLSL_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                        "kernels", "render", "glsl")
GROUP = 8  # work group: GROUP x GROUP pixels
CORE_INTS = ("row0", "col0", "nrows", "ncols", "n_obj", "obj_texels", "n_lights")
_SHADERS = {}  # (mode, resources) -> compiled shader, per process


def define_layout(info, max_obj=layout.MAX_OBJ):
    """The shared records' offsets and constants (layout.glsl_defines) as the shader's defines."""
    for name, value in layout.glsl_defines(max_obj).items():
        info.define(name, value)


def glsl(name):
    with open(os.path.join(GLSL_DIR, name), encoding="utf-8") as f:
        return f.read()


def source(glsl_file):
    """The compute source: common, color (the colour grids' functions), the mode's file (or
    files, in order), main (the create-info adds the resources)."""
    files = (glsl_file,) if isinstance(glsl_file, str) else tuple(glsl_file)
    return "\n".join(glsl(n) for n in ("common.glsl", "color.glsl") + files + ("main.glsl",))


def group(spec):
    """The work group's side for a mode: GROUP, or 1 for modes marked ONE_PER_GROUP on llvmpipe
    (the pixels it runs together share one loop budget, glsl/common.glsl's loops_cut, and the
    Gaussian modes' divergent loops spend it at the pace of the slowest pixel)."""
    import gpu

    if "ONE_PER_GROUP" in spec.defines and "llvmpipe" in gpu.platform.renderer_get():
        return 1
    return GROUP


def _kind(a):
    return "FLOAT_3D" if a.ndim == 3 and a.dtype == np.float32 and a.shape[-1] != 4 else "FLOAT_2D"


def object_cap(n):
    """The per-object arrays' size a shader is compiled for: the power of two >= n objects
    (small arrays stay in registers; one object's are no arrays at all)."""
    cap = 1
    while cap < n:
        cap *= 2
    return min(cap, gpu_layout.MAX_OBJ)


def shader(mode, spec, textures, ints):
    """The mode's shader for these table names (compiled once per process)."""
    import gpu

    names = tuple(sorted(textures))
    cap = object_cap(ints["n_obj"])
    key = (mode, cap, tuple((n, _kind(textures[n])) for n in names), tuple(sorted(ints)),
           tuple(spec.defines))
    sh = _SHADERS.get(key)
    if sh is not None:
        return sh
    info = gpu.types.GPUShaderCreateInfo()
    info.image(0, "RGBA32F", "FLOAT_2D", "out_rgba", qualifiers={"WRITE"})
    info.image(1, "RGBA32F", "FLOAT_2D", "out_dv", qualifiers={"WRITE"})
    for slot, n in enumerate(names):
        info.sampler(slot, _kind(textures[n]), n)
    for n in CORE_INTS + tuple(sorted(set(ints) - set(CORE_INTS))):
        info.push_constant("INT", n)
    define_layout(info, cap)
    info.define(f"MODE_{mode}", "1")
    for d in spec.defines:
        info.define(d, "1")
    side = group(spec)
    info.local_group_size(side, side)
    info.compute_source(source(spec.glsl))
    sh = gpu.shader.create_from_info(info)
    _SHADERS[key] = sh
    return sh


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
