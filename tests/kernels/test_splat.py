"""Splat mode: the Gaussian field on a lattice (kernels.lod.splat), drawn as voxels
(kernels.render.scene.splat)."""
import types

import numpy as np
import pytest

from kernels.lod import build_lod
from kernels.lod.splat import _axis_tables, _box_keys, auto_spacing, lattice_to_index, splat_grid
from kernels.lod.synthetic import grid_from_dense
from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction

K = 3.0


def blob(n=40, seed=0):
    """A smooth blob with some noise: dense leaves (Low: sigma 4.8) and a ragged rim."""
    x = np.indices((n, n, n)).astype(np.float64) - (n - 1) / 2.0
    r2 = (x ** 2).sum(0) / (n / 3.0) ** 2
    v = np.exp(-r2) * (1.0 + 0.1 * np.random.default_rng(seed).standard_normal((n, n, n)))
    v[r2 > 2.0] = 0.0
    return grid_from_dense(v.astype(np.float32), origin=(-3, 5, 2))


@pytest.fixture(scope="module")
def grid():
    return blob()


@pytest.fixture(scope="module")
def dev():
    return CPUDevice()


def mixture_at(gs, pts):
    """sum_i v_i a_i g_i(p), truncated at K sigma: the field mode's mixture, by brute force."""
    c, s = gs.centers(), gs.sigmas.astype(np.float64)
    w = np.nan_to_num(gs.values.astype(np.float64)) * gs.amplitudes.astype(np.float64)
    out = np.zeros(len(pts))
    for i in range(gs.count):
        q = (((pts - c[i]) / s[i]) ** 2).sum(1)
        out += np.where(q <= K * K, w[i] * np.exp(-0.5 * q), 0.0)
    return out


