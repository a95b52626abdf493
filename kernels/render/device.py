"""Render devices, in the manner of Cycles: the engine talks to a ``Device``; ``sync(scene)``
uploads/builds acceleration data once per scene change; ``begin_frame(scene, camera, tf)`` does
the per-frame set-up (weights, colours, empty-space skips, screen-tile lists) once per frame;
``render(...)`` draws the whole frame or a region of it (a band of rows, a render border) and
reuses the frame's set-up while camera, transfer function and settings are unchanged;
``end_frame()`` frees it; splat mode is drawn as the reference scene splat_scene makes. CPUDevice:
numba, parallel over rows, nogil, cached kernels. The GPU device (gaussvdb_addon/gpu/device.py:
compute shaders on Blender's gpu module) implements the same methods over a CPUDevice's frame
set-up and registers itself in ``_REGISTRY`` and ``_USABLE``.

Passes: 'Combined' float32 (H, W, 4), linear, premultiplied alpha, row 0 = bottom;
'Depth' float32 (H, W): world distance along the ray where the accumulated opacity reaches 0.5
(1e10 where it never does); 'Value' float32 (H, W): opacity-weighted mean data value (0 where
nothing was hit; level sets contribute no value).
"""
from __future__ import annotations

import time
from abc import ABC, abstractmethod
from contextlib import contextmanager

import numpy as np

from ..cachedir import set_cache_root
from . import packing
from .accel import add_halo_lists, build_gaussians, build_voxel_accel, gaussian_bounds, tile_budget
from .layout import BG_DEPTH, LS_COLOR, LS_CONST, LS_PLANE, LS_RANGE, REC_LB, Kind, Shading
from .scene import Mode, RenderScene, same_geometry
from .splat_scene import SplatGrids
from .transfer import TransferFunction, range_alpha, resampled

MAX_TILE_ENTRIES = 24_000_000  # screen-tile list entries per frame (id + pixel mask: 288 MB)


class Device(ABC):
    name = "abstract"

    @abstractmethod
    def sync(self, scene: RenderScene) -> None:
        """Build/upload the scene's geometry (objects, placement, support radius): once per key."""

    @abstractmethod
    def begin_frame(self, scene: RenderScene, camera, tf: TransferFunction):
        """The per-frame set-up for this camera, TF and settings (syncs first if the geometry
        changed); a no-op returning the kept state when they equal the last frame's."""

    def end_frame(self) -> None:
        """Drop the frame's set-up (memory); the next render() redoes it."""

    def load_kernels(self) -> float:
        """Load (or compile) the kernels once per process (seconds): first frames time only themselves."""
        return 0.0

    def band_rows(self, scene: RenderScene) -> tuple:
        """(fewest, multiple): rows a render() call should cover to keep the device busy, and the
        row multiple bands start on."""
        return 1, 1

    @abstractmethod
    def render(self, scene: RenderScene, camera, tf: TransferFunction, *, rows=None, cols=None,
               progress=None, cancel=None) -> dict:
        """Render image rows ``rows = (row0, row1)`` and columns ``cols = (col0, col1)``
        (default all; pixels are exactly those of the whole frame) and return the passes of that
        region, (row1 - row0, col1 - col0). Calls begin_frame. ``progress(fraction)`` is called
        and ``cancel()`` polled between steps of rows; on cancel the rows not yet drawn stay
        transparent and ``self.stats['cancelled']`` is True. ``stats``: seconds_sync,
        seconds_setup (this call's frame set-up, 0 when reused) and seconds_render (the whole
        call, set-up included) as floats, segments (float), cancelled (bool), threads (int)."""


