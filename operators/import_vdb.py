"""File > Import > OpenVDB as Gaussians (.vdb), and drag-and-drop of .vdb files onto the viewport."""

import bpy
from bpy.props import BoolProperty, CollectionProperty, EnumProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

LOD_ITEMS = (
    ("low", "Low", "One Gaussian per leaf (the paper's Low LOD)"),
    ("medium", "Medium", "4^3 blocks in dense leaves, 2^3 blocks or voxels in sparse ones"),
    ("high", "High", "2^3 blocks in dense leaves, one Gaussian per voxel in sparse ones"),
)


class GAUSSVDB_OT_import_vdb(bpy.types.Operator, ImportHelper):
    """Import the grids of an OpenVDB file as Gaussian point clouds"""

    bl_idname = "gaussvdb.import_vdb"
    bl_label = "Import OpenVDB as Gaussians"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".vdb"
    filter_glob: StringProperty(default="*.vdb", options={"HIDDEN"})
    directory: StringProperty(subtype="DIR_PATH", options={"HIDDEN", "SKIP_SAVE"})
    files: CollectionProperty(type=bpy.types.OperatorFileListElement, options={"HIDDEN", "SKIP_SAVE"})

    grids: StringProperty(name="Grids", default="",
                          description="Comma-separated grid names (empty: every scalar grid)")
    lods: EnumProperty(name="LODs", items=LOD_ITEMS, options={"ENUM_FLAG"}, default={"medium"},
                       description="LOD presets stored on each object")
    weights: EnumProperty(name="Weights", default="field", items=(
        ("field", "Field", "Normalized kernels times the volume they stand for (exact fields)"),
        ("paper", "Paper", "The paper's weights: sigma = half extent, value as peak")))
    level_set_band: BoolProperty(name="Zero-Crossing Band Only", default=True,
                                 description="Level sets: keep only Gaussians whose voxels straddle the surface")
    vector_magnitude: BoolProperty(name="Vector Grids as Magnitude", default=False)

    def execute(self, context):
        from ..gaussvdb_addon import importer

        paths = importer.selected_paths(self.filepath, self.directory, self.files)
        try:
            objects, message = importer.import_files(
                context, paths, grids=importer.split_names(self.grids), lods=sorted(self.lods),
                weights=self.weights, level_set_band=self.level_set_band,
                vector_magnitude=self.vector_magnitude, progress=context.window_manager)
        except importer.ImportError_ as err:
            self.report({"ERROR"}, str(err))
            return {"CANCELLED"}
        self.report({"INFO"}, message)
        return {"FINISHED"}


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
