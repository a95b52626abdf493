"""Defaults that give a good first image: a Mantaflow cache imports density (not the domain-wide
shadow grid), density is per object size (a tiny and a huge object look the same), the source path
is a Blender file path, and the first use says that it compiles and keeps that time apart."""

import importlib
import os
import shutil

import numpy as np
import pytest
from conftest import ADDON_MODULE, DATA_DIR, SAMPLE

FIRE = os.path.join(DATA_DIR, "mantaflow_fire_r96_f035.vdb")
BUNNY = os.path.join(DATA_DIR, "bunny_ls_256.vdb")


def _mod(name):
    return importlib.import_module(f"{ADDON_MODULE}.{name}")


# -- Mantaflow defaults ---------------------------------------------------------------------------
@pytest.mark.parametrize("path", [SAMPLE, FIRE])
def test_mantaflow_cache_imports_density_by_default(scene, path):
    if not os.path.isfile(path):
        pytest.skip(f"{path} not present")
    imp = _mod("gaussvdb_addon.io.importer")
    vdb = _mod("kernels.vdb")
    names = [g.name for g in vdb.read_topology(path).grids]
    assert {"density", "shadow", "flame", "velocity"} <= set(names)
    assert _mod("kernels.pipeline").cache_layout(names) == "mantaflow"
    skipped = []
    objs = imp.import_vdb(path, lods=("low",), compute_error=False, collection=scene.collection,
                          skipped=skipped)
    assert [o.gaussvdb.grid_name for o in objs] == ["density"]
    assert {n for n, _ in skipped} >= {"shadow", "flame", "temperature"}
    assert imp.status_message(objs, skipped).count("skipped") == 1
    hint = imp.default_grids_hint(path)
    assert hint.startswith("Mantaflow cache: importing density") and "shadow" in hint


def test_mantaflow_grids_the_user_asks_for(scene):
    if not os.path.isfile(FIRE):
        pytest.skip("fire cache not present")
    imp = _mod("gaussvdb_addon.io.importer")
    objs = imp.import_vdb(FIRE, grids="density, flame", lods=("low",), compute_error=False,
                          collection=scene.collection)
    assert [o.gaussvdb.grid_name for o in objs] == ["density", "flame"]


def test_other_files_import_every_scalar_grid(scene):
    imp = _mod("gaussvdb_addon.io.importer")
    pipeline = _mod("kernels.pipeline")
    assert pipeline.cache_layout(["surface"]) == ""
    assert pipeline.cache_layout(["density", "temperature"]) == ""  # density alone: no Mantaflow sign
    assert imp.default_grids(["density", "temperature"]) == (None, [])
    if os.path.isfile(BUNNY):
        assert imp.default_grids_hint(BUNNY) == "Empty Grids: every scalar grid (surface)"


# -- the source path is a Blender file path -----------------------------------------------------------
def test_source_path_is_a_blender_file_path(bpy_module, scene, tmp_path):
    bpy = bpy_module
    imp = _mod("gaussvdb_addon.io.importer")
    data = tmp_path / "data"
    data.mkdir()
    vdb_path = str(data / "smoke.vdb")
    shutil.copy(SAMPLE, vdb_path)
    objs = imp.import_vdb(vdb_path, grids="density, temperature", lods=("low",),
                          compute_error=False, collection=scene.collection)
    st = objs[0].gaussvdb
    assert st.source_file == vdb_path
    assert objs[1].gaussvdb.source_volume == st.source_volume  # one datablock per file
    assert vdb_path in bpy.utils.blend_paths(absolute=True)
    blend = str(tmp_path / "scenes" / "s.blend")
    os.makedirs(os.path.dirname(blend))
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    assert bpy.ops.file.make_paths_relative() == {"FINISHED"}
    assert st.source_file == "//../data/smoke.vdb"
    bpy.ops.wm.save_mainfile()
    # the file moves: Find Missing Files finds it in the folder it is told
    moved = tmp_path / "elsewhere"
    moved.mkdir()
    shutil.move(vdb_path, str(moved / "smoke.vdb"))
    bpy.ops.wm.open_mainfile(filepath=blend)
    obj = bpy.data.objects[objs_name(bpy, "density")]
    assert not os.path.isfile(bpy.path.abspath(obj.gaussvdb.source_file))
    assert bpy.ops.file.find_missing_files(directory=str(moved)) == {"FINISHED"}
    found = os.path.abspath(bpy.path.abspath(obj.gaussvdb.source_file))
    assert found == str(moved / "smoke.vdb")
    imp.reload_object(obj, compute_error=False)  # and the object reads it again from there
    assert imp.gaussian_set_from_object(obj, "low").count > 0


def objs_name(bpy, grid):
    return next(o.name for o in bpy.data.objects if o.gaussvdb.grid_name == grid)


