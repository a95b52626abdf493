"""Run a callable inside a GPU context. Inside the GAUSSVDB engine's render() (when it asks for a
GPU context) or view_draw there already is one (``inside()`` marks those); from a plain script or
the CLI a tiny private engine that asks for one renders a 4x4 frame on a temporary scene and
calls it there. Only call run() where the probe said a context can be had: asking for one on a
machine without EGL/GL aborts Blender."""
from __future__ import annotations

from contextlib import contextmanager

_DEPTH = [0]  # > 0 while inside a GPU context
_CALL = {}
_SCENE = "GaussVDB GPU context"


@contextmanager
def inside():
    """Mark the code under it as running in a GPU context (engine render / view_draw)."""
    _DEPTH[0] += 1
    try:
        yield
    finally:
        _DEPTH[0] -= 1


def in_context():
    return _DEPTH[0] > 0


def _engine_class():
    import bpy

    cls = _CALL.get("cls")
    if cls is None:
        class GaussVDBGPUContext(bpy.types.RenderEngine):
            bl_idname = "GAUSSVDB_GPU_CONTEXT"
            bl_label = "GaussVDB GPU context"
            bl_use_gpu_context = True

            def render(self, depsgraph):
                fn = _CALL.pop("fn")
                try:
                    with inside():
                        _CALL["result"] = fn()
                except BaseException as err:  # noqa: BLE001  (re-raised outside the render)
                    _CALL["error"] = err

        bpy.utils.register_class(GaussVDBGPUContext)
        cls = _CALL["cls"] = GaussVDBGPUContext
    return cls


def _scene():
    import bpy

    sc = bpy.data.scenes.get(_SCENE)
    if sc is None:
        sc = bpy.data.scenes.new(_SCENE)
        cam = bpy.data.objects.new(_SCENE, bpy.data.cameras.new(_SCENE))
        sc.collection.objects.link(cam)
        sc.camera = cam
        r = sc.render
        r.resolution_x = r.resolution_y = 4
        r.resolution_percentage = 100
    sc.render.engine = _engine_class().bl_idname
    return sc


def _remove(sc):
    import bpy

    cam = sc.camera
    data = cam.data if cam is not None else None
    bpy.data.scenes.remove(sc)
    if cam is not None:
        bpy.data.objects.remove(cam)
    if data is not None:
        bpy.data.cameras.remove(data)


def run(fn):
    """fn() inside a GPU context; its result (or its exception)."""
    if in_context():
        return fn()
    import bpy

    sc = _scene()
    _CALL.pop("result", None)
    _CALL.pop("error", None)
    _CALL["fn"] = fn
    try:
        bpy.ops.render.render(scene=sc.name)
    finally:
        _CALL.pop("fn", None)
        _remove(sc)  # nothing of it stays in the user's file
    if "error" in _CALL:
        raise _CALL.pop("error")
    return _CALL.pop("result", None)
