"""Object properties > GaussVDB > Reload: re-read the source file with the object's import settings."""

import bpy


class GAUSSVDB_OT_reload(bpy.types.Operator):
    """Re-read the object's .vdb file with the same grid, LODs and options, replacing its Gaussians"""

    bl_idname = "gaussvdb.reload"
    bl_label = "Reload"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.gaussvdb.is_gaussvdb and obj.type == "POINTCLOUD"

    def execute(self, context):
        from ..gaussvdb_addon.io import importer

        obj = context.object
        try:
            importer.reload_object(obj, progress=context.window_manager)
        except importer.VDBImportError as err:
            self.report({"ERROR"}, str(err))
            return {"CANCELLED"}
        self.report({"INFO"}, "reloaded " + importer.status_message([obj]))
        return {"FINISHED"}


CLASSES = (GAUSSVDB_OT_reload,)
