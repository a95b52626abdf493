"""Rendered viewport shading for GAUSSVDB: a worker thread refines the image progressively.

With the GPU device (Scene.gaussvdb.device) there is no worker: view_draw dispatches the compute
shader into a texture (again only when the view or scene changed) and draws it into the region.
``view_update`` feeds depsgraph updates to a SceneSync (no update: nothing happens);
``view_draw`` turns the region's matrices into a kernel Camera, restarts the worker when the
view or scene changed, and draws the latest image with a few ``gpu`` calls. The worker renders
at 1/8, 1/4, 1/2 and full resolution (the objects' Viewport LOD); while the view keeps changing
only the 1/8 level is drawn, the finer levels follow once the view has rested ``REST_SECONDS``.
Everything except drawing is plain Python, tested headless (``ProgressiveSchedule``; the
camera conversion is camera.py's, shared with F12).
"""

import threading
import time

import numpy as np

from . import devices
from .camera import camera_from_region, camera_key, scaled_camera

LEVELS = (8, 4, 2, 1)  # downscale factors, coarse to fine
REST_SECONDS = 0.15


def draw_texture(tex, width, height, engine=None, scene=None):
    """A premultiplied image texture over the region (width x height), through the engine's
    display-space shader when given (view_draw), else as it is."""
    import gpu
    from gpu_extras.presets import draw_texture_2d

    gpu.state.blend_set("ALPHA_PREMULT")
    if engine is not None:
        engine.bind_display_space_shader(scene)
    draw_texture_2d(tex, (0, 0), width, height)
    if engine is not None:
        engine.unbind_display_space_shader()
    gpu.state.blend_set("NONE")


# -- scheduling -----------------------------------------------------------------------------------
class ProgressiveSchedule:
    """Which level to render next. ``restart(now)`` on any change; ``next(now)`` returns the
    factor to render, or None (done, or waiting for the view to rest). Level 0 always runs
    at once; finer levels only once ``rest`` seconds passed since the last restart."""

    def __init__(self, levels=LEVELS, rest=REST_SECONDS, clock=time.monotonic):
        self.levels = tuple(levels)
        self.rest = rest
        self.clock = clock
        self.generation = 0
        self.done = len(self.levels)
        self.changed_at = -1e9

    def restart(self, now=None):
        self.generation += 1
        self.done = 0
        self.changed_at = self.clock() if now is None else now

    def next(self, now=None):
        now = self.clock() if now is None else now
        if self.done >= len(self.levels):
            return None
        if self.done > 0 and now - self.changed_at < self.rest:
            return None
        return self.levels[self.done]

    def wait_time(self, now=None):
        """Seconds until next() may return a level (0: now; None: nothing left)."""
        now = self.clock() if now is None else now
        if self.done >= len(self.levels):
            return None
        if self.done == 0:
            return 0.0
        return max(0.0, self.rest - (now - self.changed_at))

    def finished(self, factor, generation):
        if generation == self.generation and self.done < len(self.levels) \
                and self.levels[self.done] == factor:
            self.done += 1

    @property
    def converged(self):
        return self.done >= len(self.levels)


