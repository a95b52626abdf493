"""The built zip validates, installs, enables, disables and re-enables in the bpy module."""

import json
import os
import subprocess
import sys

from conftest import ROOT

INSTALL_AND_TOGGLE = r"""
import json, os, sys
import bpy, addon_utils
mod = "bl_ext.user_default.gaussvdb"
def state():
    engines = {c.bl_idname for c in bpy.types.RenderEngine.__subclasses__()
               if getattr(c, "is_registered", False) and hasattr(c, "bl_idname")}
    return {"engine": "GAUSSVDB" in engines, "operator": hasattr(bpy.types, "GAUSSVDB_OT_import_vdb"),
            "scene_props": hasattr(bpy.types.Scene, "gaussvdb"),
            "object_props": hasattr(bpy.types.Object, "gaussvdb"),
            "loaded": mod in sys.modules}
out = {}
r = bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo="user_default",
                                             enable_on_install=True)
out["install"] = sorted(r)
out["enabled"] = state()
out["module_file"] = sys.modules[mod].__file__
bpy.ops.preferences.addon_disable(module=mod)
out["disabled"] = state()
bpy.ops.preferences.addon_enable(module=mod)
out["reenabled"] = state()
print("RESULT" + json.dumps(out))
"""


def test_built_zip_installs_and_toggles(tmp_path):
    sys.path.insert(0, os.path.join(ROOT, "tools"))
    import cmd_build

    tag = f"cp{sys.version_info[0]}{sys.version_info[1]}"  # the wheels of the running Blender
    zips = cmd_build.build(["linux-x64"], [tag], str(tmp_path / "dist"))
    assert [os.path.basename(z) for z in zips] == ["gaussvdb-0.1.0-linux_x64.zip"]

    env = dict(os.environ, BLENDER_USER_EXTENSIONS=str(tmp_path / "ext"),
               BLENDER_USER_CONFIG=str(tmp_path / "config"), BLENDER_USER_SCRIPTS=str(tmp_path / "scripts"))
    proc = subprocess.run([sys.executable, "-c", INSTALL_AND_TOGGLE, zips[0]], env=env, cwd=str(tmp_path),
                          capture_output=True, text=True, timeout=600)
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT")]
    assert proc.returncode == 0 and line, proc.stdout[-2000:] + proc.stderr[-2000:]
    out = json.loads(line[-1][len("RESULT"):])
    assert out["install"] == ["FINISHED"]
    assert str(tmp_path / "ext") in out["module_file"], "the installed copy must be the one loaded"
    assert all(out["enabled"].values()), out["enabled"]
    assert not any(v for k, v in out["disabled"].items() if k != "loaded"), out["disabled"]
    assert all(out["reenabled"].values()), out["reenabled"]
