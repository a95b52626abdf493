"""Per-object settings (Object.gaussvdb): where the Gaussians came from and which LOD to draw.

The point attributes themselves are described in io/schema.py (and README "Point-cloud layout");
``lods`` lists the LODs held in gs_lod order, ``viewport_lod``/``render_lod`` pick one of them like
the Subdivision modifier's viewport and render levels. With ``use_scene_tf`` off the object's own
transfer function (the TransferFunctionProps fields) colours it instead of the scene's.
``lod_stats``: each LOD's figures from the import (lod_figures.py); ``stats_json`` the object's.
Clipping (``clip_*``): Empties that cut the object (kernels/render/scene/clip.py), in every mode.
``level_set_style``: level sets as lit surfaces (default) or translucent shells.
``shading``/``shadows``: volumes emissive (default) or lit by the scene's lights, with shadows.
``color_grid``: another grid of the file the Gaussians carry (gs_color); the ``color_*`` colour
map over it colours the object, its transfer function (scene's or own) then sets only the opacity.
"""

import json

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from ...kernels import colormap_names, lod_names
from ..io import source_path
from . import lod_figures
from .transfer_settings import TransferFunctionProps


def _tag(self, context):
    # Add-on properties fire no depsgraph update by themselves (Blender #62325).
    self.id_data.update_tag()
    if context is not None and getattr(context, "area", None) is not None:
        context.area.tag_redraw()


# Enum item callbacks must keep their strings alive while Blender holds them: one cached list per
# distinct `lods` string (a handful per file), never rebuilt for the same string.
_LOD_ITEM_CACHE = {}


def lod_items(self, context):
    key = self.lods or lod_names.DEFAULT
    items = _LOD_ITEM_CACHE.get(key)
    if items is None:
        held = [name for name in key.split(",") if name] or [lod_names.DEFAULT]
        items = [(n, lod_names.label(n), f"Draw the {lod_names.label(n)} LOD", i)
                 for i, n in enumerate(held)]
        _LOD_ITEM_CACHE[key] = items
    return items


def _is_empty(self, obj):
    return obj.type == "EMPTY"


class ClipProps:
    """Clipping: a plane (an Empty's local XY plane; the side its +Z axis points to stays), a box
    (an Empty's local [-1, 1]^3 cube, as its Cube display draws it; the inside stays) and a
    collection whose Empties cut too (Cube display: a box, any other: a plane). All cuts apply
    together."""
    clip_plane: PointerProperty(name="Clip Plane", type=bpy.types.Object, poll=_is_empty,
                                update=_tag,
                                description="Empty whose local XY plane cuts the object; the side "
                                            "its +Z axis points to stays")
    clip_box: PointerProperty(name="Clip Box", type=bpy.types.Object, poll=_is_empty, update=_tag,
                              description="Empty whose local [-1, 1] cube (Cube display) keeps "
                                          "the part of the object inside it")
    clip_collection: PointerProperty(name="Clip Collection", type=bpy.types.Collection,
                                     update=_tag,
                                     description="Every Empty in this collection cuts the object "
                                                 "too: Cube display as a box, others as a plane")


class SurfaceProps:
    """Level sets: a lit opaque surface (the zero level, shaded by the scene's lights) or the
    translucent shell of the narrow band."""
    level_set_style: EnumProperty(
        name="Level Set", update=_tag, default="SURFACE",
        items=[("SURFACE", "Surface", "Opaque surface at the zero level, lit by the scene's lights "
                                      "(a headlight when there are none)"),
               ("SHELL", "Shell", "Translucent shell of the narrow band, unlit")],
        description="How a level set is drawn")


class VolumeShadingProps:
    """Volumes: emission-absorption, or lit by the scene's lights (Blinn-Phong on the field's
    gradient, as VTK shades volumes), optionally with shadows (kernels/render/cpu/lit.py)."""
    shading: EnumProperty(
        name="Shading", update=_tag, default="EMISSION",
        items=[("EMISSION", "Emission", "The transfer function's colour glows (emission-absorption)"),
               ("LIT", "Lit", "The scene's lights (a headlight when there are none) shade the "
                              "medium by its gradient; homogeneous regions keep their emission "
                              "colour. Paper mode draws emission")],
        description="How the volume is shaded")
    shadows: BoolProperty(name="Shadows", default=False, update=_tag,
                          description="Lit volumes: each light shines through the media in its "
                                      "way (single scattering); the headlight casts none")


class ColorGridProps:
    """Colour by a second grid (imported with the object: gs_color): a colour map over that grid
    with its own range; the transfer function keeps the opacity over the object's own grid."""
    color_grid: StringProperty(name="Colour Grid",
                               description="The grid of the same file that colours this object "
                                           "(set at import; empty: coloured by its own grid)")
    color_colormap: EnumProperty(name="Colour Map", items=colormap_names.enum_items(),
                                 default="inferno", update=_tag,
                                 description="Colormap over the colour grid's values")
    color_auto_range: BoolProperty(name="Auto Range", default=True, update=_tag,
                                   description="Colour range from the colour grid's active voxels")
    color_min: FloatProperty(name="Min", default=0.0, update=_tag,
                             description="Colour grid value at the colour map's left end")
    color_max: FloatProperty(name="Max", default=1.0, update=_tag,
                             description="Colour grid value at the colour map's right end")
    color_log_scale: BoolProperty(name="Log Scale", default=False, update=_tag,
                                  description="Spread the colour map over log(value)")


