"""Transfer functions where they belong: per object (two objects of very different ranges), an
auto range that is the grid's voxel range whatever LOD is drawn, the colour legend in the
Combined pass (and from the CLI), the log-scale warning, colormap presets that store the whole
ramp, and a hand-edited ramp that picking a colormap does not silently replace."""

import importlib
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import ADDON_MODULE, ROOT, SAMPLE
from test_engine_helpers import FakeEngine, add_camera, lattice, make_object, read_image, setup_render
from vdb_fixtures import write_grid

W, H = 64, 32


def _mod(name):
    return importlib.import_module(f"{ADDON_MODULE}.gaussvdb_addon.{name}")


def _render(bpy):
    eng = FakeEngine()
    _mod("engine.final_render").render(eng, bpy.context.evaluated_depsgraph_get())
    assert not eng.errors, eng.errors
    return eng, eng.image().copy()


def _two_volumes(bpy, scene):
    """'Smoke' (values 0..1) at x 0..7 and 'Hot' (values 0..1e29) at x 16..23, side by side in an
    orthographic view along +Y: smoke covers pixel columns 8..24, hot 40..56, rows 8..24."""
    smoke = make_object(bpy, "Smoke", lattice(8, 8, 8), values=np.linspace(0.0, 1.0, 512))
    hot = make_object(bpy, "Hot", lattice(8, 8, 8, origin=(16, 0, 0)),
                      values=np.linspace(0.0, 1e29, 512))
    add_camera(bpy, scene, (11.5, -30.0, 3.5), (math.pi / 2, 0.0, 0.0), ortho_scale=32.0)
    setup_render(scene, W, H)
    s = scene.gaussvdb
    s.density_unit, s.density = "WORLD", 2.0
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    scene.render.film_transparent = True
    return smoke, hot


def _alpha(img, cols):
    return float(img[10:22, cols[0]:cols[1], 3].mean())


SMOKE, HOT = (10, 22), (42, 54)


def test_object_tf_keeps_a_small_range_visible_beside_a_huge_one(bpy_module, scene):
    bpy = bpy_module
    _smoke, hot = _two_volumes(bpy, scene)
    fr = _mod("engine.final_render")
    _, shared = _render(bpy)  # one scene TF over both: 0..1e29 squashes the smoke
    assert fr.LAST_STATS["value_range"][1] == pytest.approx(1e29, rel=1e-6)
    assert _alpha(shared, SMOKE) < 0.01 and _alpha(shared, HOT) > 0.3

    hot.gaussvdb.use_scene_tf = False
    hot.gaussvdb.colormap = "grayscale"
    _, own = _render(bpy)
    lo, hi = fr.LAST_STATS["value_range"]  # the scene's range: the smoke's alone now
    assert lo == pytest.approx(0.0, abs=1e-6) and hi == pytest.approx(1.0, rel=1e-6)
    assert _alpha(own, SMOKE) > 0.3 and _alpha(own, HOT) > 0.3
    hot_rgb = own[16, 46:50, :3] / np.maximum(own[16, 46:50, 3:4], 1e-6)
    assert np.ptp(hot_rgb, axis=1).max() < 0.02  # grey: its own colormap
    smoke_rgb = own[16, 14:18, :3]
    assert np.ptp(smoke_rgb, axis=1).min() > 0.02  # viridis: the scene's
    # the object's own density applies to it alone
    hot.gaussvdb.density = 0.0
    _, thin = _render(bpy)
    assert _alpha(thin, HOT) < 1e-6 and _alpha(thin, SMOKE) == pytest.approx(_alpha(own, SMOKE), rel=1e-5)