def test_old_string_source_path_migrates_on_load(bpy_module, scene, tmp_path):
    bpy = bpy_module
    imp = _mod("gaussvdb_addon.io.importer")
    obj = imp.import_vdb(SAMPLE, grids="density", lods=("low",), compute_error=False,
                         collection=scene.collection)[0]
    # what the previous version saved: a plain string, no Volume
    obj.gaussvdb.source_volume = None
    obj.gaussvdb["source_file"] = SAMPLE
    name = obj.name
    blend = str(tmp_path / "old.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.ops.wm.open_mainfile(filepath=blend)
    st = bpy.data.objects[name].gaussvdb
    assert st.source_volume is not None and st.source_file == SAMPLE
    assert "source_file" not in st.keys()


# -- density per object size --------------------------------------------------------------------------
def _render_alpha(bpy, tmp_path, size, unit=None):
    from tools import cmd_render

    fi = _mod("gaussvdb_addon.engine.image_file")
    imp = _mod("gaussvdb_addon.io.importer")
    bs = _mod("gaussvdb_addon.engine.blender_settings")
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    obj = imp.import_vdb(SAMPLE, grids="density", lods=("low",), compute_error=False,
                         collection=scene.collection)[0]
    bpy.context.view_layer.update()
    scale = size / bs.world_box_diagonal(obj, obj.matrix_world)
    obj.matrix_world = obj.matrix_world @ _scale(scale)
    bpy.context.view_layer.update()
    args = cmd_render.options(width=40, height=30, transparent=True, lod="low")
    scene = cmd_render.build_scene(bpy, [obj], args)
    if unit is not None:
        scene.gaussvdb.density_unit = unit
    path = str(tmp_path / f"size{size}_{unit}.exr")
    fi.render_scene_to_file(scene, path)
    from test_engine_helpers import read_image

    return read_image(bpy, path)[..., 3]


def _scale(s):
    from mathutils import Matrix

    return Matrix.Diagonal((s, s, s, 1.0))


def test_density_is_per_object_size_by_default(bpy_module, addon, tmp_path):
    """A 0.15-unit and a 15-unit copy of the same grid render with the same opacity."""
    bpy = bpy_module
    small = _render_alpha(bpy, tmp_path, 0.15)
    big = _render_alpha(bpy, tmp_path, 15.0)
    assert small.max() > 0.5, "the small object is a faint ghost"
    np.testing.assert_allclose(small, big, atol=2e-3)
    # per world unit, density 10 makes the small one far fainter than the big one
    small_w = _render_alpha(bpy, tmp_path, 0.15, unit="WORLD")
    big_w = _render_alpha(bpy, tmp_path, 15.0, unit="WORLD")
    assert small_w.max() < 0.5 * big_w.max()


# -- first use: the compile message, and compile time kept apart ------------------------------------
def test_compile_message_when_the_cache_is_empty(bpy_module, addon, tmp_path, capfd):
    kc = _mod("gaussvdb_addon.engine.kernel_cache")
    cachedir = _mod("kernels.cachedir")
    saved = cachedir._state["root"], os.environ.get("GAUSSVDB_CACHE_DIR")
    shown = []
    try:
        os.environ["GAUSSVDB_CACHE_DIR"] = str(tmp_path / "empty")
        cachedir.set_cache_root(None)
        assert not kc.compiled("render")
        assert kc.announce("render", status=shown.append)
        # a final render says so in its status line before it syncs (the sync compiles first)
        from test_engine_helpers import FakeEngine

        eng = FakeEngine()
        _mod("gaussvdb_addon.engine.final_render").announce_compile(eng)
        shown += eng.stats
    finally:
        cachedir._state["root"] = saved[0]
        if saved[1] is None:
            os.environ.pop("GAUSSVDB_CACHE_DIR", None)
        else:
            os.environ["GAUSSVDB_CACHE_DIR"] = saved[1]
    assert shown == ["Compiling GaussVDB kernels (first use, about a minute)..."] * 2
    assert shown[0] in capfd.readouterr().err


def test_compile_time_is_reported_apart(bpy_module, scene, tmp_path):
    from test_engine_helpers import FakeEngine, add_camera, lattice, make_object, setup_render

    bpy = bpy_module
    fr = _mod("gaussvdb_addon.engine.final_render")
    kc = _mod("gaussvdb_addon.engine.kernel_cache")
    make_object(bpy, "Cloud", lattice(8, 8, 8), values=np.linspace(0, 1, 512))
    add_camera(bpy, scene, (3.5, -40.0, 3.5), (1.5707963, 0.0, 0.0))
    setup_render(scene, 24, 16)
    _mod("gaussvdb_addon.engine.devices")._FINAL.clear()  # as in a new session: the next render loads its device
    eng = FakeEngine()
    fr.render(eng, bpy.context.evaluated_depsgraph_get())
    assert not eng.errors
    first = dict(fr.LAST_STATS)
    assert first["seconds_compile"] > 0.0 and kc.compiled("render")
    fr.render(FakeEngine(), bpy.context.evaluated_depsgraph_get())
    assert fr.LAST_STATS["seconds_compile"] == 0.0  # warm: nothing to load
    # the import keeps its own warm-up apart too
    imp = _mod("gaussvdb_addon.io.importer")
    obj = imp.import_vdb(SAMPLE, grids="density", lods=("low",), compute_error=False,
                         collection=scene.collection)[0]
    assert "seconds_compile" in obj.gaussvdb.stats()
