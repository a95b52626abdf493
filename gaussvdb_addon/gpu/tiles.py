"""The frame's screen-tile lists built on the GPU (glsl/tiles.glsl): footprints, entry bounds and
per-tile counts, one small readback of the counts for the prefix sum (numpy), the fill and the
per-tile sort. Call inside a GPU context (context.run)."""
from __future__ import annotations

import numpy as np

from ...kernels.render.gpu import assembly as asm
from ...kernels.render.gpu import tables as gpu_layout
from ...kernels.render.gpu import tables_tiles
from . import compute

GROUP = asm.TILES_GROUP  # invocations per work group (one Gaussian or one entry each)
# gpu.compute.dispatch ends with a texture-fetch and image-access barrier: each pass sees the last
LISTS = ("t_start", "t_ent", "t_lb")  # what build() returns (RGBA32F tables)
MAX_ENTRIES = int(gpu_layout.EXACT) - 1  # entries one frame's GPU lists hold (ids are exact floats)
STAGES = asm.TILE_STAGES  # stage: (samplers, images, ints)


class TooMany(Exception):
    """The lists pass what this GPU's textures (or exact float ids) hold: use the CPU's."""


def _shader(stage):
    return compute.compiled(asm.tiles_program(stage))


def _run(stage, n, tex, ints):
    import gpu

    sh = _shader(stage)
    sh.bind()
    samplers, images, _ = STAGES[stage]
    for name in samplers:
        sh.uniform_sampler(name, tex[name])
    for name, *_ in images:
        sh.image(name, tex[name])
    for name, v in ints.items():
        sh.uniform_int(name, int(v))
    groups = max(1, -(-n // GROUP))
    gx = min(groups, gpu.capabilities.max_work_group_count_get(0))
    gpu.compute.dispatch(sh, gx, -(-groups // gx), 1)


def _table(n):
    """An empty RGBA32F table texture of n texels (gpu_layout's fold: ROW_TEXELS wide)."""
    import gpu

    return gpu.types.GPUTexture((gpu_layout.ROW_TEXELS, max(1, -(-n // gpu_layout.ROW_TEXELS))),
                                format="RGBA32F")


def _counter(ntx, nty):
    import gpu

    t = gpu.types.GPUTexture((ntx, nty), format="R32UI")
    t.clear(format="UINT", value=(0,))
    return t


def build(frame):
    """{t_start, t_ent, t_lb: GPUTexture} for the frame, and the entries' count; TooMany when
    they do not fit."""
    import gpu

    m = int(frame.gauss.mu.shape[0])
    ntx, nty = tables_tiles.tile_grid(frame)
    limit = gpu.capabilities.max_texture_size_get()
    if max(ntx, nty) > limit or -(-m // gpu_layout.ROW_TEXELS) > limit:
        raise TooMany(f"{ntx}x{nty} tiles, {m} Gaussians")
    tex = compute.upload(tables_tiles.tile_inputs(frame))
    tex.update(tl_box=_table(m), t_lb=_table(m), cnt=_counter(ntx, nty))
    _run("FOOT", m, tex, {"n_g": m})
    buf = tex["cnt"].read()
    buf.dimensions = ntx * nty
    start = tables_tiles.starts(np.frombuffer(buf, np.uint32).reshape(nty, ntx))
    total = int(start[-1])
    if total > MAX_ENTRIES or -(-max(total, 1) // gpu_layout.ROW_TEXELS) > limit:
        raise TooMany(f"{total} tile entries")
    tex.update(compute.upload({"t_start": gpu_layout.fold_scalars(start)}))
    n = max(total, 1)
    tex.update(t_raw=_table(n), t_tile=_table(n), t_ent=_table(n), cnt=_counter(ntx, nty))
    _run("FILL", m, tex, {"n_g": m, "ntx": ntx})
    _run("SORT", total, tex, {"n_ent": total})
    return {k: tex[k] for k in LISTS}, total
