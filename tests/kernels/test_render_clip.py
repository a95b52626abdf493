"""Per-object clip planes and boxes (kernels.render.scene.clip), in every mode: the cut side is empty,
rays that do not cross a plane are untouched (bit for bit), and a cut across the view equals the
camera's clip range placed there (the medium ends at the cut: no hollow shell)."""
import dataclasses

import numpy as np
import pytest

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.scene import clip
from kernels.render.scene.synthetic import gaussian_set, grid_from_dense

N = 16
CENTRE = np.full(3, 7.5)
# (mode, screen tiles): particles and field by their tile lists and by the leaf walk
CASES = [("particles", True), ("particles", False), ("field", True), ("field", False),
         ("paper", True), ("reference", True)]


@pytest.fixture(scope="module")
def blob():
    g = np.arange(N)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    vol = np.exp(-((X - 7.5) ** 2 + (Y - 7.5) ** 2 + (Z - 7.5) ** 2) / (2 * 3.0 ** 2))
    cs = np.stack([X, Y, Z], -1).reshape(-1, 3).astype(float)
    sig = 0.8
    gs = gaussian_set(cs, sig, vol.ravel(), 1.0 / ((2 * np.pi) ** 1.5 * sig ** 3))
    return gs, grid_from_dense(vol, (0, 0, 0))


@pytest.fixture(scope="module")
def devices():
    return {True: CPUDevice(), False: CPUDevice(screen_tiles=False)}


TF = TransferFunction.from_colormap("viridis", 0, 1, density=0.5)


def camera():
    """Orthographic, looking along +y at the blob; the centre is 2 r in front of the camera."""
    return Camera.frame_box([-1] * 3, [N] * 3, 24, 20, direction=(0, 1, 0), kind="ortho")


def render(devices, blob, mode, tiles, hs=None, cam=None):
    gs, grid = blob
    sc = RenderScene([RenderObject(gs, grid=grid, clip=hs)], mode=mode, transmittance_min=0)
    return devices[tiles].render(sc, cam or camera(), TF)


def pixel_x(cam):
    """World x of each image column's rays (the camera's x axis is world +x)."""
    ex = cam.plane()[0]
    return cam.cam_to_world[0, 3] + ((np.arange(cam.width) + 0.5) / cam.width - 0.5) * ex


@pytest.mark.parametrize("mode,tiles", CASES)
def test_plane_along_view_cuts_columns(devices, blob, mode, tiles):
    """Plane x = 7.2 keeping +x: the rays run parallel to it, so each is kept whole or cut whole."""
    full = render(devices, blob, mode, tiles)
    hs = clip.plane_from_point_normal((7.2, 0, 0), (1, 0, 0))
    cut = render(devices, blob, mode, tiles, hs)
    x = pixel_x(camera())
    kept, gone = x > 7.2, x < 7.2
    assert full["Combined"][:, gone, 3].max() > 0.2  # there was something to cut
    assert cut["Combined"][:, gone].max() == 0.0
    assert (cut["Depth"][:, gone] == 1e10).all()
    for p in ("Combined", "Depth", "Value"):
        np.testing.assert_array_equal(cut[p][:, kept], full[p][:, kept])


@pytest.mark.parametrize("mode,tiles", [c for c in CASES if c[0] != "paper"])
def test_plane_across_view_equals_camera_clip(devices, blob, mode, tiles):
    """Plane y = 7.5 keeping +y (away from the camera) cuts the blob through its centre: the image
    is that of the camera clipped there, and its centre shows the blob's core colour."""
    cam = camera()
    start = float(CENTRE[1] - cam.cam_to_world[1, 3])
    ref = render(devices, blob, mode, tiles, cam=dataclasses.replace(cam, clip_start=start))
    hs = clip.plane_from_point_normal(CENTRE, (0, 1, 0))
    cut = render(devices, blob, mode, tiles, hs)
    full = render(devices, blob, mode, tiles)
    assert ref["Combined"][..., 3].max() > 0.2
    np.testing.assert_allclose(cut["Combined"], ref["Combined"], atol=1e-6)
    np.testing.assert_allclose(cut["Value"], ref["Value"], atol=1e-6)
    # the cut opens the blob: less in front of the core, so the core's (yellow) value shows more
    assert cut["Value"][10, 12] > full["Value"][10, 12] + 0.05


@pytest.mark.parametrize("mode,tiles", [("particles", True), ("particles", False), ("field", True),
                                        ("reference", True)])
