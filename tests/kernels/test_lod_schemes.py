"""Hand-checked LOD schemes on synthetic grids (one dense leaf, a one-voxel sheet, a checkerboard
sparse leaf, tiles, a level-set sheet, the merge pass)."""
import numpy as np
import pytest

from kernels.lod import PRESETS, build_lod
from kernels.lod.synthetic import grid_from_dense, make_grid

TP = (2 * np.pi) ** 1.5


def ramp_leaf():
    x, y, z = np.meshgrid(np.arange(8), np.arange(8), np.arange(8), indexing="ij")
    return (0.1 + 0.01 * x + 0.001 * y + 0.0001 * z).astype(np.float32)


def sheet_leaf():
    m = np.zeros((8, 8, 8), bool)
    m[:, :, 3] = True
    return np.where(m, 0.25, 0).astype(np.float32), m


def test_presets_listing():
    assert PRESETS[:3] == ("low", "medium", "high")
    assert set(PRESETS) == {"low", "medium", "high", "variance", "merged", "adaptive"}


def test_dense_leaf_low():
    v = ramp_leaf()
    g = grid_from_dense(v, origin=(16, -8, 0))
    for w, s in (("paper", 3.5), ("field", 4.8)):
        gs = build_lod(g, "low", w)
        assert gs.count == 1 and gs.n_spheres == 1
        assert gs.group_origins.tolist() == [[16, -8, 0]]
        np.testing.assert_array_equal(gs.offsets[0], [3.5, 3.5, 3.5])
        np.testing.assert_allclose(gs.sigmas[0], [s] * 3, rtol=1e-6)
        np.testing.assert_allclose(gs.values[0], v.mean(), rtol=1e-6)
        assert gs.voxels[0] == 512
        amp = 1.0 if w == "paper" else 512 / (TP * 4.8 ** 3)
        np.testing.assert_allclose(gs.amplitudes[0], amp, rtol=1e-6)


@pytest.mark.parametrize("preset,edge,n", [("medium", 4, 8), ("high", 2, 64)])
def test_dense_leaf_blocks(preset, edge, n):
    v = ramp_leaf()
    g = grid_from_dense(v)
    for w, s in (("paper", edge / 2), ("field", 0.6 * edge)):
        gs = build_lod(g, preset, w)
        assert gs.count == n and gs.n_spheres == n
        np.testing.assert_allclose(gs.sigmas, s, rtol=1e-6)
        assert np.all(gs.voxels == edge ** 3)
        # block order x, y, z; centres on the block lattice; values are block means
        k = 0
        for x0 in range(0, 8, edge):
            for y0 in range(0, 8, edge):
                for z0 in range(0, 8, edge):
                    c = np.array([x0, y0, z0]) + (edge - 1) / 2
                    np.testing.assert_array_equal(gs.offsets[k], c)
                    blk = v[x0:x0 + edge, y0:y0 + edge, z0:z0 + edge]
                    np.testing.assert_allclose(gs.values[k], blk.mean(), rtol=1e-6)
                    k += 1


def test_sheet_low_clamps_sigma():
    v, m = sheet_leaf()
    g = grid_from_dense(v, m)
    gs = build_lod(g, "low", "paper")
    assert gs.count == 1 and gs.n_ellipsoids == 1
    np.testing.assert_array_equal(gs.offsets[0], [3.5, 3.5, 3.0])
    # paper formula: (max - min)/2 over voxel centres = (3.5, 3.5, 0) -> z clamped to 1/2 voxel
    np.testing.assert_array_equal(gs.sigmas[0], [3.5, 3.5, 0.5])
    assert gs.voxels[0] == 64 and gs.values[0] == pytest.approx(0.25)
    gf = build_lod(g, "low", "field")
    np.testing.assert_allclose(gf.sigmas[0], [4.8, 4.8, 0.6], rtol=1e-6)
    np.testing.assert_allclose(gf.amplitudes[0], 64 / (TP * 4.8 * 4.8 * 0.6), rtol=1e-6)


