"""Clip Empties on GaussVDB objects (object_settings.ClipProps) through the scene sync (final
render and viewport alike) and `./gaussvdb render --clip-plane/--clip-box`."""
import json
import math
import os

import numpy as np
import pytest
from conftest import ROOT, SAMPLE, run_cli
from test_engine_helpers import lattice, make_object, read_image


def _mod(name):
    import importlib

    return importlib.import_module(f"bl_ext.user_default.gaussvdb.{name}")


def _empty(bpy, name, location, rotation=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0), display="PLAIN_AXES",
           collection=None):
    e = bpy.data.objects.new(name, None)
    e.empty_display_type = display
    e.location, e.rotation_euler, e.scale = location, rotation, scale
    (collection or bpy.context.scene.collection).objects.link(e)
    return e


def _inside(rows, pts):
    return (np.c_[pts, np.ones(len(pts))] @ np.asarray(rows).T >= -1e-9).all(1)


PTS = np.random.default_rng(0).uniform(-2, 18, (4000, 3))


@pytest.mark.parametrize("viewport", [False, True])
def test_plane_box_and_collection_reach_the_render_scene(bpy_module, scene, viewport):
    bpy = bpy_module
    ss = _mod("gaussvdb_addon.engine.scene_sync")
    ob = make_object(bpy, "Cloud", lattice(16, 4, 8))
    sync = ss.SceneSync(viewport=viewport)
    assert sync.sync(bpy.context.evaluated_depsgraph_get()).objects[0].clip is None
    # a plane at x = 7.5 whose +Z is turned to +X: keeps x >= 7.5
    plane = _empty(bpy, "Plane", (7.5, 0.0, 0.0), (0.0, math.pi / 2, 0.0))
    ob.gaussvdb.clip_plane = plane
    sync.dirty = True
    rows = sync.sync(bpy.context.evaluated_depsgraph_get()).objects[0].clip
    np.testing.assert_array_equal(_inside(rows, PTS), PTS[:, 0] >= 7.5)
    # moved: the next sync cuts at the new place
    plane.location.x = 3.0
    sync.dirty = True
    rows = sync.sync(bpy.context.evaluated_depsgraph_get()).objects[0].clip
    np.testing.assert_array_equal(_inside(rows, PTS), PTS[:, 0] >= 3.0)
    # plus a box [2, 6] x [-1, 3] x [0, 10] and, from a collection, a plane keeping z <= 6
    box = _empty(bpy, "Box", (4.0, 1.0, 5.0), scale=(2.0, 2.0, 5.0), display="CUBE")
    ob.gaussvdb.clip_box = box
    coll = bpy.data.collections.new("Cuts")
    scene.collection.children.link(coll)
    _empty(bpy, "Top", (0.0, 0.0, 6.0), (math.pi, 0.0, 0.0), collection=coll)
    ob.gaussvdb.clip_collection = coll
    sync.dirty = True
    rows = sync.sync(bpy.context.evaluated_depsgraph_get()).objects[0].clip
    want = ((PTS[:, 0] >= 3.0) & (np.abs(PTS[:, 0] - 4) <= 2) & (np.abs(PTS[:, 1] - 1) <= 2)
            & (np.abs(PTS[:, 2] - 5) <= 5) & (PTS[:, 2] <= 6.0))
    np.testing.assert_array_equal(_inside(rows, PTS), want)
    # a flattened Empty cuts nothing and says so
    box.scale = (2.0, 0.0, 5.0)
    sync.dirty = True
    rows = sync.sync(bpy.context.evaluated_depsgraph_get()).objects[0].clip
    assert rows.shape[0] == 2 and any("'Box'" in w and "singular" in w for w in sync.warnings)


def _render(tmp_path, name, *extra):
    out = tmp_path / f"{name}.exr"
    env = dict(os.environ, GAUSSVDB_BLENDER_EXTENSIONS=os.environ["BLENDER_USER_EXTENSIONS"])
    proc = run_cli(ROOT, "render", SAMPLE, "--size", "48x36", "--lod", "low", "--transparent",
                   "--out", str(out), "--json", *extra, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def _alpha(bpy, path):
    return read_image(bpy, path).reshape(-1, 4)[:, 3]


def test_cli_clip_options(bpy_module, tmp_path):
    """A plane and a box that keep everything leave the image as it was; a plane beyond the volume
    keeps nothing; a box through its middle keeps part of it."""
    bpy = bpy_module
    plain = _alpha(bpy, _render(tmp_path, "plain"))
    assert plain.max() > 0.1
    keep = _alpha(bpy, _render(tmp_path, "keep", "--clip-plane=-1e6,0,0,1,0,0",
                               "--clip-box=-1e6,-1e6,-1e6,1e6,1e6,1e6"))
    np.testing.assert_array_equal(keep, plain)
    none = _alpha(bpy, _render(tmp_path, "none", "--clip-plane", "1e6,0,0,1,0,0"))
    assert none.max() == 0.0


def test_level_set_style_and_lights_reach_the_render_scene(bpy_module, scene):
    """Level sets default to lit surfaces; Shell keeps the translucent shell. Suns shine along
    their local -Z with their strength; point, spot and area lights are points with their power."""
    bpy = bpy_module
    ss = _mod("gaussvdb_addon.engine.scene_sync")
    ob = make_object(bpy, "Shell", lattice(4, 4, 4), grid_class="level_set")
    sync = ss.SceneSync(viewport=False)
    rs = sync.sync(bpy.context.evaluated_depsgraph_get())
    assert rs.objects[0].surface and rs.lights == ()
    ob.gaussvdb.level_set_style = "SHELL"
    for kind, loc, energy in (("SUN", (0, 0, 5), 3.0), ("AREA", (1, 2, 3), 500.0)):
        data = bpy.data.lights.new(kind, kind)
        data.energy, data.color = energy, (1.0, 0.5, 0.25)
        lt = bpy.data.objects.new(kind, data)
        lt.location = loc
        lt.rotation_euler = (0.0, math.pi / 2, 0.0) if kind == "SUN" else (0.0, 0.0, 0.0)
        scene.collection.objects.link(lt)
    sync.dirty = True
    rs = sync.sync(bpy.context.evaluated_depsgraph_get())
    assert not rs.objects[0].surface
    by_kind = {lt.kind: lt for lt in rs.lights}
    np.testing.assert_allclose(by_kind["sun"].vector, (-1, 0, 0), atol=1e-6)  # local -Z turned to -X
    assert by_kind["sun"].strength == 3.0
    np.testing.assert_allclose(by_kind["point"].vector, (1, 2, 3))
    np.testing.assert_allclose(by_kind["point"].color, (1.0, 0.5, 0.25))
    assert by_kind["point"].strength == 500.0
