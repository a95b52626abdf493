"""File > Import > OpenVDB as Gaussians (.vdb), and drag-and-drop of .vdb files onto the viewport.

Thin: the work is in gaussvdb_addon/io/importer.py (convert everything first, then create objects).

Long imports in the UI: `execute` runs the conversion one step (one grid x one LOD) per timer event
as a modal operator (gaussvdb_addon/io/modal_import.py's steps), with the window manager's progress
bar; Esc between steps cancels and leaves the scene as it was (no datablock exists before the last
step). When the kernels it needs are not compiled yet, its first steps wait for the background
warm-up (engine/warmup_service.py) instead of compiling with the interface frozen. Headless
(`blender -b`, the bpy module, scripts) and Redo run the same steps synchronously, with no event
loop to listen to.
"""

import os

import bpy
from bpy.props import BoolProperty, CollectionProperty, EnumProperty, FloatProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from ..kernels import lod_names

# Files larger than this run as a modal (cancellable) job in the UI; smaller ones finish at once.
MODAL_MIN_BYTES = 4 << 20


class GAUSSVDB_OT_import_vdb(bpy.types.Operator, ImportHelper):
    """Import the grids of an OpenVDB file as Gaussian point clouds"""

    bl_idname = "gaussvdb.import_vdb"
    bl_label = "Import OpenVDB as Gaussians"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".vdb"
    filter_glob: StringProperty(default="*.vdb", options={"HIDDEN"})
    directory: StringProperty(subtype="DIR_PATH", options={"HIDDEN", "SKIP_SAVE", "SKIP_PRESET"})
    files: CollectionProperty(type=bpy.types.OperatorFileListElement,
                              options={"HIDDEN", "SKIP_SAVE", "SKIP_PRESET"})

    grids: StringProperty(name="Grids", default="", options={"SKIP_PRESET"},
                          description="Comma-separated grid names (empty: every scalar grid; of a "
                                      "Mantaflow cache only density, not the domain-wide shadow)")
    color_grid: StringProperty(name="Colour Grid", default="", options={"SKIP_PRESET"},
                               description="Another grid of the same file that colours the "
                                           "imported grids (e.g. a fire's temperature, opacity "
                                           "by density); empty: each is coloured by itself")
    lods: EnumProperty(name="LODs", items=lod_names.enum_items(), options={"ENUM_FLAG"},
                       default={lod_names.DEFAULT},
                       description="LOD presets stored on each object (shift-click for several)")
    tolerance: FloatProperty(name="Tolerance", default=lod_names.DEFAULT_TOLERANCE, min=0.0,
                             soft_max=0.2, precision=3,
                             description="Adaptive LOD: largest field NRMSE over the active voxels")
    weights: EnumProperty(name="Weights", default=lod_names.WEIGHTS[0],
                          items=lod_names.weight_items(),
                          description="How each Gaussian's size and amplitude are chosen")
    level_set_band: BoolProperty(name="Zero-Crossing Band Only", default=True,
                                 description="Level sets: keep only Gaussians whose voxels straddle the surface")
    vector_magnitude: BoolProperty(name="Vector Grids as Magnitude", default=False,
                                   description="Import vec3 grids (velocity) as their magnitude")
    use_sequence: BoolProperty(name="Sequence", default=True,
                               description="A numbered file with numbered siblings (or several "
                                           "numbered files selected) is one sequence: one object "
                                           "per grid that follows the timeline")
    measure_error: BoolProperty(name="Measure Field Error", default=True,
                                description="Compare each LOD's Gaussian field with the voxels (shown in the panel)")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        row = layout.row(align=True)
        row.menu("GAUSSVDB_MT_import_presets", text=bpy.types.GAUSSVDB_MT_import_presets.bl_label)
        row.operator("gaussvdb.import_preset_add", text="", icon="ADD")
        row.operator("gaussvdb.import_preset_add", text="", icon="REMOVE").remove_active = True
        layout.prop(self, "grids")
        if not self.grids.strip():
            from ..gaussvdb_addon.io import importer

            layout.label(text=importer.default_grids_hint(self.filepath), icon="INFO")
        layout.prop(self, "color_grid")
        col = layout.column(heading="LODs")
        col.prop(self, "lods")
        if self.lods & set(lod_names.TOLERANCE_PRESETS):
            layout.prop(self, "tolerance")
        layout.prop(self, "weights")
        layout.prop(self, "level_set_band")
        layout.prop(self, "vector_magnitude")
        layout.prop(self, "measure_error")
        from ..gaussvdb_addon.io import sequence_import

        if sequence_import.has_siblings(self.filepath):
            layout.prop(self, "use_sequence")

    def invoke(self, context, event):
        # Drag-and-drop (FileHandler) sets the path: show the options, then import.
        return self.invoke_popup(context)

    def _options(self):
        """The dialog's settings as the ConvertOptions the import converts with."""
        from ..kernels.convert_options import ConvertOptions

        return ConvertOptions(grids=self.grids, lods=sorted(self.lods), weights=self.weights,
                              level_set_band=self.level_set_band,
                              vector_magnitude=self.vector_magnitude,
                              compute_error=self.measure_error, tolerance=self.tolerance,
                              color_grid=self.color_grid.strip())

    def execute(self, context):
        from ..gaussvdb_addon.engine import warmup_service
        from ..gaussvdb_addon.io import importer, sequence_import
        from ..kernels import warmup

        if not self.lods:  # (scripts may import a grid alone: importer.import_vdb(path, lods=()))
            self.report({"ERROR"}, "choose at least one LOD preset")
            return {"CANCELLED"}
        paths = importer.selected_paths(self.filepath, self.directory, self.files)
        big = sum(os.path.getsize(p) for p in paths if os.path.isfile(p)) >= MODAL_MIN_BYTES
        if self.use_sequence and sequence_import.any_sequence(paths):
            big = False  # in one go: every frame is read once, then one frame is converted
        ui = context.window is not None and not bpy.app.background and not self.options.is_repeat
        # kernels not compiled yet: wait for the background warm-up (modal, Esc) rather than
        # compile here with the interface frozen
        wait = warmup_service.needed(warmup.jobs_for(lods=sorted(self.lods),
                                                     error=self.measure_error)) if ui else []
        if ui and (big or wait):
            return self._start_modal(context, paths, wait)
        try:
            _objects, message = importer.import_files(context, paths, options=self._options(),
                                                      sequence=self.use_sequence,
                                                      progress=context.window_manager)
        except importer.VDBImportError as err:
            self.report({"ERROR"}, str(err))
            return {"CANCELLED"}
        self.report({"INFO"}, message)
        return {"FINISHED"}

    # -- the modal path (UI only) ----------------------------------------------------------------
    def _start_modal(self, context, paths, wait):
        from ..gaussvdb_addon.io import modal_import

        self._steps = modal_import.import_steps(context, paths, self._options(),
                                                sequence=self.use_sequence, wait=wait)
        wm = context.window_manager
        wm.progress_begin(0, 1000)
        self._timer = wm.event_timer_add(0.01, window=context.window)
        wm.modal_handler_add(self)
        self._status(context, "Compiling GaussVDB kernels in the background..." if wait
                     else "Importing OpenVDB as Gaussians...")
        return {"RUNNING_MODAL"}

    @staticmethod
    def _status(context, text):
        context.workspace.status_text_set(f"{text} (Esc to cancel)")

    def _stop_modal(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        context.workspace.status_text_set(None)
        self._steps.close()

    def modal(self, context, event):
        from ..gaussvdb_addon.io import importer

        if event.type == "ESC":
            self._stop_modal(context)
            self.report({"WARNING"}, "Import cancelled: nothing was created")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"RUNNING_MODAL"}  # block other input while importing (Esc still reaches us)
        try:
            try:
                fraction, text = next(self._steps)
                context.window_manager.progress_update(int(1000 * fraction))
                self._status(context, text)
                return {"RUNNING_MODAL"}
            except StopIteration as stop:
                objs, message = stop.value
            self._stop_modal(context)
        except importer.VDBImportError as err:
            self._stop_modal(context)
            self.report({"ERROR"}, str(err))
            return {"CANCELLED"}
        self.report({"WARNING"} if "NaN/Inf" in message else {"INFO"}, message)
        return {"FINISHED"}

    def cancel(self, context):
        if getattr(self, "_timer", None) is not None:
            self._stop_modal(context)


class GAUSSVDB_FH_vdb(bpy.types.FileHandler):
    bl_idname = "GAUSSVDB_FH_vdb"
    bl_label = "OpenVDB as Gaussians"
    bl_import_operator = "gaussvdb.import_vdb"
    bl_file_extensions = ".vdb"

    @classmethod
    def poll_drop(cls, context):
        return context.area is not None and context.area.type == "VIEW_3D"


def menu_import(self, context):
    self.layout.operator(GAUSSVDB_OT_import_vdb.bl_idname, text="OpenVDB as Gaussians (.vdb)")


CLASSES = (GAUSSVDB_OT_import_vdb, GAUSSVDB_FH_vdb)


def register_extra():
    bpy.types.TOPBAR_MT_file_import.append(menu_import)


def unregister_extra():
    bpy.types.TOPBAR_MT_file_import.remove(menu_import)
