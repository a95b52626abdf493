"""field / reference / paper modes, several objects, level sets, tiles."""
import numpy as np
import pytest

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction, available_devices, get_device
from kernels.render.scene.synthetic import gaussian_set, grid_from_dense


@pytest.fixture(scope="module")
def dev():
    return get_device("CPU")


def test_devices_registry():
    assert "CPU" in available_devices()
    with pytest.raises(ValueError):
        get_device("nope")


def test_reference_constant_leaf_closed_form(dev):
    """One leaf of constant value v: trilinear field is v inside, ramps to the background 0 over
    the outer half voxel; with a linear alpha ramp tau = density * v/vmax * 7.75 along x."""
    v = 0.8
    grid = grid_from_dense(np.full((8, 8, 8), v), (0, 0, 0))
    sc = RenderScene([RenderObject(grid=grid)], mode="reference", step=0.25, transmittance_min=0)
    tf = TransferFunction.from_ramp([0, 1], [[1, 1, 1, 0], [1, 1, 1, 1]], 0.0, 1.0, density=0.3)
    m = np.eye(4)
    m[:3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # camera z = +x: looks along -x
    m[:3, 3] = [20, 3.5, 3.5]
    cam = Camera(m, 3, 3, "ortho", ortho_scale=0.6)
    img = dev.render(sc, cam, tf)["Combined"]
    tau = 0.3 * v * 7.75
    np.testing.assert_allclose(img[1, 1, 3], -np.expm1(-tau), rtol=2e-6)


def test_field_single_gaussian_vs_quadrature(dev):
    c = np.array([0.2, 0.1, -0.3])
    gs = gaussian_set([c], [1.5], [2.0], [0.9])
    tf = TransferFunction.from_colormap("viridis", 0.0, 2.0, alpha="ramp", density=0.7)
    m = np.eye(4)
    m[:3, 3] = [0.5, -0.4, 20]
    cam = Camera(m, 3, 3, "ortho", ortho_scale=2.0)
    sc = RenderScene([RenderObject(gs)], mode="field", step=0.01, transmittance_min=0)
    img = dev.render(sc, cam, tf)["Combined"]
    # quadrature of the DVR integral along the central ray
    o = np.array([0.5, -0.4, 20.0])
    t = np.linspace(20 + 0.3 - 4.6, 20 + 0.3 + 4.6, 200001)
    tm = 0.5 * (t[1:] + t[:-1])
    dt = t[1] - t[0]
    x = o[None] + tm[:, None] * np.array([0, 0, -1.0])
    q = np.sum(((x - c) / 1.5) ** 2, 1)
    s = np.where(q < 9, 2.0 * 0.9 * np.exp(-q / 2), np.nan)
    rgba = np.nan_to_num(tf(s))
    sig = 0.7 * rgba[:, 3]
    T = np.exp(-np.concatenate([[0], np.cumsum(sig * dt)[:-1]]))
    w = T * -np.expm1(-sig * dt)
    ref = np.concatenate([(w[:, None] * rgba[:, :3]).sum(0), [w.sum()]])
    assert ref[3] > 0.3
    np.testing.assert_allclose(img[1, 1], ref, atol=2e-5)


def test_field_vs_reference_smooth_blob(dev):
    """Gaussians placed on every voxel (normalised weights, sigma 0.8 voxel) reproduce the
    voxel field up to the kernel's blur (the blob's peak drops by (9 / 9.64)^1.5 = 10%)."""
    n = 16
    g = np.arange(n)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    vol = np.exp(-((X - 7.5) ** 2 + (Y - 7.5) ** 2 + (Z - 7.5) ** 2) / (2 * 3.0 ** 2))
    cs = np.stack([X, Y, Z], -1).reshape(-1, 3).astype(float)
    sig = 0.8
    amp = 1.0 / ((2 * np.pi) ** 1.5 * sig ** 3)
    gs = gaussian_set(cs, sig, vol.ravel(), amp)
    grid = grid_from_dense(vol, (0, 0, 0))
    tf = TransferFunction.from_colormap("viridis", 0, 1, density=0.5)
    cam = Camera.frame_box([0] * 3, [15] * 3, 16, 16, direction=(1, 0.5, -0.3))
    f = dev.render(RenderScene([RenderObject(gs, grid=grid)], mode="field", support_k=3.5), cam, tf)["Combined"]
    r = dev.render(RenderScene([RenderObject(gs, grid=grid)], mode="reference", support_k=3.5), cam, tf)["Combined"]
    assert r[..., 3].max() > 0.3
    assert np.abs(f - r).max() < 0.06 and np.abs(f - r).mean() < 0.01


def test_paper_differs_where_wrong(dev):
    tf = TransferFunction.from_colormap("viridis", 0, 1, alpha="constant", density=1.0)
    m = np.eye(4)
    m[:3, 3] = [0, 0, 20]
    cam = Camera(m, 3, 3, "ortho", ortho_scale=0.3)
    # (1) small sigma at fixed mass: 1/det(Sigma) blows up; C += T c A overshoots the colour
    s = 0.05
    gs = gaussian_set([[0, 0, 0]], [s], [1.0], [1.0 / ((2 * np.pi) ** 1.5 * s ** 3) * 1e-3])
    col = tf(1.0)[:3]
    p = dev.render(RenderScene([RenderObject(gs)], mode="paper"), cam, tf)["Combined"][1, 1]
    q = dev.render(RenderScene([RenderObject(gs)], mode="particles"), cam, tf)["Combined"][1, 1]
    assert np.all(q[:3] <= col + 1e-6) and q[3] <= 1
    assert p[0] > 10 * col[0]  # paper is far brighter than the brightest colormap entry
    # (2) overlap: two coincident Gaussians of different values; paper sees only the first hit
    gs2 = gaussian_set([[0, 0, 0], [0, 0, 0.2]], [1.0], [0.0, 1.0], [1.0, 1.0])
    tf2 = TransferFunction.from_colormap("grayscale", 0, 1, alpha="constant", density=0.5)
    p2 = dev.render(RenderScene([RenderObject(gs2)], mode="paper"), cam, tf2)["Combined"][1, 1]
    q2 = dev.render(RenderScene([RenderObject(gs2)], mode="particles", tau_max=0.01), cam, tf2)["Combined"][1, 1]
    one = dev.render(RenderScene([RenderObject(gaussian_set([[0, 0, 0.2]], [1.0], [1.0], [1.0]))],
                                 mode="particles"), cam, tf2)["Combined"][1, 1]
    assert q2[3] > one[3] + 0.05  # both Gaussians attenuate
    assert abs(p2[3] - q2[3]) > 0.05


def two_blobs(color_a, color_b, offset):
    cs = np.array([[x, y, z] for x in range(-2, 3) for y in range(-2, 3) for z in range(-2, 3)], float)
    ga = gaussian_set(cs, 1.0, 0.5, 1.0)
    gb = gaussian_set(cs, 1.0, 0.5, 1.0)
    ma = np.eye(4)
    mb = np.eye(4)
    mb[:3, :3] *= 0.7
    mb[:3, 3] = offset
    ta = TransferFunction.from_ramp([0, 1], [color_a + [1], color_a + [1]], 0, 1, density=1.0)
    tb = TransferFunction.from_ramp([0, 1], [color_b + [1], color_b + [1]], 0, 1, density=1.0 / 0.7)
    return RenderObject(ga, ma, tf=ta), RenderObject(gb, mb, tf=tb)


@pytest.mark.parametrize("mode", ["particles", "field"])
def test_two_overlapping_objects_composite_by_depth(dev, mode):
    a, b = two_blobs([1, 0, 0], [0, 0, 1], [0, 0, -3.0])  # boxes overlap; b is below a
    tf = TransferFunction.from_colormap("viridis", 0, 1)
    m = np.eye(4)
    m[:3, 3] = [0, 0, 30]
    top = Camera(m, 5, 5, "ortho", ortho_scale=2)
    bottom = Camera(np.diag([1, -1, -1, 1.0]) @ np.eye(4), 5, 5, "ortho", ortho_scale=2)
    bottom.cam_to_world[:3, 3] = [0, 0, -30]
    sc = RenderScene([a, b], mode=mode)
    img_top = dev.render(sc, top, tf)["Combined"][2, 2]
    img_bot = dev.render(sc, bottom, tf)["Combined"][2, 2]
    assert img_top[0] > 2 * img_top[2]   # red in front from above
    assert img_bot[2] > 2 * img_bot[0]   # blue in front from below
    # order of objects in the list does not matter
    sw = dev.render(RenderScene([b, a], mode=mode), top, tf)["Combined"][2, 2]
    np.testing.assert_allclose(sw, img_top, atol=1e-6)
    # one merged object with both sets of Gaussians (same world placement) gives the same image
    if mode == "particles":
        def centres(gs):
            return gs.offsets.astype(float) + np.repeat(gs.group_origins, np.diff(gs.group_start), 0)

        cs_a, cs_b = centres(a.gaussians), centres(b.gaussians)
        wb = cs_b * 0.7 + [0, 0, -3.0]
        # express b's Gaussians in a's index space: sigma 0.7, colour via value
        sig = np.concatenate([np.ones((len(cs_a), 3)), np.full((len(wb), 3), 0.7)])
        merged = gaussian_set(np.concatenate([cs_a, wb]), sig,
                              np.concatenate([np.zeros(len(cs_a)), np.ones(len(wb))]), 1.0)
        tfm = TransferFunction.from_ramp([0, 1], [[1, 0, 0, 1], [0, 0, 1, 1]], 0, 1, density=1.0,
                                         interpolation="CONSTANT")
        ref = dev.render(RenderScene([RenderObject(merged)], mode=mode, tau_max=0.1), top, tfm)["Combined"][2, 2]
        np.testing.assert_allclose(img_top, ref, atol=2e-3)


def test_level_set_constant_colour_and_height(dev):
    cs = np.array([[x, y, z] for x in range(4) for y in range(4) for z in range(8)], float)
    gs = gaussian_set(cs, 0.8, np.nan, 1.0, grid_class="level_set")
    tf = TransferFunction.from_colormap("viridis", 0, 1, alpha="ramp", density=2.0)  # alpha ignored
    m = np.eye(4)
    m[:3, :3] = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]  # looks along -x, image up = +z
    m[:3, 3] = [20, 1.5, 3.5]
    cam = Camera(m, 4, 16, "ortho", ortho_scale=9)
    ob = RenderObject(gs, level_set_color=(0.2, 0.5, 0.1))
    assert ob.is_level_set
    img = dev.render(RenderScene([ob]), cam, tf)["Combined"]
    a = img[..., 3]
    assert a.max() > 0.99
    hit = a > 0.01
    np.testing.assert_allclose(img[..., :3][hit] / a[hit][:, None], np.tile([0.2, 0.5, 0.1], (hit.sum(), 1)), rtol=1e-5)
    img2 = dev.render(RenderScene([RenderObject(gs, level_set_color="z")]), cam, tf)["Combined"]
    col = img2[..., :3] / np.maximum(img2[..., 3:], 1e-9)
    # viridis goes dark purple (bottom) -> yellow (top): green channel grows with height
    rows = [r for r in range(16) if img2[r, 1, 3] > 0.5]
    assert col[rows[-1], 1, 1] > col[rows[0], 1, 1] + 0.3


