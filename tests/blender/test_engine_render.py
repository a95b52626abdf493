"""Final renders through the GAUSSVDB engine: files, colours, errors, cancellation, stats."""

import math
import os
import time

import numpy as np
import pytest
from test_engine_helpers import FakeEngine, add_camera, lattice, make_object, read_image, setup_render

W, H = 64, 32


def _ramp_scene(bpy, scene):
    """A level-set slab 64 x 4 x 32 voxels seen along +Y by an orthographic camera whose pixel
    centres sit on the Gaussian centres: the colour over X is the colormap over X."""
    make_object(bpy, "Slab", lattice(64, 4, 32), grid_class="level_set").gaussvdb.level_set_style = "SHELL"
    add_camera(bpy, scene, (31.5, -20.0, 15.5), (math.pi / 2, 0.0, 0.0), ortho_scale=64.0)
    setup_render(scene, W, H)
    s = scene.gaussvdb
    s.mode = "PARTICLES"
    s.level_set_color = "X"
    s.density_unit = "WORLD"
    s.density = 50.0
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    scene.render.film_transparent = False


def test_ramp_png_matches_colormap_table(bpy_module, scene, tmp_path):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import image_file
    from bl_ext.user_default.gaussvdb.kernels.render.scene.colormaps import colormap

    bpy = bpy_module
    _ramp_scene(bpy, scene)
    scene.gaussvdb.colormap = "viridis"
    path = str(tmp_path / "ramp.png")
    stats = image_file.render_scene_to_file(scene, path)
    assert os.path.isfile(path)
    assert stats["gaussians"] == 64 * 4 * 32 and stats["width"] == W
    px = read_image(bpy, path)  # 8-bit values / 255, row 0 = bottom
    tab = colormap("viridis").astype(np.float64)
    cols = np.arange(4, W - 4)
    expect = np.stack([np.interp(cols / 63.0 * 255.0, np.arange(256), tab[:, k]) for k in range(3)], 1)
    got = px[4:H - 4][:, cols, :3]
    err = np.abs(got - expect[None]).max()
    assert err <= 1.0 / 255.0 + 1e-6, f"max error {err * 255:.3f}/255"


def test_errors_surface_as_runtime_error(bpy_module, scene, tmp_path):
    bpy = bpy_module
    _ramp_scene(bpy, scene)
    scene.gaussvdb.mode = "REFERENCE"  # the slab has no source file
    scene.render.filepath = str(tmp_path / "x.png")
    with pytest.raises(RuntimeError, match="source file"):
        bpy.ops.render.render(write_still=True)
    scene.gaussvdb.mode = "PARTICLES"
    scene.camera = None
    with pytest.raises(RuntimeError, match="no camera"):
        bpy.ops.render.render(write_still=True)


