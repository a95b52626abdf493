"""Properties-editor panels of the GAUSSVDB engine: Render (mode, transfer function with its
colormap presets, performance, film), View Layer > Passes > Data, World > Surface."""

import bpy
from bl_ui.utils import PresetPanel

from ..engine import blender_settings
from . import presets


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
        layout.prop(s, "device")  # like Cycles' Device
        layout.prop(s, "mode")
        col = layout.column(align=True)
        col.prop(s, "early_termination")
        if s.mode == "PARTICLES":
            col.prop(s, "tau_max")
        elif s.mode in ("FIELD", "SPLAT", "REFERENCE"):
            col.prop(s, "step_scale")


class GAUSSVDB_PT_colormap_presets(PresetPanel, bpy.types.Panel):
    bl_label = "Colormap Presets"
    preset_subdir = presets.COLORMAP_PRESET_SUBDIR
    preset_operator = "script.execute_preset"
    preset_add_operator = "gaussvdb.colormap_preset_add"


class GAUSSVDB_PT_transfer(_Base, bpy.types.Panel):
    bl_label = "Transfer Function"
    bl_parent_id = "GAUSSVDB_PT_render"

    def draw_header_preset(self, context):
        GAUSSVDB_PT_colormap_presets.draw_panel_header(self.layout)

    def draw(self, context):
        from ..engine import scene_sync
        from . import transfer_ui

        transfer_ui.draw_transfer(self.layout, context.scene.gaussvdb,
                                  scene_sync.scene_tf_users(context.scene), presets_row=False)


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


class GAUSSVDB_PT_performance(_Base, bpy.types.Panel):
    bl_label = "Performance"
    bl_parent_id = "GAUSSVDB_PT_render"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        rd = context.scene.render
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column(align=True)
        col.prop(rd, "threads_mode")  # Blender's own setting, as Cycles uses it
        sub = col.column(align=True)
        sub.enabled = rd.threads_mode == "FIXED"
        sub.prop(rd, "threads")


class GAUSSVDB_PT_sequences(_Base, bpy.types.Panel):
    bl_label = "Sequences"
    bl_parent_id = "GAUSSVDB_PT_render"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        from ..engine import sequence_frames

        s = context.scene.gaussvdb
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "sequence_memory", text="Memory (MB)")
        cache = sequence_frames.CACHE
        layout.label(text=f"{len(cache)} frames held, {cache.nbytes / 1e6:.0f} MB")
        layout.prop(s, "use_sequence_disk_cache")
        sub = layout.column()
        sub.active = s.use_sequence_disk_cache
        sub.prop(s, "sequence_cache_dir")


class GAUSSVDB_PT_film(_Base, bpy.types.Panel):
    bl_label = "Film"
    bl_parent_id = "GAUSSVDB_PT_render"

    def draw(self, context):
        scene = context.scene
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(scene.render, "film_transparent", text="Transparent")
        sub = layout.column()
        sub.active = not scene.render.film_transparent
        if scene.world is None:
            sub.prop(scene.gaussvdb, "background")
        else:
            _draw_world_color(sub, scene.world, text="Background")


def _draw_world_color(layout, world, text="Color"):
    node = blender_settings.surface_background_node(world)
    if node is not None and not node.inputs["Color"].is_linked:
        layout.prop(node.inputs["Color"], "default_value", text=text)
        layout.prop(node.inputs["Strength"], "default_value", text="Strength")
    else:
        layout.prop(world, "color", text=text)


class GAUSSVDB_PT_passes_data(bpy.types.Panel):
    """View Layer Properties > Passes > Data for this engine (the Passes parent is Blender's)."""

    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "view_layer"
    bl_label = "Data"
    bl_parent_id = "VIEWLAYER_PT_layer_passes"
    COMPAT_ENGINES = {"GAUSSVDB"}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        layer = context.view_layer
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column(heading="Include", align=True)
        col.prop(layer, "use_pass_z", text="Depth")
        col.prop(layer.gaussvdb, "use_pass_value")


class GAUSSVDB_PT_world(bpy.types.Panel):
    """World Properties > Surface: the background colour this engine draws."""

    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "world"
    bl_label = "Surface"
    COMPAT_ENGINES = {"GAUSSVDB"}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES and context.world is not None

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        _draw_world_color(layout, context.world)


CLASSES = (GAUSSVDB_PT_colormap_presets, GAUSSVDB_PT_render,
           GAUSSVDB_PT_transfer, GAUSSVDB_PT_level_sets, GAUSSVDB_PT_performance,
           GAUSSVDB_PT_sequences, GAUSSVDB_PT_film,
           GAUSSVDB_PT_passes_data, GAUSSVDB_PT_world)
