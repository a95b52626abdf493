"""Object properties panel: source, class, LODs held, Viewport/Render LOD, Reload, clipping,
per-LOD figures (a UIList of Object.gaussvdb.lod_stats)."""

import math

import bpy

from ...kernels import lod_names
from ..io import schema
from ..properties import lod_figures

FIGURE_COLUMNS = ("LOD", "Gaussians", "Memory", "NRMSE", "Time")


def draw_color_grid(layout, settings):
    """Colour by a second grid: which one (set at import) and its colour map and range."""
    col = layout.column(heading="Colour")
    row = col.row()
    row.enabled = False
    row.prop(settings, "color_grid")
    col.prop(settings, "color_colormap")
    col.prop(settings, "color_auto_range")
    sub = col.column(align=True)
    sub.active = not settings.color_auto_range
    sub.prop(settings, "color_min")
    sub.prop(settings, "color_max")
    col.prop(settings, "color_log_scale")
    col.label(text="Opacity: the transfer function over " + (settings.grid_name or "the grid"),
              icon="INFO")


def draw_clip(layout, settings):
    """Clipping: plane, box, collection of Empties (object_settings.ClipProps)."""
    col = layout.column(heading="Clip", align=True)
    col.prop(settings, "clip_plane", text="Plane")
    col.prop(settings, "clip_box", text="Box")
    col.prop(settings, "clip_collection", text="Collection")


class GAUSSVDB_UL_lod_stats(bpy.types.UIList):
    """The LODs an object holds, one row of figures (FIGURE_COLUMNS) each."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        row = layout.row(align=True)
        row.label(text=lod_names.label(item.name))
        row.label(text=f"{item.count:,}")
        row.label(text=lod_figures.fmt_bytes(item.bytes))
        row.label(text="-" if math.isnan(item.nrmse) else f"{100 * item.nrmse:.2f}%")
        row.label(text=f"{item.seconds:.2f} s")


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
        layout.use_property_decorate = False
        col = layout.column()
        vol = settings.source_volume
        if vol is not None and vol.is_sequence:
            self._draw_sequence(context, layout, settings, vol)
        else:
            col.prop(settings, "source_file")
        row = col.row()
        row.enabled = False
        row.prop(settings, "grid_name")
        info = col.column(align=True)
        info.label(text=f"Class: {settings.grid_class.replace('_', ' ')}"
                        f" ({settings.value_type or 'float'}), {settings.weights} weights")
        if schema.lod_names(context.object):
            info.label(text=f"LODs held: {settings.lods.replace(',', ', ')}")
            col = layout.column(align=True)
            col.prop(settings, "viewport_lod", text="Viewport")
            col.prop(settings, "render_lod", text="Render")
        else:
            info.label(text="No Gaussians: drawn in Reference mode only", icon="INFO")
        layout.operator("gaussvdb.reload", icon="FILE_REFRESH")
        if settings.grid_class == "level_set":
            layout.prop(settings, "level_set_style")
        else:
            row = layout.row(align=True)
            row.prop(settings, "shading")
            if settings.shading == "LIT":
                row.prop(settings, "shadows")
            if settings.color_grid:
                draw_color_grid(layout, settings)
        draw_clip(layout, settings)

        if not len(settings.lod_stats):
            return
        row = layout.row(align=True)
        for head in FIGURE_COLUMNS:
            row.label(text=head)
        layout.template_list("GAUSSVDB_UL_lod_stats", "", settings, "lod_stats", settings,
                             "lod_stats_index", rows=len(settings.lod_stats))

    @staticmethod
    def _draw_sequence(context, layout, settings, vol):
        """Blender's Volume sequence settings (on the source Volume, shared by the grids of one
        sequence) and the file the current frame shows."""
        from ..engine import sequence_frames

        col = layout.column()
        col.prop(vol, "filepath", text="First Frame")
        sub = col.column(align=True)
        sub.prop(vol, "frame_duration", text="Frames")
        sub.prop(vol, "frame_start", text="Start")
        sub.prop(vol, "frame_offset", text="Offset")
        col.prop(vol, "sequence_mode", text="Mode")
        col.prop(settings, "sequence_range")
        try:
            pat, asked, shown = sequence_frames.file_number(context.object, context.scene.frame_current)
        except (ValueError, OSError):
            return
        if pat is None:
            text = "No frame number in the file name"
        elif shown is None:
            text = "No frame at this time" if asked is None else f"Frame {asked}: missing"
        else:
            text = pat.name(shown) + ("" if shown == asked else f" (holding: {asked} is missing)")
        col.label(text=text, icon="FILE_VOLUME")


CLASSES = (GAUSSVDB_UL_lod_stats, GAUSSVDB_PT_object)