@pytest.mark.parametrize("preset", ["medium", "high"])
def test_sheet_singles(preset):
    v, m = sheet_leaf()
    gs = build_lod(grid_from_dense(v, m), preset, "paper")
    assert gs.count == 64 and np.all(gs.voxels == 1)
    np.testing.assert_array_equal(gs.sigmas, 0.5)  # half-voxel radii
    assert np.all(gs.offsets[:, 2] == 3.0)
    assert sorted(map(tuple, gs.offsets[:, :2].tolist())) == [(float(x), float(y)) for x in range(8) for y in range(8)]


def test_sheet_variance():
    # spatial variance 5.25 + 5.25 > 4: split x at 4, then y at 4 -> four 4x4x1 clusters (2.5 <= 4)
    v, m = sheet_leaf()
    gs = build_lod(grid_from_dense(v, m), "variance", "paper")
    assert gs.count == 4 and np.all(gs.voxels == 16)
    np.testing.assert_array_equal(gs.offsets, [[1.5, 1.5, 3], [1.5, 5.5, 3], [5.5, 1.5, 3], [5.5, 5.5, 3]])
    np.testing.assert_array_equal(gs.sigmas, [[1.5, 1.5, 0.5]] * 4)
    gf = build_lod(grid_from_dense(v, m), "variance", "field")
    np.testing.assert_allclose(gf.sigmas, [[2.4, 2.4, 0.6]] * 4, rtol=1e-6)


def test_variance_splits_on_value():
    v = np.full((8, 8, 8), 0.2, np.float32)
    v[4:] = 0.9  # two homogeneous halves along x
    gs = build_lod(grid_from_dense(v), "variance", "field", var_spatial=100.0)
    assert gs.count == 2
    np.testing.assert_allclose(np.sort(gs.values), [0.2, 0.9], rtol=1e-6)
    gs1 = build_lod(grid_from_dense(v), "variance", "field", var_spatial=100.0, var_value=1.0)
    assert gs1.count == 1


def test_checkerboard():
    x, y, z = np.meshgrid(np.arange(8), np.arange(8), np.arange(8), indexing="ij")
    m = (x + y + z) % 2 == 0
    v = np.where(m, 0.5 + 0.01 * x, 0).astype(np.float32)
    g = grid_from_dense(v, m)
    lo = build_lod(g, "low", "paper")
    assert lo.count == 1 and lo.voxels[0] == 256
    np.testing.assert_array_equal(lo.sigmas[0], [3.5] * 3)  # bbox is the whole leaf
    np.testing.assert_allclose(lo.values[0], v[m].mean(), rtol=1e-6)
    for p in ("medium", "high"):  # no complete 2^3 cell: one Gaussian per active voxel
        gs = build_lod(g, p, "field")
        assert gs.count == 256 and np.all(gs.voxels == 1)
        np.testing.assert_allclose(gs.sigmas, 0.6, rtol=1e-6)


def test_sparse_medium_blocks_and_leftovers():
    m = np.zeros((8, 8, 8), bool)
    m[2:4, 4:6, 0:2] = True  # one aligned full 2^3 cell
    m[5, 5, 5] = m[0, 0, 7] = True  # leftovers
    m[1:3, 0:2, 0:2] = True  # unaligned 2^3: becomes 8 singles (aligned tiling)
    v = np.where(m, 1.0, 0).astype(np.float32)
    gs = build_lod(grid_from_dense(v, m), "medium", "paper")
    blocks = gs.voxels == 8
    assert blocks.sum() == 1 and (gs.voxels == 1).sum() == int(m.sum()) - 8
    np.testing.assert_array_equal(gs.offsets[blocks][0], [2.5, 4.5, 0.5])
    np.testing.assert_array_equal(gs.sigmas[blocks][0], [1, 1, 1])


