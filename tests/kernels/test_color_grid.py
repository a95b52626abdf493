"""Colour by one grid, opacity by another: the second grid's values at the Gaussians against its
voxels as the bundled openvdb reads them (a fire-like fixture: density and temperature, with
different topologies, a background and tiles), and images coloured by the second grid against
those coloured by the first, in every mode."""
import numpy as np
import pytest
from vdb_fixtures import openvdb, write_fire_like

from kernels import pipeline
from kernels.lod import PRESETS, build_lod
from kernels.lod.second_grid import attach, gaussian_boxes, sample, second_bricks, second_values
from kernels.render import MODES, Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.synthetic import grid_from_dense
from kernels.vdb import read_vdb

BACKGROUND = 0.25


@pytest.fixture(scope="module")
def fire(tmp_path_factory):
    path = str(write_fire_like(tmp_path_factory.mktemp("fire") / "fire.vdb", BACKGROUND))
    density, temperature = read_vdb(path).grids
    ov = openvdb()
    tgrid = next(g for g in ov.readAll(path)[0] if g.name == "temperature")
    return path, density, temperature, tgrid.getConstAccessor()


def kept_voxels(grid):
    """{(i, j, k)} of the grid's active voxels and (origin, size) of its active tiles."""
    org = np.asarray(grid.leaf_origins, np.int64)
    bits = np.unpackbits(np.ascontiguousarray(grid.leaf_masks).view(np.uint8), axis=1,
                         bitorder="little").astype(bool)
    local = np.stack(np.unravel_index(np.arange(512), (8, 8, 8)), -1)
    vox = {tuple(o + local[i]) for o, b in zip(org, bits) for i in np.flatnonzero(b)}
    return vox


def test_fixture_has_what_the_test_needs(fire):
    _, density, temperature, acc = fire
    assert temperature.background == BACKGROUND
    assert np.asarray(density.tile_active).any() and np.asarray(temperature.tile_active).any()
    # density voxels without a temperature voxel read as the temperature's background
    assert acc.getValue((0, 0, 0)) == BACKGROUND and acc.isValueOn((0, 0, 0)) is False


@pytest.mark.parametrize("weights", ["field", "paper"])
@pytest.mark.parametrize("preset", PRESETS)
def test_values_are_the_second_grids_voxels(fire, preset, weights):
    """Each Gaussian's second value is the mean of the second grid's voxels (openvdb getValue)
    over the voxels its own value averages: its grid with itself as the second grid gives the
    Gaussian's own values bit for bit (the same voxels, the same order), and High's single-voxel
    Gaussians hold that voxel's value exactly."""
    if preset == "adaptive" and weights == "paper":
        pytest.skip("the adaptive preset fits field weights")
    _, density, temperature, acc = fire
    gs = build_lod(density, preset, weights)
    np.testing.assert_array_equal(second_values(gs, density, density), gs.values)
    cv = second_values(gs, density, temperature)
    kept = kept_voxels(density)
    lo, ext = gaussian_boxes(gs)
    n_leaf = int(gs.group_start[gs.n_leaf_groups])
    expect = np.empty(gs.count)
    for g in range(gs.count):
        box = [tuple(lo[g] + d) for d in np.ndindex(*ext[g])]
        if g < n_leaf:
            box = [v for v in box if v in kept]
        assert len(box) == (gs.voxels[g] if g < n_leaf else np.prod(ext[g]))
        expect[g] = np.mean([acc.getValue(tuple(int(c) for c in v)) for v in box])
    np.testing.assert_allclose(cv, expect, rtol=2e-7, atol=0)
    if preset == "high":
        single = gs.voxels == 1
        centres = np.rint(gs.centers()[single]).astype(int)
        assert single.sum() > 1000
        np.testing.assert_array_equal(cv[single], [acc.getValue(tuple(c)) for c in centres])


def test_bricks_and_samples_are_getvalue(fire):
    _, density, temperature, acc = fire
    cells = np.array([[0, 0, 0], [2, 1, 1], [3, 0, 1], [7, 7, 7]])
    b = second_bricks(cells, temperature)
    for c, cell in enumerate(cells):
        for d in [(0, 0, 0), (9, 9, 9), (3, 5, 1), (0, 4, 9)]:
            ijk = tuple(int(v) for v in cell * 8 - 1 + np.array(d))
            assert b[c][d] == np.float32(acc.getValue(ijk))
    pts = np.array([[0, 0, 0], [20, 3, 10], [40, 40, 40], [5, 5, 5]])
    np.testing.assert_array_equal(sample(temperature, pts), [acc.getValue(tuple(p)) for p in pts])