@pytest.mark.parametrize("lod, spacing", [("low", 1), ("low", 2), ("low", 4), ("high", 1)])
def test_lattice_holds_the_mixture(grid, lod, spacing):
    # High at spacing 1: centres on the half-voxel lattice, few sigmas (the axis tables' path)
    gs = build_lod(grid if lod == "low" else blob(16), lod)
    if lod == "high":
        assert _axis_tables(gs.centers(), gs.sigmas.astype(np.float64), K)[-1] >= 0
    sg = splat_grid(gs, spacing, K)
    # active voxels: lattice index -> the set's index space -> the mixture there
    lo = np.asarray(sg.leaf_origins, np.int64)
    bits = np.unpackbits(sg.leaf_masks.view(np.uint8), axis=1, bitorder="little").astype(bool)
    leaf, vox = np.nonzero(bits)
    assert len(leaf) == sg.active_voxels > 0
    ijk = lo[leaf] + np.stack([vox // 64, (vox // 8) % 8, vox % 8], 1)
    pts = (np.c_[ijk, np.ones(len(ijk))] @ lattice_to_index(spacing).T)[:, :3]
    want = mixture_at(gs, pts)
    np.testing.assert_allclose(sg.leaf_values[leaf, vox], want, rtol=1e-5, atol=1e-6 * want.max())
    assert np.all(want != 0)
    # world placement: the grid's lattice maps where the set's index space does
    np.testing.assert_allclose(sg.index_to_world, np.asarray(gs.index_to_world) @ lattice_to_index(spacing))


def test_spacing_follows_the_lod(grid):
    low, high = build_lod(grid, "low"), build_lod(grid, "high")
    assert auto_spacing(low) >= 2 and auto_spacing(high) == 1
    assert splat_grid(low).active_voxels < splat_grid(high).active_voxels / 1.5  # the cost follows the LOD
    with pytest.raises(ValueError, match="spacing"):
        splat_grid(low, 3)


def test_spacing_is_the_voxel_weighted_quantile():
    """auto_spacing counts weights below each spacing (no sort): the same as the sorted 10%
    quantile of the smallest sigmas, weighted by voxels, over 1.2."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        n = int(rng.integers(1, 400))
        gs = types.SimpleNamespace(sigmas=rng.uniform(0.3, 12.0, (n, 3)).astype(np.float32),
                                   voxels=rng.integers(0, 512, n).astype(np.int32))
        sig = gs.sigmas.astype(np.float64).min(1)
        w = np.maximum(gs.voxels, 1).astype(np.float64)
        o = np.argsort(sig, kind="stable")
        cum = np.cumsum(w[o])
        q = sig[o][np.searchsorted(cum, 0.1 * cum[-1])] / 1.2
        assert auto_spacing(gs) == max(sp for sp in (1, 2, 4, 8) if sp <= max(q, 1.0))


def test_cells_marked_densely_are_the_listed_ones():
    rng = np.random.default_rng(4)
    lo = rng.integers(-40, 40, (300, 3))
    hi = lo + rng.integers(0, 4, (300, 3))
    dense, listed = _box_keys(lo, hi), _box_keys(lo, hi, dense=0)
    assert len(dense) > 300 and np.array_equal(dense, listed)


def test_thread_count_does_not_change_the_lattice(grid):
    import numba

    gs = build_lod(grid, "medium")
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = splat_grid(gs, 2)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        b = splat_grid(gs, 2)
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(a.leaf_values, b.leaf_values) and np.array_equal(a.leaf_masks, b.leaf_masks)


@pytest.mark.parametrize("lod, spacing", [("low", 2), ("high", 1)])
def test_chunks_do_not_change_the_lattice(grid, lod, spacing):
    """Cells are summed a chunk at a time (bounded memory): any chunk gives the same bits."""
    gs = build_lod(grid, lod)
    a, b = splat_grid(gs, spacing, K), splat_grid(gs, spacing, K, chunk=3)
    assert len(a.leaf_origins) > 3
    for f in ("leaf_origins", "leaf_masks", "leaf_values"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def view(grid, size=48):
    lo = np.asarray(grid.bbox_min, float) - 6
    hi = np.asarray(grid.bbox_max, float) + 6
    cam = Camera.frame_box(lo, hi, size, size, direction=(0.35, 1.0, -0.3))
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.0, density=0.15)
    return cam, tf


@pytest.mark.parametrize("lod", ["low", "high"])
def test_splat_draws_the_field_modes_image(dev, grid, lod):
    """Same model as field mode, sampled on the lattice: close to field mode's image, and the lattice
    makes it cheaper in samples than field mode's Gaussian terms."""
    gs = build_lod(grid, lod)
    cam, tf = view(grid)
    obj = [RenderObject(gs, grid=grid)]
    field = dev.render(RenderScene(obj, mode="field", step=0.25), cam, tf)["Combined"]
    terms = dev.stats["segments"]
    splat = dev.render(RenderScene(obj, mode="splat", step=0.25), cam, tf)["Combined"]
    samples = dev.stats["segments"]
    assert field[..., 3].max() > 0.5
    err = np.abs(splat - field).max()
    assert err < (0.03 if lod == "low" else 0.06), err
    assert samples < terms / 4


def test_splat_keeps_its_lattice_and_draws_level_sets_from_voxels(dev):
    n = 24
    x = np.indices((n, n, n)).astype(np.float32) - (n - 1) / 2.0
    sdf = np.sqrt((x ** 2).sum(0)) - 7.0
    ls = grid_from_dense(np.clip(sdf, -3, 3), mask=np.abs(sdf) < 3, grid_class="level_set", background=3.0)
    fog = blob(24)
    gl, gf = build_lod(ls, "high"), build_lod(fog, "low")
    cam, tf = view(fog)
    m = np.eye(4)
    m[:3, 3] = [30.0, 0.0, 0.0]
    objs = [RenderObject(gf, grid=fog), RenderObject(gl, m, grid=ls, is_level_set=True)]
    a = dev.render(RenderScene(objs, mode="splat"), cam, tf)["Combined"]
    assert dev.stats["seconds_sync"] > 0
    grid_obj = dev._splats.drawn(RenderScene(objs, mode="splat")).objects[0].grid
    # a new transfer function: no new lattice
    b = dev.render(RenderScene(objs, mode="splat"), cam, TransferFunction.from_colormap("magma", 0, 1, density=0.15))
    assert dev._splats.drawn(RenderScene(objs, mode="splat")).objects[0].grid is grid_obj
    assert not np.array_equal(a, b["Combined"])
    # the level set alone: exactly the reference mode's image
    one = [objs[1]]
    np.testing.assert_array_equal(dev.render(RenderScene(one, mode="splat"), cam, tf)["Combined"],
                                  dev.render(RenderScene(one, mode="reference"), cam, tf)["Combined"])
    with pytest.raises(ValueError, match="shell.*voxels"):
        dev.render(RenderScene([RenderObject(gl, name="shell", is_level_set=True)], mode="splat"), cam, tf)