class CPUDevice(Device):
    """numba CPU device. ``threads``: numba threads (default all). ``cache_dir``: numba's cache
    (default: kernels.cachedir's rule), if given before the kernels' first import here."""
    name = "CPU"

    def __init__(self, threads=None, cache_dir=None, tile_rows=None, screen_tiles=True):
        if cache_dir:
            set_cache_root(cache_dir)
        from . import _cpu, _cpu_tiles  # noqa: F401  (compiles or loads cached kernels lazily)
        self._k = _cpu
        self._kt = _cpu_tiles
        self.screen_tiles = bool(screen_tiles)  # particles/field: screen tiles, else the leaf walk
        self.tiles_elsewhere = False  # a GPU device builds the frame's screen-tile lists itself
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
        if scene.mode == "reference":  # what this mode draws from; the other mode's on demand
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
            bounds = (None if o.gaussians is None else self.gacc.g_bounds[k] if self.gacc is not None
                      else gaussian_bounds(o.gaussians, scene.support_k))
            if bounds is not None:
                (lo, hi), self.index_box[k] = bounds  # centres; the supports' box
            else:
                if o.grid is not None:
                    lo = np.asarray(o.grid.bbox_min, np.float64)
                    hi = np.asarray(o.grid.bbox_max, np.float64)
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
        """Lit particles' Gaussians.grad (_cpu_lit.lit_gradients), once per sync: field weights
        (value x amplitude) do not change with the transfer function."""
        if self._grad is None:
            from ._cpu_lit import lit_gradients

            A = self._gaussians()
            fw = np.nan_to_num(A.g_val) * A.g_amp
            for k, o in enumerate(self._objects):
                if o.is_level_set:  # only volumes are lit
                    fw[A.g_first[k]:A.g_first[k + 1]] = 0.0
            self._grad = lit_gradients(A.g_mu, A.g_inv, fw, A.g_first, self._support_k)
        return self._grad

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

    # -- render ---------------------------------------------------------------------------
    def _prepare(self, scene, tf):
        """The frame's transfer functions and the packed per-object and transfer tables."""
        tfs, obj_tf = packing.transfer_functions(scene, tf, resampled)
        obj_ctf = packing.color_functions(scene, tfs, resampled)
        ref = self._gaussians().obj_ref if scene.mode != "reference" else np.zeros((max(1, len(scene.objects)), 3))
        objects = packing.pack_objects(scene, obj_tf, self.w2i, self.coord_range, self.voxel_world, ref,
                                       obj_ctf if (obj_ctf >= 0).any() else None)
        return tfs, objects, packing.pack_transfer(scene, tfs)

    def _gauss_weights(self, mode, tfs, obj_tf, obj_kind, obj_ls, obj_ctf=None):
        """Per-Gaussian extinction scale (particles/paper: density * alpha(v) * a; level sets:
        density * a) and colour (a volume coloured by a second grid: its colour map at the
        second grid's value), or field weights (v * a; level sets: a)."""
        A = self.gacc
        m = A.g_val.shape[0]
        w = np.zeros(m)
        col = np.zeros((m, 3))
        for k in range(len(obj_tf)):
            s = slice(A.g_first[k], A.g_first[k + 1])
            if s.stop == s.start:
                continue
            t = tfs[obj_tf[k]]
            v, a = A.g_val[s], A.g_amp[s]
            if mode == Mode.FIELD:
                w[s] = a if obj_kind[k] else np.nan_to_num(v) * a
                continue
            if obj_kind[k]:
                w[s] = t.density * a
                ls = obj_ls[k]
                if ls[LS_CONST] > 0.5:
                    col[s] = ls[LS_COLOR:LS_COLOR + 3]
                else:
                    c = A.g_mu[s] @ ls[LS_PLANE:LS_PLANE + 3] + ls[LS_PLANE + 3]
                    lo, hi = ls[LS_RANGE], ls[LS_RANGE + 1]
                    x = (c - lo) / (hi - lo) if hi > lo else np.full(c.shape, 0.5)
                    self._k.lut_rows(t.lut, x, col[s])
            else:
                rgba = np.empty((v.shape[0], 4))
                self._k.lut_rows(t.lut, np.where(np.isnan(v), np.nan, t.normalize(v)), rgba)
                w[s] = t.density * rgba[:, 3] * a
                col[s] = rgba[:, :3]
                if obj_ctf is not None and obj_ctf[k] >= 0:
                    ct, cv = tfs[obj_ctf[k]], A.g_cval[s]
                    self._k.lut_rows(ct.lut, np.where(np.isnan(cv), np.nan, ct.normalize(cv)), rgba)
                    col[s] = rgba[:, :3]
        return w, col

    def _color_weights(self, objects):
        """The second mixture's field weights (second value x amplitude): the volumes coloured by a
        grid (less its background objects.cbg, the mixture where no Gaussian is, as the reference's
        voxels), the surfaces' signed distances (Objects.sdf); zero elsewhere; None if none."""
        sel = np.flatnonzero((objects.ctf >= 0) | (objects.sdf != 0))
        if not sel.size:
            return None
        A = self.gacc
        cw = np.zeros(A.g_val.shape[0])
        for k in sel:
            s = slice(A.g_first[k], A.g_first[k + 1])
            cv = A.g_cval[s]
            cw[s] = np.where(np.isnan(cv), 0.0, cv - objects.cbg[k] * (objects.ctf[k] >= 0)) * A.g_amp[s]
        return cw

    def _cell_skip(self, mode, acc, w, tfs, obj_tf, obj_kind):
        c = acc.n_cells
        if c == 0:
            return np.zeros(1, np.uint8)
        if mode == Mode.REFERENCE:
            skip = np.zeros(c, np.uint8)
            cell_obj = acc.cell_obj
            for k in range(len(obj_tf)):
                sel = cell_obj == k
                t = tfs[obj_tf[k]]
                if obj_kind[k] == Kind.SURFACE:
                    continue
                if obj_kind[k]:
                    skip[sel] = t.density <= 0
                else:
                    skip[sel] = (range_alpha(t, acc.brick_lo[sel], acc.brick_hi[sel]) <= 0) | (t.density <= 0)
            return skip
        items = acc.cell_items
        starts = acc.cell_start[:-1]
        if mode != Mode.FIELD:
            mx = np.maximum.reduceat(np.abs(w[items]), starts)
            return (mx <= 0).astype(np.uint8)
        # field: bound the summed field per cell: [sum of negative weights, sum of positive]
        wi = w[items]
        lo = np.add.reduceat(np.minimum(wi, 0.0), starts)
        hi = np.add.reduceat(np.maximum(wi, 0.0), starts)
        cobj = self.gacc.g_obj[items[starts]]
        skip = np.zeros(c, np.uint8)
        for k in range(len(obj_tf)):
            sel = cobj == k
            t = tfs[obj_tf[k]]
            if obj_kind[k] == Kind.SURFACE:
                skip[sel] = hi[sel] <= 0
            elif obj_kind[k]:
                skip[sel] = (t.density <= 0) | (hi[sel] <= 0)
            else:
                skip[sel] = (range_alpha(t, lo[sel], hi[sel]) <= 0) | (t.density <= 0)
        return skip

    def _screen_tiles(self, mode, scene, camera, g_w):
        """Per-frame screen-tile lists for the particles and field modes (_cpu_tiles): starts,
        ids, pixel masks and each Gaussian's entry bound; or empty arrays (the kernels then walk
        the leaf hierarchy) when switched off or when the lists would pass accel.tile_budget (a
        camera inside a dense volume puts every support near the eye plane in every tile)."""
        none = packing.NO_TILES + (None,)
        A = self.gacc
        m = A.g_mu.shape[0]
        if not self.screen_tiles or m == 0 or mode > Mode.FIELD:
            return none
        if self.tiles_elsewhere:  # no lists, no leaf walk: this frame is only drawn elsewhere
            return packing.NO_TILES + (np.zeros(m),)
        i2w = [np.asarray(o.matrix_world, np.float64) for o in scene.objects]
        tiles = self._kt.screen_tiles(camera.packed(), i2w, A.g_mu, A.g_inv, A.g_obj, g_w,
                                      float(scene.support_k), tile_budget(m, MAX_TILE_ENTRIES))
        return none if tiles is None else tiles

    def _frame_key(self, mode, scene, camera, prep):
        """What a frame's state depends on besides the geometry (sync count): mode, tile switch,
        camera, settings, shading (lit, shadows: the shadow grids), transfer-function tables."""
        _, objects, transfer = prep
        tables = (objects.tf, transfer.lut, transfer.par, objects.kind, objects.ls, objects.step,
                  objects.clip, objects.lit, transfer.lights, transfer.settings, objects.ctf,
                  objects.cbg, objects.sdf)
        return (self._sync_count, mode, bool(self.screen_tiles), self.tiles_elsewhere,
                camera.packed().tobytes()) + tuple(
            np.ascontiguousarray(a).tobytes() for a in tables)

    def begin_frame(self, scene, camera, tf):
        if scene.mode == "splat" or self.gacc is None or not same_geometry(scene.geometry_key(), self._key):
            self.sync(scene)  # splat: the key is its lattices' (made there, timed as the sync)
        scene = self._splats.drawn(scene)
        mode = Mode.of(scene.mode)
        prep = self._prepare(scene, tf)
        if mode == Mode.PARTICLES and (prep[1].kind == Kind.SURFACE).any():
            # surfaces are found by the field sampler: such a frame draws as field
            mode = Mode.FIELD
        key = self._frame_key(mode, scene, camera, prep)
        if self._frame is not None and self._frame.key == key:
            self.stats["seconds_setup"] = 0.0
            return self._frame
        self._frame = None  # g_rec is rewritten below: the old frame's state is gone
        t0 = time.perf_counter()
        with self._thread_count(scene):
            frame = self._build_frame(mode, scene, camera, prep)
        frame.key = key
        self._frame = frame
        self.stats["seconds_setup"] = time.perf_counter() - t0
        return frame

    def end_frame(self):
        self._frame = None

    def load_kernels(self):
        from .synthetic import warm_objects

        t0 = time.perf_counter()
        tiny = CPUDevice(threads=self.threads)  # a throwaway: this device's state stays as it is
        objs, cam = warm_objects()
        for mode in ("particles", "splat"):  # splat: its lattices' and the voxel bricks' kernels too
            tiny.render(RenderScene(objs, mode=mode), cam, TransferFunction.from_colormap("grayscale", 0.0, 1.0))
        return time.perf_counter() - t0

    def _build_frame(self, mode, scene, camera, prep):
        tfs, objects, transfer = prep
        obj_tf, obj_kind = objects.tf, objects.kind
        tiles, t_lb = packing.NO_TILES, None
        if mode == Mode.REFERENCE:
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
            g_w, g_col = self._gauss_weights(mode, tfs, obj_tf, obj_kind, objects.ls,
                                             objects.ctf if (objects.ctf >= 0).any() else None)
            if self._g_rec is None or self._g_rec.shape[0] != acc.g_mu.shape[0]:
                self._g_rec = packing.test_records(acc)
            lit = mode == Mode.PARTICLES and (objects.lit != 0).any()
            gauss = packing.pack_gaussians(acc, g_w, g_col, self._g_rec,
                                           self._color_weights(objects) if mode == Mode.FIELD else None,
                                           self._lit_gradients() if lit else None)
            *tiles, t_lb = self._screen_tiles(mode, scene, camera, gauss.w)
            if t_lb is not None:
                gauss.rec[:, REC_LB] = t_lb  # read with the rest of the row when a pixel tests the Gaussian
            if t_lb is None or (obj_kind == Kind.SURFACE).any() or (objects.lit == Shading.LIT_SHADOWS).any():
                acc = self._halo_lists()  # the leaf walk, surface normals, shadow rays
        cell_skip = self._cell_skip(mode, acc, gauss.w, tfs, obj_tf, obj_kind)
        if mode == Mode.REFERENCE and acc.n_cells:  # which screen tiles have leaves to walk
            tiles = self._kt.leaf_tiles(camera.packed(), objects.w2i, acc.cell_xyz, acc.cell_obj, cell_skip)
        accel = packing.pack_accel(acc, cell_skip, tuple(tiles), voxels=mode == Mode.REFERENCE,
                                   xfer=(obj_tf, transfer))
        if (objects.lit == Shading.LIT_SHADOWS).any():
            objects = self._shadow_grids(mode, scene, tfs, objects, gauss, accel, transfer)
        return _Frame(mode, camera.packed(), camera.width, camera.height, gauss, objects, accel,
                      transfer)

    def _shadow_grids(self, mode, scene, tfs, objects, gauss, accel, transfer):
        """The shadowed lit volumes' grids of optical depth towards each light (_cpu_lit): points
        SHADOW_POINTS along each object's longest index axis, shadow rays through the voxels
        (reference) or the Gaussians with the particles' extinction weights (closed form)."""
        from . import _cpu_lit

        grid, pts, owner = _cpu_lit.shadow_points(self.index_box, objects.lit, len(scene.objects),
                                                  transfer.lights.shape[0])
        nl = transfer.lights.shape[0]
        voxels = mode == Mode.REFERENCE
        wext = np.zeros(1) if voxels else self._gauss_weights(Mode.PARTICLES, tfs, objects.tf,
                                                              objects.kind, objects.ls)[0]
        tau = np.zeros((pts.shape[0], nl))
        i2w = np.stack([np.asarray(o.matrix_world, np.float64) for o in scene.objects])
        with self._thread_count(scene):
            _cpu_lit.shadow_grid(voxels, owner, pts, i2w, gauss, wext, objects, accel, transfer, tau)
        return objects._replace(sh_grid=grid, sh_tau=tau.ravel())

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
        r0, r1, c0, c1 = region(frame, rows, cols)
        nr, nc = r1 - r0, c1 - c0
        # the kernels write float32 passes (rounded from their float64 as astype would); rows a
        # cancel leaves undrawn stay transparent
        rgba = np.zeros((nr, nc, 4), np.float32)
        depth = np.full((nr, nc), BG_DEPTH, np.float32)
        value = np.zeros((nr, nc), np.float32)
        segs = np.zeros(nr)
        cancelled = False
        with self._thread_count(scene) as threads:
            # with progress/cancel: steps of tile_rows, by default the rows band_rows asks of a
            # call (fewer per thread leave threads idle on the slowest row: see band_rows)
            step = self.tile_rows or self.band_rows(scene)[0]
            step = max(1, int(step)) if (progress or cancel) else nr
            a = 0
            while a < nr:
                if cancel is not None and cancel():
                    cancelled = True
                    break
                b = min(nr, a + step)
                self._k.render_rows(int(frame.mode), frame.cam, r0 + a, r0 + b, c0, c1,
                                    frame.gauss, frame.objects, frame.accel, frame.transfer,
                                    packing.Output(rgba[a:b], depth[a:b], value[a:b], segs[a:b]),
                                    threads)
                a = b
                if progress is not None:
                    progress(a / nr)
        self.stats.update(seconds_setup=float(t_setup), seconds_render=float(time.perf_counter() - t0),
                          segments=float(segs.sum()), cancelled=bool(cancelled), threads=int(threads))
        out = {"Combined": rgba}
        if "Depth" in scene.passes:
            out["Depth"] = depth
        if "Value" in scene.passes:
            out["Value"] = value
        return out


