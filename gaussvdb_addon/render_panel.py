"""Render properties panels for the GAUSSVDB engine (mode, transfer function, quality, passes)."""

import bpy


class _Base:
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {"GAUSSVDB"}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES


class GAUSSVDB_OT_transfer_from_colormap(bpy.types.Operator):
    """Fill the transfer function ramp from the chosen colormap (creates it when missing)"""

    bl_idname = "gaussvdb.transfer_from_colormap"
    bl_label = "Load Colormap"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        from . import transfer_ramp

        s = context.scene.gaussvdb
        transfer_ramp.ensure_texture(s)
        transfer_ramp.fill_from_colormap(s, s.colormap, s.colormap_alpha.lower())
        context.scene.update_tag()
        return {"FINISHED"}


class GAUSSVDB_PT_render(_Base, bpy.types.Panel):
    bl_label = "GaussVDB"

    def draw(self, context):
        s = context.scene.gaussvdb
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "mode")
        col = layout.column(align=True)
        col.prop(s, "early_termination")
        if s.mode == "PARTICLES":
            col.prop(s, "tau_max")
        elif s.mode in ("FIELD", "REFERENCE"):
            col.prop(s, "step_scale")
        layout.prop(s, "threads")


class GAUSSVDB_PT_transfer(_Base, bpy.types.Panel):
    bl_label = "Transfer Function"
    bl_parent_id = "GAUSSVDB_PT_render"

    def draw(self, context):
        s = context.scene.gaussvdb
        layout = self.layout
        row = layout.row(align=True)
        row.prop(s, "colormap", text="")
        row.prop(s, "colormap_alpha", text="")
        row.operator(GAUSSVDB_OT_transfer_from_colormap.bl_idname, text="", icon="FILE_REFRESH")
        tex = s.ramp_texture
        if tex is not None and tex.color_ramp is not None:
            layout.template_color_ramp(tex, "color_ramp", expand=True)
        else:
            layout.label(text="The colormap preset is used until the ramp is created", icon="INFO")
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "density")
        layout.prop(s, "auto_range")
        col = layout.column(align=True)
        col.active = not s.auto_range
        col.prop(s, "value_min")
        col.prop(s, "value_max")
        layout.prop(s, "log_scale")


class GAUSSVDB_PT_level_sets(_Base, bpy.types.Panel):
    bl_label = "Level Sets"
    bl_parent_id = "GAUSSVDB_PT_render"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.gaussvdb
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "level_set_color", text="Colour")
        if s.level_set_color == "CONSTANT":
            layout.prop(s, "level_set_constant")


class GAUSSVDB_PT_film(_Base, bpy.types.Panel):
    bl_label = "Film and Passes"
    bl_parent_id = "GAUSSVDB_PT_render"

    def draw(self, context):
        s = context.scene.gaussvdb
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(context.scene.render, "film_transparent", text="Transparent")
        sub = layout.column()
        sub.active = not context.scene.render.film_transparent
        sub.prop(s, "background")
        col = layout.column(heading="Passes")
        col.prop(s, "use_pass_depth")
        col.prop(s, "use_pass_value")


CLASSES = (GAUSSVDB_OT_transfer_from_colormap, GAUSSVDB_PT_render, GAUSSVDB_PT_transfer,
           GAUSSVDB_PT_level_sets, GAUSSVDB_PT_film)