def test_write_still_and_passes(bpy_module, scene, tmp_path):
    bpy = bpy_module
    _ramp_scene(bpy, scene)
    scene.render.film_transparent = True
    scene.view_layers[0].use_pass_z = True
    scene.view_layers[0].gaussvdb.use_pass_value = True
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(tmp_path / "still.png")
    scene.render.use_file_extension = False
    bpy.ops.render.render(write_still=True)
    px = read_image(bpy, str(tmp_path / "still.png"))
    assert px.shape == (H, W, 4)
    assert px[H // 2, W // 2, 3] > 0.99  # the opaque slab
    rr = bpy.data.images["Render Result"]
    assert rr is not None


def test_test_break_stops_quickly_and_stats(bpy_module, scene):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import final_render

    bpy = bpy_module
    make_object(bpy, "Cloud", lattice(16, 16, 16), values=np.linspace(0, 1, 16 ** 3))
    add_camera(bpy, scene, (7.5, -40.0, 7.5), (math.pi / 2, 0.0, 0.0))
    setup_render(scene, 200, 150)
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    dg = bpy.context.evaluated_depsgraph_get()

    eng = FakeEngine()
    final_render.render(eng, dg)  # warm-up (compiles or loads the kernels), full image
    assert not eng.errors
    assert eng.progress[-1] == 1.0
    assert any("4,096 Gaussians" in s and "render" in s for s in eng.stats)
    assert eng.image()[75, 100, 3] > 0.05

    eng = FakeEngine(break_after=2)
    t0 = time.perf_counter()
    final_render.render(eng, dg)
    t1 = time.perf_counter()
    assert eng.t_break is not None
    assert t1 - eng.t_break < 0.5, f"stopped {t1 - eng.t_break:.2f} s after Esc"
    assert final_render.LAST_STATS["cancelled"]
    assert t1 - t0 < 5.0


def test_bands_whole_tile_rows_after_one_setup(bpy_module, scene):
    """The frame is prepared once; the bands are whole screen-tile rows (several per thread), so
    the band size never collapses to a row however long the set-up took."""
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import devices, final_render

    bpy = bpy_module
    make_object(bpy, "Cloud", lattice(16, 16, 16), values=np.linspace(0, 1, 16 ** 3))
    add_camera(bpy, scene, (7.5, -40.0, 7.5), (math.pi / 2, 0.0, 0.0))
    setup_render(scene, 120, 203)
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    dg = bpy.context.evaluated_depsgraph_get()
    dev = devices.final_device()
    calls = []
    render = dev.render

    def counting(*a, **k):
        out = render(*a, **k)
        if "rows" in k:  # the bands (load_kernels draws the scene once whole, at 8x8)
            calls.append((k["rows"], dev.stats["seconds_setup"]))
        return out

    dev.render = counting  # the real device, its calls recorded
    try:
        eng = FakeEngine()
        final_render.render(eng, dg)
    finally:
        del dev.render
    assert not eng.errors and eng.image()[100, 60, 3] > 0.05
    rows = [r for r, _ in calls]
    assert rows[0][0] == 0 and rows[-1][1] == 203
    assert all(a[1] == b[0] for a, b in zip(rows, rows[1:]))
    assert all(r1 % 8 == 0 and r1 - r0 >= 32 for r0, r1 in rows[:-1])
    assert all(s == 0.0 for _, s in calls)  # set up once, before the bands
    stats = final_render.LAST_STATS
    for k in ("seconds_compile", "seconds_sync", "seconds_setup", "seconds_render"):
        assert type(stats[k]) is float, k
    assert 0.0 < stats["seconds_setup"] < stats["seconds_render"]
    assert stats["region"] == [0, 0, 120, 203] and stats["threads"] == 2


def test_splat_mode_renders_the_field_through_the_engine(bpy_module, scene, tmp_path):
    """F12 in Splat mode draws the Gaussian field as Field mode does (the same model on a lattice),
    and the mode's switch back and forth re-syncs (no stale lattice or voxels)."""
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import image_file

    bpy = bpy_module
    c = lattice(12, 12, 12)
    v = np.exp(-(((c - 5.5) / 4.0) ** 2).sum(1))
    make_object(bpy, "Fog", c, v, sigma=2.0)  # a field smooth on the unit lattice splat picks
    add_camera(bpy, scene, (5.5, -30.0, 5.5), (math.pi / 2, 0.0, 0.0), ortho_scale=16.0)
    setup_render(scene, 32, 32)
    scene.render.film_transparent = True
    s = scene.gaussvdb
    s.density_unit, s.density = "WORLD", 0.5
    img = {}
    for mode in ("FIELD", "SPLAT", "FIELD"):
        s.mode = mode
        path = str(tmp_path / f"{mode}.png")
        image_file.render_scene_to_file(scene, path)
        img[mode] = read_image(bpy, path)
    a = img["FIELD"][..., 3]
    assert a.max() > 0.3
    # the PNG holds straight colour: compare it premultiplied (a faint pixel's colour is noise)
    pre = {k: np.concatenate([v[..., :3] * v[..., 3:], v[..., 3:]], -1) for k, v in img.items()}
    assert np.abs(pre["SPLAT"] - pre["FIELD"]).max() <= 3.0 / 255.0
