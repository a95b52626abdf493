"""The one registration hub: every module with Blender classes is listed here, in order."""

import os

import bpy

from .. import operators
from ..kernels import cachedir, openvdb_binding
from .engine import gpu_choice, render_engine, warmup_service
from .io import source_path, versioning
from .properties import lod_figures, object_settings, render_settings
from .ui import object_panel, preferences, presets, render_panel, transfer_ui

# Properties first (others point at them), panels last (they draw the rest).
# versioning: the load handler that upgrades files written by older versions. warmup_service:
# the background compile of the kernels (UI only), after the preferences that show it.
MODULES = (lod_figures, object_settings, source_path, render_settings, presets, operators,
           gpu_choice, render_engine, render_panel, object_panel, transfer_ui, preferences,
           warmup_service, versioning)


def bundled_openvdb():
    """The openvdb binding Blender bundles (the reader's route for files older than v222)."""
    bpy.utils.expose_bundled_modules()
    import openvdb

    return openvdb


def register():
    if not (os.environ.get("GAUSSVDB_CACHE_DIR") or os.environ.get("NUMBA_CACHE_DIR")):
        # compiled kernels go in the extension's user folder, never in its (read-only) source
        pkg = __package__.rsplit(".", 1)[0]
        try:
            cachedir.set_cache_root(bpy.utils.extension_path_user(pkg, path="kernel_cache",
                                                                  create=True))
        except (ValueError, OSError):  # not loaded as an extension: the default rule applies
            pass
    openvdb_binding.set_loader(bundled_openvdb)
    # a GPU context only where one can be had (gpu_choice): asking for one without GL aborts Blender
    render_engine.GaussVDBRenderEngine.bl_use_gpu_context = gpu_choice.initial_gpu_context()
    for module in MODULES:
        for cls in module.CLASSES:
            bpy.utils.register_class(cls)
        if hasattr(module, "register_extra"):
            module.register_extra()


def unregister():
    for module in reversed(MODULES):
        if hasattr(module, "unregister_extra"):
            module.unregister_extra()
        for cls in reversed(module.CLASSES):
            if getattr(cls, "is_registered", False):
                bpy.utils.unregister_class(cls)
