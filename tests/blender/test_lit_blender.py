"""Lit volumes on the Blender side: Object.gaussvdb.shading/shadows reach the render scene, and
`./gaussvdb render --shading lit [--shadows]` changes the image (and --shading emission, the
default, does not)."""
import json
import os

import numpy as np
from conftest import ROOT, SAMPLE, run_cli
from test_engine_helpers import lattice, make_object, read_image


def test_shading_reaches_the_render_scene(bpy_module, scene):
    import importlib

    bpy = bpy_module
    ss = importlib.import_module("bl_ext.user_default.gaussvdb.gaussvdb_addon.engine.scene_sync")
    ob = make_object(bpy, "Cloud", lattice(8, 4, 4))
    sync = ss.SceneSync(viewport=False)
    o = sync.sync(bpy.context.evaluated_depsgraph_get()).objects[0]
    assert (o.shading, o.shadows) == ("emission", False)
    ob.gaussvdb.shading, ob.gaussvdb.shadows = "LIT", True
    sync.dirty = True
    o = sync.sync(bpy.context.evaluated_depsgraph_get()).objects[0]
    assert (o.shading, o.shadows) == ("lit", True)


def _render(tmp_path, name, *extra):
    out = tmp_path / f"{name}.exr"
    env = dict(os.environ, GAUSSVDB_BLENDER_EXTENSIONS=os.environ["BLENDER_USER_EXTENSIONS"])
    proc = run_cli(ROOT, "render", SAMPLE, "--size", "40x30", "--lod", "low", "--mode", "reference",
                   "--transparent", "--out", str(out), "--json", *extra, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def test_cli_shading_options(bpy_module, tmp_path):
    bpy = bpy_module
    plain = read_image(bpy, _render(tmp_path, "plain"))
    emission = read_image(bpy, _render(tmp_path, "emission", "--shading", "emission"))
    lit = read_image(bpy, _render(tmp_path, "lit", "--shading", "lit"))
    shadows = read_image(bpy, _render(tmp_path, "shadows", "--shading", "lit", "--shadows"))
    np.testing.assert_array_equal(emission, plain)
    assert plain[..., 3].max() > 0.1
    # lighting changes the colour, never the opacity
    np.testing.assert_array_equal(lit[..., 3], plain[..., 3])
    assert np.abs(lit[..., :3] - plain[..., :3]).max() > 0.01
    assert np.abs(shadows[..., :3] - lit[..., :3]).max() > 0.01
