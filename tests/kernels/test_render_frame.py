"""A frame's set-up is done once and reused by every band or region of it (bitwise the same
pixels); the stats' types; camera clipping along the view axis."""

import math

import numpy as np
import pytest

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.synthetic import gaussian_set, grid_from_dense

MODES = ["particles", "field", "paper", "reference"]


def blob_object(amplitude=8 / ((2 * np.pi) ** 1.5 * 1.2 ** 3)):
    """A 24^3 smooth blob as a grid (reference) and as Gaussians on every other voxel."""
    n = 24
    x = np.arange(n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    vol = np.exp(-((X - 12) ** 2 + (Y - 11) ** 2 + (Z - 12.5) ** 2) / (2 * 5.0 ** 2)).astype(np.float32)
    vol[vol < 0.05] = 0
    c = np.stack(np.meshgrid(x[::2] + 0.5, x[::2] + 0.5, x[::2] + 0.5, indexing="ij"), -1).reshape(-1, 3)
    v = vol[::2, ::2, ::2].reshape(-1)
    keep = v > 0
    gs = gaussian_set(c[keep], 1.2, v[keep], amplitude)
    return RenderObject(gs, np.diag([0.1, 0.1, 0.1, 1.0]), grid=grid_from_dense(vol))


def blob_scene(mode):
    return RenderScene([blob_object()], mode=mode, passes=("Depth", "Value"), threads=2)


TF = TransferFunction.from_colormap("viridis", 0.0, 1.0, density=2.0)


def camera(**kw):
    return Camera.frame_box([0, 0, 0], [2.4, 2.4, 2.4], 45, 37, direction=(1.0, 0.8, -0.5), **kw)


@pytest.fixture(scope="module")
def dev():
    return CPUDevice()


@pytest.mark.parametrize("mode", MODES)
def test_bands_and_regions_are_the_frame_bitwise(dev, mode):
    sc = blob_scene(mode)
    cam = camera()
    dev.end_frame()
    full = dev.render(sc, cam, tf=TF)
    assert dev.stats["seconds_setup"] > 0.0
    assert full["Combined"][..., 3].max() > 0.02  # drawn (paper mode is faint)
    cuts = [0, 5, 6, 21, 37]  # uneven bands, one of a single row, not on tile boundaries
    bands = [dev.render(sc, cam, TF, rows=(a, b)) for a, b in zip(cuts[:-1], cuts[1:])]
    assert dev.stats["seconds_setup"] == 0.0  # the frame's set-up was kept
    region = dev.render(sc, cam, TF, rows=(7, 30), cols=(5, 41))
    for k in full:
        joined = np.concatenate([b[k] for b in bands])
        assert joined.tobytes() == full[k].tobytes(), k
        assert region[k].shape[:2] == (23, 36)
        assert region[k].tobytes() == np.ascontiguousarray(full[k][7:30, 5:41]).tobytes(), k
    with pytest.raises(ValueError, match="outside"):
        dev.render(sc, cam, TF, cols=(40, 46))


def test_frame_state_follows_camera_tf_settings_and_tiles(dev):
    sc = blob_scene("particles")
    cam = camera()
    base = dev.render(sc, cam, TF)["Combined"]
    changed = {
        "density": lambda: dev.render(sc, cam, TransferFunction.from_colormap("viridis", 0, 1, density=4.0)),
        "colormap": lambda: dev.render(sc, cam, TransferFunction.from_colormap("plasma", 0, 1, density=2.0)),
        "camera": lambda: dev.render(sc, camera(margin=1.3), TF),
        "background": lambda: dev.render(RenderScene(sc.objects, background=(0.2, 0.3, 0.4, 1.0)), cam, TF),
    }
    for name, fn in changed.items():
        img = fn()["Combined"]
        assert dev.stats["seconds_setup"] > 0.0, name
        assert not np.array_equal(img, base), name
        again = dev.render(sc, cam, TF)["Combined"]  # back to the first frame: same pixels
        assert again.tobytes() == base.tobytes(), name
    dev.screen_tiles = False
    try:
        walk = dev.render(sc, cam, TF)["Combined"]
        assert dev.stats["seconds_setup"] > 0.0
        assert np.abs(walk - base).max() < 1e-6
    finally:
        dev.screen_tiles = True


def test_stats_types(dev):
    sc = blob_scene("field")
    dev.render(sc, camera(), TF, progress=lambda f: None)
    types = {"seconds_sync": float, "seconds_setup": float, "seconds_render": float,
             "segments": float, "cancelled": bool, "threads": int}
    assert set(dev.stats) == set(types)
    for k, t in types.items():
        assert type(dev.stats[k]) is t, (k, type(dev.stats[k]))
    assert 0.0 <= dev.stats["seconds_setup"] <= dev.stats["seconds_render"] < 60.0
    assert dev.stats["threads"] == 2 and dev.stats["segments"] > 0


def _alpha(dev, sc, cam):
    return dev.render(sc, cam, TF)["Combined"][..., 3].astype(np.float64)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("kind", ["persp", "ortho"])
def test_clip_range_cuts_the_volume(dev, mode, kind):
    sc = blob_scene(mode)
    cam = camera(kind=kind)
    full = _alpha(dev, sc, cam)
    assert full.max() > 0.02
    # the view-axis depths of the volume's box corners
    rot, pos = cam.basis()
    corners = np.array([[x, y, z] for x in (0, 2.4) for y in (0, 2.4) for z in (0, 2.4)])
    depth = (corners - pos) @ -rot[:, 2]
    near, far = depth.min(), depth.max()
    same = dict(cam.__dict__, clip_start=0.0, clip_end=1e30)
    assert _alpha(dev, sc, Camera(**same)).tobytes() == full.tobytes()
    assert _alpha(dev, sc, Camera(**dict(same, clip_end=0.99 * near))).max() == 0.0
    assert _alpha(dev, sc, Camera(**dict(same, clip_start=1.01 * far))).max() == 0.0
    # a clip plane moved through the volume: less and less is left in front of clip_end, more and
    # more is cut away by clip_start
    ends = [_alpha(dev, sc, Camera(**dict(same, clip_end=near + f * (far - near)))).sum()
            for f in (0.3, 0.5, 0.7)]
    starts = [_alpha(dev, sc, Camera(**dict(same, clip_start=near + f * (far - near)))).sum()
              for f in (0.3, 0.5, 0.7)]
    assert 0.0 < ends[0] < ends[1] < ends[2] < full.sum()
    assert full.sum() > starts[0] > starts[1] > starts[2] > 0.0


@pytest.mark.parametrize("pixel", [(1, 1), (0, 2)])
def test_clip_start_through_a_gaussian_centre_halves_its_depth(dev, pixel):
    """Perspective: clip distances are view-axis depths, so a ray at angle a to the axis is cut at
    clip_start / cos a. A Gaussian centred on pixel (i, j)'s ray, cut at its centre's depth: that
    ray keeps exactly half its optical depth (closed form)."""
    i, j = pixel
    cam = Camera(np.eye(4), 3, 3, "persp", fov_x=math.radians(60))
    ex, ey, ox, oy = cam.plane()
    d = np.array([((i + 0.5) / 3 - 0.5) * ex + ox, ((j + 0.5) / 3 - 0.5) * ey + oy, -1.0])
    d /= np.linalg.norm(d)
    centre = 10.0 * d
    sc = RenderScene([RenderObject(gaussian_set([centre], 0.4, [1.0], [1.0]))], transmittance_min=0.0)
    tf = TransferFunction.from_ramp([0, 1], [[1, 1, 1, 1], [1, 1, 1, 1]], 0.0, 1.0, density=3.0)
    a_full = dev.render(sc, cam, tf)["Combined"][j, i, 3]
    cut = Camera(np.eye(4), 3, 3, "persp", fov_x=math.radians(60), clip_start=-centre[2])
    a_half = dev.render(sc, cut, tf)["Combined"][j, i, 3]
    tau = -math.log1p(-float(a_full))
    assert tau > 0.5
    np.testing.assert_allclose(-math.log1p(-float(a_half)), 0.5 * tau, rtol=1e-5)
