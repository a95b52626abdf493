"""The transfer-function properties, one definition for the scene (Scene.gaussvdb: the default)
and each object (Object.gaussvdb: used when its "Use Scene Transfer Function" is off).

``colormap`` fills the editable ramp (transfer_ramp). A ramp edited by hand is kept: picking
another colormap through the property then leaves it alone (the panel shows "Edited"), and the
panel's colormap menu asks before replacing it (GAUSSVDB_OT_colormap_pick), the way Blender keeps a
modified preset until one is picked again on purpose.
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, PointerProperty, StringProperty

from ...kernels import colormap_names

COLORMAP_ITEMS = colormap_names.enum_items()
ALPHA_ITEMS = (("RAMP", "Ramp", "Alpha rises linearly from 0 at the low end to 1 at the high end"),
               ("CONSTANT", "Constant", "Alpha 1 everywhere (density alone sets the opacity)"),
               ("KEEP", "Keep", "Only the colours change; the ramp's alpha is kept"))


def _tag(self, context):
    # Add-on properties fire no depsgraph update by themselves (Blender #62325).
    self.id_data.update_tag()


def _colormap_changed(self, context):
    from . import transfer_ramp

    if not transfer_ramp.is_edited(self):
        transfer_ramp.fill_from_colormap(self, self.colormap, self.colormap_alpha.lower())
    self.id_data.update_tag()


class TransferFunctionProps:
    """Mixin of the PropertyGroups that carry a transfer function (Blender registers the
    annotations of base classes too)."""

    colormap: EnumProperty(name="Colormap", items=COLORMAP_ITEMS, default=colormap_names.DEFAULT,
                           update=_colormap_changed,
                           description="Colormap preset written into the transfer function ramp")
    colormap_alpha: EnumProperty(name="Alpha", default="RAMP", items=ALPHA_ITEMS,
                                 update=_colormap_changed,
                                 description="The opacity a colormap preset writes into the ramp")
    ramp_texture: PointerProperty(name="Transfer Function", type=bpy.types.Texture,
                                  description="Blend texture whose colour ramp maps data values "
                                              "to colour and opacity")
    ramp_signature: StringProperty(name="Ramp Signature", options={"HIDDEN"},
                                   description="The ramp as last loaded from a colormap or preset "
                                               "(a differing ramp was edited by hand)")
    auto_range: BoolProperty(name="Auto Range", default=True, update=_tag,
                             description="Value range from the voxels of the grids drawn (the "
                                         "same for every LOD)")
    value_min: FloatProperty(name="Min", default=0.0, update=_tag,
                             description="Data value at the ramp's left end (Auto Range off)")
    value_max: FloatProperty(name="Max", default=1.0, update=_tag,
                             description="Data value at the ramp's right end (Auto Range off)")
    log_scale: BoolProperty(name="Log Scale", default=False, update=_tag,
                            description="Spread the ramp over log(value) (for data spanning decades)")
    density: FloatProperty(name="Density", default=10.0, min=0.0, soft_max=1000.0, update=_tag,
                           description="Extinction where the transfer function's alpha is 1, in "
                                       "the Density Unit (per object size: optical depth across "
                                       "the object's box diagonal)")
    density_unit: EnumProperty(
        name="Density Unit", default="OBJECT", update=_tag,
        description="What Density is measured per",
        items=(("OBJECT", "Per Object Size",
                "Optical depth across the diagonal of the largest rendered object's box: the same "
                "image at any scale (10: about ten across)"),
               ("WORLD", "Per World Unit", "Extinction per world unit (scene length unit)")))

    def load_ramp(self, stops, interpolation="LINEAR"):
        """Replace the ramp by ``stops`` [(position, (r, g, b, a)), ...] (linear colour), as a
        saved colormap preset does; the result counts as not edited."""
        from . import transfer_ramp

        transfer_ramp.load_stops(self, stops, interpolation)


def target(context):
    """The transfer-function settings a button or preset acts on (object's or scene's)."""
    return getattr(context, "gaussvdb_tf", None) or context.scene.gaussvdb