def test_tiles_progress_cancel(dev):
    cs = np.array([[x, y, 0] for x in range(6) for y in range(6)], float)
    sc = RenderScene([RenderObject(gaussian_set(cs, 1.0, np.linspace(0, 1, 36)))])
    tf = TransferFunction.from_colormap("coolwarm", 0, 1)
    cam = Camera.frame_box([-2, -2, -2], [7, 7, 2], 20, 40, direction=(0, 0.3, -1))
    full = dev.render(sc, cam, tf)
    tiled = CPUDevice(tile_rows=7)
    seen = []
    out = tiled.render(sc, cam, tf, progress=seen.append)
    assert seen[-1] == 1.0 and len(seen) == 6
    for k in full:
        assert np.array_equal(out[k], full[k])
    band = dev.render(sc, cam, tf, rows=(10, 17))
    assert np.array_equal(band["Combined"], full["Combined"][10:17])
    calls = []
    out = tiled.render(sc, cam, tf, cancel=lambda: len(calls) > 1 or calls.append(1))
    assert tiled.stats["cancelled"] and np.all(out["Combined"][14:] == 0)


def test_sync_is_skipped_when_geometry_unchanged(dev):
    sc = RenderScene([RenderObject(gaussian_set([[0, 0, 0]], 1.0))])
    dev.sync(sc)
    assert dev.stats["seconds_sync"] > 0
    dev.sync(sc)
    assert dev.stats["seconds_sync"] == 0.0
    sc.objects[0].matrix_world = np.diag([2.0, 2, 2, 1])
    dev.sync(sc)
    assert dev.stats["seconds_sync"] > 0