def region(frame, rows, cols):
    """(row0, row1, col0, col1) of a render() call's rows and cols (None: all) in the frame."""
    r0, r1 = (0, frame.height) if rows is None else (int(rows[0]), int(rows[1]))
    c0, c1 = (0, frame.width) if cols is None else (int(cols[0]), int(cols[1]))
    if not (0 <= r0 <= r1 <= frame.height and 0 <= c0 <= c1 <= frame.width):
        raise ValueError(f"rows {r0}..{r1} / columns {c0}..{c1} outside the "
                         f"{frame.width}x{frame.height} image")
    return r0, r1, c0, c1


class _Frame:
    """A frame's state from begin_frame: the kernels' inputs (packing's groups: this frame's
    weights, colours, cell skips, screen-tile lists), the packed camera and its key."""

    def __init__(self, mode, cam, width, height, gauss, objects, accel, transfer):
        self.mode, self.cam, self.width, self.height = mode, cam, width, height
        self.gauss, self.objects, self.accel, self.transfer = gauss, objects, accel, transfer
        self.key = None


_REGISTRY = {"CPU": CPUDevice}
_USABLE = {}  # name -> callable: whether this machine can run that device (the GPU's probe)


def available_devices():
    """Names of the devices usable here (a GPU device adds itself to _REGISTRY, its check to _USABLE)."""
    return [n for n in _REGISTRY if n not in _USABLE or _USABLE[n]()]


def get_device(name="CPU", **kw) -> Device:
    try:
        return _REGISTRY[name](**kw)
    except KeyError:
        raise ValueError(f"unknown device {name!r}; available: {available_devices()}") from None
