"""Scene render settings (Scene.gaussvdb): mode, transfer function, quality."""

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
)

MODES = (
    ("PARTICLES", "Particles", "Each Gaussian classified by its value; closed-form optical depth"),
    ("FIELD", "Field", "Transfer function on the summed Gaussian field (post-classification DVR)"),
    ("REFERENCE", "Reference", "Direct volume render of the source voxels: the ground truth"),
    ("PAPER", "Paper", "The seed paper's closest-hit renderer, for comparison only"),
)

COLORMAPS = (
    "viridis", "plasma", "inferno", "magma", "cividis", "turbo", "jet", "coolwarm", "grayscale",
)


def _tag(self, context):
    self.id_data.update_tag()


def _colormap_changed(self, context):
    from . import transfer_ramp

    transfer_ramp.fill_from_colormap(self, self.colormap, self.colormap_alpha.lower())
    self.id_data.update_tag()


def _passes_changed(self, context):
    scene = self.id_data
    for layer in scene.view_layers:
        layer.update_render_passes()  # the compositor's Render Layers node shows the new sockets
    scene.update_tag()


class GaussVDBRenderSettings(bpy.types.PropertyGroup):
    mode: EnumProperty(name="Mode", items=MODES, default="PARTICLES", update=_tag)
    colormap: EnumProperty(
        name="Colormap",
        items=[(n, n.title(), f"{n} colormap") for n in COLORMAPS],
        default="viridis",
        update=_colormap_changed,
    )
    colormap_alpha: EnumProperty(
        name="Alpha", default="RAMP", update=_colormap_changed,
        description="The opacity a colormap preset writes into the ramp",
        items=(("RAMP", "Ramp", "Alpha rises linearly from 0 at the low end to 1 at the high end"),
               ("CONSTANT", "Constant", "Alpha 1 everywhere (density alone sets the opacity)"),
               ("KEEP", "Keep", "Only the colours change; the ramp's alpha is kept")))
    ramp_texture: PointerProperty(name="Transfer Function", type=bpy.types.Texture)
    auto_range: BoolProperty(name="Auto Range", default=True, update=_tag,
                             description="Value range from the data of the objects rendered")
    value_min: FloatProperty(name="Min", default=0.0, update=_tag)
    value_max: FloatProperty(name="Max", default=1.0, update=_tag)
    log_scale: BoolProperty(name="Log Scale", default=False, update=_tag)
    density: FloatProperty(name="Density", default=10.0, min=0.0, soft_max=1000.0, update=_tag,
                           description="Extinction per world unit where the transfer function's alpha is 1")
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


CLASSES = (GaussVDBRenderSettings,)


def register_extra():
    bpy.types.Scene.gaussvdb = PointerProperty(type=GaussVDBRenderSettings)


def unregister_extra():
    if hasattr(bpy.types.Scene, "gaussvdb"):
        del bpy.types.Scene.gaussvdb
