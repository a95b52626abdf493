"""Transfer-function UI shared by the scene (render properties) and objects (object properties):
the colormap menu (asks before replacing a hand-edited ramp), the ramp, range (with the range in
use), log scale (with its warning) and density; and the colour legend's sub-panel.

Which settings an operator or preset acts on: the ``gaussvdb_tf`` context pointer the object
panel sets (``layout.context_pointer_set``), else the scene's.
"""

import bpy

from ...kernels import colormap_names


def _fmt(v):
    return f"{v:.4g}"


def draw_transfer(layout, settings, objects, presets_row=True):
    """The transfer function of ``settings`` (scene or object), for ``objects`` that use it;
    ``presets_row``: the colormap preset menu in the panel (the scene's has it in its header)."""
    from ..engine import scene_sync
    from ..properties import transfer_ramp
    from . import presets

    layout.context_pointer_set("gaussvdb_tf", settings)
    edited = transfer_ramp.is_edited(settings)
    row = layout.row(align=True)
    row.operator_menu_enum("gaussvdb.colormap_pick", "colormap",
                           text=colormap_names.label(settings.colormap) + (" (Edited)" if edited else ""),
                           icon="COLOR")
    row.prop(settings, "colormap_alpha", text="")
    if presets_row:
        presets.draw_colormap_presets(layout)
    tex = settings.ramp_texture
    if tex is not None and tex.color_ramp is not None:
        layout.template_color_ramp(tex, "color_ramp", expand=True)
    else:
        layout.label(text="The colormap preset is used until the ramp is created", icon="INFO")
    layout.use_property_split = True
    layout.use_property_decorate = False
    col = layout.column(align=True)
    col.prop(settings, "density")
    col.prop(settings, "density_unit", text="Per")
    layout.prop(settings, "auto_range")
    col = layout.column(align=True)
    col.active = not settings.auto_range
    col.prop(settings, "value_min")
    col.prop(settings, "value_max")
    rng = scene_sync.stored_range(settings, objects)
    layout.label(text="Range in use: from the drawn LOD" if rng is None else
                 f"Range in use: {_fmt(rng[0])} to {_fmt(rng[1])}", icon="DRIVER_DISTANCE")
    layout.prop(settings, "log_scale")
    if settings.log_scale:
        for o in objects:
            v = scene_sync.values_of(o.gaussvdb)
            msg = v and scene_sync.log_warning(o.gaussvdb.grid_name or o.name, v[3])
            if msg:
                layout.label(text=msg, icon="ERROR")


class GAUSSVDB_PT_legend(bpy.types.Panel):
    bl_label = "Legend"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_parent_id = "GAUSSVDB_PT_render"
    bl_options = {"DEFAULT_CLOSED"}
    COMPAT_ENGINES = {"GAUSSVDB"}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw_header(self, context):
        self.layout.prop(context.scene.gaussvdb, "show_legend", text="")

    def draw(self, context):
        s = context.scene.gaussvdb
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.active = s.show_legend
        layout.prop(s, "legend_corner")
        layout.prop(s, "legend_size")
        layout.prop(s, "legend_units")


class GAUSSVDB_PT_object_transfer(bpy.types.Panel):
    bl_label = "Transfer Function"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"
    bl_parent_id = "GAUSSVDB_PT_object"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.gaussvdb.is_gaussvdb

    def draw(self, context):
        obj = context.object
        s = obj.gaussvdb
        layout = self.layout
        layout.prop(s, "use_scene_tf")
        if s.use_scene_tf:
            layout.label(text="Coloured by the scene's transfer function (Render properties)")
            return
        draw_transfer(layout, s, [obj])


CLASSES = (GAUSSVDB_PT_legend, GAUSSVDB_PT_object_transfer)