def test_pipeline_carries_the_colour_grid(fire):
    path, density, temperature, _ = fire
    cg = pipeline.convert_file(path, ["density"], ["low", "high"], color_grid="temperature",
                               compute_error=False)[0]
    assert cg.color_grid == "temperature" and cg.color_stats["max"] == pytest.approx(3.0)
    for cl in cg.lods:
        np.testing.assert_array_equal(cl.gset.color_values,
                                      second_values(cl.gset, density, temperature))
    with pytest.raises(pipeline.ConversionError) as err:
        pipeline.convert_file(path, ["density"], ["low"], color_grid="heat")
    msg = str(err.value)
    assert "\n" not in msg and "'heat'" in msg and "fire.vdb" in msg and "temperature" in msg


# -- images -------------------------------------------------------------------------------------
def scene_pair(fire, mode, lit=False):
    _, density, temperature, _ = fire
    gs = attach(build_lod(density, "medium"), density, temperature)
    m = np.diag([0.1, 0.1, 0.1, 1.0])
    ctf = TransferFunction.from_colormap("inferno", BACKGROUND, 3.0, alpha="constant")
    shading = "lit" if lit else "emission"
    kw = dict(mode=mode, transmittance_min=0.0)
    own = RenderScene([RenderObject(gs, m, grid=density, shading=shading)], **kw)
    other = RenderScene([RenderObject(gs, m, grid=density, shading=shading, color_tf=ctf,
                                      color_grid=temperature)], **kw)
    return own, other


@pytest.fixture(scope="module")
def dev():
    """The device under test (tests/blender/test_gpu_twins.py runs the image tests on the GPU's)."""
    return CPUDevice()


CAM = Camera.frame_box(np.array([-0.1, -0.1, -0.1]), np.array([3.3, 2.5, 2.5]), 40, 30,
                       direction=(1.0, 0.8, -0.6))
TF = TransferFunction.from_colormap("viridis", 0.0, 1.0, density=3.0)


@pytest.mark.parametrize("lit", [False, True], ids=["emission", "lit"])
@pytest.mark.parametrize("mode", MODES)
def test_second_grid_changes_colour_not_alpha(dev, fire, mode, lit):
    if lit and mode == "paper":
        pytest.skip("paper mode draws emission")
    own, other = scene_pair(fire, mode, lit)
    a = dev.render(own, CAM, TF)
    b = dev.render(other, CAM, TF)
    alpha = a["Combined"][..., 3]
    assert (alpha > 0.05).sum() > 100
    # particles: the colour spread decides where intervals close; the optical depth is exact
    np.testing.assert_allclose(b["Combined"][..., 3], alpha, atol=1e-5 if mode == "particles" else 0)
    np.testing.assert_array_equal(b["Value"], a["Value"]) if mode != "particles" else None
    diff = np.abs(b["Combined"][..., :3] - a["Combined"][..., :3]).max(-1)
    assert (diff[alpha > 0.05] > 0.02).mean() > 0.5


@pytest.mark.parametrize("mode", MODES)
def test_constant_colour_grid_gives_one_hue(dev, fire, mode):
    """A colour grid of one value everywhere (its background: no voxels at all): every pixel has
    the colour map's colour at that value, whatever the opacity (premultiplied rgb / alpha);
    in field mode too, whose colour mixture is the grid's background away from the Gaussians."""
    _, density, _, _ = fire
    const = grid_from_dense(np.zeros((1, 1, 1)), active=np.zeros((1, 1, 1), bool), background=0.7)
    gs = attach(build_lod(density, "medium"), density, const)
    assert np.all(gs.color_values == np.float32(0.7))
    ctf = TransferFunction.from_colormap("inferno", 0.0, 1.0, alpha="constant")
    m = np.diag([0.1, 0.1, 0.1, 1.0])
    sc = RenderScene([RenderObject(gs, m, grid=density, color_tf=ctf, color_grid=const)], mode=mode)
    img = dev.render(sc, CAM, TF)["Combined"]
    a = img[..., 3]
    sel = a > 0.05
    assert sel.sum() > 100
    want = ctf(0.7)[:3]
    got = img[sel][:, :3] / a[sel][:, None]
    if mode == "paper":  # its closest-hit blending scales the brightness: compare the hue
        want, got = want / want.sum(), got / got.sum(1)[:, None]
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), rtol=1e-4, atol=1e-5)


def test_reference_needs_the_colour_grid(fire):
    _, density, temperature, _ = fire
    gs = attach(build_lod(density, "low"), density, temperature)
    ctf = TransferFunction.from_colormap("inferno", 0.0, 3.0)
    sc = RenderScene([RenderObject(gs, grid=density, color_tf=ctf, name="fire")], mode="reference")
    with pytest.raises(ValueError, match="fire.*second grid"):
        CPUDevice().render(sc, CAM, TF)
    with pytest.raises(ValueError, match="color_values"):
        RenderObject(build_lod(density, "low"), color_tf=ctf)
