"""Scene sync (LOD choice, no work for an unchanged depsgraph), the viewport camera maths and the
progressive scheduler, all headless."""

import math

import numpy as np
import pytest
from test_engine_helpers import add_camera, lattice, make_object, setup_render


def _mod(name):
    import importlib

    return importlib.import_module(f"bl_ext.user_default.gaussvdb.gaussvdb_addon.{name}")


def _two_lod_object(bpy):
    low = lattice(2, 2, 2, origin=(0, 0, 0)) * 4
    med = lattice(4, 4, 4)
    pts = np.concatenate([low, med])
    lod = np.concatenate([np.zeros(len(low)), np.ones(len(med))]).astype(np.int8)
    ob = make_object(bpy, "TwoLOD", pts, lod_index=lod, lods="low,medium")
    ob.gaussvdb.viewport_lod = "low"
    ob.gaussvdb.render_lod = "medium"
    return ob


def test_viewport_and_render_lod(bpy_module, scene):
    bpy = bpy_module
    ss = _mod("engine.scene_sync")
    _two_lod_object(bpy)
    dg = bpy.context.evaluated_depsgraph_get()
    r = ss.SceneSync(viewport=False)
    r.sync(dg)
    v = ss.SceneSync(viewport=True)
    v.sync(dg)
    assert (r.gaussians, v.gaussians) == (64, 8)
    ob = bpy.data.objects["TwoLOD"]
    ob.gaussvdb.viewport_lod = "medium"
    v.dirty = True
    dg = bpy.context.evaluated_depsgraph_get()
    v.sync(dg)
    assert v.gaussians == 64


class _Upd:
    def __init__(self, ident, geometry=False, transform=False):
        self.id, self.is_updated_geometry, self.is_updated_transform = ident, geometry, transform


def test_unchanged_depsgraph_costs_nothing(bpy_module, scene):
    bpy = bpy_module
    ss = _mod("engine.scene_sync")
    ob = make_object(bpy, "Cloud", lattice(4, 4, 4))
    dg = bpy.context.evaluated_depsgraph_get()
    s = ss.SceneSync(viewport=True)
    first = s.sync(dg)
    assert (s.reads, s.builds) == (1, 1)
    assert s.note_updates([]) is False
    assert s.sync(dg) is first and (s.reads, s.builds) == (1, 1)
    # a transform update rebuilds the scene (placement) but reads no Gaussians
    ob.location = (1.0, 2.0, 3.0)
    dg = bpy.context.evaluated_depsgraph_get()
    assert s.note_updates([_Upd(ob, transform=True)])
    moved = s.sync(dg)
    assert (s.reads, s.builds) == (1, 2)
    assert moved.objects[0].gaussians is first.objects[0].gaussians
    assert np.allclose(moved.objects[0].matrix_world[:3, 3], (1, 2, 3))
    # the device sees the same geometry key only when nothing moved
    assert moved.geometry_key() != first.geometry_key()
    # a geometry update reads that object again
    assert s.note_updates([_Upd(ob, geometry=True)])
    s.sync(dg)
    assert s.reads == 2


def test_viewport_session_update_skips_unchanged(bpy_module, scene):
    bpy = bpy_module
    vp = _mod("engine.viewport")
    make_object(bpy, "Cloud", lattice(4, 4, 4))
    dg = bpy.context.evaluated_depsgraph_get()

    class Eng:
        def tag_redraw(self):
            pass

    sess = vp.ViewportSession(Eng())
    assert sess.update(None, dg) is True
    reads, builds = sess.sync.reads, sess.sync.builds
    assert sess.update(None, dg) is False  # no depsgraph updates: nothing done
    assert (sess.sync.reads, sess.sync.builds) == (reads, builds)


def _rays(cam):
    from bl_ext.user_default.gaussvdb.kernels.render import generate_rays

    return generate_rays(cam)