def test_tiles_one_gaussian_each():
    v = np.zeros((8, 8, 8), np.float32)
    v[0, 0, 0] = 2.0
    g = grid_from_dense(v, tiles=[((128, 0, 0), 128, 0.5, True), ((-8, 0, 0), 8, 0.75, True),
                                  ((0, 8, 0), 8, 9.0, False)])
    for p in PRESETS:
        gs = build_lod(g, p, "field")
        assert gs.count == 3 and len(gs.group_origins) == 3 and gs.n_leaf_groups == 1
        t = slice(1, 3)  # tiles after the leaves, sorted by origin
        np.testing.assert_array_equal(gs.group_origins[t], [[-8, 0, 0], [128, 0, 0]])
        np.testing.assert_array_equal(gs.offsets[t], [[3.5] * 3, [63.5] * 3])
        np.testing.assert_allclose(gs.sigmas[t], [[4.8] * 3, [76.8] * 3], rtol=1e-6)
        np.testing.assert_array_equal(gs.values[t], [0.75, 0.5])
        np.testing.assert_array_equal(gs.voxels[t], [512, 128 ** 3])
    gp = build_lod(g, "high", "paper")
    np.testing.assert_array_equal(gp.sigmas[1:], [[3.5] * 3, [63.5] * 3])


def test_level_set_band_and_uniform_values():
    dx = 0.1
    z = np.arange(8)[None, None, :] * np.ones((8, 8, 1))
    phi = ((z - 3.2) * dx).astype(np.float32)  # |phi| <= 0.0866 only for z = 3, 4
    g = grid_from_dense(phi, np.ones((8, 8, 8), bool), grid_class="level_set",
                        index_to_world=np.diag([dx, dx, dx, 1.0]))
    gs = build_lod(g, "high", "field")
    assert gs.count == 128 and np.all(gs.values == 1.0) and not gs.has_values
    assert set(gs.offsets[:, 2].tolist()) == {3.0, 4.0}
    full = build_lod(g, "high", "field", level_set_band=False)
    assert full.count == 64  # dense leaf: 2^3 blocks over the whole band
    lo = build_lod(g, "low", "paper")
    np.testing.assert_array_equal(lo.offsets[0], [3.5, 3.5, 3.5])
    np.testing.assert_array_equal(lo.sigmas[0], [3.5, 3.5, 0.5])


def test_merge_across_leaf_borders():
    v = np.full((24, 24, 24), 0.5, np.float32)
    g = grid_from_dense(v)
    assert len(g.leaf_origins) == 27
    # high: 2^3 blocks -> 6^3 super-cells, 4 per axis (the paper's merge: merge_check off)
    gs = build_lod(g, "merged", "field", merge_check=False)
    assert gs.count == 64 and np.all(gs.voxels == 216)
    # the check keeps none: the wide Gaussians blur the block's faces, every super-cell meets one
    assert build_lod(g, "merged", "field").params["merges_undone"] == 64
    np.testing.assert_allclose(gs.sigmas, 3.6, rtol=1e-6)
    c = np.sort(np.unique(gs.centers()[:, 0]))
    np.testing.assert_array_equal(c, [2.5, 8.5, 14.5, 20.5])  # [6..11] straddles x = 8
    lo = build_lod(g, "low", "field", merge=True, merge_check=False)  # 27 leaves -> one 24^3
    assert lo.count == 1 and lo.voxels[0] == 27 * 512
    np.testing.assert_array_equal(lo.centers()[0], [11.5] * 3)
    # inhomogeneous: nothing merges
    v2 = np.random.default_rng(1).uniform(0.1, 1.0, v.shape).astype(np.float32)
    assert build_lod(grid_from_dense(v2), "merged", "field").count == 27 * 64


def test_empty_and_bad_arguments():
    g = make_grid(np.zeros((0, 3)), np.zeros((0, 512), bool), np.zeros((0, 512)))
    for p in PRESETS:
        gs = build_lod(g, p)
        assert gs.count == 0 and gs.group_start.tolist() == [0]
    with pytest.raises(ValueError):
        build_lod(g, "ultra")
    with pytest.raises(ValueError):
        build_lod(g, "low", "peak")
    with pytest.raises(TypeError):
        build_lod(g, "low", bogus=1)
