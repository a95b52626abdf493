"""Issue 8, end to end: extreme .vdb files written with the bundled openvdb, imported with the
importer's plain function (``import_vdb``) and rendered through the scene-sync helper and the
device. Each case either renders a finite, sensible image (checked against an independent float64
numpy closed form where the image is exact) or stops with a clear VDBImportError and leaves the
scene as it was.

The closed form: with a constant-alpha transfer function, particles mode is exact,
alpha = 1 - exp(-density * sum_i a_i * integral of g_i over the ray clipped to its k-sigma
ellipsoid), evaluated here per pixel in numpy (no numba, no traversal)."""

import importlib
import math
import warnings

import numpy as np
import pytest
from conftest import ADDON_MODULE
from scipy.special import erf  # noqa: F401  (only to fail early if scipy is missing)
from vdb_fixtures import openvdb, write_grid, write_nan_inf

from tests.references import closed_form_alpha


def _mod(name):
    return importlib.import_module(f"{ADDON_MODULE}.{name}")


def _imp():
    return _mod("gaussvdb_addon.io.importer")


def _ids(bpy):
    return (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.pointclouds))


def _rot(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


# -- render helpers ----------------------------------------------------------------------------------
def _world_box(obj):
    mw = np.array(obj.matrix_world, np.float64)
    lo = np.array(obj.gaussvdb.leaf_box_min, np.float64)
    hi = np.array(obj.gaussvdb.leaf_box_max, np.float64)
    c = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    w = c @ mw.T
    return w[:, :3].min(0), w[:, :3].max(0)


def _voxel_world(obj):
    m = np.array(obj.matrix_world, np.float64)[:3, :3]
    return float(abs(np.linalg.det(m))) ** (1.0 / 3.0)


def sync_scene(bpy, scene, mode="PARTICLES"):
    """SceneSync (final-render flavour) of the current depsgraph -> (RenderScene, scene TF, sync)."""
    ss = _mod("gaussvdb_addon.engine.scene_sync")
    s = scene.gaussvdb
    s.mode = mode
    s.density_unit = "WORLD"  # the closed forms here take density per world unit
    scene.view_layers[0].use_pass_z = True
    scene.view_layers[0].gaussvdb.use_pass_value = True
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    scene.render.film_transparent = True  # alpha = the volume's opacity alone
    sync = ss.SceneSync(viewport=False)
    rs = sync.sync(bpy.context.evaluated_depsgraph_get())
    return rs, sync.transfer_function(s), sync


def const_tf(density, opacity=1.0, color=(0.2, 0.6, 0.9)):
    TF = _mod("kernels.render").TransferFunction
    lut = np.tile(np.array([*color, opacity], np.float32), (256, 1))
    return TF(lut, 0.0, 1.0, density=density)


def frame(obj, size=24, direction=(1.0, 0.6, -0.4), kind="persp"):
    Camera = _mod("kernels.render").Camera
    lo, hi = _world_box(obj)
    return Camera.frame_box(lo, hi, size, size, direction=direction, kind=kind)


def device():
    return _mod("gaussvdb_addon.engine.devices").final_device()


def check_sane(out, tf=None):
    c = out["Combined"]
    assert np.all(np.isfinite(c)), "non-finite Combined"
    assert c[..., 3].min() >= 0.0 and c[..., 3].max() <= 1.0 + 1e-6
    assert c[..., :3].min() >= -1e-7
    if tf is not None:  # premultiplied: never brighter than the brightest colour times alpha
        cmax = float(tf.lut[:, :3].max())
        assert np.all(c[..., :3] <= cmax * c[..., 3:] + 1e-6)
    for k in ("Depth", "Value"):
        if k in out:
            assert np.all(np.isfinite(out[k])), f"non-finite {k} pass"


def import_one(path, **kw):
    objs = _imp().import_vdb(str(path), **{"lods": ("high",), "compute_error": False, **kw})
    assert len(objs) == 1
    return objs[0]


def check_closed_form(bpy, scene, obj, density_voxel=0.5, size=20, direction=(1.0, 0.6, -0.4),
                      kind="persp", atol=2e-5, cam=None):
    """Render obj through SceneSync + device with a constant TF and compare to the closed form."""
    rs, _, sync = sync_scene(bpy, scene)
    assert len(rs.objects) == 1
    ro = rs.objects[0]
    rs.transmittance_min = 0.0  # early termination would cap alpha at 1 - 1e-3
    dens = density_voxel / _voxel_world(obj)
    tf = const_tf(dens)
    cam = frame(obj, size, direction, kind) if cam is None else cam
    out = device().render(rs, cam, tf)
    check_sane(out, tf)
    ref = closed_form_alpha(cam, ro.gaussians, ro.matrix_world, dens, rs.support_k)
    err = np.abs(out["Combined"][..., 3] - ref).max()
    assert ref.max() > 0.05, ref.max()
    assert err <= atol, (err, np.unravel_index(np.argmax(np.abs(out["Combined"][..., 3] - ref)), ref.shape),
                         out["Combined"][..., 3].max(), ref.max())
    return out


def write_with_voxel_size(path, vals, voxel, **kw):
    """OpenVDB refuses voxel sizes below ~1e-5 ('nearly singular'): write 0.5 and patch the stored
    UniformScaleMap (scale, voxelSize, 1/s, 1/s^2, 1/(2s), each a Vec3d) to ``voxel``."""
    write_grid(path, vals, voxel_size=0.5, **kw)
    data = bytearray(open(path, "rb").read())
    key = b"UniformScaleMap"
    at = data.find(key)
    assert at > 0 and data.find(key, at + 1) < 0
    at += len(key)
    old = np.frombuffer(bytes(data[at:at + 120]), "<f8")
    np.testing.assert_allclose(old, np.repeat([0.5, 0.5, 2.0, 4.0, 1.0], 3))
    new = np.repeat([voxel, voxel, 1 / voxel, 1 / voxel ** 2, 0.5 / voxel], 3).astype("<f8")
    data[at:at + 120] = new.tobytes()
    open(path, "wb").write(bytes(data))
    return path


# -- cases ------------------------------------------------------------------------------------------
def test_nan_inf_voxels_never_crash_or_half_build(bpy_module, scene, tmp_path):
    """Whatever the importer decides, Blender survives, the scene is whole and Combined is finite."""
    bpy = bpy_module
    path = write_nan_inf(tmp_path / "naninf.vdb")
    before = _ids(bpy)
    try:
        obj = import_one(path, lods=("low", "high"))
    except _imp().VDBImportError as err:
        assert _ids(bpy) == before and "naninf.vdb" in str(err)
        return
    assert obj.type == "POINTCLOUD"
    for mode in ("PARTICLES", "FIELD"):
        rs, tf, _ = sync_scene(bpy, scene, mode)
        out = device().render(rs, frame(obj, 16), tf)
        assert np.all(np.isfinite(out["Combined"]))
        assert 0 <= out["Combined"][..., 3].min() and out["Combined"][..., 3].max() <= 1 + 1e-6


def test_nan_inf_voxels_sanitized_or_refused(bpy_module, scene, tmp_path):
    """The issue allows two outcomes: refused with a clear message naming the problem, or imported
    with a warning that counts the bad voxels (3 here), finite Gaussians and a finite image."""
    bpy = bpy_module
    path = write_nan_inf(tmp_path / "naninf.vdb")
    before = _ids(bpy)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            obj = import_one(path, lods=("low", "high"), compute_error=True)
        except _imp().VDBImportError as err:
            assert _ids(bpy) == before
            assert any(w in str(err).lower() for w in ("nan", "inf", "non-finite")), str(err)
            return
    text = " ".join(str(w.message) for w in caught) + " " + obj.gaussvdb.stats_json
    assert ("nan" in text.lower() or "non-finite" in text.lower()) and "3" in text, text
    imp = _imp()
    for lod in ("low", "high"):
        gs = imp.gaussian_set_from_object(obj, lod)
        assert np.all(np.isfinite(gs.values)), lod
    for mode in ("PARTICLES", "FIELD", "PAPER"):
        rs, tf, _ = sync_scene(bpy, scene, mode)
        # the paper's compositing adds colour c*A while alpha grows by 1 - exp(-A) < A, so its
        # premultiplied colour may exceed cmax * alpha: only finiteness and range apply to it
        check_sane(device().render(rs, frame(obj, 16), tf), None if mode == "PAPER" else tf)


def test_values_spanning_1e_minus30_to_1e30(bpy_module, scene, tmp_path):
    vals = np.logspace(-30, 30, 16 ** 3).astype(np.float32).reshape(16, 16, 16)
    obj = import_one(write_grid(tmp_path / "span.vdb", vals), compute_error=True)
    stats = _imp().object_stats(obj)[0]
    assert stats["value_min"] == pytest.approx(1e-30, rel=1e-6)
    assert stats["value_max"] == pytest.approx(1e30, rel=1e-6)
    assert np.isfinite(stats["nrmse"])
    s = scene.gaussvdb
    s.density = 2.0
    for mode in ("PARTICLES", "FIELD", "PAPER"):
        for log in (False, True):
            s.log_scale = log
            rs, tf, _ = sync_scene(bpy_module, scene, mode)
            if log:
                assert tf.vmin > 0 and tf.vmax / tf.vmin > 1e50
            out = device().render(rs, frame(obj, 16), tf)
            check_sane(out, tf if mode != "PAPER" else None)
            if log:  # most voxels are mid-range on a log axis: the block is visible
                assert out["Combined"][..., 3].max() > 0.05, (mode, log)
    # exact closed form with a constant TF (all values equally opaque)
    check_closed_form(bpy_module, scene, obj)


@pytest.mark.parametrize("voxel", [1e-6, 1e6])
def test_extreme_voxel_sizes_same_image(bpy_module, scene, tmp_path, voxel):
    """Voxel size 1e-6 / 1e6 with the density per voxel fixed: the same image as voxel size 1."""
    vals = np.linspace(0.1, 1.0, 12 * 10 * 8, dtype=np.float32).reshape(12, 10, 8)
    imgs = []
    for vs in (1.0, voxel):
        for o in list(bpy_module.data.objects):
            bpy_module.data.objects.remove(o)
        obj = import_one(write_with_voxel_size(tmp_path / f"vs{vs:g}.vdb", vals, vs))
        np.testing.assert_allclose(np.array(obj.matrix_world)[:3, :3], vs * np.eye(3), rtol=1e-6)
        scene.gaussvdb.density = 0.4 / vs
        rs, tf, _ = sync_scene(bpy_module, scene)
        out = device().render(rs, frame(obj, 20), tf)
        check_sane(out, tf)
        imgs.append(out)
    a, b = imgs
    assert a["Combined"][..., 3].max() > 0.2
    np.testing.assert_allclose(b["Combined"], a["Combined"], atol=1e-5)
    hit = a["Depth"] < 1e9
    np.testing.assert_allclose(b["Depth"][hit] / voxel, a["Depth"][hit], rtol=1e-5)
    check_closed_form(bpy_module, scene, obj)


def test_oblique_anisotropic_transform(bpy_module, scene, tmp_path):
    """0.5 x 0.5 x 3 voxels, rotated and shifted: the closed form in index space agrees."""
    m = np.eye(4)
    m[:3, :3] = _rot((1, 2, 3), 0.6) @ np.diag([0.5, 0.5, 3.0])
    m[:3, 3] = (1.25, -2.0, 0.75)
    vals = np.linspace(0.1, 1.0, 10 * 9 * 6, dtype=np.float32).reshape(10, 9, 6)
    obj = import_one(write_grid(tmp_path / "oblique.vdb", vals, origin=(-3, 2, 5), matrix=m))
    np.testing.assert_allclose(np.array(obj.matrix_world), m, atol=1e-6)
    for kind, direction in (("persp", (1.0, 0.6, -0.4)), ("ortho", tuple(m[:3, 2]))):
        check_closed_form(bpy_module, scene, obj, kind=kind, direction=direction)


def test_indices_near_1e6(bpy_module, scene, tmp_path):
    """A grid at index ~ (1e6, -1e6, 1e6) (voxel 2^-7, leaf aligned): placement exact, image = closed
    form and = the same grid at the origin moved there by its matrix (translation exact in float32,
    as Blender stores matrix_world)."""
    vals = np.linspace(0.2, 1.0, 8 * 8 * 8, dtype=np.float32).reshape(8, 8, 8)
    org = (1_000_064, -1_000_064, 999_936)
    obj = import_one(write_grid(tmp_path / "far.vdb", vals, origin=org, voxel_size=2.0 ** -7))
    cam = frame(obj, 20)
    out = check_closed_form(bpy_module, scene, obj, cam=cam)
    gs = _imp().gaussian_set_from_object(obj, "high")
    c = np.repeat(gs.group_origins, np.diff(gs.group_start), 0) + gs.offsets.astype(np.float64)
    assert np.all(c.min(0) >= np.array(org) - 0.5) and np.all(c.max(0) <= np.array(org) + 7.5)
    # same data at the origin, matrix translated to the same world place
    for o in list(bpy_module.data.objects):
        bpy_module.data.objects.remove(o)
    m = np.diag([2.0 ** -7, 2.0 ** -7, 2.0 ** -7, 1.0])
    m[:3, 3] = np.array(org, float) * 2.0 ** -7
    near = import_one(write_grid(tmp_path / "near.vdb", vals, matrix=m))
    img = check_closed_form(bpy_module, scene, near, cam=cam)
    np.testing.assert_allclose(img["Combined"], out["Combined"], atol=1e-5)


def test_single_voxel(bpy_module, scene, tmp_path):
    vals = np.zeros((3, 3, 3), np.float32)
    vals[1, 1, 1] = 0.7
    obj = import_one(write_grid(tmp_path / "one.vdb", vals, origin=(5, -2, 9), voxel_size=0.3),
                     lods=("low", "medium", "high", "variance", "merged"))
    for lod in ("low", "high", "merged"):
        gs = _imp().gaussian_set_from_object(obj, lod)
        assert len(gs.values) == 1 and gs.values[0] == np.float32(0.7)
    for kind in ("persp", "ortho"):
        check_closed_form(bpy_module, scene, obj, density_voxel=2.0, kind=kind)
    for mode in ("FIELD", "PAPER"):
        rs, tf, _ = sync_scene(bpy_module, scene, mode)
        check_sane(device().render(rs, frame(obj, 12), tf))


def test_one_voxel_thick_sheet(bpy_module, scene, tmp_path):
    vals = np.full((24, 20, 1), 0.8, np.float32)
    obj = import_one(write_grid(tmp_path / "sheet.vdb", vals, origin=(0, 0, 3)))
    # face on, oblique, and edge on (grazing along the sheet: rays run inside it)
    for direction in ((0.0, 0.0, -1.0), (1.0, 0.6, -0.4), (1.0, 0.0, 0.0)):
        check_closed_form(bpy_module, scene, obj, density_voxel=0.3, direction=direction, kind="ortho")
    for mode in ("FIELD", "PAPER"):
        rs, tf, _ = sync_scene(bpy_module, scene, mode)
        check_sane(device().render(rs, frame(obj, 16, (1.0, 0.0, 0.0), "ortho"), tf))


def test_empty_grid_refused_scene_untouched(bpy_module, scene, tmp_path):
    bpy = bpy_module
    before = _ids(bpy)
    imp = _imp()
    for name, vals in (("none", None), ("allbg", np.zeros((8, 8, 8), np.float32))):
        path = write_grid(tmp_path / f"{name}.vdb", vals)
        with pytest.raises(imp.VDBImportError, match="empty grid"):
            imp.import_vdb(str(path))
        assert _ids(bpy) == before
    # an empty scene renders the background, nothing else
    rs, tf, _ = sync_scene(bpy, scene)
    Camera = _mod("kernels.render").Camera
    out = device().render(rs, Camera(np.eye(4), 8, 8), tf)
    check_sane(out)
    assert np.all(out["Combined"][..., 3] == 0) or np.allclose(out["Combined"][..., 3], 1.0)


@pytest.mark.parametrize("bg", [1e-30, 1e30])
def test_level_set_extreme_background(bpy_module, scene, tmp_path, bg):
    ov = openvdb()
    g = ov.createLevelSetSphere(radius=5.0, center=(0.0, 0.0, 0.0), voxelSize=0.5, halfWidth=3.0)
    g.name = "surface"
    g.background = bg
    path = tmp_path / "ls.vdb"
    ov.write(str(path), grids=[g])
    obj = import_one(path, lods=("medium",))
    assert obj.gaussvdb.grid_class == "level_set"
    scene.gaussvdb.density = 50.0
    for mode in ("PARTICLES", "FIELD"):
        rs, tf, _ = sync_scene(bpy_module, scene, mode)
        cam = frame(obj, 24, (0.0, 1.0, 0.0), "ortho")
        out = device().render(rs, cam, tf)
        check_sane(out)
        a = out["Combined"][..., 3]
        assert a[12, 12] > 0.99, (mode, a[12, 12])  # the sphere's middle is opaque
        assert a[0, 0] < 1e-3                        # the corners see past the sphere
        # the silhouette is a disc of radius 5 (world): the ortho image spans ortho_scale
        px = cam.ortho_scale / 24
        yy, xx = np.mgrid[0:24, 0:24]
        r = np.hypot((xx + 0.5 - 12) * px, (yy + 0.5 - 12) * px)
        assert np.all(a[r < 4.0] > 0.9) and np.all(a[r > 6.5] < 0.05)