def test_auto_range_is_the_voxel_range_at_every_lod(bpy_module, scene):
    bpy = bpy_module
    imp = _mod("io.importer")
    scene_sync = _mod("engine.scene_sync")
    from kernels.render import voxel_stats
    from kernels.vdb import read_vdb

    obj = imp.import_vdb(SAMPLE, grids=["density"], lods=("low", "medium", "high"),
                         compute_error=False, collection=scene.collection)[0]
    want = voxel_stats(read_vdb(SAMPLE, ["density"]).grids[0])
    stored = obj.gaussvdb.voxel_stats()
    assert stored["min"] == pytest.approx(want["min"]) and stored["max"] == pytest.approx(want["max"])
    ranges, lod_max = {}, {}
    for lod in ("low", "medium", "high"):
        obj.gaussvdb.render_lod = lod
        sync = scene_sync.SceneSync(viewport=False)
        sync.sync(bpy.context.evaluated_depsgraph_get())
        tf = sync.transfer_function(scene.gaussvdb)
        ranges[lod] = (tf.vmin, tf.vmax)
        lod_max[lod] = float(np.max(sync.scene.objects[0].gaussians.values))
    scene.gaussvdb.mode = "REFERENCE"
    sync = scene_sync.SceneSync(viewport=False)
    sync.sync(bpy.context.evaluated_depsgraph_get())
    ranges["reference"] = (sync.transfer_function(scene.gaussvdb).vmin,
                           sync.transfer_function(scene.gaussvdb).vmax)
    assert len(set(ranges.values())) == 1, ranges
    assert ranges["low"] == pytest.approx((want["min"], want["max"]))
    assert lod_max["low"] < want["max"]  # the old rule (the drawn LOD's range) differs
    assert scene_sync.stored_range(scene.gaussvdb, [obj]) == pytest.approx(ranges["low"])
    # an object imported before the figures were stored falls back to the drawn LOD's values
    st = json.loads(obj.gaussvdb.stats_json)
    del st["values"]
    obj.gaussvdb.stats_json = json.dumps(st)
    scene.gaussvdb.mode = "PARTICLES"
    obj.gaussvdb.render_lod = "low"
    sync = scene_sync.SceneSync(viewport=False)
    sync.sync(bpy.context.evaluated_depsgraph_get())
    assert sync.transfer_function(scene.gaussvdb).vmax == pytest.approx(lod_max["low"])
    assert scene_sync.stored_range(scene.gaussvdb, [obj]) is None  # "from the drawn LOD"


def test_legend_pixels_in_the_chosen_corner(bpy_module, scene):
    bpy = bpy_module
    _smoke, hot = _two_volumes(bpy, scene)
    setup_render(scene, 192, 128)
    _, plain = _render(bpy)
    s = scene.gaussvdb
    s.show_legend, s.legend_corner, s.legend_size = True, "TOP_LEFT", 0.6
    _, with_legend = _render(bpy)
    assert _mod("engine.final_render").LAST_STATS["legend"]
    changed = np.any(np.abs(with_legend - plain) > 1e-6, axis=-1)
    ys, xs = np.nonzero(changed)
    assert ys.min() > 128 * 0.3 and xs.max() < 192 * 0.5  # top left (row 0 is the bottom)
    corner = with_legend[64:, :96]
    assert np.all(corner > 0.99, axis=-1).sum() > 100  # white frame and labels
    assert (corner[..., 3] > 0.999).sum() > 300  # the opaque bar
    one_bar = xs.max()
    hot.gaussvdb.use_scene_tf = False  # two transfer functions: two bars
    _, two = _render(bpy)
    xs2 = np.nonzero(np.any(np.abs(two - plain) > 1e-6, axis=-1))[1]
    assert xs2.max() > one_bar + 20


