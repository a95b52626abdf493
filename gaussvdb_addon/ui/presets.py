"""Presets shipped in presets/ and the menus that list and load them (the operators that save
them: operators/presets.py).

- Import LOD presets: presets/operator/gaussvdb.import_vdb/*.py, the folder Blender's own operator
  presets use for `gaussvdb.import_vdb` (bl_options PRESET), so the file browser's preset menu and
  ours list the same files. Each sets `op.lods`, `op.weights`, `op.level_set_band`.
- Colormap presets: presets/gaussvdb/colormap/*.py, each sets the colormap name and the whole
  ramp (positions, colours, alphas, interpolation) of the transfer function they are applied to:
  an object's own (the object panel's ``gaussvdb_tf`` context pointer) or else the scene's.
  Saving one writes the same (``preset_text``); the shipped files are ``preset_text`` of each
  colormap on a fresh ramp.

`bpy.utils.register_preset_path(EXTENSION_ROOT)` adds the shipped folder to the preset search path; presets
the user saves go to the user's scripts/presets/<subdir> (AddPresetBase does that) and show up beside.
"""

import os

import bpy

# register_preset_path() takes the folder that HOLDS "presets/": the extension's root.
EXTENSION_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PRESET_DIR = os.path.join(EXTENSION_ROOT, "presets")
IMPORT_PRESET_SUBDIR = "operator/gaussvdb.import_vdb"
COLORMAP_PRESET_SUBDIR = "gaussvdb/colormap"


class GAUSSVDB_MT_import_presets(bpy.types.Menu):
    bl_label = "LOD Presets"
    preset_subdir = IMPORT_PRESET_SUBDIR
    preset_operator = "script.execute_preset"
    draw = bpy.types.Menu.draw_preset


class GAUSSVDB_MT_colormap_presets(bpy.types.Menu):
    bl_label = "Colormap Presets"
    preset_subdir = COLORMAP_PRESET_SUBDIR
    preset_operator = "script.execute_preset"
    draw = bpy.types.Menu.draw_preset


TF_DEFINE = 'settings = getattr(bpy.context, "gaussvdb_tf", None) or bpy.context.scene.gaussvdb'


def preset_text(settings):
    """The Python lines of a colormap preset of ``settings``: the colormap name, the alpha mode
    and every ramp element (``load_ramp`` marks the result as not edited)."""
    from ..properties import transfer_ramp

    lines = ["import bpy", TF_DEFINE, "", f"settings.colormap = {settings.colormap!r}",
             f"settings.colormap_alpha = {settings.colormap_alpha!r}"]
    stops = transfer_ramp.stops_of(settings)
    if stops:
        lines.append("settings.load_ramp([")
        lines += [f"    ({p!r}, {tuple(c)!r})," for p, c in stops]
        lines.append(f"], {settings.ramp_texture.color_ramp.interpolation!r})")
    return "\n".join(lines) + "\n"


def draw_colormap_presets(layout):
    """One row: the colormap preset menu with add/remove buttons (for the render panel)."""
    row = layout.row(align=True)
    row.menu("GAUSSVDB_MT_colormap_presets", text=GAUSSVDB_MT_colormap_presets.bl_label)
    row.operator("gaussvdb.colormap_preset_add", text="", icon="ADD")
    row.operator("gaussvdb.colormap_preset_add", text="", icon="REMOVE").remove_active = True


CLASSES = (GAUSSVDB_MT_import_presets, GAUSSVDB_MT_colormap_presets)


def register_extra():
    bpy.utils.register_preset_path(EXTENSION_ROOT)


def unregister_extra():
    bpy.utils.unregister_preset_path(EXTENSION_ROOT)
