"""The field error's lattice path (kernels/lod/error_lattice*.py): the classes it takes, its per
cell sums against a brute-force truncated sum (both the separable and the node-by-node sums), and
the whole evaluation against the pair lists: the same figures to 1e-11 per cell (only the order
of the additions differs), identical for any chunk size and thread count."""
import dataclasses

import numba
import numpy as np
import pytest

from kernels.lod import build_lod, field_error
from kernels.lod import error_lattice as L
from kernels.lod import error_lattice_sums as S
from kernels.lod import mixture as E
from kernels.lod.synthetic import random_sparse_grid
from tests.kernels.test_lod_stream import with_tiles

CASES = [("high", "fog_volume"), ("low", "fog_volume"), ("variance", "fog_volume"),
         ("merged", "fog_volume"), ("medium", "fog_volume"), ("high", "level_set"),
         ("medium", "level_set")]


def _grid(preset, cls, seed=11):
    g = random_sparse_grid(seed, n_leaves=40, span=4, density=0.6, grid_class=cls)
    return with_tiles(g) if cls == "fog_volume" else g


def _close(lat, pairs):
    sse, mx, npts, inter, union = lat
    rs, rm, rn, ri, ru = pairs
    np.testing.assert_allclose(sse, rs, rtol=1e-11, atol=1e-300)
    np.testing.assert_allclose(mx, rm, rtol=1e-11, atol=1e-300)
    assert np.array_equal(npts, rn) and np.array_equal(inter, ri) and np.array_equal(union, ru)


@pytest.mark.parametrize("preset,cls", CASES)
def test_lattice_equals_pairs_for_any_chunk(preset, cls):
    g = _grid(preset, cls)
    gs = build_lod(g, preset)
    st0, pairs = E._evaluate(g, gs, E.DEFAULT_K, 7, lattice=False)
    runs = [E._evaluate(g, gs, E.DEFAULT_K, chunk) for chunk in (1, 7, 10 ** 9)]
    for st, got in runs:
        _close(got, pairs)
        for a, b in zip(runs[0][1], got):
            assert np.array_equal(a, b)  # chunk size: the very same bits
    if preset in ("high", "medium", "merged"):
        assert runs[0][0]["pairs"] < st0["pairs"] // 10  # the lattice took most Gaussians
    e_lat, e_pairs = field_error(g, gs), E._evaluate(g, gs, E.DEFAULT_K, lattice=False)
    assert e_lat["nrmse"] == pytest.approx(np.sqrt(np.sum(e_pairs[1][0] * e_pairs[0]["cw"])
                                                   / e_lat["points"]) / e_lat["nrmse_denominator"],
                                           rel=1e-12)


def test_classes_of_high_and_low():
    g = _grid("high", "fog_volume")
    csig, ce = L.lattice_classes(build_lod(g, "high"), E.DEFAULT_K)
    got = {(tuple(np.float64(s).round(6)), tuple(e)) for s, e in zip(csig, ce)}
    assert got == {((0.6,) * 3, (1, 1, 1)), ((1.2,) * 3, (2, 2, 2))}
    # Low: one sigma 4.8 Gaussian per dense leaf, 19.2 voxels of reach: beyond the 27 leaves
    assert len(L.lattice_classes(build_lod(g, "low"), E.DEFAULT_K)[0]) == 0
    # a smaller k lets the 4^3 blocks of Medium in, a larger one keeps them out
    gm = build_lod(g, "medium")
    assert (4, 4, 4) in {tuple(e) for e in L.lattice_classes(gm, 4.0)[1]}
    assert (4, 4, 4) not in {tuple(e) for e in L.lattice_classes(gm, 4.5)[1]}


def test_off_lattice_centres_stay_on_the_pair_lists():
    g = random_sparse_grid(5, n_leaves=20, span=3)
    gs = build_lod(g, "high")
    gs = dataclasses.replace(gs, offsets=gs.offsets + np.float32(0.25))  # no half-voxel lattice
    assert len(L.lattice_classes(gs, E.DEFAULT_K)[0]) == 0
    st, got = E._evaluate(g, gs, E.DEFAULT_K, 4)
    _, ref = E._evaluate(g, gs, E.DEFAULT_K, 4, lattice=False)
    for a, b in zip(ref, got):
        assert np.array_equal(a, b)
    assert got[0].sum() > 0


def test_mixed_class_groups_and_other_k():
    # Medium leaves mix 4^3 blocks, 2^3 blocks and voxels; k = 3 cuts closer
    g = _grid("medium", "fog_volume", seed=4)
    gs = build_lod(g, "medium")
    for k in (3.0, 4.0):
        _, pairs = E._evaluate(g, gs, k, 5, lattice=False)
        _close(E._evaluate(g, gs, k, 5)[1], pairs)


