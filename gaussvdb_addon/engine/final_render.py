"""F12 / animation renders of the GAUSSVDB engine (the render to a file is image_file.py's; the
device is devices.py's, the camera camera.py's).

The frame's set-up is done once (``device.begin_frame``), then the image (or the render border's
region, as Cycles does: Blender pads it to the full size unless the result is cropped) is drawn in
bands of whole screen-tile rows (``device.band_rows``: eight per thread at least), sized from the
drawing time so one band takes about 0.15 s, with
``update_progress`` / ``update_result`` after each band and ``test_break`` before each (and polled
by the device inside a band), so Esc stops a render within half a second. Combined is linear and
premultiplied, written straight into the pass buffer (row 0 is the bottom row in both). Any error
is reported with ``report`` and ``error_set``: ``bpy.ops.render.render`` then raises RuntimeError
with the message and ``blender -b`` exits non-zero.
"""

import time
import traceback

import bpy
import numpy as np

from . import camera as cameras
from . import devices

TARGET_BAND_SECONDS = 0.15
# Partial results shown in the Image Editor this often; headless renders (blender -b, the CLI)
# show none, so they skip these full-frame copies (8 M floats at 1920x1080).
PROGRESSIVE_SECONDS = 0.5
# The figures of the last final render in this process. Blender calls the engine and takes no
# return value, so this record is how the caller of bpy.ops.render.render reads them
# (image_file.render_scene_to_file returns a copy).
LAST_STATS = {}


class RenderCancelled(Exception):
    pass


# -- image size and region ------------------------------------------------------------------------
def render_size(scene):
    r = scene.render
    f = r.resolution_percentage / 100.0
    return max(1, int(r.resolution_x * f)), max(1, int(r.resolution_y * f))


def render_region(scene, width, height):
    """The pixels drawn, (x0, y0, x1, y1) from the bottom left: the render border when it is on
    (Blender's rounding: border fraction x size in float32, truncated), else the whole image."""
    r = scene.render
    if not r.use_border:
        return 0, 0, width, height

    def px(frac, size):
        return int(np.float32(frac) * np.float32(size))

    x0, x1 = px(r.border_min_x, width), px(r.border_max_x, width)
    y0, y1 = px(r.border_min_y, height), px(r.border_max_y, height)
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"the render border ({r.border_min_x:.3f}..{r.border_max_x:.3f} x "
                         f"{r.border_min_y:.3f}..{r.border_max_y:.3f}) covers no pixel")
    return x0, y0, x1, y1


# -- passes ---------------------------------------------------------------------------------------
PASS_LAYOUT = {"Depth": (1, "Z", "VALUE"), "Value": (1, "X", "VALUE")}


def wanted_passes(view_layer):
    """(name, channels, channel ids, pass type) of the view layer's extra passes (View Layer > Passes)."""
    from .blender_settings import passes

    return [(name, *PASS_LAYOUT[name]) for name in passes(view_layer)]


def register_passes(engine, scene, renderlayer):
    if scene is None or renderlayer is None:
        return
    engine.register_pass(scene, renderlayer, "Combined", 4, "RGBA", "COLOR")
    for name, ch, chid, pass_type in wanted_passes(renderlayer):
        engine.register_pass(scene, renderlayer, name, ch, chid, pass_type)


def wait_for_kernels(engine, mode):
    """Before a render loads its kernels: when the background warm-up (warmup_service) compiles
    the ones this mode needs, wait for it (the status says so, Esc stops the render) instead of
    compiling them here too. In background mode only a second process started by this one
    (an import's, a command line render's) is waited for, and one compiling none of this mode's
    kernels is stopped: this render compiles them in-process."""
    from ...kernels import warmup
    from . import warmup_service

    wanted = warmup.jobs_for(modes=(mode,))
    warmup_service.stop_unless(wanted)  # background mode: an import's guess at another mode
    jobs = warmup_service.needed(wanted)
    if not jobs:
        return
    result = warmup_service.wait(jobs, cancel=engine.test_break, report=lambda text:
                                 engine.update_stats("", f"GaussVDB | {text} (Esc to cancel)"))
    if result == "cancelled":
        raise RenderCancelled()
    if result != "done":  # the warm-up failed: the kernels compile here, as without it
        engine.report({"WARNING"}, f"GaussVDB: background compile {result}; compiling here")