def test_log_scale_warns_with_the_fraction_not_shown(bpy_module, scene, tmp_path):
    bpy = bpy_module
    imp = _mod("io.importer")
    dense = np.linspace(-0.6, 1.0, 16)[:, None, None] * np.ones((16, 8, 8))
    dense[dense == 0] = 0.01
    path = write_grid(tmp_path / "signed.vdb", dense.astype(np.float32), name="heat")
    obj = imp.import_vdb(str(path), lods=("low",), compute_error=False,
                         collection=scene.collection)[0]
    frac = float((dense <= 0).mean())
    add_camera(bpy, scene, (7.5, -30.0, 3.5), (math.pi / 2, 0.0, 0.0), ortho_scale=24.0)
    setup_render(scene, 32, 16)
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    eng, _ = _render(bpy)
    assert not any(k == {"WARNING"} for k, _ in eng.reports)  # linear scale: nothing to say
    scene.gaussvdb.log_scale = True
    eng, img = _render(bpy)
    warn = [m for k, m in eng.reports if k == {"WARNING"}]
    assert warn == [f"GaussVDB: log scale: {100 * frac:.0f}% of the voxels of 'heat' are <= 0 "
                    "and not shown"]
    assert _mod("engine.final_render").LAST_STATS["warnings"] == [warn[0][len("GaussVDB: "):]]
    assert img[..., 3].max() > 0.05  # the positive part is still drawn
    # an object's own log scale warns for that object
    scene.gaussvdb.log_scale = False
    obj.gaussvdb.use_scene_tf = False
    obj.gaussvdb.log_scale = True
    eng, _ = _render(bpy)
    assert [m for k, m in eng.reports if k == {"WARNING"}] == warn


def _ramp(settings):
    r = settings.ramp_texture.color_ramp
    return r.interpolation, sorted((e.position, tuple(e.color)) for e in r.elements)


def _same(a, b):
    """Two _ramp results alike (a preset stores 6 decimals)."""
    return a[0] == b[0] and len(a[1]) == len(b[1]) and np.allclose(
        [[p, *c] for p, c in a[1]], [[p, *c] for p, c in b[1]], atol=2e-6)


def _edit(settings):
    r = settings.ramp_texture.color_ramp
    r.elements[3].color = (1.0, 0.0, 0.0, 0.7)
    r.elements[5].position = 0.31
    r.interpolation = "EASE"


def test_picking_a_colormap_keeps_a_hand_edit_until_confirmed(bpy_module, scene):
    bpy = bpy_module
    ramp = _mod("properties.transfer_ramp")
    s = scene.gaussvdb
    s.colormap = "viridis"
    assert not ramp.is_edited(s)
    s.colormap = "plasma"  # not edited: the property fills the ramp
    plasma = _ramp(s)
    _edit(s)
    edited = _ramp(s)
    assert ramp.is_edited(s) and edited != plasma
    s.colormap = "magma"  # the property keeps the edit (the panel shows "Magma (Edited)")
    assert _ramp(s) == edited and ramp.is_edited(s)
    assert bpy.ops.gaussvdb.colormap_pick(colormap="jet") == {"FINISHED"}  # confirmed pick
    assert s.colormap == "jet" and not ramp.is_edited(s) and _ramp(s)[0] == "LINEAR"
    # the operator acts on an object's own transfer function through the context pointer
    ob = bpy.data.objects.new("Vol", None)
    scene.collection.objects.link(ob)
    with bpy.context.temp_override(gaussvdb_tf=ob.gaussvdb):
        bpy.ops.gaussvdb.colormap_pick(colormap="cividis")
    assert ob.gaussvdb.colormap == "cividis" and s.colormap == "jet"
    assert ob.gaussvdb.ramp_texture.name.endswith(": Vol")


def test_colormap_preset_round_trips_the_whole_ramp(bpy_module, scene):
    bpy = bpy_module
    ramp = _mod("properties.transfer_ramp")
    s = scene.gaussvdb
    s.colormap = "turbo"
    _edit(s)
    saved = _ramp(s)
    assert bpy.ops.gaussvdb.colormap_preset_add(name="My Edited Turbo") == {"FINISHED"}
    path = bpy.utils.preset_find("My_Edited_Turbo", "gaussvdb/colormap")
    try:
        bpy.ops.gaussvdb.colormap_pick(colormap="grayscale")
        assert not _same(_ramp(s), saved)
        bpy.ops.script.execute_preset(filepath=path, menu_idname="GAUSSVDB_MT_colormap_presets")
        assert s.colormap == "turbo" and _same(_ramp(s), saved)
        assert not ramp.is_edited(s)  # as loaded: picking a colormap now replaces it at once
        # the same preset applied to an object's transfer function
        ob = bpy.data.objects.new("Vol", None)
        scene.collection.objects.link(ob)
        with bpy.context.temp_override(gaussvdb_tf=ob.gaussvdb):
            bpy.ops.script.execute_preset(filepath=path, menu_idname="GAUSSVDB_MT_colormap_presets")
        assert _same(_ramp(ob.gaussvdb), saved)
    finally:
        bpy.ops.gaussvdb.colormap_preset_add(name="My_Edited_Turbo", remove_name=True)
    assert not os.path.exists(path)


