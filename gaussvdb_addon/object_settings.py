"""Per-object settings (Object.gaussvdb): where the Gaussians came from and which LOD to draw."""

import json

import bpy
from bpy.props import BoolProperty, EnumProperty, PointerProperty, StringProperty

LOD_LABELS = {"low": "Low", "medium": "Medium", "high": "High"}


def _tag(self, context):
    # Add-on properties fire no depsgraph update by themselves (Blender #62325).
    self.id_data.update_tag()


def lod_items(self, context):
    held = [name for name in self.lods.split(",") if name] or ["medium"]
    # Enum callbacks must keep their strings alive while Blender holds them.
    lod_items.cache = [(n, LOD_LABELS.get(n, n.title()), f"{n} LOD") for n in held]
    return lod_items.cache


class GaussVDBObjectSettings(bpy.types.PropertyGroup):
    is_gaussvdb: BoolProperty(name="GaussVDB Object", default=False)
    source_file: StringProperty(name="Source File", subtype="FILE_PATH")
    grid_name: StringProperty(name="Grid")
    grid_class: StringProperty(name="Class")
    lods: StringProperty(name="LODs Held", description="Comma-separated LOD presets stored on the object")
    weights: StringProperty(name="Weights", default="field")
    level_set_band: BoolProperty(name="Zero-Crossing Band Only", default=True)
    vector_magnitude: BoolProperty(name="Vector Magnitude", default=False)
    viewport_lod: EnumProperty(name="Viewport LOD", items=lod_items, update=_tag)
    render_lod: EnumProperty(name="Render LOD", items=lod_items, update=_tag)
    stats_json: StringProperty(name="Statistics", description="Per-LOD figures as JSON")

    def stats(self) -> dict:
        try:
            return json.loads(self.stats_json or "{}")
        except ValueError:
            return {}


CLASSES = (GaussVDBObjectSettings,)


def register_extra():
    bpy.types.Object.gaussvdb = PointerProperty(type=GaussVDBObjectSettings)


def unregister_extra():
    if hasattr(bpy.types.Object, "gaussvdb"):
        del bpy.types.Object.gaussvdb
