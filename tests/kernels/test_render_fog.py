"""Reference mode's one-fog-volume loop (cpu.fog) against the general piece sampler it stands in
for, and its inline absorption against expm1."""
import numpy as np
import pytest

from kernels.render import Camera, RenderObject, RenderScene, TransferFunction, get_device
from kernels.render.cpu.fog import FOG_CHUNK, absorbed
from kernels.render.scene.synthetic import grid_from_dense


def test_absorbed_matches_expm1_to_double_precision():
    tau = np.concatenate([np.geomspace(1e-300, 1e3, 4001), [0.0625, np.nextafter(0.0625, 0)]])
    got = np.array([absorbed(t) for t in tau])
    want = -np.expm1(-tau)
    assert np.max(np.abs(got - want) / want) < 4e-16


def blob(shape=(24, 20, 16), seed=3):
    rng = np.random.default_rng(seed)
    x, y, z = np.meshgrid(*(np.linspace(-1, 1, n) for n in shape), indexing="ij")
    d = np.exp(-3 * (x * x + y * y + z * z)) * (0.6 + 0.4 * rng.random(shape))
    d[d < 0.15] = 0.0  # voids inside the leaves, and background around them
    return grid_from_dense(d, (0, 0, 0))


@pytest.mark.parametrize("step", [0.37, 0.09])
def test_one_fog_volume_equals_the_general_sampler(step):
    """A second object far outside the view sends the same rays through the general sampler
    (merged pieces, per-sample calls): same samples, same image to rounding, Depth and Value
    passes included, for a step that leaves partial steps per leaf and early termination on;
    at 0.09 a leaf crossing of 3 voxels is more than FOG_CHUNK samples (several chunks)."""
    assert 3.0 / 0.09 > FOG_CHUNK
    dev = get_device("CPU")
    grid = blob()
    tf = TransferFunction.from_colormap("inferno", 0.0, 1.0, alpha="ramp", density=0.9)
    cam = Camera.frame_box([-1, -1, -1], [24, 20, 16], 48, 40, direction=(0.3, 1.0, 0.2))
    far = np.eye(4)
    far[:3, 3] = [1e5, 0, 0]
    kw = dict(mode="reference", step=step, passes=("Depth", "Value"), transmittance_min=0.05)
    one = dev.render(RenderScene([RenderObject(grid=grid)], **kw), cam, tf)
    segs = dev.stats["segments"]
    two = dev.render(RenderScene([RenderObject(grid=grid), RenderObject(grid=grid, matrix_world=far)],
                                 **kw), cam, tf)
    assert dev.stats["segments"] == segs > 0
    a = one["Combined"][..., 3]
    assert (a > 0.5).sum() > 100 and (a == 0).sum() > 100  # covers opaque and empty pixels
    np.testing.assert_allclose(one["Combined"], two["Combined"], rtol=0, atol=2e-7)
    hit = one["Depth"] < 1e9
    assert hit.sum() > 100 and (hit == (two["Depth"] < 1e9)).all()
    np.testing.assert_allclose(one["Depth"][hit], two["Depth"][hit], rtol=1e-6)
    np.testing.assert_allclose(one["Value"], two["Value"], rtol=1e-6, atol=1e-7)


def test_transparent_sub_blocks_skip_no_sample_that_draws(monkeypatch):
    """The sampler's skip of sub-blocks whose samples are all transparent (packing.clear_bits)
    gives the same images bit for bit, and the same sample count, as sampling them all: table
    ranges from the voids' value and from above it (most of the blob then clear), oblique and
    axis-aligned views (rays along cell faces)."""
    from kernels.render.inputs import packing

    dev = get_device("CPU")
    grid = blob()
    no_bits = lambda sub_max, *a: np.zeros(sub_max.shape[0], np.int64)  # noqa: E731
    for lo, direction in ((0.0, (0.3, 1.0, 0.2)), (0.4, (0.3, 1.0, 0.2)), (0.4, (0.0, 1.0, 0.0))):
        tf = TransferFunction.from_colormap("inferno", lo, 1.0, alpha="ramp", density=0.9)
        cam = Camera.frame_box([-1, -1, -1], [24, 20, 16], 48, 40, direction=direction)
        kw = dict(mode="reference", step=0.37, passes=("Depth", "Value"), transmittance_min=0.05)
        with monkeypatch.context() as m:
            m.setattr(packing, "clear_bits", no_bits)
            dev.end_frame()  # the frame's state is cached by camera and table: build it anew
            want = dev.render(RenderScene([RenderObject(grid=grid)], **kw), cam, tf)
            segs = dev.stats["segments"]
        dev.end_frame()
        got = dev.render(RenderScene([RenderObject(grid=grid)], **kw), cam, tf)
        assert (dev._frame.accel.clear != 0).any()
        assert dev.stats["segments"] == segs > 0
        for name in want:
            np.testing.assert_array_equal(got[name], want[name])
