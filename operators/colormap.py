"""Properties editor > transfer function > colormap menu: fill the ramp from a colormap."""

import bpy
from bpy.props import EnumProperty

from ..gaussvdb_addon.properties.transfer_settings import COLORMAP_ITEMS, target
from ..kernels import colormap_names


class GAUSSVDB_OT_colormap_pick(bpy.types.Operator):
    """Fill the transfer function ramp from a colormap (asks first when the ramp was edited by hand)"""

    bl_idname = "gaussvdb.colormap_pick"
    bl_label = "Load Colormap"
    bl_options = {"REGISTER", "UNDO"}

    colormap: EnumProperty(name="Colormap", items=COLORMAP_ITEMS)

    def invoke(self, context, event):
        from ..gaussvdb_addon.properties import transfer_ramp

        if transfer_ramp.is_edited(target(context)):
            return context.window_manager.invoke_confirm(
                self, event, title="Replace the Edited Ramp?", confirm_text="Replace",
                message=f"The ramp was edited by hand; {colormap_names.label(self.colormap)} replaces it")
        return self.execute(context)

    def execute(self, context):
        from ..gaussvdb_addon.properties import transfer_ramp

        s = target(context)
        transfer_ramp.fill_from_colormap(s, self.colormap, s.colormap_alpha.lower())
        s.colormap = self.colormap  # the ramp is no longer edited: the update fills the same
        s.id_data.update_tag()
        return {"FINISHED"}


CLASSES = (GAUSSVDB_OT_colormap_pick,)
