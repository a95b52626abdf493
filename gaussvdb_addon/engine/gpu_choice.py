"""Which device a render uses: Scene.gaussvdb.device (CPU / GPU). The engine asks Blender for a
GPU context (bl_use_gpu_context, read when the class registers) only where the probe says one can
be had: always in the UI; in background mode (blender -b, the bpy module) once the GPU device is
chosen (the setting's update, a file loaded with it, the CLI) and the probe passed, by
registering the engine class again with the flag on. A machine without EGL/GL never asks, so
Blender never aborts there; the GPU choice then falls back to the CPU device with a warning
(devices.chosen_device, which reads the flag from the engine it renders for). Choosing the device
only starts the probe: the render waits for its answer (render_init), so no property update waits
on a child process."""

import bpy
from bpy.app.handlers import persistent

from ..gpu import probe


def engine_class():
    from .render_engine import GaussVDBRenderEngine

    return GaussVDBRenderEngine


def initial_gpu_context():
    """The engine's flag at registration: on in the UI (it draws with a GPU), off in background
    mode until the GPU device is chosen and the probe passes (ensure)."""
    return not bpy.app.background


def ensure():
    """The GPU device is wanted: (ok, GPU name or why not). Turns the engine's GPU context on
    when it is off and the probe passes."""
    ok, text = probe.probe()
    cls = engine_class()
    if ok and not cls.bl_use_gpu_context and getattr(cls, "is_registered", False):
        bpy.utils.unregister_class(cls)
        cls.bl_use_gpu_context = True
        bpy.utils.register_class(cls)
    return ok, text


def device_changed(settings, context):
    if settings.device == "GPU" and bpy.app.background:
        probe.start()
        if probe.answer() is not None:
            ensure()
    settings.id_data.update_tag()


@persistent
def _on_load(_filepath=""):
    if bpy.app.background and any(getattr(s, "gaussvdb", None) is not None
                                  and s.gaussvdb.device == "GPU" for s in bpy.data.scenes):
        probe.start()


@persistent
def _before_render(scene=None, *_):
    """A render starts (before Blender reads the engine's GPU-context flag): the GPU device's
    probe answer is awaited here, where a render may wait."""
    scene = scene or bpy.context.scene
    if (bpy.app.background and scene.render.engine == engine_class().bl_idname
            and scene.gaussvdb.device == "GPU"):
        ensure()


def register_extra():
    if _on_load not in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.append(_on_load)
    if _before_render not in bpy.app.handlers.render_init:
        bpy.app.handlers.render_init.append(_before_render)


def unregister_extra():
    if _on_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_on_load)
    if _before_render in bpy.app.handlers.render_init:
        bpy.app.handlers.render_init.remove(_before_render)


CLASSES = ()
