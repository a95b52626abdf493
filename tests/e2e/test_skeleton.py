"""The walking skeleton: kernels stand alone, the extension registers and unregisters cleanly."""

import os
import subprocess
import sys

from conftest import ROOT

IMPORT_ALL_KERNELS = """
import importlib, pkgutil, sys
sys.modules["bpy"] = None  # any `import bpy` below now raises ImportError
import kernels
names = [m.name for m in pkgutil.walk_packages(kernels.__path__, "kernels.")]
for name in names:
    importlib.import_module(name)
assert sys.modules["bpy"] is None
assert not any(m.startswith(("bpy.", "bl_")) for m in sys.modules), "a kernel pulled in Blender"
print(len(names))
"""


def test_kernels_import_without_bpy():
    out = subprocess.run([sys.executable, "-c", IMPORT_ALL_KERNELS], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.split()[-1]) >= 1


def _engine_ids(bpy):
    return {c.bl_idname for c in bpy.types.RenderEngine.__subclasses__()
            if getattr(c, "is_registered", False) and hasattr(c, "bl_idname")}


def test_addon_registers_engine_operator_and_properties(scene, bpy_module):
    bpy = bpy_module
    assert "GAUSSVDB" in _engine_ids(bpy)
    assert hasattr(bpy.types, "GAUSSVDB_OT_import_vdb")
    assert hasattr(scene, "gaussvdb") and scene.gaussvdb.mode == "PARTICLES"
    scene.render.engine = "GAUSSVDB"
    # Built-in panels opted in through COMPAT_ENGINES.
    assert "GAUSSVDB" in bpy.types.RENDER_PT_format.COMPAT_ENGINES


def test_disable_leaves_nothing_registered(addon, bpy_module):
    import addon_utils
    from conftest import ADDON_MODULE

    bpy = bpy_module
    addon_utils.disable(ADDON_MODULE, default_set=True)
    try:
        assert "GAUSSVDB" not in _engine_ids(bpy)
        assert not hasattr(bpy.types, "GAUSSVDB_OT_import_vdb")
        assert not hasattr(bpy.types.Scene, "gaussvdb")
        assert not hasattr(bpy.types.Object, "gaussvdb")
        assert "GAUSSVDB" not in bpy.types.RENDER_PT_format.COMPAT_ENGINES
    finally:
        addon_utils.enable(ADDON_MODULE, default_set=True, handle_error=None)
    assert "GAUSSVDB" in _engine_ids(bpy)


def test_sample_is_bundled():
    from conftest import SAMPLE

    with open(SAMPLE, "rb") as f:
        head = f.read(8)
    assert int.from_bytes(head, "little") & 0xFFFFFFFF == 0x56444220
    assert os.path.getsize(SAMPLE) > 100_000
