"""Colour by a second grid on the Blender side: the import (function and operator) carries the
colour grid's values (gs_color) and its name, they read back bit for bit (after a save and
reload too), the scene sync hands the colour map and, in reference mode, the colour grid to the
kernels, a missing colour grid is a one-line error that creates nothing, and `./gaussvdb render
--color-grid` changes the colour of the image but not its opacity."""
import importlib
import json
import os

import numpy as np
import pytest
from conftest import ADDON_MODULE, ROOT, run_cli
from test_engine_helpers import read_image
from vdb_fixtures import write_fire_like


def _mod(name):
    return importlib.import_module(f"{ADDON_MODULE}.{name}")


@pytest.fixture(scope="module")
def fire(tmp_path_factory):
    return str(write_fire_like(tmp_path_factory.mktemp("fire") / "fire.vdb", 0.25))


def test_import_carries_the_colour_grid(scene, fire, bpy_module, tmp_path):
    bpy = bpy_module
    imp = _mod("gaussvdb_addon.io.importer")
    vdb = _mod("kernels.vdb")
    lod = _mod("kernels.lod")
    second = _mod("kernels.lod.second_grid")
    obj, = imp.import_vdb(fire, grids="density", lods=("low", "medium"), color_grid="temperature",
                          compute_error=False, collection=scene.collection)
    assert obj.gaussvdb.color_grid == "temperature"
    assert "gs_color" in obj.data.attributes
    density, temperature = vdb.read_vdb(fire).grids
    for name in ("low", "medium"):
        gs = imp.gaussian_set_from_object(obj, name)
        want = second.second_values(lod.build_lod(density, name), density, temperature)
        np.testing.assert_array_equal(gs.color_values, want)
        assert gs.color_background == 0.25
    path, name = str(tmp_path / "fire.blend"), obj.name
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects[name]
    assert obj.gaussvdb.color_grid == "temperature"
    np.testing.assert_array_equal(imp.gaussian_set_from_object(obj, "medium").color_values,
                                  second.second_values(lod.build_lod(density, "medium"), density,
                                                       temperature))


def test_scene_sync_hands_over_the_colour_map(scene, fire, bpy_module):
    bpy = bpy_module
    imp = _mod("gaussvdb_addon.io.importer")
    ss = _mod("gaussvdb_addon.engine.scene_sync")
    coloured, = imp.import_vdb(fire, grids="density", lods=("low",), color_grid="temperature",
                               compute_error=False, collection=scene.collection)
    plain, = imp.import_vdb(fire, grids="density", lods=("low",), compute_error=False,
                            collection=scene.collection)
    assert plain.gaussvdb.color_grid == "" and "gs_color" not in plain.data.attributes
    coloured.gaussvdb.color_colormap = "magma"
    scene.gaussvdb.mode = "REFERENCE"
    sync = ss.SceneSync()
    objs = {o.name: o for o in sync.sync(bpy.context.evaluated_depsgraph_get()).objects}
    c, p = objs[coloured.name], objs[plain.name]
    # the legend shows the colour map over the colour grid, and the plain object's scene TF
    legend = {e.title: e for e in sync.legend_entries(sync.transfer_function(scene.gaussvdb))}
    assert set(legend) == {"temperature", "density"}
    np.testing.assert_array_equal(legend["temperature"].lut, c.color_tf.lut)
    assert p.color_tf is None and p.color_grid is None
    assert c.color_grid.name == "temperature" and c.grid.name == "density"
    st = coloured.gaussvdb.color_stats()
    assert (c.color_tf.vmin, c.color_tf.vmax) == (st["min"], st["max"]) and st["max"] == 3.0
    coloured.gaussvdb.color_auto_range = False
    coloured.gaussvdb.color_min, coloured.gaussvdb.color_max = 1.0, 2.0
    c = next(o for o in ss.SceneSync().sync(bpy.context.evaluated_depsgraph_get()).objects
             if o.name == coloured.name)
    assert (c.color_tf.vmin, c.color_tf.vmax) == (1.0, 2.0)


def test_missing_colour_grid_is_one_line(scene, fire, bpy_module):
    imp = _mod("gaussvdb_addon.io.importer")
    before = len(bpy_module.data.objects)
    with pytest.raises(imp.VDBImportError) as err:
        imp.import_vdb(fire, grids="density", lods=("low",), color_grid="heat", compute_error=False,
                       collection=scene.collection)
    msg = str(err.value)
    assert "\n" not in msg and "'heat'" in msg and "fire.vdb" in msg and "temperature" in msg
    assert len(bpy_module.data.objects) == before


def _render(fire, tmp_path, name, mode, *extra):
    out = tmp_path / f"{name}.exr"
    env = dict(os.environ, GAUSSVDB_BLENDER_EXTENSIONS=os.environ["BLENDER_USER_EXTENSIONS"])
    proc = run_cli(ROOT, "render", fire, "--grid", "density", "--size", "40x30", "--lod", "low",
                   "--mode", mode, "--transparent", "--out", str(out), "--json", *extra, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("mode", ["field", "reference"])
def test_cli_color_grid(bpy_module, fire, tmp_path, mode):
    bpy = bpy_module
    plain = read_image(bpy, _render(fire, tmp_path, "plain", mode)[0])
    out, stats = _render(fire, tmp_path, "temp", mode, "--color-grid", "temperature")
    temp = read_image(bpy, out)
    assert stats["color_grid"] == "temperature"
    assert plain[..., 3].max() > 0.1
    np.testing.assert_array_equal(temp[..., 3], plain[..., 3])
    assert np.abs(temp[..., :3] - plain[..., :3]).max() > 0.05


def test_operator_takes_a_colour_grid(scene, fire, bpy_module):
    bpy = bpy_module
    res = bpy.ops.gaussvdb.import_vdb(filepath=fire, grids="density", color_grid="temperature",
                                      lods={"low"}, measure_error=False, use_sequence=False)
    assert res == {"FINISHED"}
    obj, = scene.objects
    assert obj.gaussvdb.color_grid == "temperature" and "gs_color" in obj.data.attributes
    with pytest.raises(RuntimeError, match="'heat'"):  # the operator's error report
        bpy.ops.gaussvdb.import_vdb(filepath=fire, grids="density", color_grid="heat",
                                    lods={"low"}, use_sequence=False)
    assert len(scene.objects) == 1
