"""GPUDevice: the CPU device's scene sync and frame set-up (it holds a CPUDevice), drawn by compute
shaders on Blender's ``gpu`` module. Per frame key the mode's tables (kernels/render/gpu/tables*.py)
are uploaded once (geometry once per sync), then each render() call is one dispatch per step of
rows and a readback; ``render_texture`` leaves the image on the GPU (the viewport draws it).

Adding a mode: a GLSL file beside common.glsl defining ``void trace_mode(Ray r, inout State st)``,
its tables in gpu_layout.MODE_TABLES (geometry, frame), and its shader in the mode's entry of
kernels/render/devices/modes.py (``gpu``). Frames this device does not draw (modes without a shader) are
refused; frames the GPU cannot draw exactly (``fallback(frame)``) go to the CPU device.

Lit volumes are drawn in every mode that has them (reference, particles, field; paper has none):
the shaders are then compiled with LIT (the Gaussian modes' shading code, common.glsl's
shade_sample), the shadow grids and particles' centre gradients come from the CPU device's frame.
Volumes coloured by a second grid are drawn here in every mode too (their tables:
tables_color, added to every mode's; glsl/color.glsl).

The Gaussian modes' screen-tile lists are built here on the GPU (tiles.py; the CPU device's frame
then has none: its begin_frame's ``lists_elsewhere``, Frame.tiles_elsewhere); lists too long for
the GPU come from the CPU device, and a frame too long for both is drawn by it.
``GPUDevice(gpu_tiles=False)`` uploads the CPU's lists.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from ...kernels.render.devices import bands, modes
from ...kernels.render.devices.cpu_device import CPUDevice
from ...kernels.render.devices.device import Device, register_device
from ...kernels.render.gpu import case, tables_color, tables_gauss, tables_tiles
from ...kernels.render.gpu import tables as gpu_layout
from ...kernels.render.inputs.layout import BG_DEPTH
from . import compute, context, tiles

# the shaders of the modes this device draws (kernels/render/devices/modes.py), by name
MODES = {m.name.lower(): s.gpu for m, s in modes.SPECS.items() if s.drawn_as is None and s.gpu is not None}
STEP_ROWS = 64  # rows per dispatch when progress or cancel is asked for
NO_LISTS = "no screen-tile lists"  # the fallback's word when neither device's lists fit


class NoLists(Exception):
    """The frame's screen-tile lists pass what the GPU and the CPU build: the CPU device draws it."""


