"""The GAUSSVDB render engine: a thin class; the work happens in final_render/viewport and kernels."""

import bpy

# Built-in panels that make sense for this engine (Cycles' get_panels() pattern, in reverse:
# we opt in to the panels we want rather than out of the ones we do not).
_COMPAT_PANELS = (
    "RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_output", "RENDER_PT_encoding",
    "RENDER_PT_color_management", "RENDER_PT_color_management_curves",
    "RENDER_PT_post_processing", "RENDER_PT_stamp", "RENDER_PT_dimensions", "RENDER_PT_time_stretching",
    "RENDER_PT_format_presets", "RENDER_PT_output_views", "RENDER_PT_stamp_note", "RENDER_PT_stamp_burn",
    "DATA_PT_camera", "DATA_PT_lens", "DATA_PT_camera_display", "DATA_PT_camera_dof",
    "DATA_PT_context_camera", "DATA_PT_camera_safe_areas", "DATA_PT_custom_props_camera",
    "DATA_PT_context_pointcloud", "DATA_PT_pointcloud_attributes", "DATA_PT_custom_props_pointcloud",
    "OBJECT_PT_context_object", "OBJECT_PT_transform", "OBJECT_PT_relations", "OBJECT_PT_collections",
    "OBJECT_PT_visibility", "OBJECT_PT_display", "OBJECT_PT_custom_props",
    "VIEWLAYER_PT_layer", "VIEWLAYER_PT_layer_passes",
    "SCENE_PT_scene", "SCENE_PT_unit", "SCENE_PT_custom_props",
    "WORLD_PT_context_world", "TEXTURE_PT_context", "TEXTURE_PT_colors", "TEXTURE_PT_colors_ramp",
)


class GaussVDBRenderEngine(bpy.types.RenderEngine):
    bl_idname = "GAUSSVDB"
    bl_label = "GaussVDB"
    bl_use_preview = False
    bl_use_postprocess = True
    bl_use_shading_nodes_custom = False

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.viewport = None

    def __del__(self):
        viewport = getattr(self, "viewport", None)
        if viewport is not None:
            viewport.stop()

    def render(self, depsgraph):
        from . import final_render

        final_render.render(self, depsgraph)

    def update_render_passes(self, scene=None, renderlayer=None):
        from . import final_render

        final_render.register_passes(self, scene, renderlayer)

    def view_update(self, context, depsgraph):
        from . import viewport

        if self.viewport is None:
            self.viewport = viewport.ViewportSession(self)
        self.viewport.update(context, depsgraph)

    def view_draw(self, context, depsgraph):
        if self.viewport is not None:
            self.viewport.draw(context, depsgraph)


CLASSES = (GaussVDBRenderEngine,)


def _panels():
    for name in _COMPAT_PANELS:
        panel = getattr(bpy.types, name, None)
        if panel is not None and hasattr(panel, "COMPAT_ENGINES"):
            yield panel


def register_extra():
    for panel in _panels():
        panel.COMPAT_ENGINES.add(GaussVDBRenderEngine.bl_idname)


def unregister_extra():
    for panel in _panels():
        panel.COMPAT_ENGINES.discard(GaussVDBRenderEngine.bl_idname)
