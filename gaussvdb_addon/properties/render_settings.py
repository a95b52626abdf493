"""Scene render settings (Scene.gaussvdb): mode, transfer function, quality; the Value pass
switch of each view layer (ViewLayer.gaussvdb). Threads, the Depth pass and the background are
Blender's own settings (see blender_settings.py)."""

import bpy
from bpy.app.handlers import persistent
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    PointerProperty,
    StringProperty,
)

from ...kernels import mode_names
from .transfer_settings import TransferFunctionProps

MODES = mode_names.enum_items()


def _tag(self, context):
    self.id_data.update_tag()


def _value_pass_changed(self, context):
    scene = self.id_data  # a view layer's settings belong to its scene
    for layer in scene.view_layers:
        layer.update_render_passes()  # the compositor's Render Layers node shows the new socket
    scene.update_tag()


def _device_changed(self, context):
    from ..engine import gpu_choice

    gpu_choice.device_changed(self, context)


class GaussVDBRenderSettings(TransferFunctionProps, bpy.types.PropertyGroup):
    device: EnumProperty(name="Device", default="CPU", update=_device_changed,
                         description="Device to render with",
                         items=(("CPU", "CPU", "Render on the CPU (numba kernels): every mode, "
                                               "lit volumes and shadows"),
                                ("GPU", "GPU Compute", "Render with compute shaders on Blender's GPU "
                                                       "module (OpenGL, Vulkan, Metal); falls back "
                                                       "to the CPU where no GPU context can be had "
                                                       "or for what it does not draw")))
    # the transfer function (colormap, ramp, range, log scale, density): transfer_settings
    mode: EnumProperty(name="Mode", items=MODES, default=mode_names.DEFAULT.upper(), update=_tag,
                       description="How the Gaussians are turned into an image")
    early_termination: FloatProperty(name="Early Termination", default=1e-3, min=0.0, max=0.5,
                                     precision=4, subtype="FACTOR", update=_tag,
                                     description="Stop a ray when its transmittance (the fraction "
                                                 "of light left) falls below this (0: never)")
    step_scale: FloatProperty(name="Step", default=0.5, min=0.01, max=4.0, update=_tag,
                              description="Sample step of the field and reference modes, in voxels "
                                          "(splat mode: in cells of its lattice)")
    tau_max: FloatProperty(name="Max Optical Depth", default=0.1, min=1e-4, max=10.0, update=_tag,
                           description="Particles mode: overlapping Gaussians of different colours are "
                                       "mixed over stretches of at most this optical depth x colour "
                                       "spread. Lower is more exact, higher is faster (0.3: about 12% "
                                       "faster, under one 8-bit step from converged)")
    level_set_color: EnumProperty(
        name="Level Set Colour",
        description="How level-set surfaces are coloured",
        items=(("X", "X", "Colormap over world X across the surface's box"),
               ("Y", "Y", "Colormap over world Y across the surface's box"),
               ("Z", "Height (Z)", "Colormap over world Z across the surface's box"),
               ("CONSTANT", "Constant", "One colour")),
        default="Z", update=_tag)
    level_set_constant: FloatVectorProperty(name="Surface Colour", subtype="COLOR", size=3,
                                            default=(0.8, 0.8, 0.8), min=0.0, max=1.0, update=_tag,
                                            description="Colour of level-set surfaces (Constant)")
    background: FloatVectorProperty(name="Background", subtype="COLOR", size=3,
                                    default=(0.0, 0.0, 0.0), min=0.0, update=_tag,
                                    description="Colour behind the volumes when the scene has no "
                                                "World (otherwise the World's colour is used)")

    # -- colour legend (kernels/render/scene/legend.py draws it) -----------------------------------
    show_legend: BoolProperty(name="Legend", default=False, update=_tag,
                              description="Draw a scalar bar (colormap, range, ticks, grid name) "
                                          "over the render and the viewport")
    legend_corner: EnumProperty(name="Corner", default="BOTTOM_RIGHT", update=_tag,
                                description="Corner of the image the legend sits in",
                                items=(("TOP_LEFT", "Top Left", "The image's top left corner"),
                                       ("TOP_RIGHT", "Top Right", "The image's top right corner"),
                                       ("BOTTOM_LEFT", "Bottom Left", "The image's bottom left corner"),
                                       ("BOTTOM_RIGHT", "Bottom Right",
                                        "The image's bottom right corner")))
    legend_size: FloatProperty(name="Size", default=0.4, min=0.1, max=1.0, subtype="FACTOR",
                               update=_tag, description="Legend height, as a fraction of the image height")
    legend_units: StringProperty(name="Units", default="", update=_tag,
                                 description="Shown after the grid name (e.g. kg/m3)")

    # -- sequences (gaussvdb_addon/engine/sequence_frames.py) --------------------------------------
    sequence_memory: FloatProperty(name="Memory Budget", default=2048.0, min=0.0, soft_max=65536.0,
                                   precision=0,
                                   description="Megabytes of converted sequence frames kept in "
                                               "memory, least recently used out (0: only the "
                                               "frames on screen)")
    use_sequence_disk_cache: BoolProperty(name="Disk Cache", default=False,
                                          description="Keep converted sequence frames on disk (the "
                                                      "compact encoding), so playback and renders "
                                                      "elsewhere do not convert again")
    sequence_cache_dir: StringProperty(name="Cache Folder", default="", subtype="DIR_PATH",
                                       description="Folder of the disk cache (empty: "
                                                   "gaussvdb_cache next to the .blend)")


class GaussVDBViewLayerSettings(bpy.types.PropertyGroup):
    use_pass_value: BoolProperty(name="Value", default=False, update=_value_pass_changed,
                                 description="Render pass: opacity-weighted mean data value along "
                                             "the ray (0 where nothing is hit)")


CLASSES = (GaussVDBRenderSettings, GaussVDBViewLayerSettings)


# -- settings of older versions, now Blender's own -------------------------------------------------
def migrate(scene):
    """Move the settings older versions kept on Scene.gaussvdb to Blender's: threads ->
    Render > Performance, use_pass_depth -> each view layer's Z pass, use_pass_value -> each
    view layer's Value pass. Files saved with them still hold them as ID properties."""
    old = scene.gaussvdb  # the stored values are still in the group, as plain ID properties
    changed = False
    threads = old.get("threads")
    if threads is not None:
        if int(threads) > 0:
            scene.render.threads_mode = "FIXED"
            scene.render.threads = int(threads)
        del old["threads"]
        changed = True
    for key in ("use_pass_depth", "use_pass_value"):
        on = old.get(key)
        if on is None:
            continue
        for layer in scene.view_layers:
            if on and key == "use_pass_depth":
                layer.use_pass_z = True
            elif on:
                layer.gaussvdb.use_pass_value = True
        del old[key]
        changed = True
    return changed


@persistent
def _migrate_on_load(_filepath=""):
    for scene in bpy.data.scenes:
        migrate(scene)


def register_extra():
    bpy.types.Scene.gaussvdb = PointerProperty(type=GaussVDBRenderSettings)
    bpy.types.ViewLayer.gaussvdb = PointerProperty(type=GaussVDBViewLayerSettings)
    if _migrate_on_load not in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.append(_migrate_on_load)


def unregister_extra():
    if _migrate_on_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_migrate_on_load)
    for owner in (bpy.types.ViewLayer, bpy.types.Scene):
        if hasattr(owner, "gaussvdb"):
            del owner.gaussvdb