class GPUDevice(Device):
    name = "GPU"

    def __init__(self, threads=None, cache_dir=None, gpu_tiles=True, **kw):
        self.cpu = CPUDevice(threads=threads, cache_dir=cache_dir, **kw)
        self.gpu_tiles = bool(gpu_tiles)  # the Gaussian modes' screen-tile lists built here (tiles.py)
        self._geom = None  # (key, Tables, textures)
        self._up = None  # (frame key, Tables, textures)
        self._out = None  # the last output textures (reused while the band size stays)
        self.stats = {}
        self.renderer = None

    def sync(self, scene):
        self.cpu.sync(scene)
        self.stats["seconds_sync"] = self.cpu.stats.get("seconds_sync", 0.0)

    def begin_frame(self, scene, camera, tf):
        frame = self.cpu.begin_frame(scene, camera, tf, lists_elsewhere=self.gpu_tiles)
        if modes.spec(frame.mode).color == modes.GAUSSIANS and tables_color.colored(frame):
            frame.color_values = self.cpu.color_values()  # (the Gaussians' colours: tables_color)
        self.stats["seconds_setup"] = self.cpu.stats.get("seconds_setup", 0.0)
        return frame

    def end_frame(self):
        self.cpu.end_frame()
        self._up = None

    def band_rows(self, scene):
        return 8, 8

    def load_kernels(self, modes=None, *, scene=None, camera=None, tf=None):
        return 0.0

    @staticmethod
    def fallback(frame):
        """Why this device hands the frame to the CPU device (None: it draws it)."""
        if modes.spec(frame.mode).draws == modes.GAUSSIANS:
            return tables_gauss.unsupported(frame)
        return None

    def _cpu_render(self, *args, **kw):
        """The CPU device's image (its frame then has its own screen-tile lists)."""
        return self.cpu.render(*args, **kw)

    def _overflow(self, scene, camera, tf, rgba, dv, r0, c0):
        """Redraw on the CPU device the screen tiles with a ray that ran out of hit slots."""
        tiles = tables_gauss.overflow_tiles(dv[..., 0], r0, c0)
        for (a, b), (c, d) in tiles:
            out = self._cpu_render(scene, camera, tf, rows=(a, b), cols=(c, d))
            rgba[a - r0:b - r0, c - c0:d - c0] = out["Combined"]
            dv[a - r0:b - r0, c - c0:d - c0, 0] = out.get("Depth", BG_DEPTH)
            dv[a - r0:b - r0, c - c0:d - c0, 1] = out.get("Value", 0.0)
        return len(tiles)

    def _spec(self, frame):
        name = modes.spec(frame.mode).mode.name.lower()
        spec = MODES.get(name)
        if spec is None:
            raise ValueError(f"{name} mode is not yet on the GPU device (use the CPU device)")
        return name, spec

    def _tables(self, frame):
        """The frame's uploaded tables (geometry reused while the sync is the same)."""
        name, spec = self._spec(frame)
        geo_fn = gpu_layout.MODE_TABLES[name][0]
        gkey = (self.cpu.geometry_version, name, tables_gauss.lit(frame))
        if self._geom is None or self._geom[0] != gkey:
            self._geom = None
            t = geo_fn(frame)
            self._geom = (gkey, t, compute.upload(t.textures))
        if self._up is None or self._up[0] != frame.key:
            t = case.frame_tables(frame, name)
            tex = compute.upload(t.textures)
            if tables_gauss.on_gpu(frame):
                tex.update(self._tile_lists(frame))
                t.textures.update({n: np.zeros((1, 1, 4), np.float32) for n in tiles.LISTS})  # names, kinds
            self._up = (frame.key, t, tex)
        _, gt, gtex = self._geom
        _, ft, ftex = self._up
        ints = dict(gt.ints, **ft.ints)
        tex = dict(gtex, **ftex)
        arrays = dict(gt.textures, **ft.textures)
        self.stats["gpu_bytes"] = gpu_layout.nbytes(gt) + gpu_layout.nbytes(ft) + sum(
            16 * ftex[n].width * ftex[n].height for n in tiles.LISTS if tables_gauss.on_gpu(frame))
        return name, spec, arrays, tex, ints

    def _tile_lists(self, frame):
        """t_start, t_ent, t_lb built on the GPU; the CPU's lists uploaded when they do not fit."""
        try:
            lists, n = tiles.build(frame)
            self.stats.update(gpu_tile_entries=n, tile_lists="GPU")
            return lists
        except tiles.TooMany as e:
            t = tables_tiles.cpu_lists(frame)
            if t is None:
                raise NoLists(str(e)) from None
            self.stats.update(gpu_tile_entries=int(t["t_ent"].size // 4), tile_lists="CPU")
            return compute.upload(t)

    def _dispatch(self, frame, rows, cols):
        import gpu

        name, spec, arrays, tex, ints = self._tables(frame)
        spec = dataclasses.replace(spec, defines=spec.defines + case.frame_defines(frame, arrays))
        sh = compute.shader(name, spec, arrays, ints)
        self._out = compute.dispatch(sh, tex, ints, rows, cols, self._out, compute.group(spec))
        self.renderer = gpu.platform.renderer_get()
        return self._out

    def render(self, scene, camera, tf, *, rows=None, cols=None, progress=None, cancel=None):
        t0 = time.perf_counter()
        frame = self.begin_frame(scene, camera, tf)
        why = self.fallback(frame)
        if why is not None:
            out = self._cpu_render(scene, camera, tf, rows=rows, cols=cols, progress=progress,
                                   cancel=cancel)
            self.stats = dict(self.cpu.stats, fallback=why)
            return out
        t_setup = self.stats["seconds_setup"]
        r0, r1, c0, c1 = bands.region(frame, rows, cols)
        nr, nc = r1 - r0, c1 - c0
        rgba = np.zeros((nr, nc, 4), np.float32)
        dv = np.zeros((nr, nc, 4), np.float32)
        dv[..., 0] = BG_DEPTH
        step = STEP_ROWS if (progress or cancel) else max(nr, 1)
        cancelled = False

        def draw(a, b):
            out = self._dispatch(frame, (r0 + a, r0 + b), (c0, c1))
            rgba[a:b] = compute.read(out[0])
            dv[a:b] = compute.read(out[1])

        if nr and nc:
            try:
                cancelled = context.run(lambda: bands.draw_bands(nr, step, draw, progress, cancel))
            except NoLists:  # (a camera inside a dense volume): the CPU's leaf walk draws it
                out = self._cpu_render(scene, camera, tf, rows=rows, cols=cols, progress=progress,
                                       cancel=cancel)
                self.stats = dict(self.cpu.stats, fallback=NO_LISTS)
                return out
            self.stats["overflow_tiles"] = self._overflow(scene, camera, tf, rgba, dv, r0, c0)
        self.stats.update(seconds_setup=float(t_setup), seconds_render=float(time.perf_counter() - t0),
                          segments=0.0, cancelled=bool(cancelled), threads=1, gpu=self.renderer)
        self.stats.pop("fallback", None)
        res = bands.passes(scene, rgba, dv[..., 0], dv[..., 1])
        return {k: np.ascontiguousarray(v) for k, v in res.items()}

    def render_texture(self, scene, camera, tf):
        """The whole frame's Combined pass as a GPU texture (call inside a GPU context: view_draw);
        None when this device hands the frame to the CPU (fallback)."""
        frame = self.begin_frame(scene, camera, tf)
        if self.fallback(frame) is not None:
            return None
        try:
            return self._dispatch(frame, (0, frame.height), (0, frame.width))[0]
        except NoLists:
            return None


def register():
    """GPU in kernels.render.devices.device's registry (available_devices lists it where the probe says yes)."""
    from . import probe

    register_device("GPU", GPUDevice, lambda: probe.probe()[0])


register()
