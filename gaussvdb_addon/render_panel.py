"""Render properties panel for the GAUSSVDB engine."""

import bpy


class GAUSSVDB_PT_render(bpy.types.Panel):
    bl_label = "GaussVDB"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {"GAUSSVDB"}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        settings = context.scene.gaussvdb
        layout = self.layout
        layout.use_property_split = True
        layout.prop(settings, "mode")
        layout.prop(settings, "colormap")
        layout.prop(settings, "density")
        layout.prop(settings, "early_termination")
        layout.prop(settings, "threads")


CLASSES = (GAUSSVDB_PT_render,)
