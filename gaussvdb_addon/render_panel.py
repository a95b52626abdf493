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
        from . import scene_sync, transfer_ui

        transfer_ui.draw_transfer(self.layout, context.scene.gaussvdb,
                                  scene_sync.scene_tf_users(context.scene))


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


CLASSES = (GAUSSVDB_PT_render, GAUSSVDB_PT_transfer,
           GAUSSVDB_PT_level_sets, GAUSSVDB_PT_film)
