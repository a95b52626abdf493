"""Preferences > Add-ons > GaussVDB: the compiled kernels (state, cache folder and size,
Compile Now)."""

import bpy

from ..engine import warmup_service


class GAUSSVDB_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = __package__.rsplit(".", 2)[0]  # the add-on's package (bl_ext.<repo>.gaussvdb)

    def draw(self, context):
        layout = self.layout
        box = layout.box()
        box.label(text="Compiled kernels", icon="SCRIPT")
        box.label(text=warmup_service.state_text())
        col = box.column(align=True)
        col.label(text=f"Cache: {warmup_service.cache_folder()}")
        col.label(text=f"Size: {warmup_service.cache_size_text()}")
        row = box.row()
        if warmup_service.running():
            st = warmup_service.status()
            n = st.get("count") or 1
            row.progress(factor=int(st.get("index", 0)) / n, type="BAR",
                         text=f"{st.get('name') or 'starting'}")
            row.operator("gaussvdb.stop_compile", icon="CANCEL")
        else:
            row.operator("gaussvdb.compile_kernels", icon="PLAY")


CLASSES = (GAUSSVDB_AP_preferences,)
