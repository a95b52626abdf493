"""Properties over random sparse grids: counts, exact single coverage, mass, thread independence,
encoding round trip, level sets' signed distances."""
import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_fixtures import bits_from_masks

from kernels.lod import PRESETS, build_lod, decode_compact, encode_compact, field_error
from kernels.lod.gridprep import effective_masks
from kernels.lod.synthetic import random_sparse_grid

NON_OVERLAPPING = PRESETS  # every scheme here is a partition of the (kept) active voxels


def active_points(grid):
    masks, _ = effective_masks(grid)
    bits = bits_from_masks(masks)
    li, n = np.nonzero(bits)
    loc = np.stack([n >> 6, (n >> 3) & 7, n & 7], 1)
    return grid.leaf_origins[li].astype(np.int64) + loc


def boxes(gs):
    """Voxel boxes from field-weight sigmas (sigma = 0.6 x edge)."""
    ext = np.rint(gs.sigmas.astype(np.float64) / 0.6).astype(np.int64)
    c = gs.centers()
    lo = np.rint(c - (ext - 1) / 2).astype(np.int64)
    return lo, lo + ext - 1, ext


grids = st.builds(random_sparse_grid, seed=st.integers(0, 10_000), n_leaves=st.integers(1, 6),
                  density=st.floats(0.05, 0.9), grid_class=st.sampled_from(["fog_volume", "level_set"]))


@settings(max_examples=12, deadline=None)
@given(grid=grids)
def test_partition_of_active_voxels(grid):
    pts = active_points(grid)
    for p in NON_OVERLAPPING:
        gs = build_lod(grid, p, "field")
        assert gs.count <= len(pts)
        assert int(gs.voxels.sum()) == len(pts)
        lo, hi, ext = boxes(gs)
        inside = np.all((pts[:, None, :] >= lo[None]) & (pts[:, None, :] <= hi[None]), axis=2)
        cover = inside.sum(1)
        assert np.all(cover == 1), p  # every kept active voxel in exactly one Gaussian's box
        # a Gaussian's box holds exactly its voxels
        np.testing.assert_array_equal(inside.sum(0), gs.voxels)
        assert np.all(gs.voxels <= ext.prod(1))
        # group structure: non-empty groups, leaf groups sorted by origin
        assert np.all(np.diff(gs.group_start) > 0)
        o = gs.group_origins[:gs.n_leaf_groups]
        assert np.all(np.lexsort(o.T[::-1]) == np.arange(len(o)))


@settings(max_examples=8, deadline=None)
@given(grid=grids, weights=st.sampled_from(["field", "paper"]))
def test_encoding_round_trip(grid, weights):
    for p in PRESETS:
        if p == "adaptive" and weights == "paper":
            continue  # it fits field weights only
        gs = build_lod(grid, p, weights)
        dec = decode_compact(encode_compact(gs))
        for f in ("group_origins", "group_start", "offsets", "sigmas", "amplitudes", "voxels"):
            np.testing.assert_array_equal(getattr(dec, f), getattr(gs, f), err_msg=f)
        rng = gs.params["value_max"] - gs.params["value_min"]
        np.testing.assert_allclose(dec.values, gs.values, rtol=0, atol=1e-3 * rng + 1e-12)
        assert dec.grid_class == gs.grid_class and dec.lod == p and dec.weights == weights
        assert (dec.distances is None) == (gs.grid_class != "level_set")
        if dec.distances is not None:  # a level set's, in the value stream
            np.testing.assert_allclose(dec.distances, gs.distances, rtol=0, atol=1e-3 * rng + 1e-12)


@pytest.mark.parametrize("seed", [3, 4])
def test_level_set_distances_are_the_means_of_their_voxels(seed):
    """A level set's Gaussians: value 1 (the shell's occupancy), and as signed distance the mean of
    the voxels each stands for, as the second-grid sampler gives it (the level set coloured by
    itself: the kept voxels of the Gaussian's own box); a set without them (an older file)
    encodes no values and decodes without them."""
    from dataclasses import replace

    from kernels.lod.second_grid import second_values

    ls = random_sparse_grid(seed, n_leaves=12, span=3, density=0.6, dense_frac=0.3,
                            grid_class="level_set")
    for p in PRESETS:
        gs = build_lod(ls, p)
        assert np.all(gs.values == 1) and gs.distances.dtype == np.float32, p
        np.testing.assert_allclose(gs.distances, second_values(gs, ls, ls), rtol=1e-6, atol=1e-6,
                                   err_msg=p)
    old = replace(gs, distances=None)
    enc = encode_compact(old)
    assert "values" not in enc and "value_const" not in enc
    assert decode_compact(enc).distances is None and np.all(decode_compact(enc).values == 1)


def _all_arrays(gs):
    return [gs.group_origins, gs.group_start, gs.offsets, gs.sigmas, gs.values, gs.amplitudes,
            gs.voxels]


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")
def test_identical_for_1_and_2_threads():
    grid = random_sparse_grid(7, n_leaves=40, span=4, density=0.6)
    ls = random_sparse_grid(8, n_leaves=20, span=3, grid_class="level_set")
    old = numba.get_num_threads()
    res = {}
    try:
        for nt in (1, 2):
            numba.set_num_threads(nt)
            out = []
            for g in (grid, ls):
                for p in PRESETS:
                    gs = build_lod(g, p, "field")
                    out.append((_all_arrays(gs), field_error(g, gs)))
            res[nt] = out
    finally:
        numba.set_num_threads(old)
    for (a1, e1), (a2, e2) in zip(res[1], res[2]):
        for x, y in zip(a1, a2):
            np.testing.assert_array_equal(x, y)
        for k in ("rmse", "nrmse", "max_abs", "points", "pairs"):
            assert e1[k] == e2[k]


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")
def test_parallel_kernels_match_serial_twins(monkeypatch):
    """Grids of SERIAL_BELOW leaves or more run the scheme kernels on threads, smaller ones on the
    calling thread alone: the same output either way (High also at 1 thread, and with paper
    weights)."""
    from kernels.lod import schemes

    n = schemes.SERIAL_BELOW + 64
    grids = [random_sparse_grid(11 + k, n_leaves=n, span=9, density=0.2, dense_frac=0.05,
                                grid_class=c) for k, c in enumerate(("fog_volume", "level_set"))]
    runs = [(p, "field", 2) for p in PRESETS] + [("high", "paper", 2), ("high", "field", 1)]
    old = numba.get_num_threads()
    try:
        for g in grids:
            for p, w, nt in runs:
                with monkeypatch.context() as m:
                    m.setattr(schemes, "SERIAL_BELOW", 1 << 40)
                    ref = _all_arrays(build_lod(g, p, w))
                numba.set_num_threads(nt)
                for x, y in zip(ref, _all_arrays(build_lod(g, p, w))):
                    np.testing.assert_array_equal(x, y)
                numba.set_num_threads(old)
    finally:
        numba.set_num_threads(old)