@pytest.mark.parametrize("kind,fit,size,shift", [
    ("PERSP", "AUTO", (64, 48), (0.0, 0.0)),
    ("PERSP", "AUTO", (48, 64), (0.1, -0.05)),
    ("PERSP", "VERTICAL", (64, 40), (0.05, 0.1)),
    ("PERSP", "HORIZONTAL", (40, 64), (-0.1, 0.0)),
    ("ORTHO", "AUTO", (64, 48), (0.1, 0.2)),
    ("ORTHO", "VERTICAL", (48, 64), (0.0, -0.1)),
])
def test_viewport_camera_equals_final_camera(bpy_module, scene, kind, fit, size, shift):
    """Region matrices as Blender builds them for the camera view (view = inverse camera matrix,
    window = the camera's projection for the region size) give the final render's rays."""
    bpy = bpy_module
    cm = _mod("engine.camera")
    w, h = size
    ob = add_camera(bpy, scene, (3.0, -8.0, 2.5), (1.2, 0.1, 0.4),
                    ortho_scale=7.0 if kind == "ORTHO" else None, lens=35.0)
    ob.data.sensor_fit = fit
    ob.data.sensor_width, ob.data.sensor_height = 36.0, 20.0
    ob.data.shift_x, ob.data.shift_y = shift
    setup_render(scene, w, h)
    dg = bpy.context.evaluated_depsgraph_get()
    final = cm.scene_camera(scene, dg, w, h)
    window = ob.evaluated_get(dg).calc_matrix_camera(dg, x=w, y=h)
    view = ob.matrix_world.inverted()
    region = cm.camera_from_matrices(view, window, w, h, kind == "PERSP")
    o1, d1 = _rays(final)
    o2, d2 = _rays(region)
    assert np.abs(d1 - d2).max() < 1e-6  # Blender matrices are float32
    # orthographic origins may differ only along the viewing direction (near plane)
    off = o2 - o1
    perp = off - (off * d1).sum(1, keepdims=True) * d1
    assert np.abs(perp).max() < 1e-5
    # and the final camera projects like Blender's own projection matrix
    world = o1 + d1 * 5.0
    p = np.array(window) @ np.array(view) @ np.c_[world, np.ones(len(world))].T
    ndc = (p[:2] / p[3]).T
    jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    expect = np.c_[((ii.ravel() + 0.5) / w) * 2 - 1, ((jj.ravel() + 0.5) / h) * 2 - 1]
    assert np.abs(ndc - expect).max() < 1e-5


def test_progressive_schedule(addon):
    sched_mod = _mod("engine.viewport")
    s = sched_mod.ProgressiveSchedule(levels=(8, 4, 2, 1), rest=0.15, clock=lambda: 0.0)
    assert s.next(0.0) is None  # nothing submitted
    s.restart(now=10.0)
    g = s.generation
    assert s.next(10.0) == 8  # the coarse level at once, even while moving
    s.finished(8, g)
    assert s.next(10.05) is None and s.wait_time(10.05) == pytest.approx(0.10)
    s.restart(now=10.05)  # the view moved again: back to the coarse level
    assert s.next(10.06) == 8
    s.finished(8, g)  # a stale generation's result does not advance
    assert s.next(10.06) == 8
    s.finished(8, s.generation)
    got = []
    t = 10.3  # the view rests: refine to full resolution
    while (f := s.next(t)) is not None:
        got.append(f)
        s.finished(f, s.generation)
    assert got == [4, 2, 1] and s.converged


def test_viewport_worker_refines(bpy_module, scene):
    """The worker's step() renders 1/8 .. full resolution of the submitted view, headless."""
    bpy = bpy_module
    cm, vp = _mod("engine.camera"), _mod("engine.viewport")
    make_object(bpy, "Cloud", lattice(8, 8, 8), values=np.linspace(0, 1, 512))
    add_camera(bpy, scene, (3.5, -30.0, 3.5), (math.pi / 2, 0.0, 0.0))
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    dg = bpy.context.evaluated_depsgraph_get()

    class Eng:
        redraws = 0

        def tag_redraw(self):
            self.redraws += 1

    sess = vp.ViewportSession(Eng())
    sess.update(None, dg)
    sess.schedule.rest = 0.0
    cam = cm.scene_camera(scene, dg, 64, 48)
    sess.job = None
    with sess.lock:
        sess.schedule.restart()
        sess.job = (sess.schedule.generation, sess.sync.scene, cam, sess.sync.transfer_function(scene.gaussvdb))
    sizes = []
    while sess.step() is not None:
        sizes.append(sess.image[2].shape[:2])
    assert sizes == [(6, 8), (12, 16), (24, 32), (48, 64)]
    assert sess.schedule.converged and sess.engine.redraws == 4
    assert sess.image[2][24, 32, 3] > 0.0
