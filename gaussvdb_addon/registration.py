"""The one registration hub: every module with Blender classes is listed here, in order."""

import bpy

from .. import operators
from . import engine, object_panel, object_settings, presets, render_panel, render_settings

# Properties first (others point at them), panels last (they draw the rest).
MODULES = (object_settings, render_settings, presets, operators, engine, render_panel, object_panel)


def register():
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
