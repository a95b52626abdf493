"""Object properties panel: source, LODs held, Viewport/Render LOD, per-LOD figures."""

import bpy


class GAUSSVDB_PT_object(bpy.types.Panel):
    bl_label = "GaussVDB"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.gaussvdb.is_gaussvdb

    def draw(self, context):
        settings = context.object.gaussvdb
        layout = self.layout
        layout.use_property_split = True
        layout.prop(settings, "source_file")
        layout.prop(settings, "grid_name")
        layout.prop(settings, "viewport_lod")
        layout.prop(settings, "render_lod")


CLASSES = (GAUSSVDB_PT_object,)
