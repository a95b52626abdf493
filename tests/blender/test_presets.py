"""Issue 5: the shipped import LOD presets and colormap presets load and set their properties."""

import builtins
import glob
import os
import types

import pytest
from conftest import ROOT, SAMPLE

IMPORT_DIR = os.path.join(ROOT, "presets", "operator", "gaussvdb.import_vdb")
COLORMAP_DIR = os.path.join(ROOT, "presets", "gaussvdb", "colormap")


def test_preset_folders_are_registered(addon, bpy_module):
    bpy = bpy_module
    found = bpy.utils.preset_paths("operator/gaussvdb.import_vdb")
    assert any(os.path.samefile(p, IMPORT_DIR) for p in found)
    assert any(os.path.samefile(p, COLORMAP_DIR) for p in bpy.utils.preset_paths("gaussvdb/colormap"))
    names = {os.path.splitext(os.path.basename(p))[0] for p in glob.glob(IMPORT_DIR + "/*.py")}
    assert {"Low", "Medium", "High", "Variance", "Merged", "Low_Paper", "Medium_Paper",
            "High_Paper"} <= names
    for cls in ("GAUSSVDB_MT_import_presets", "GAUSSVDB_OT_import_preset_add",
                "GAUSSVDB_MT_colormap_presets", "GAUSSVDB_OT_colormap_preset_add"):
        assert hasattr(bpy.types, cls)
    assert bpy.utils.preset_find("Medium", "operator/gaussvdb.import_vdb")


def _run_import_preset(bpy, path):
    """Execute a preset file as the preset menu does. Headless there is no active operator, so
    `bpy.context.active_operator` is stood in for by a namespace; its values then go to the real
    operator, which checks them against its enums."""
    props = types.SimpleNamespace()
    fake = types.SimpleNamespace(context=types.SimpleNamespace(active_operator=props))

    def fake_import(name, *args, **kwargs):
        return fake if name == "bpy" else builtins.__import__(name, *args, **kwargs)

    with open(path, encoding="utf-8") as f:
        code = compile(f.read(), path, "exec")
    exec(code, {"__builtins__": dict(vars(builtins), __import__=fake_import), "__name__": "__main__"})
    return props


@pytest.mark.parametrize("name,lods,weights", [
    ("Low", {"low"}, "field"), ("High_Paper", {"high"}, "paper"),
    ("Merged", {"merged"}, "field"), ("Low_Medium_High", {"low", "medium", "high"}, "field")])
def test_import_presets_set_operator_properties(scene, bpy_module, name, lods, weights):
    bpy = bpy_module
    props = _run_import_preset(bpy, os.path.join(IMPORT_DIR, name + ".py"))
    assert set(props.lods) == lods and props.weights == weights and props.level_set_band
    if name == "Low_Medium_High":  # and the operator honours them
        res = bpy.ops.gaussvdb.import_vdb(filepath=SAMPLE, grids="density", lods=set(props.lods),
                                          weights=props.weights, measure_error=False)
        assert res == {"FINISHED"}
        assert bpy.context.scene.objects[0].gaussvdb.lods == "low,medium,high"


def test_every_shipped_import_preset_is_valid(addon, bpy_module):
    bpy = bpy_module
    enum = bpy.ops.gaussvdb.import_vdb.get_rna_type().properties
    lod_ids = {i.identifier for i in enum["lods"].enum_items}
    for path in glob.glob(IMPORT_DIR + "/*.py"):
        props = _run_import_preset(bpy, path)
        assert set(props.lods) <= lod_ids and props.weights in ("field", "paper"), path


def test_colormap_presets_set_scene_colormap(scene, bpy_module):
    bpy = bpy_module
    files = sorted(glob.glob(COLORMAP_DIR + "/*.py"))
    items = {i.identifier for i in bpy.types.Scene.bl_rna.properties["gaussvdb"].fixed_type
             .bl_rna.properties["colormap"].enum_items}
    assert {os.path.splitext(os.path.basename(f))[0].lower() for f in files} == items
    for path in (os.path.join(COLORMAP_DIR, "Magma.py"), os.path.join(COLORMAP_DIR, "Viridis.py")):
        res = bpy.ops.script.execute_preset(filepath=path, menu_idname="GAUSSVDB_MT_colormap_presets")
        assert res == {"FINISHED"}
        want = os.path.splitext(os.path.basename(path))[0].lower()
        assert scene.gaussvdb.colormap == want


def test_add_and_remove_user_colormap_preset(scene, bpy_module):
    bpy = bpy_module
    scene.gaussvdb.colormap = "turbo"
    assert bpy.ops.gaussvdb.colormap_preset_add(name="My Turbo") == {"FINISHED"}
    path = bpy.utils.preset_find("My_Turbo", "gaussvdb/colormap")
    with open(path, encoding="utf-8") as f:
        assert "settings.colormap = 'turbo'" in f.read()
    scene.gaussvdb.colormap = "jet"
    bpy.ops.script.execute_preset(filepath=path, menu_idname="GAUSSVDB_MT_colormap_presets")
    assert scene.gaussvdb.colormap == "turbo"
    assert bpy.ops.gaussvdb.colormap_preset_add(name="My_Turbo", remove_name=True) == {"FINISHED"}
    assert not os.path.exists(path)