class GaussVDBObjectSettings(ClipProps, SurfaceProps, VolumeShadingProps, ColorGridProps,
                             TransferFunctionProps, bpy.types.PropertyGroup):
    is_gaussvdb: BoolProperty(name="GaussVDB Object", default=False)
    source_volume: PointerProperty(name="Source", type=bpy.types.Volume,
                                   description="Volume datablock holding the source file's path "
                                               "(a Blender file path: relative, missing-file search)")
    source_file: StringProperty(name="Source File", subtype="FILE_PATH",
                                get=lambda self: source_path.get_source_file(self),
                                set=lambda self, value: source_path.set_source_file(self, value),
                                description="The .vdb file the Gaussians were converted from")
    grid_name: StringProperty(name="Grid")
    grid_class: StringProperty(name="Class")
    value_type: StringProperty(name="Value Type")
    lods: StringProperty(name="LODs Held",
                         description="Comma-separated LOD presets stored on the object, in gs_lod order")
    weight_rule: EnumProperty(name="Weights", items=lod_names.weight_items(),
                              default=lod_names.WEIGHTS[0],
                              description="How the Gaussians' amplitudes were set at import")
    # Files from before weight_rule hold the rule as text here (io/versioning moves it over)
    weights: StringProperty(name="Weights (Old Files)", default="", options={"HIDDEN"})

    def weights_rule(self) -> str:
        """The weight rule, from weight_rule or (an older file not yet upgraded: a linked
        object) the text it was stored as."""
        return self.weights if self.weights in lod_names.WEIGHTS else self.weight_rule
    level_set_band: BoolProperty(name="Zero-Crossing Band Only", default=True)
    vector_magnitude: BoolProperty(name="Vector Magnitude", default=False)

    def convert_options(self, **changes):
        """The ConvertOptions this object was imported with (what Reload and its sequence
        frames convert with again), with ``changes``."""
        from ...kernels.convert_options import ConvertOptions

        return ConvertOptions(weights=self.weights_rule(), level_set_band=bool(self.level_set_band),
                              vector_magnitude=bool(self.vector_magnitude), **changes)
    viewport_lod: EnumProperty(name="Viewport LOD", items=lod_items, update=_tag,
                               description="LOD drawn in the viewport")
    render_lod: EnumProperty(name="Render LOD", items=lod_items, update=_tag,
                             description="LOD used for final renders")
    index_to_world: StringProperty(name="Index to World",
                                   description="The grid's transform at import: 16 float64 numbers, "
                                               "row-major 4x4, column-vector form (exact; Blender "
                                               "float properties are float32)")
    leaf_box_min: FloatVectorProperty(name="Leaf Box Min", size=3,
                                      description="Index-space box of the grid's leaves and tiles")
    leaf_box_max: FloatVectorProperty(name="Leaf Box Max", size=3)
    layout_version: IntProperty(name="Layout Version", default=0)
    stats_json: StringProperty(name="Statistics",
                               description="The import's figures as JSON (the per-LOD ones: lod_stats)")
    lod_stats: CollectionProperty(name="LOD Figures", type=lod_figures.GaussVDBLODFigures)
    lod_stats_index: IntProperty(name="Active LOD Figures", options={"HIDDEN", "SKIP_SAVE"})
    sequence_range: EnumProperty(
        name="Range Over", default="SEQUENCE", update=_tag,
        description="A sequence's automatic transfer-function range",
        items=(("SEQUENCE", "All Frames", "The range over every frame: colours stay put while playing"),
               ("FRAME", "Each Frame", "Each frame's own range")))
    use_scene_tf: BoolProperty(name="Use Scene Transfer Function", default=True, update=_tag,
                               description="Colour this object with the scene's transfer function; "
                                           "off: with its own colormap, range, log scale and density")

    def stats(self) -> dict:
        """The import's figures: the object's (JSON) and, under "lods", each LOD's."""
        try:
            figures = json.loads(self.stats_json or "{}")
        except ValueError:
            figures = {}
        return dict(figures, lods=lod_figures.as_dicts(self))

    def voxel_stats(self):
        """The grid's value figures stored at import (kernels.render.voxel_stats: min, max,
        positive_min, nonpositive, voxels), or None for objects imported before they were."""
        v = self.stats().get("values")
        return v if isinstance(v, dict) and "min" in v and "max" in v else None

    def color_stats(self):
        """The colour grid's value figures stored at import (as voxel_stats), or None."""
        v = self.stats().get("color_values") if self.color_grid else None
        return v if isinstance(v, dict) and "min" in v and "max" in v else None


CLASSES = (GaussVDBObjectSettings,)


def register_extra():
    bpy.types.Object.gaussvdb = PointerProperty(type=GaussVDBObjectSettings)


def unregister_extra():
    if hasattr(bpy.types.Object, "gaussvdb"):
        del bpy.types.Object.gaussvdb