def test_shipped_presets_hold_their_colormaps_ramp(bpy_module, scene):
    bpy = bpy_module
    s = scene.gaussvdb
    for name in ("Magma", "Coolwarm"):
        bpy.ops.wm.read_homefile(use_empty=True)
        s = bpy.context.scene.gaussvdb
        s.colormap = name.lower()
        fresh = _ramp(s)
        bpy.ops.gaussvdb.colormap_pick(colormap="jet")
        path = os.path.join(ROOT, "presets", "gaussvdb", "colormap", name + ".py")
        bpy.ops.script.execute_preset(filepath=path, menu_idname="GAUSSVDB_MT_colormap_presets")
        assert s.colormap == name.lower() and _same(_ramp(s), fresh)


def test_cli_legend_and_log_warning(tmp_path):
    dense = np.linspace(-1.0, 1.0, 16)[:, None, None] * np.ones((16, 12, 12))
    dense[dense == 0] = 0.05
    src = write_grid(tmp_path / "signed.vdb", dense.astype(np.float32), name="heat")
    out = tmp_path / "legend.png"
    env = dict(os.environ, GAUSSVDB_BLENDER_EXTENSIONS=os.environ["BLENDER_USER_EXTENSIONS"])
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "cli.py"), "render", str(src),
                           "--lod", "low", "--size", "160x120", "--legend", "--log-scale",
                           "--out", str(out), "--json"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    stats = json.loads(proc.stdout[proc.stdout.index("{"):])
    assert stats["legend"] is True
    assert "gaussvdb render: warning: log scale: 50% of the voxels of 'heat' are <= 0 and not shown" \
        in proc.stderr
    import bpy

    px = read_image(bpy, out)
    assert px.shape == (120, 160, 4)
    corner = px[:60, 80:]  # bottom right, the default corner
    assert np.all(corner > 0.99, axis=-1).sum() > 50
    assert not np.all(px[60:, :80] > 0.99, axis=-1).any()  # no legend elsewhere


def test_viewport_overlay_draws_the_legend_with_gpu(tmp_path):
    """The overlay view_draw draws, for real: legend_overlay.draw_viewport into a GPU offscreen
    (in a separate process: a machine without EGL aborts it rather than raising)."""
    out = tmp_path / "overlay.npz"
    env = dict(os.environ, GAUSSVDB_BLENDER_EXTENSIONS=os.environ["BLENDER_USER_EXTENSIONS"])
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "tests", "blender", "legend_gpu_draw.py"), str(out)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0 and ("EGL" in proc.stderr or "epoxy" in proc.stderr) and not out.exists():
        pytest.skip("no GPU context for headless drawing here: " + proc.stderr.strip()[-200:])
    assert proc.returncode == 0, proc.stderr[-3000:]
    from kernels.render.scene.legend import composite

    z = np.load(out)
    px, patch = z["pixels"], z["patch"]
    want = composite(np.zeros_like(px), patch, "top_right")
    assert (want[..., 3] > 0).sum() > 1000
    drawn = px[..., 3] > 0.01
    ys, xs = np.nonzero(drawn)
    assert ys.min() > px.shape[0] * 0.1 and xs.min() > px.shape[1] * 0.3  # top right
    err = np.abs(px - want)
    assert err.max() < 0.01, f"max difference {err.max():.4f} on {z['renderer']}"
    # through the engine's display-space shader, as view_draw draws it (Standard view, a float
    # target: the sRGB encoding is left to the window's framebuffer), the same colours
    np.testing.assert_allclose(z["display"], want, atol=0.01)
