"""Cameras, transfer functions, colormaps (no numba kernels)."""
import math

import numpy as np
import pytest

from kernels.colormap_names import MATPLOTLIB, NAMES
from kernels.render import Camera, TransferFunction, colormap, colormap_names, generate_rays, srgb_to_linear
from kernels.render.scene.colormaps import linear_to_srgb, ramp_error, stops_from_table
from kernels.render.scene.transfer import value_range


def test_colormap_names_and_shapes():
    assert colormap_names() == list(NAMES)  # a table for every name, none without one
    for n in NAMES:
        t = colormap(n)
        assert t.shape == (256, 3) and t.dtype == np.float32
        assert t.min() >= 0 and t.max() <= 1
    with pytest.raises(KeyError):
        colormap("nope")


def test_colormaps_match_matplotlib():
    mpl = pytest.importorskip("matplotlib")
    for n in NAMES:
        ref = mpl.colormaps[MATPLOTLIB[n]].resampled(256)(np.arange(256))[:, :3]
        np.testing.assert_allclose(colormap(n), ref, atol=1e-6, err_msg=n)


def test_srgb_roundtrip_and_known_values():
    x = np.linspace(0, 1, 101)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-12)
    assert abs(srgb_to_linear(0.5) - 0.21404114) < 1e-7
    assert linear_to_srgb(-0.25) == 0.0  # negative light encodes as black
    # a table entry written linear and shown through the Standard view lands within 1/255
    t = colormap("viridis")
    back = np.round(linear_to_srgb(srgb_to_linear(t)) * 255)
    assert np.max(np.abs(back - np.round(t * 255))) <= 1


def test_tf_lookup_linear_log_nan():
    tf = TransferFunction.from_colormap("grayscale", 0.0, 2.0, alpha="ramp")
    out = tf(np.array([-1.0, 0.0, 1.0, 2.0, 5.0, np.nan]))
    np.testing.assert_allclose(out[:, 3], [0, 0, 0.5, 1, 1, 0], atol=1e-6)
    assert np.all(out[5] == 0)
    lg = TransferFunction.from_colormap("grayscale", 1.0, 100.0, log_scale=True)
    np.testing.assert_allclose(lg(np.array([10.0, 0.0, -3.0]))[:, 3], [0.5, 0, 0], atol=1e-6)
    with pytest.raises(ValueError):
        TransferFunction.from_colormap("viridis", 0.0, 1.0, log_scale=True)


def test_tf_from_ramp_and_stops():
    tf = TransferFunction.from_ramp([0.0, 1.0], [[1, 0, 0, 0], [0, 0, 1, 1]], 0, 10)
    np.testing.assert_allclose(tf(5.0), [0.5, 0, 0.5, 0.5], atol=1e-2)
    c = TransferFunction.from_ramp([0.0, 0.5], [[1, 0, 0, 1], [0, 1, 0, 1]], 0, 1, interpolation="CONSTANT")
    assert c(0.25)[0] == 1.0 and c(0.75)[1] == 1.0
    pos, rgba = stops_from_table(colormap("viridis"))
    assert pos.shape == (32,) and rgba.shape == (32, 4) and pos[0] == 0 and pos[-1] == 1
    np.testing.assert_allclose(rgba[:, 3], pos)  # alpha ramps 0 -> 1
    assert ramp_error("viridis") < 1 / 255  # the 32 fitted stops stay within one 8-bit step


def test_value_range():
    assert value_range([3.0, np.nan, 1.0]) == (1.0, 3.0)
    # a flat range widens downwards: the one value maps to the top of the ramp, never its end
    assert value_range([-1.0, 0.0, 4.0], log_scale=True) == (0.4, 4.0)
    assert value_range([0.5, 0.5]) == (0.0, 0.5)  # the empty background stays transparent
    assert value_range([-3.0]) == (-6.0, -3.0)
    assert value_range([0.0]) == (-1.0, 0.0)
    assert value_range([]) == (0.0, 1.0)


def test_camera_persp_rays_fov_rows_bottom_up():
    cam = Camera(np.eye(4), 40, 20, "persp", fov_x=math.radians(90))
    o, d = generate_rays(cam)
    assert o.shape == (800, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1, atol=1e-12)
    assert np.all(d[:, 2] < 0)
    # horizontal fov: the left/right pixel edges at +-45 deg (centres slightly inside)
    right = d[39]
    ang = math.degrees(math.atan2(right[0], -right[2]))
    assert 43.0 < ang < 45.0
    assert d[0, 1] < 0 and d[-1, 1] > 0  # row 0 is the bottom row
    tall = Camera(np.eye(4), 20, 40, "persp", fov_x=math.radians(90))
    _, d2 = generate_rays(tall)
    top = d2[-1]
    assert 43.0 < math.degrees(math.atan2(top[1], -top[2])) < 45.0  # AUTO fit: larger dimension


def test_camera_ortho_and_shift_and_rows():
    m = np.eye(4)
    m[:3, 3] = [1, 2, 3]
    cam = Camera(m, 4, 2, "ortho", ortho_scale=8.0, shift_x=0.25)
    o, d = generate_rays(cam)
    np.testing.assert_allclose(d, np.tile([0, 0, -1.0], (8, 1)))
    np.testing.assert_allclose(o[:4, 0], 1 + np.array([-3, -1, 1, 3]) + 2.0)  # shift 0.25 * 8
    np.testing.assert_allclose(o[[0, 4], 1], [2 - 1, 2 + 1])
    o2, _ = generate_rays(cam, rows=(1, 2))
    np.testing.assert_allclose(o2, o[4:])


@pytest.mark.parametrize("kind", ["persp", "ortho"])
def test_frame_box_sees_whole_box(kind):
    lo, hi = np.array([10.0, -3, 5]), np.array([14.0, 9, 6])
    cam = Camera.frame_box(lo, hi, 64, 48, direction=(1, 1, -0.5), kind=kind)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    r, p = cam.basis()
    ex, ey, _, _ = cam.plane()
    for c in corners:
        v = r.T @ (c - p)
        assert v[2] < 0
        if kind == "persp":
            x, y = v[0] / -v[2], v[1] / -v[2]
        else:
            x, y = v[0], v[1]
        assert abs(x) < ex / 2 and abs(y) < ey / 2
    centre = r.T @ ((lo + hi) / 2 - p)
    assert abs(centre[0]) < 1e-9 and abs(centre[1]) < 1e-9
