"""Scene render settings (Scene.gaussvdb): mode, transfer function, quality."""

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from .transfer_settings import TransferFunctionProps

MODES = (
    ("PARTICLES", "Particles", "Each Gaussian classified by its value; closed-form optical depth"),
    ("FIELD", "Field", "Transfer function on the summed Gaussian field (post-classification DVR)"),
    ("REFERENCE", "Reference", "Direct volume render of the source voxels: the ground truth"),
    ("PAPER", "Paper", "The seed paper's closest-hit renderer, for comparison only"),
)


def _tag(self, context):
    self.id_data.update_tag()


def _passes_changed(self, context):
    scene = self.id_data
    for layer in scene.view_layers:
        layer.update_render_passes()  # the compositor's Render Layers node shows the new sockets
    scene.update_tag()


class GaussVDBRenderSettings(TransferFunctionProps, bpy.types.PropertyGroup):
    # the transfer function (colormap, ramp, range, log scale, density): transfer_settings
    mode: EnumProperty(name="Mode", items=MODES, default="PARTICLES", update=_tag)
    early_termination: FloatProperty(name="Early Termination", default=1e-3, min=0.0, max=0.5,
                                     precision=4, update=_tag,
                                     description="Stop a ray when its transmittance falls below this (0: never)")
    step_scale: FloatProperty(name="Step", default=0.5, min=0.01, max=4.0, update=_tag,
                              description="Sample step of the field and reference modes, in voxels")
    tau_max: FloatProperty(name="Max Optical Depth", default=0.1, min=1e-4, max=10.0, update=_tag,
                           description="Particles mode: subdivide overlapping segments until this optical depth")
    threads: IntProperty(name="Threads", default=0, min=0, max=1024, update=_tag,
                         description="CPU threads (0: all)")
    level_set_color: EnumProperty(
        name="Level Set Colour",
        items=(("X", "X", "Colormap over world X across the surface's box"),
               ("Y", "Y", "Colormap over world Y across the surface's box"),
               ("Z", "Height (Z)", "Colormap over world Z across the surface's box"),
               ("CONSTANT", "Constant", "One colour")),
        default="Z", update=_tag)
    level_set_constant: FloatVectorProperty(name="Surface Colour", subtype="COLOR", size=3,
                                            default=(0.8, 0.8, 0.8), min=0.0, max=1.0, update=_tag)
    background: FloatVectorProperty(name="Background", subtype="COLOR", size=3,
                                    default=(0.0, 0.0, 0.0), min=0.0, update=_tag)
    use_pass_depth: BoolProperty(name="Depth", default=False, update=_passes_changed,
                                 description="World distance where the opacity reaches 0.5 (1e10: none)")
    use_pass_value: BoolProperty(name="Value", default=False, update=_passes_changed,
                                 description="Opacity-weighted mean data value along the ray")

    # -- colour legend (kernels/render/legend.py draws it) -----------------------------------
    show_legend: BoolProperty(name="Legend", default=False, update=_tag,
                              description="Draw a scalar bar (colormap, range, ticks, grid name) "
                                          "over the render and the viewport")
    legend_corner: EnumProperty(name="Corner", default="BOTTOM_RIGHT", update=_tag,
                                items=(("TOP_LEFT", "Top Left", ""), ("TOP_RIGHT", "Top Right", ""),
                                       ("BOTTOM_LEFT", "Bottom Left", ""),
                                       ("BOTTOM_RIGHT", "Bottom Right", "")))
    legend_size: FloatProperty(name="Size", default=0.4, min=0.1, max=1.0, subtype="FACTOR",
                               update=_tag, description="Legend height, as a fraction of the image height")
    legend_units: StringProperty(name="Units", default="", update=_tag,
                                 description="Shown after the grid name (e.g. kg/m3)")


CLASSES = (GaussVDBRenderSettings,)


def register_extra():
    bpy.types.Scene.gaussvdb = PointerProperty(type=GaussVDBRenderSettings)


def unregister_extra():
    if hasattr(bpy.types.Scene, "gaussvdb"):
        del bpy.types.Scene.gaussvdb