def announce_compile(engine):
    """Console and status bar say so before the kernels compile for the first time."""
    from . import kernel_cache

    kernel_cache.announce("render", status=lambda msg: engine.update_stats("", msg))


# -- the render -----------------------------------------------------------------------------------
def render(engine, depsgraph):
    """RenderEngine.render body. Never raises: errors go to report/error_set."""
    try:
        _render(engine, depsgraph)
    except RenderCancelled:
        pass
    except Exception as err:  # noqa: BLE001  (everything must surface, not just known errors)
        traceback.print_exc()
        msg = f"GaussVDB: {err}" if str(err) else f"GaussVDB: {type(err).__name__}"
        LAST_STATS.clear()
        LAST_STATS["error"] = msg
        engine.report({"ERROR"}, msg)
        engine.error_set(msg)


def _render(engine, depsgraph):
    name = devices.chosen_device(engine, depsgraph.scene)
    if name == "GPU":
        from ..gpu import context

        with context.inside():  # this render() has the engine's GPU context
            _render_on(engine, depsgraph, name)
    else:
        _render_on(engine, depsgraph, name)


def _render_on(engine, depsgraph, name):
    from . import legend_overlay, scene_sync

    device = devices.final_device(name)
    t0 = time.perf_counter()
    scene = depsgraph.scene
    width, height = render_size(scene)
    camera = cameras.scene_camera(scene, depsgraph, width, height)
    region = render_region(scene, width, height)
    sync = scene_sync.SceneSync(viewport=False)
    rscene = sync.sync(depsgraph)
    tf = sync.transfer_function(scene.gaussvdb)
    for msg in sync.warnings:  # log scale over values <= 0, missing sequence frames
        engine.report({"WARNING"}, f"GaussVDB: {msg}")
    for msg in sync.errors:  # an unreadable sequence frame: said, and the animation goes on (an
        engine.report({"WARNING"}, f"GaussVDB: error: {msg}")  # ERROR report would stop it)
    engine.update_stats("", f"GaussVDB | syncing {sync.gaussians:,} Gaussians")
    device.sync(rscene)
    t_sync = time.perf_counter() - t0
    # the kernels this scene's frames run (its mode, lights, surfaces...), loaded or on first
    # use compiled before the frame is timed
    wait_for_kernels(engine, rscene.mode)  # a background warm-up compiling them: its progress
    engine.update_stats("", "GaussVDB | loading the kernels")
    announce_compile(engine)
    t_compile = device.load_kernels(scene=rscene, camera=camera, tf=tf)

    t1 = time.perf_counter()
    engine.update_stats("", f"GaussVDB | preparing the frame ({sync.gaussians:,} Gaussians)")
    device.begin_frame(rscene, camera, tf)  # once per frame; the bands only draw pixels
    t_setup = time.perf_counter() - t1

    def legend(combined):  # the colour legend (scene.gaussvdb.show_legend), over the image
        return legend_overlay.composite(scene.gaussvdb, sync, tf, combined)

    try:
        cancelled, legend_drawn = _draw(engine, depsgraph, device, rscene, camera, tf, region,
                                        legend)
    finally:
        device.end_frame()  # the frame's tile lists can be large
    t_render = time.perf_counter() - t1
    if device.stats.get("fallback"):  # the GPU device handed this frame to the CPU
        engine.report({"INFO"}, f"GaussVDB: {device.stats['fallback']} are drawn by the CPU device")
    stats = dict(seconds_compile=t_compile, seconds_sync=t_sync, seconds_setup=t_setup,
                 seconds_render=t_render, width=width, height=height, region=list(region),
                 mode=rscene.mode, gaussians=sync.gaussians, objects=len(rscene.objects),
                 threads=device.stats.get("threads"), cancelled=cancelled,
                 value_range=[tf.vmin, tf.vmax], warnings=list(sync.warnings),
                 errors=list(sync.errors), frame=scene.frame_current, legend=legend_drawn,
                 device=device.name, gpu=getattr(device, "renderer", None),
                 fallback=device.stats.get("fallback"))
    LAST_STATS.clear()
    LAST_STATS.update(stats)
    engine.update_stats("", f"GaussVDB | {sync.gaussians:,} Gaussians | sync {t_sync:.2f} s | "
                            f"render {t_render:.2f} s"
                            f"{f' | kernels {t_compile:.1f} s' if t_compile >= 0.5 else ''}"
                            f"{' | cancelled' if cancelled else ''}")