# -- the session ----------------------------------------------------------------------------------
class ViewportSession:
    def __init__(self, engine):
        from .scene_sync import SceneSync

        self.engine = engine
        self.sync = SceneSync(viewport=True)
        self.schedule = ProgressiveSchedule()
        self.lock = threading.Condition()
        self.job = None  # (generation, rscene, camera, tf)
        self.image = None  # (generation, factor, rgba (h, w, 4) float32)
        self.cam_key = None
        self.scene_version = 0
        self.error = None
        self.thread = None
        self.stopping = False
        self.device = None
        self.texture = None
        self.texture_key = None
        self.tf = None  # the scene transfer function of the current job (the legend shows it)
        self.legend_cache = {}
        self.frame = None
        self.gpu = None  # (GPUDevice, drawn key, its texture) with the GPU device

    # -- called from Blender's main thread ---------------------------------------------------
    def update(self, context, depsgraph):
        first = self.sync.scene is None
        changed = self.sync.note_updates(depsgraph.updates) or first
        frame = depsgraph.scene.frame_current  # sequence objects follow the timeline
        if frame != self.frame:
            self.frame = frame
            self.sync.dirty = changed = True
        if not changed:
            return False
        self.sync.sync(depsgraph)
        self.scene_version += 1
        self.cam_key = None  # next draw restarts the worker
        return True

    def submit(self, rscene, camera, tf):
        with self.lock:
            self.schedule.restart()
            self.job = (self.schedule.generation, rscene, camera, tf)
            self.error = None
            if self.thread is None or not self.thread.is_alive():
                self.stopping = False
                self.thread = threading.Thread(target=self._worker, name="GaussVDB viewport",
                                               daemon=True)
                self.thread.start()
            self.lock.notify_all()

    def draw(self, context, depsgraph):
        region, rd = context.region, context.region_data
        cam = camera_from_region(region, rd)
        key = (camera_key(cam), self.scene_version)
        if depsgraph.scene.gaussvdb.device == "GPU" and self._draw_gpu(depsgraph, cam, key, region):
            return
        if key != self.cam_key:
            self.cam_key = key
            if self.sync.scene is None:
                self.sync.sync(depsgraph)
            tf = self.sync.transfer_function(depsgraph.scene.gaussvdb)
            self.tf = tf
            if self.device is None and self.image is None:  # the worker's first render
                from . import kernel_cache

                kernel_cache.announce("render", status=lambda msg: self.engine.update_stats("", msg))
            self.submit(self.sync.scene, cam, tf)
        if self.error or self.sync.errors:
            self.engine.update_stats("", f"GaussVDB error: {self.error or self.sync.errors[0]}")
        with self.lock:
            image = self.image
        if image is None or self.sync.scene is None:
            return
        import bpy

        if bpy.app.background:
            return
        self._draw_image(depsgraph.scene, image[2], region.width, region.height)
        if depsgraph.scene.gaussvdb.show_legend and self.tf is not None:
            from . import legend_overlay

            legend_overlay.draw_viewport(depsgraph.scene.gaussvdb, self.sync, self.tf,
                                         region.width, region.height, self.legend_cache,
                                         self.engine, depsgraph.scene)
        if not self.schedule.converged:
            self.engine.tag_redraw()

    def _draw_image(self, scene, rgba, width, height):
        import gpu

        h, w = rgba.shape[:2]
        buf = gpu.types.Buffer("FLOAT", w * h * 4, np.minimum(rgba, 65000.0).ravel())
        tex = gpu.types.GPUTexture((w, h), format="RGBA16F", data=buf)
        draw_texture(tex, width, height, self.engine, scene)

    def _draw_gpu(self, depsgraph, cam, key, region):
        """The GPU device's image, dispatched when the view or scene changed, drawn into the
        region; False when the frame is the CPU's (the GPU cannot run here, or falls back)."""
        from ..gpu import context, probe

        if not probe.probe()[0]:
            return False
        if self.sync.scene is None:
            self.sync.sync(depsgraph)
        if self.gpu is None:
            self.gpu = [devices.new_device("GPU"), None, None]
        dev = self.gpu[0]
        if self.gpu[1] != key:
            self.tf = self.sync.transfer_function(depsgraph.scene.gaussvdb)
            try:
                with context.inside():  # view_draw has the window's GPU context
                    tex = dev.render_texture(self.sync.scene, cam, self.tf)
            except Exception as err:  # noqa: BLE001  (said in the header, as the worker's)
                self.error = str(err) or type(err).__name__
                tex = None
            if tex is None:
                return self.error is not None
            self.gpu[1:] = [key, tex]
            self.error = None
        if self.error:
            self.engine.update_stats("", f"GaussVDB error: {self.error}")
            return True
        scene = depsgraph.scene
        draw_texture(self.gpu[2], region.width, region.height, self.engine, scene)
        if scene.gaussvdb.show_legend and self.tf is not None:
            from . import legend_overlay

            legend_overlay.draw_viewport(scene.gaussvdb, self.sync, self.tf, region.width,
                                         region.height, self.legend_cache, self.engine, scene)
        return True

    def stop(self):
        with self.lock:
            self.stopping = True
            self.lock.notify_all()
        t = self.thread
        if t is not None and t.is_alive() and t is not threading.current_thread():
            t.join(timeout=1.0)

    # -- worker thread ------------------------------------------------------------------------
    def step(self):
        """Render the next scheduled level of the current job, if any; returns the factor drawn
        (None when nothing was due). The worker loops on this; tests call it directly."""
        with self.lock:
            job = self.job
            factor = self.schedule.next()
            gen = self.schedule.generation
        if job is None or factor is None or job[0] != gen:
            return None
        _, rscene, cam, tf = job
        if self.device is None:
            # its own device: a final render may run on the main thread at the same time
            self.device = devices.new_device()
        c = scaled_camera(cam, factor)
        out = self.device.render(rscene, c, tf,
                                 cancel=lambda: self.stopping or self.schedule.generation != gen)
        if self.device.stats.get("cancelled"):
            return None
        with self.lock:
            if self.schedule.generation == gen:
                self.image = (gen, factor, out["Combined"])
                self.schedule.finished(factor, gen)
        if not self.stopping:
            try:
                self.engine.tag_redraw()
            except (ReferenceError, AttributeError):
                pass
        return factor

    def _worker(self):
        while True:
            with self.lock:
                if self.stopping:
                    return
                wait = self.schedule.wait_time()
                if wait is None or wait > 0:
                    self.lock.wait(timeout=0.5 if wait is None else wait)
                    continue
            try:
                self.step()
            except Exception as err:  # noqa: BLE001
                with self.lock:
                    self.error = str(err) or type(err).__name__
                    self.schedule.done = len(self.schedule.levels)
