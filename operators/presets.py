"""Save and remove presets (Blender's AddPresetBase): the import LOD presets and the colormap
presets whose menus are in gaussvdb_addon/ui/presets.py."""

import bpy
from bl_operators.presets import AddPresetBase

from ..gaussvdb_addon.ui import presets


class GAUSSVDB_OT_import_preset_add(AddPresetBase, bpy.types.Operator):
    """Add or remove an import LOD preset"""

    bl_idname = "gaussvdb.import_preset_add"
    bl_label = "Add Import LOD Preset"
    preset_menu = "GAUSSVDB_MT_import_presets"
    preset_subdir = presets.IMPORT_PRESET_SUBDIR
    preset_defines = ["op = bpy.context.active_operator"]
    preset_values = ["op.lods", "op.tolerance", "op.weights", "op.level_set_band",
                     "op.vector_magnitude", "op.measure_error"]


class GAUSSVDB_OT_colormap_preset_add(AddPresetBase, bpy.types.Operator):
    """Add or remove a colormap preset (the whole ramp is saved)"""

    bl_idname = "gaussvdb.colormap_preset_add"
    bl_label = "Add Colormap Preset"
    preset_menu = "GAUSSVDB_MT_colormap_presets"
    preset_subdir = presets.COLORMAP_PRESET_SUBDIR
    preset_defines = ["settings = bpy.context.scene.gaussvdb"]
    preset_values = ["settings.colormap"]

    def add(self, context, filepath):
        from ..gaussvdb_addon.properties import transfer_ramp
        from ..gaussvdb_addon.properties.transfer_settings import target

        settings = target(context)
        transfer_ramp.ensure_texture(settings)
        with open(filepath, "w", encoding="utf-8") as f:
            f.write(presets.preset_text(settings))


CLASSES = (GAUSSVDB_OT_import_preset_add, GAUSSVDB_OT_colormap_preset_add)
