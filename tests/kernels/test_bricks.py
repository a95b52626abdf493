"""The reference mode's voxel bricks (kernels/render/inputs/bricks.py) against a voxel-by-voxel lookup:
leaves with missing neighbours (background in the apron), NaN voxels (ignored by the value
range), negative origins, and a leaf with no neighbour at all."""
import numpy as np
from conftest import SAMPLE

from kernels.render.inputs.accel import _grid_leaves
from kernels.render.inputs.bricks import leaf_bricks
from kernels.render.scene.synthetic import grid_from_dense
from kernels.vdb import read_vdb

BG = -0.5


def sparse_grid():
    rng = np.random.default_rng(7)
    d = rng.random((29, 21, 17)).astype(np.float32) + 0.1
    d[rng.random(d.shape) < 0.3] = BG  # whole leaves of background are dropped
    d[:8, :8, 8:16] = BG
    d[20:, 13:, :] = BG
    d[3, 4, 5] = np.nan
    d[10:16, 1, 2] = np.nan
    g = grid_from_dense(d, (-13, 5, -9), background=BG)
    org = np.concatenate([np.asarray(g.leaf_origins, np.int64).reshape(-1, 3), [[400, 400, 400]]])
    val = np.concatenate([np.asarray(g.leaf_values, np.float32).reshape(-1, 8, 8, 8),
                          np.full((1, 8, 8, 8), 2.0, np.float32)])  # a lone leaf far away
    return org, val


def voxel_lookup(org, val, bg):
    leaves = {tuple(o): v for o, v in zip(org, val)}
    out = np.empty((len(org), 10, 10, 10), np.float32)
    for c, o in enumerate(org):
        for i, j, k in np.ndindex(10, 10, 10):
            p = o - 1 + (i, j, k)
            leaf = leaves.get(tuple(p // 8 * 8))
            out[c, i, j, k] = bg if leaf is None else leaf[tuple(p % 8)]
    return out


def test_bricks_equal_the_voxel_lookup():
    org, val = sparse_grid()
    assert len(org) > 10
    b, lo, hi = leaf_bricks(org, val, BG)
    want = voxel_lookup(org, val, np.float32(BG))
    np.testing.assert_array_equal(b, want)
    flat = want.reshape(len(org), -1)
    np.testing.assert_array_equal(lo, np.nanmin(flat, axis=1))
    np.testing.assert_array_equal(hi, np.nanmax(flat, axis=1))
    assert (b[-1, 1:9, 1:9, 1:9] == 2.0).all() and (b[-1, 0] == np.float32(BG)).all()
    assert np.isnan(b).any()  # the NaN voxels reached their bricks


def test_an_all_nan_brick_has_no_range():
    org = np.array([[0, 0, 0]], np.int64)
    val = np.full((1, 8, 8, 8), np.nan, np.float32)
    b, lo, hi = leaf_bricks(org, val, np.nan)
    assert np.isnan(b).all() and np.isnan(lo[0]) and np.isnan(hi[0])


def test_the_bundled_sample_builds_the_same_bricks():
    g = read_vdb(SAMPLE, grids=["density"]).grids[0]
    org, val = _grid_leaves(g)
    b, _, _ = leaf_bricks(org, val, float(g.background or 0.0))
    sel = np.random.default_rng(1).choice(len(org), 12, replace=False)
    np.testing.assert_array_equal(b[sel], voxel_lookup(org, val, np.float32(g.background or 0.0))[sel])


def test_sub_block_max_is_the_max_of_the_voxels_its_samples_read():
    from kernels.render.inputs.bricks import sub_max

    org, val = sparse_grid()
    b, _, _ = leaf_bricks(org, val, BG)
    b[0, :3, :3, :3] = np.nan  # sub-block 0 of brick 0 all NaN: -inf
    got = sub_max(b)
    rd = [range(0, 3), range(2, 5), range(4, 7), range(6, 10)]  # stencils from voxels 2s, 2s + 1
    for c in range(len(org)):
        for s in range(64):
            box = b[c][np.ix_(rd[s // 16], rd[s // 4 % 4], rd[s % 4])]
            want = np.nanmax(box) if not np.isnan(box).all() else -np.inf
            assert got[c, s] == np.float32(want)
    assert got[0, 0] == -np.inf
