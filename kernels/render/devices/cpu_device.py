"""CPUDevice: numba, parallel over rows, nogil, cached kernels (device.py says what a device does).
Its sync builds what frames draw from on first use (the Gaussians, their per-leaf lists, the
voxel bricks); its begin_frame makes the frame (frame.Frame) from frame_setup's arrays as the
mode's entry in modes.py asks; its render draws bands of rows (bands.py) with launch.render_rows."""
from __future__ import annotations

import dataclasses
import time
from contextlib import contextmanager

import numpy as np

from ...cachedir import set_cache_root
from ..inputs import packing
from ..inputs.accel import add_halo_lists, build_gaussians, build_voxel_accel, gaussian_bounds
from ..inputs.layout import REC_LB, Kind, Shading
from ..scene.objects import RenderScene, same_geometry
from ..scene.splat import SplatGrids
from ..scene.transfer import TransferFunction, resampled
from . import bands, frame_setup, modes
from .device import Device, register_device
from .frame import Frame


class CPUDevice(Device):
    """numba CPU device. ``threads``: numba threads (default all). ``cache_dir``: numba's cache
    (default: kernels.cachedir's rule), if given before the kernels' first import here."""
    name = "CPU"

    def __init__(self, threads=None, cache_dir=None, tile_rows=None, screen_tiles=True):
        if cache_dir:
            set_cache_root(cache_dir)
        from ..cpu import launch  # (compiles or loads cached kernels lazily, per mode)
        from ..cpu import tiles as _cpu_tiles
        self._k = launch
        self._kt = _cpu_tiles
        self.screen_tiles = bool(screen_tiles)  # particles/field: screen tiles, else the leaf walk
        self.threads = threads
        self.tile_rows = tile_rows  # rows per step with progress/cancel (None: see render)
        self._key = None
        self.gacc = None
        self._g_rec = None  # the per-ray test records (render)
        self._grad = None  # lit particles' gradients (_lit_gradients)
        self._sync_count = 0  # geometry version: part of the frame key
        self._frame = None  # the current frame's state (begin_frame)
        self.vacc = None
        self._objects, self._support_k = (), 3.0  # the synced scene's (sync)
        self._splats = SplatGrids()  # splat mode's lattices (splat_scene)
        self.stats = {}
        self._warmed = set()  # (mode, features) of the scenes load_kernels drew

    @property
    def geometry_version(self) -> int:
        """Counts the syncs that changed the geometry: what a frame draws from changes with it."""
        return self._sync_count

    # -- sync -----------------------------------------------------------------------------
    def sync(self, scene: RenderScene) -> None:
        t0 = time.perf_counter()
        scene = self._splats.drawn(scene)
        key = scene.geometry_key()
        if same_geometry(key, self._key):
            self.stats["seconds_sync"] = 0.0
            return
        objs = scene.objects
        self._frame = None
        self._sync_count += 1
        # what a frame draws from is built on its first use (_gaussians, _halo_lists, _voxels): a
        # reference frame needs only the voxel bricks, a screen-tile frame no per-leaf lists
        self._objects, self._support_k = objs, float(scene.support_k)
        self.gacc = self.vacc = None
        self._g_rec = self._grad = None
        if modes.spec(scene.mode).draws == modes.VOXELS:  # what this mode draws from; the others' on demand
            self._voxels()
        else:
            self._gaussians()
        # per-object world coordinate ranges (level-set colouring) and voxel sizes
        n = len(objs)
        self.w2i = np.zeros((n, 4, 4))
        self.coord_range = np.zeros((n, 3, 2))
        self.voxel_world = np.ones(n)
        self.index_box = np.zeros((n, 2, 3))  # the lit volumes' shadow grids span these
        for k, o in enumerate(objs):
            m = o.matrix_world
            self.w2i[k] = np.linalg.inv(m)
            self.voxel_world[k] = float(np.prod(np.linalg.norm(m[:3, :3], axis=0))) ** (1.0 / 3.0)
            if o.grid is not None:  # drawn from its voxels: their box, whichever LOD it holds
                lo = np.asarray(o.grid.bbox_min, np.float64)
                hi = np.asarray(o.grid.bbox_max, np.float64)
                self.index_box[k] = lo, hi
            elif o.gaussians is not None:  # centres; the supports' box
                (lo, hi), self.index_box[k] = (
                    self.gacc.g_bounds[k] if self.gacc is not None
                    else gaussian_bounds(o.gaussians, scene.support_k))
            else:
                lo = hi = np.zeros(3)
                self.index_box[k] = lo, hi
            corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                for z in (lo[2], hi[2])])
            wc = corners @ m.T
            self.coord_range[k, :, 0] = wc[:, :3].min(0)
            self.coord_range[k, :, 1] = wc[:, :3].max(0)
        self._key = key
        self.stats["seconds_sync"] = time.perf_counter() - t0

    def _gaussians(self):
        """The synced Gaussians (accel.build_gaussians), built on the first frame that draws them."""
        if self.gacc is None:
            self.gacc = build_gaussians(self._objects, self._support_k)
        return self.gacc

    def _lit_gradients(self):
        """Lit particles' Gaussians.grad (cpu.lit.lit_gradients), once per sync: field weights
        (value x amplitude) do not change with the transfer function."""
        if self._grad is None:
            from ..cpu.lit import lit_gradients

            A = self._gaussians()
            fw = np.nan_to_num(A.g_val) * A.g_amp
            for k, o in enumerate(self._objects):
                if o.is_level_set:  # only volumes are lit
                    fw[A.g_first[k]:A.g_first[k + 1]] = 0.0
            self._grad = lit_gradients(A.g_mu, A.g_inv, fw, A.g_first, self._support_k)
        return self._grad

    def color_values(self):
        """The synced Gaussians' second-grid values in the frames' order (NaN: none), or None
        when the scene drew no Gaussians."""
        return None if self.gacc is None else self.gacc.g_cval

    def _halo_lists(self):
        """The Gaussians with their per-leaf lists (the leaf walk, paper mode, surface normals)."""
        acc = self._gaussians()
        if not acc.has_lists:
            add_halo_lists(acc, self._support_k)
        return acc

    def _voxels(self):
        """The reference mode's voxel bricks, built on its first frame."""
        if self.vacc is None and any(o.grid is not None for o in self._objects):
            self.vacc = build_voxel_accel(self._objects)
        return self.vacc

    # -- frame ----------------------------------------------------------------------------
    def _prepare(self, spec, scene, tf):
        """The frame's transfer functions and the packed per-object and transfer tables."""
        tfs, obj_tf = packing.transfer_functions(scene, tf, resampled)
        obj_ctf = packing.color_functions(scene, tfs, resampled)
        ref = (self._gaussians().obj_ref if spec.draws == modes.GAUSSIANS
               else np.zeros((max(1, len(scene.objects)), 3)))
        objects = packing.pack_objects(scene, obj_tf, self.w2i, self.coord_range, self.voxel_world, ref,
                                       obj_ctf if (obj_ctf >= 0).any() else None)
        return tfs, objects, packing.pack_transfer(scene, tfs)

    def _screen_tiles(self, mode, scene, camera, g_w, elsewhere=False):
        """This device's screen-tile lists for the frame (frame_setup.screen_tiles)."""
        return frame_setup.screen_tiles(modes.spec(mode), scene, camera, self.gacc, g_w,
                                        self.screen_tiles, elsewhere)

    def _frame_key(self, mode, scene, camera, prep, lists_elsewhere):
        """What a frame's state depends on besides the geometry (sync count): mode, tile switch,
        camera, settings, shading (lit, shadows: the shadow grids), transfer-function tables."""
        _, objects, transfer = prep
        tables = (objects.tf, transfer.lut, transfer.par, objects.kind, objects.ls, objects.step,
                  objects.clip, objects.lit, transfer.lights, transfer.settings, objects.ctf,
                  objects.cbg, objects.sdf)
        return (self._sync_count, mode, bool(self.screen_tiles), lists_elsewhere,
                camera.packed().tobytes()) + tuple(
            np.ascontiguousarray(a).tobytes() for a in tables)

    def begin_frame(self, scene, camera, tf, *, lists_elsewhere=False):
        """Device.begin_frame; ``lists_elsewhere``: the caller builds the Gaussians' screen-tile
        lists itself (a GPU device): the frame has none and says so (Frame.tiles_elsewhere)."""
        if scene.mode == "splat" or self.gacc is None or not same_geometry(scene.geometry_key(), self._key):
            self.sync(scene)  # splat: the key is its lattices' (made there, timed as the sync)
        scene = self._splats.drawn(scene)
        spec = modes.spec(scene.mode)
        prep = self._prepare(spec, scene, tf)
        mode = modes.frame_mode(spec.mode, surfaces=bool((prep[1].kind == Kind.SURFACE).any()))
        key = self._frame_key(mode, scene, camera, prep, bool(lists_elsewhere))
        if self._frame is not None and self._frame.key == key:
            self.stats["seconds_setup"] = 0.0
            return self._frame
        self._frame = None  # g_rec is rewritten below: the old frame's state is gone
        t0 = time.perf_counter()
        with self._thread_count(scene):
            frame = self._build_frame(modes.spec(mode), scene, camera, prep, bool(lists_elsewhere))
        frame.key = key
        self._frame = frame
        self.stats["seconds_setup"] = time.perf_counter() - t0
        return frame

    def end_frame(self):
        self._frame = None

    def load_kernels(self, modes=None, *, scene=None, camera=None, tf=None,
                     variants=("plain", "general")):
        """Device.load_kernels: a frame of ``scene`` (with ``camera``, ``tf``), drawn at 8x8 on this
        device (its sync is kept for the frame that follows), or, without a scene, each of
        ``modes`` (names; None: every mode) on small synthetic objects. Each mode compiles only its
        own kernels (cpu.per_mode); a scene's frame also those of the lights, clipping, colour
        grids and surfaces it uses. ``variants``: the synthetic scenes' kinds, each with band
        kernels of its own (cpu.launch.kernel_code): "plain" (one fog volume; unlit Gaussians),
        "general" (two volumes; lit Gaussians)."""
        t0 = time.perf_counter()
        if scene is not None:
            key = (scene.mode, scene.features())
            if key in self._warmed:
                return 0.0
            small = dataclasses.replace(camera, width=min(8, camera.width), height=min(8, camera.height))
            self.render(scene, small, tf or TransferFunction.from_colormap("grayscale", 0.0, 1.0))
            self._warmed.add(key)
            return time.perf_counter() - t0
        from ..scene.synthetic import warm_objects
        from . import modes as table  # (the argument is named modes)

        tiny = CPUDevice(threads=self.threads)  # a throwaway: this device's state stays as it is
        objs, grid_objs, cam = warm_objects()
        gray = TransferFunction.from_colormap("grayscale", 0.0, 1.0)
        for mode in modes or [m.name.lower() for m in table.SPECS]:
            voxels = table.spec(mode).draws == table.VOXELS and table.spec(mode).drawn_as is None
            for variant in variants:
                if voxels:
                    scene_objs = grid_objs * (2 if variant == "general" else 1)
                elif variant == "general":
                    scene_objs = [dataclasses.replace(o, shading="lit") for o in objs]
                else:
                    scene_objs = objs
                tiny.render(RenderScene(scene_objs, mode=mode), cam, gray)
        return time.perf_counter() - t0

    def _build_frame(self, spec, scene, camera, prep, lists_elsewhere):
        tfs, objects, transfer = prep
        obj_tf, obj_kind = objects.tf, objects.kind
        tiles, t_lb = packing.NO_TILES, None
        voxels = spec.draws == modes.VOXELS
        elsewhere = False
        if voxels:
            acc = self._voxels()
            if acc is None:
                raise ValueError("reference mode needs the source grids (RenderObject.grid)")
            for k, o in enumerate(scene.objects):
                if objects.ctf[k] >= 0 and o.color_grid is None:
                    raise ValueError(f"reference mode: {o.name or 'an object'} is coloured by a "
                                     "second grid but has none (RenderObject.color_grid)")
            gauss = packing.empty_gaussians()
        else:
            acc = self._gaussians()
            colored = (objects.ctf >= 0).any()
            g_w, g_col = frame_setup.gauss_weights(acc, spec.field, tfs, obj_tf, obj_kind, objects.ls,
                                                   objects.ctf if colored else None)
            if self._g_rec is None or self._g_rec.shape[0] != acc.g_mu.shape[0]:
                self._g_rec = packing.test_records(acc)
            lit = spec.lights == modes.CENTRES and (objects.lit != 0).any()
            gauss = packing.pack_gaussians(acc, g_w, g_col, self._g_rec,
                                           frame_setup.color_weights(acc, objects) if spec.field else None,
                                           self._lit_gradients() if lit else None)
            *tiles, t_lb = self._screen_tiles(spec.mode, scene, camera, gauss.w, lists_elsewhere)
            if t_lb is not None:
                gauss.rec[:, REC_LB] = t_lb  # read with the rest of the row when a pixel tests the Gaussian
            if t_lb is None or (obj_kind == Kind.SURFACE).any() or (objects.lit == Shading.LIT_SHADOWS).any():
                acc = self._halo_lists()  # the leaf walk, surface normals, shadow rays
            elsewhere = lists_elsewhere and acc.g_mu.shape[0] > 0
        cell_skip = frame_setup.cell_skip(spec, acc, gauss.w, tfs, obj_tf, obj_kind)
        if spec.leaf_tiles and acc.n_cells:  # which screen tiles have leaves to walk
            tiles = self._kt.leaf_tiles(camera.packed(), objects.w2i, acc.cell_xyz, acc.cell_obj, cell_skip)
        accel = packing.pack_accel(acc, cell_skip, tuple(tiles), voxels=voxels, xfer=(obj_tf, transfer))
        if (objects.lit == Shading.LIT_SHADOWS).any():
            wext = np.zeros(1) if voxels else frame_setup.gauss_weights(
                self.gacc, False, tfs, objects.tf, objects.kind, objects.ls)[0]  # the particles' extinction
            objects = frame_setup.shadow_grids(voxels, scene, self.index_box, objects, gauss, wext, accel,
                                               transfer)
        return Frame(spec.mode, camera.packed(), camera.width, camera.height, gauss, objects, accel,
                     transfer, tiles_elsewhere=bool(elsewhere))

    # -- render ---------------------------------------------------------------------------
    def band_rows(self, scene):
        # The kernels spread a band's screen-tile rows over the threads in static chunks, so a
        # band of a few rows per thread waits on its slowest one (paper mode at two per thread:
        # F12 1.2-1.75x one call); eight per thread keep the threads busy.
        return 8 * self._kt.TILE * self._num_threads(scene), self._kt.TILE

    def _num_threads(self, scene):
        """The numba threads a frame of this scene runs on."""
        import numba

        threads = scene.threads if scene.threads else self.threads
        if not threads:
            return numba.get_num_threads()
        return max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS))

    @contextmanager
    def _thread_count(self, scene):
        import numba

        old = numba.get_num_threads()
        numba.set_num_threads(self._num_threads(scene))
        try:
            yield numba.get_num_threads()
        finally:
            numba.set_num_threads(old)

    def render(self, scene, camera, tf, *, rows=None, cols=None, progress=None, cancel=None):
        t0 = time.perf_counter()
        frame = self.begin_frame(scene, camera, tf)
        t_setup = self.stats["seconds_setup"]
        r0, r1, c0, c1 = bands.region(frame, rows, cols)
        nr = r1 - r0
        # the kernels write float32 passes (rounded from their float64 as astype would); rows a
        # cancel leaves undrawn stay transparent
        rgba, depth, value = bands.blank(nr, c1 - c0)
        segs = np.zeros(nr)
        code = self._k.kernel_code(frame.mode, frame.objects, frame.accel, frame.transfer)
        with self._thread_count(scene) as threads:

            def draw(a, b):
                self._k.render_rows(code, frame.cam, r0 + a, r0 + b, c0, c1,
                                    frame.gauss, frame.objects, frame.accel, frame.transfer,
                                    packing.Output(rgba[a:b], depth[a:b], value[a:b], segs[a:b]),
                                    threads)

            # with progress/cancel: steps of tile_rows, by default the rows band_rows asks of a
            # call (fewer per thread leave threads idle on the slowest row: see band_rows)
            step = self.tile_rows or self.band_rows(scene)[0]
            step = max(1, int(step)) if (progress or cancel) else nr
            cancelled = bands.draw_bands(nr, step, draw, progress, cancel)
        self.stats.update(seconds_setup=float(t_setup), seconds_render=float(time.perf_counter() - t0),
                          segments=float(segs.sum()), cancelled=bool(cancelled), threads=int(threads))
        return bands.passes(scene, rgba, depth, value)


register_device("CPU", CPUDevice)
