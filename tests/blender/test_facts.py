"""One home for each fact: the LOD presets (kernels/lod_names.py) and the colormaps
(kernels/colormap_names.py) are what every layer lists; the per-LOD figures of an import live in
Object.gaussvdb.lod_stats, exact where the Gaussians are read back with them, and older files that
hold them as JSON are moved over when they load."""

import glob
import importlib
import json
import math
import os
import re

import numpy as np
import pytest
from conftest import ADDON_MODULE, ROOT, SAMPLE

COLORMAP_DIR = os.path.join(ROOT, "presets", "gaussvdb", "colormap")
IMPORT_DIR = os.path.join(ROOT, "presets", "operator", "gaussvdb.import_vdb")


def _mod(name):
    return importlib.import_module(f"{ADDON_MODULE}.{name}")


def _items(prop):
    return tuple((i.identifier, i.name, i.description) for i in prop.enum_items)


def test_kernels_list_the_fact_modules():
    from kernels import colormap_names, lod, lod_names
    from kernels.render import colormap_names as table_names

    assert lod.PRESETS == lod_names.PRESETS and lod.WEIGHTS == lod_names.WEIGHTS
    assert lod.DEFAULTS["tolerance"] == lod_names.DEFAULT_TOLERANCE
    assert set(lod_names.LABELS) == set(lod_names.DESCRIPTIONS) == set(lod_names.PRESETS)
    assert set(lod_names.TOLERANCE_PRESETS) <= set(lod_names.PRESETS)
    assert table_names() == list(colormap_names.NAMES)  # every name has a table, and no other


def test_enum_items_are_the_fact_modules(addon, bpy_module):
    bpy = bpy_module
    lod_names, colormap_names = _mod("kernels.lod_names"), _mod("kernels.colormap_names")
    op = bpy.ops.gaussvdb.import_vdb.get_rna_type().properties
    assert _items(op["lods"]) == lod_names.enum_items()
    assert _items(op["weights"]) == lod_names.weight_items()
    assert set(op["lods"].default_flag) == {lod_names.DEFAULT}
    assert op["tolerance"].default == pytest.approx(lod_names.DEFAULT_TOLERANCE)
    scene_props = bpy.types.Scene.bl_rna.properties["gaussvdb"].fixed_type.bl_rna.properties
    object_props = bpy.types.Object.bl_rna.properties["gaussvdb"].fixed_type.bl_rna.properties
    for props in (scene_props, object_props):
        assert _items(props["colormap"]) == colormap_names.enum_items()
        assert props["colormap"].default == colormap_names.DEFAULT
    pick = bpy.ops.gaussvdb.colormap_pick.get_rna_type().properties["colormap"]
    assert _items(pick) == colormap_names.enum_items()
    mode_names = _mod("kernels.mode_names")
    assert tuple(i + (v.value,) for i, v in zip(_items(scene_props["mode"]), scene_props["mode"].enum_items)) \
        == mode_names.enum_items()
    assert scene_props["mode"].default == mode_names.DEFAULT.upper()
    assert {i[0].lower() for i in mode_names.enum_items()} == set(mode_names.NAMES)
    assert _mod("kernels.render.scene.objects").Mode is mode_names.Mode  # one home for the ids


def test_shipped_presets_name_only_known_facts():
    from kernels import colormap_names, lod_names

    files = sorted(glob.glob(os.path.join(COLORMAP_DIR, "*.py")))
    assert files
    named = set()
    for path in files:
        text = open(path, encoding="utf-8").read()
        found = re.findall(r"^settings\.colormap = '([^']*)'$", text, re.M)
        assert len(found) == 1 and found[0] in colormap_names.NAMES, path
        named.add(found[0])
    assert named == set(colormap_names.NAMES)  # a shipped preset for every colormap
    for path in glob.glob(os.path.join(IMPORT_DIR, "*.py")):
        text = open(path, encoding="utf-8").read()
        lods = re.findall(r"^op\.lods = \{([^}]*)\}$", text, re.M)
        assert len(lods) == 1, path
        assert set(re.findall(r"'([^']*)'", lods[0])) <= set(lod_names.PRESETS), path
        weights = re.findall(r"^op\.weights = '([^']*)'$", text, re.M)
        assert weights and weights[0] in lod_names.WEIGHTS, path


def test_lod_figures_are_a_collection_with_exact_read_back_values(scene, bpy_module):
    imp = _mod("gaussvdb_addon.io.importer")
    lod_names = _mod("kernels.lod_names")
    obj = imp.import_vdb(SAMPLE, grids=["density"], lods=("low", "adaptive"), compute_error=True)[0]
    st = obj.gaussvdb
    assert [i.name for i in st.lod_stats] == ["low", "adaptive"]
    assert "lods" not in json.loads(st.stats_json)  # one home: the collection
    stats = imp.object_stats(obj)
    assert [s["label"] for s in stats] == [lod_names.label(n) for n in ("low", "adaptive")]
    assert stats[1]["count"] == st.lod_stats[1].count and "tolerance_met" in stats[1]
    assert "tolerance_met" not in stats[0] and 0 < stats[0]["nrmse"] < 1
    # the figures the Gaussians are read back with stay float64: what the kernels computed
    schema = _mod("gaussvdb_addon.io.schema")
    gs = schema.converted_gaussian_set(imp.convert_file(SAMPLE, ["density"], ["low"], compute_error=False)[0])
    assert stats[0]["sigma_scale"] == gs.sigma_scale != float(np.float32(gs.sigma_scale))
    assert stats[0]["value_max"] == gs.params["value_max"]
    back = imp.gaussian_set_from_object(obj, "low")
    assert back.sigma_scale == gs.sigma_scale and back.params == gs.params
    # not measured: no error figures (NaN in the collection), and the panel's list draws
    plain = imp.import_vdb(SAMPLE, grids=["density"], lods=("low",), compute_error=False)[0]
    assert math.isnan(plain.gaussvdb.lod_stats[0].nrmse)
    assert "nrmse" not in imp.object_stats(plain)[0]


def test_older_files_move_their_json_figures_into_the_collection(scene, bpy_module, tmp_path):
    bpy = bpy_module
    imp = _mod("gaussvdb_addon.io.importer")
    obj = imp.import_vdb(SAMPLE, grids=["density"], lods=("low", "medium"), compute_error=True)[0]
    want = imp.object_stats(obj)
    st = obj.gaussvdb
    old = dict(json.loads(st.stats_json), lods=want)  # what older versions wrote
    st.lod_stats.clear()
    st.stats_json = json.dumps(old)
    assert imp.object_stats(obj) == want  # read from the JSON where it is not moved yet
    path, name = str(tmp_path / "old.blend"), obj.name
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects[name]
    assert [i.name for i in obj.gaussvdb.lod_stats] == ["low", "medium"]
    assert "lods" not in json.loads(obj.gaussvdb.stats_json)
    assert imp.object_stats(obj) == want
    assert obj.gaussvdb.stats()["values"] == old["values"]


def test_saved_render_mode_values_never_move(addon, bpy_module):
    """A .blend stores the render mode's enum value: the modes kept the numbers they had when the
    menu gained Splat in its middle (REFERENCE 2, PAPER 3), so saved scenes keep their mode."""
    s = bpy_module.context.scene.gaussvdb
    for name, value in (("REFERENCE", 2), ("PAPER", 3), ("SPLAT", 4), ("PARTICLES", 0)):
        s.mode = name
        assert s["mode"] == value
    s["mode"] = 2  # as a file saved before Splat holds it
    assert s.mode == "REFERENCE"