def test_two_halves_make_the_whole(devices, blob, mode, tiles):
    """The two sides of a plane across the view: their transmittances multiply to the whole's
    (exactly in particles mode; up to the sample grid in field/reference)."""
    a = render(devices, blob, mode, tiles, clip.plane_from_point_normal(CENTRE, (0, 1, 0)))
    b = render(devices, blob, mode, tiles, clip.plane_from_point_normal(CENTRE, (0, -1, 0)))
    f = render(devices, blob, mode, tiles)
    ta, tb, tf = (1 - r["Combined"][..., 3].astype(np.float64) for r in (a, b, f))
    tol = 1e-6 if mode == "particles" else 2e-2
    np.testing.assert_allclose(ta * tb, tf, atol=tol)
    assert (ta < 0.95).any() and (tb < 0.95).any()


@pytest.mark.parametrize("mode,tiles", CASES)
def test_box(devices, blob, mode, tiles):
    """Box [4, 11] x [5, 10] x [3, 12]: rays outside its x/z range see nothing; rays inside see
    the blob between its y faces (the camera clipped to y in [5, 10], away from the x/z sides)."""
    lo, hi = np.array([4.0, 5.0, 3.0]), np.array([11.0, 10.0, 12.0])
    hs = clip.box_from_corners(lo, hi)
    cam = camera()
    cut = render(devices, blob, mode, tiles, hs)["Combined"]
    full = render(devices, blob, mode, tiles)["Combined"]
    x = pixel_x(cam)
    ez = cam.plane()[1]
    z = cam.cam_to_world[2, 3] + ((np.arange(cam.height) + 0.5) / cam.height - 0.5) * ez
    inside = (z[:, None] > lo[2]) & (z[:, None] < hi[2]) & (x[None] > lo[0]) & (x[None] < hi[0])
    assert cut[~inside].max() == 0.0
    assert cut[inside, 3].min() > 0.0
    # paper mode's closest hits change with the cut (it ignores Gaussians it enters inside others),
    # and it drops Gaussians that straddle the camera's clip start: no comparison there
    if mode != "paper":
        assert (cut[inside, 3] < full[inside, 3] - 1e-3).all()
        y0 = float(cam.cam_to_world[1, 3])
        ref = render(devices, blob, mode, tiles, cam=dataclasses.replace(
            cam, clip_start=lo[1] - y0, clip_end=hi[1] - y0))["Combined"]
        np.testing.assert_allclose(cut[inside], ref[inside], atol=1e-6)


def test_box_matrix_matches_corners():
    """An Empty's local [-1, 1]^3 cube scaled by (3.5, 2.5, 4.5) and moved to (7.5, 7.5, 7.5)
    is the box [4, 11] x [5, 10] x [3, 12]; its XY plane keeps +z."""
    m = np.diag([3.5, 2.5, 4.5, 1.0])
    m[:3, 3] = 7.5
    pts = np.random.default_rng(1).uniform(0, 15, (2000, 3))
    inside_m = (np.c_[pts, np.ones(len(pts))] @ clip.box_from_matrix(m).T >= 0).all(1)
    inside_c = (np.c_[pts, np.ones(len(pts))] @ clip.box_from_corners((4, 5, 3), (11, 10, 12)).T >= 0).all(1)
    np.testing.assert_array_equal(inside_m, inside_c)
    kept = (np.c_[pts, np.ones(len(pts))] @ clip.plane_from_matrix(m).T >= 0).ravel()
    np.testing.assert_array_equal(kept, pts[:, 2] >= 7.5)


def test_bad_clip_is_refused():
    with pytest.raises(ValueError, match="normal"):
        clip.plane_from_point_normal((0, 0, 0), (0, 0, 0))
    with pytest.raises(ValueError, match="min < max"):
        clip.box_from_corners((0, 0, 0), (1, -1, 1))
    with pytest.raises(ValueError, match="singular"):
        clip.plane_from_matrix(np.diag([1.0, 1.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="rows"):
        clip.halfspaces([[1.0, 2.0, 3.0]])
    with pytest.raises(ValueError, match="object Brain: clip must be rows"):
        CPUDevice().render(RenderScene([RenderObject(gaussian_set([[0.0, 0.0, 0.0]], 1.0), name="Brain",
                                                     clip=[[1.0, 0.0, np.nan, 0.0]])]), camera(), TF)
