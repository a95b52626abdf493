"""Preferences > Add-ons > GaussVDB: Compile Now (the kernel warm-up in the background) and Stop.

Thin: the work is in gaussvdb_addon/engine/warmup_service.py (``start``, ``stop``).
"""

import time

import bpy


class GAUSSVDB_OT_compile_kernels(bpy.types.Operator):
    """Compile the GaussVDB kernels now, in a background process (Blender stays usable; in
    background mode, blender -b, before it returns)"""

    bl_idname = "gaussvdb.compile_kernels"
    bl_label = "Compile Now"

    def execute(self, context):
        from ..gaussvdb_addon.engine import warmup_service

        if bpy.app.background:  # no interface to keep responsive: compile here (a farm's set-up)
            t0 = time.perf_counter()
            try:
                seconds = warmup_service.compile_here()
            except warmup_service.WarmupError as err:
                self.report({"ERROR"}, str(err))
                return {"CANCELLED"}
            self.report({"INFO"}, f"GaussVDB: compiled {len(seconds)} kernel groups in "
                        f"{time.perf_counter() - t0:.1f} s")
            return {"FINISHED"}
        jobs = warmup_service.start()
        self.report({"INFO"}, f"GaussVDB: compiling {len(jobs)} kernel groups in the background"
                    if jobs else "GaussVDB: every kernel is compiled already")
        return {"FINISHED"}


class GAUSSVDB_OT_stop_compile(bpy.types.Operator):
    """Stop the background compile (what it compiled so far stays in the cache)"""

    bl_idname = "gaussvdb.stop_compile"
    bl_label = "Stop"

    def execute(self, context):
        from ..gaussvdb_addon.engine import warmup_service

        warmup_service.stop()
        return {"FINISHED"}


CLASSES = (GAUSSVDB_OT_compile_kernels, GAUSSVDB_OT_stop_compile)
