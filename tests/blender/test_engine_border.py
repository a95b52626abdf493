"""Final renders of a region (render border, cropped or not), camera clipping and pixel aspect
through the GAUSSVDB engine in real Blender."""

import numpy as np
import pytest
from test_engine_helpers import FakeEngine, add_camera, lattice, make_object, read_image, setup_render

W, H = 90, 60


def _cloud_scene(bpy, scene):
    import mathutils

    make_object(bpy, "Cloud", lattice(12, 12, 12), values=np.linspace(0, 1, 12 ** 3))
    eye = mathutils.Vector((20.0, -25.0, 12.0))
    look = (mathutils.Vector((5.5, 5.5, 5.5)) - eye).to_track_quat("-Z", "Y").to_euler()
    add_camera(bpy, scene, eye, look, lens=40.0)  # 34 units from the cloud's centre
    setup_render(scene, W, H)
    s = scene.gaussvdb
    s.mode = "PARTICLES"
    s.density_unit, s.density = "WORLD", 0.6
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    scene.render.film_transparent = True


def _render_exr(bpy, scene, path):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import image_file

    image_file.render_scene_to_file(scene, str(path))
    return read_image(bpy, path)


@pytest.mark.parametrize("crop", [True, False])
def test_render_border_draws_the_region_only(bpy_module, scene, tmp_path, crop):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import final_render

    bpy = bpy_module
    _cloud_scene(bpy, scene)
    full = _render_exr(bpy, scene, tmp_path / "full.exr")
    assert full[..., 3].max() > 0.3
    r = scene.render
    r.use_border = True
    r.use_crop_to_border = crop
    # 0.29 x 90 is 26.1 but 0.29 x 60 = 17.4 and float32 0.29 x 100 rounds up to 29: odd sizes
    r.border_min_x, r.border_max_x = 0.29, 0.81
    r.border_min_y, r.border_max_y = 0.2, 0.75
    part = _render_exr(bpy, scene, tmp_path / "part.exr")
    x0, y0, x1, y1 = final_render.LAST_STATS["region"]
    assert (x0, y0, x1, y1) == final_render.render_region(scene, W, H)
    assert 0 < x0 < x1 < W and 0 < y0 < y1 < H
    inside = full[y0:y1, x0:x1]
    if crop:
        assert part.shape == (y1 - y0, x1 - x0, 4)
        assert part.tobytes() == np.ascontiguousarray(inside).tobytes()
    else:
        assert part.shape == full.shape
        assert part[y0:y1, x0:x1].tobytes() == np.ascontiguousarray(inside).tobytes()
        outside = np.ones((H, W), bool)
        outside[y0:y1, x0:x1] = False
        assert np.all(part[outside] == 0.0) and full[outside][:, 3].max() > 0.1


def test_render_border_off_or_empty(bpy_module, scene):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import final_render

    bpy = bpy_module
    _cloud_scene(bpy, scene)
    r = scene.render
    r.border_min_x, r.border_max_x = 0.5, 0.6
    assert final_render.render_region(scene, W, H) == (0, 0, W, H)  # border off
    r.use_border = True
    r.border_min_x, r.border_max_x = 0.5, 0.505
    eng = FakeEngine()
    final_render.render(eng, bpy.context.evaluated_depsgraph_get())
    assert eng.errors and "covers no pixel" in eng.errors[0]


def _alpha_sum(bpy, scene):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import final_render

    eng = FakeEngine()
    final_render.render(eng, bpy.context.evaluated_depsgraph_get())
    assert not eng.errors
    return float(eng.image()[..., 3].sum())


def test_camera_clip_start_and_end(bpy_module, scene):
    bpy = bpy_module
    _cloud_scene(bpy, scene)
    cam = scene.camera.data
    cam.clip_start, cam.clip_end = 0.1, 1000.0
    full = _alpha_sum(bpy, scene)
    assert full > 10.0
    cam.clip_end = 5.0  # the cloud is 25 - 45 units away
    assert _alpha_sum(bpy, scene) == 0.0
    cam.clip_start, cam.clip_end = 100.0, 1000.0
    assert _alpha_sum(bpy, scene) == 0.0
    cam.clip_start = 35.0
    mid = _alpha_sum(bpy, scene)
    assert 0.0 < mid < full


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
@pytest.mark.parametrize("size, aspect", [((90, 60), (1, 1)), ((90, 60), (1, 2)), ((60, 90), (3, 1))])
def test_camera_plane_matches_blenders_view_frame(bpy_module, scene, kind, fit, size, aspect):
    """The image rectangle of camera_from_object (sensor fit, shift, pixel aspect) against
    Blender's own camera frame for the scene."""
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import camera

    bpy = bpy_module
    ob = add_camera(bpy, scene, (0, 0, 0), (0, 0, 0), ortho_scale=3.0 if kind == "ORTHO" else None, lens=35.0)
    cam = ob.data
    cam.sensor_fit, cam.sensor_width, cam.sensor_height = fit, 36.0, 20.0
    cam.shift_x, cam.shift_y = 0.1, -0.05
    setup_render(scene, *size)
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = aspect
    c = camera.scene_camera(scene, None, *size)
    ex, ey, ox, oy = c.plane()
    fr = np.array([list(v) for v in cam.view_frame(scene=scene)])
    if kind == "PERSP":
        fr = fr[:, :2] / -fr[:, 2:3]  # onto the plane z = -1
    lo, hi = fr[:, :2].min(0), fr[:, :2].max(0)
    np.testing.assert_allclose([lo[0], hi[0], lo[1], hi[1]],
                               [ox - ex / 2, ox + ex / 2, oy - ey / 2, oy + ey / 2], rtol=1e-5, atol=1e-6)