def _brute(csig, ce, k, W, q):
    """The class-q field at a cell's voxels from its window of nodes, summed plainly."""
    k2 = k * k
    s = csig[q].astype(np.float64)
    e = ce[q]
    acc = np.zeros(512)
    vox = np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), -1).reshape(-1, 3)
    for J in np.ndindex(*[24 // e[a] for a in range(3)]):
        Jr = np.array(J) - 8 // e  # node index relative to the cell's leaf
        pos = e * Jr + (e - 1) / 2.0
        d = (vox - pos) / s
        qq = ((d[:, 0] ** 2 + d[:, 1] ** 2) + d[:, 2] ** 2)
        w = W.get(tuple(Jr), 0.0)
        if w:
            acc += np.where(qq <= k2, w * np.exp(-0.5 * qq), 0.0)
    return acc


@pytest.mark.parametrize("k", [3.0, 4.0])
def test_cell_sums_against_brute_force(k):
    csig = np.array([[0.6] * 3, [1.2] * 3, [2.4] * 3, [0.6, 0.6, 1.2], [1.2, 0.6, 0.6]], np.float32)
    ce = np.array([[1, 1, 1], [2, 2, 2], [4, 4, 4], [1, 1, 2], [2, 1, 1]], np.int64)
    tab = L.class_tables(csig, ce, k)
    nper, nw, wr, wnode, qa, ea, tz, ez, nlev, xys, xyt, xyl, xye, cost, nwm, nlm = tab
    rng = np.random.default_rng(1)
    # the 27 leaves around the cell as groups 0..26, every node of every class present
    keys = np.array([E.cell_keys(np.array([[dx, dy, dz]]))[0]
                     for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)], np.int64)
    corg = np.zeros((1, 3), np.int64)
    per = np.prod(nper, 1)
    base = np.concatenate([[0], np.cumsum(27 * per)[:-1]])
    slot = base[:, None] + np.arange(27)[None, :] * per[:, None]  # class q of leaf g
    for density in (0.02, 1.0):
        nodes = rng.random(int(27 * per.sum())) * (rng.random(int(27 * per.sum())) < density)
        nb = np.empty(27, np.int64)
        S.neighbours(0, corg, keys, 27, nb)
        assert np.array_equal(nb, np.arange(27))
        W = np.empty(nwm ** 3)
        colnz = np.zeros(nwm * nwm, np.bool_)
        Z = np.empty(nwm * nwm * nlm * 8)
        for q in range(len(csig)):
            ref_nodes = {}
            for g in range(27):
                lx, ly, lz = g // 9 - 1, (g // 3) % 3 - 1, g % 3 - 1
                for j in np.ndindex(*nper[q]):
                    v = nodes[slot[q, g] + (j[0] * nper[q, 1] + j[1]) * nper[q, 2] + j[2]]
                    ref_nodes[(lx * nper[q, 0] + j[0], ly * nper[q, 1] + j[1],
                               lz * nper[q, 2] + j[2])] = v
            ref = _brute(csig, ce, k, ref_nodes, q)
            nnz, ncol = S._window(q, nb, slot, nodes, nper, nw, wr, wnode, nwm, W, colnz)
            a1, a2 = np.zeros(512), np.zeros(512)
            S._direct(q, k * k, nw, qa, ea, nwm, W, a1)
            S._separable(q, nw, tz, ez, nlev, xys, xyt, xyl, xye, nwm, nlm, W, colnz, Z, a2)
            np.testing.assert_allclose(a1, ref, rtol=1e-12, atol=1e-14)
            np.testing.assert_allclose(a2, ref, rtol=1e-12, atol=1e-14)
            a3 = np.zeros(512)
            S.lattice_cell(0, corg, k * k, keys, 27, slot * (np.arange(len(csig)) == q)[:, None]
                           - (np.arange(len(csig)) != q)[:, None], nodes, *tab, nb, W, colnz, Z,
                           a3)
            np.testing.assert_allclose(a3, ref, rtol=1e-12, atol=1e-14)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")
def test_lattice_identical_for_1_and_2_threads():
    g = random_sparse_grid(2, n_leaves=300, span=5, density=0.7, dense_frac=0.6)
    gs = build_lod(g, "high")
    old = numba.get_num_threads()
    res = []
    try:
        for nt in (1, 2):
            numba.set_num_threads(nt)
            res.append(E._evaluate(g, gs, E.DEFAULT_K, 1000)[1])
    finally:
        numba.set_num_threads(old)
    for a, b in zip(*res):
        assert np.array_equal(a, b)