def _draw(engine, depsgraph, device, rscene, camera, tf, region, finish):
    """The region's pixels, band by band, into a result of its size (with a border, Blender
    places it in the image); ``finish(combined)`` draws over the finished image (-> whether it
    drew). Returns (cancelled, what finish returned)."""
    x0, y0, x1, y1 = region
    w, h = x1 - x0, y1 - y0
    layer_name = depsgraph.view_layer.name
    combined = np.zeros((h, w, 4), np.float32)
    extra = {name: np.full((h, w), 1e10 if name == "Depth" else 0.0, np.float32)
             for name, *_ in wanted_passes(depsgraph.view_layer)}
    result = engine.begin_result(0, 0, w, h, layer=layer_name)
    layer = result.layers[0]
    for name, ch, chid, _pass_type in wanted_passes(depsgraph.view_layer):
        if layer.passes.find(name) < 0:
            engine.end_result(result, cancel=True)
            engine.add_pass(name, ch, chid, layer=layer_name)
            result = engine.begin_result(0, 0, w, h, layer=layer_name)
            layer = result.layers[0]

    def flush():
        layer.passes["Combined"].rect.foreach_set(combined.reshape(-1))
        for name, buf in extra.items():
            p = layer.passes.get(name) if hasattr(layer.passes, "get") else layer.passes[name]
            if p is not None:
                p.rect.foreach_set(buf.reshape(-1))

    least, align = device.band_rows(rscene)  # whole screen-tile rows, eight per thread
    row = y0
    band = least
    cancelled = False
    last_flush = time.perf_counter()
    progressive = not bpy.app.background
    while row < y1:
        if engine.test_break():
            cancelled = True
            break
        r1 = _band_end(row, band, y1, align)
        tb = time.perf_counter()
        out = device.render(rscene, camera, tf, rows=(row, r1), cols=(x0, x1), cancel=engine.test_break)
        dt = time.perf_counter() - tb
        combined[row - y0:r1 - y0] = out["Combined"]
        for name in extra:
            if name in out:
                extra[name][row - y0:r1 - y0] = out[name]
        if device.stats.get("cancelled"):
            cancelled = True
            break
        per_row = dt / max(1, r1 - row)
        band = int(max(least, min(h, TARGET_BAND_SECONDS / max(per_row, 1e-9))))
        row = r1
        engine.update_progress((row - y0) / h)
        now = time.perf_counter()
        if progressive and row < y1 and now - last_flush > PROGRESSIVE_SECONDS:
            flush()
            engine.update_result(result)
            last_flush = now
    finished = not cancelled and finish(combined)
    flush()
    engine.end_result(result)
    return cancelled, finished


def _band_end(row, band, end, align):
    """The end of the band from row: on a multiple of align unless at the end."""
    r1 = (row + band) // align * align
    return min(end, r1 if r1 > row else row + band)
