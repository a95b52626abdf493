"""The GAUSSVDB render engine: a thin class; the work happens in final_render/viewport and kernels."""

import bpy

# Blender's own panels shown for this engine, Cycles' get_panels() way: every panel meant for any
# engine (its COMPAT_ENGINES holds BLENDER_RENDER: output, colour management, camera with its
# background images, mesh and light data, physics with the Mantaflow domain, ...) except the ones
# that do nothing here, plus Blender's Passes parent panel (our Data sub-panel hangs under it).
# Camera depth of field is EEVEE/Workbench-only and stays hidden: the engine has no DOF.
HIDDEN_PANELS = (
    "DATA_PT_preview", "TEXTURE_PT_preview",  # no material/texture previews (bl_use_preview)
    "RENDER_PT_stereoscopy", "DATA_PT_camera_stereoscopy",  # one view only
    "RENDER_PT_freestyle", "MATERIAL_PT_freestyle_line",  # no Freestyle lines
    "EEVEE_MATERIAL_PT_viewport_settings", "DATA_PT_context_lightprobe",
)
HIDDEN_PREFIXES = ("VIEWLAYER_PT_freestyle", "DATA_PT_lightprobe")  # Freestyle, EEVEE light probes
EXTRA_PANELS = ("VIEWLAYER_PT_layer_passes",)


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
        # object's own lookup, not bpy's: by the time of the last __del__ Blender may have freed
        # the engine (5.2 then raises ReferenceError on any attribute); our own one is still here
        try:
            viewport = object.__getattribute__(self, "viewport")
        except (AttributeError, ReferenceError):
            return
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


def _all_panels(cls=bpy.types.Panel):
    for sub in cls.__subclasses__():
        yield sub
        yield from _all_panels(sub)


def compat_panels():
    """Blender's panels this engine opts in to (the rule above, applied to the panels loaded)."""
    out = []
    for panel in _all_panels():
        name = panel.__name__
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if not isinstance(engines, set):
            continue
        wanted = name in EXTRA_PANELS or ("BLENDER_RENDER" in engines and name not in HIDDEN_PANELS
                                          and not name.startswith(HIDDEN_PREFIXES))
        if wanted and not name.startswith("GAUSSVDB_"):
            out.append(panel)
    return out


_OPTED_IN = []


def register_extra():
    _OPTED_IN[:] = compat_panels()
    for panel in _OPTED_IN:
        panel.COMPAT_ENGINES.add(GaussVDBRenderEngine.bl_idname)


def unregister_extra():
    for panel in _OPTED_IN:
        panel.COMPAT_ENGINES.discard(GaussVDBRenderEngine.bl_idname)
    _OPTED_IN.clear()
