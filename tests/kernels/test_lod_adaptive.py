"""The adaptive preset: meets its tolerance (re-measured with field_error) on grids with known fields
and on a shared grid, says so honestly when it cannot, needs fewer Gaussians for looser tolerances
than for tight ones, is thread-count independent and round-trips through the compact encoding."""
import os

import numba
import numpy as np
import pytest
from conftest import SAMPLE, shared_data_files

from kernels.lod import build_lod, decode_compact, encode_compact, field_error
from kernels.lod.encoding import VALUE_TOL
from kernels.lod.synthetic import grid_from_dense, random_sparse_grid

N = 24


def _xyz():
    return np.meshgrid(*(np.arange(N),) * 3, indexing="ij")


def blob():
    """A smooth, wavy field inside a ball (the fog stops at the ball, at values 0.2 to 1)."""
    x, y, z = _xyz()
    m = (x - 11.5) ** 2 + (y - 11.5) ** 2 + (z - 11.5) ** 2 <= 100
    v = 0.6 + 0.4 * np.cos(0.4 * x) * np.cos(0.3 * y + 0.2 * z)
    return grid_from_dense(np.where(m, v, 0).astype(np.float32), m, origin=(-8, 0, 16))


def step_edge():
    """A full block whose value jumps from 0.2 to 1 across the plane x = 11.5."""
    x, _, _ = _xyz()
    return grid_from_dense(np.where(x < 12, 0.2, 1.0).astype(np.float32), np.ones((N,) * 3, bool))


def checkerboard():
    """8^3 squares of 0.3 and 1.0 (step edges on three axes)."""
    x, y, z = _xyz()
    v = np.where(((x // 8) + (y // 8) + (z // 8)) % 2, 1.0, 0.3).astype(np.float32)
    return grid_from_dense(v, np.ones((N,) * 3, bool))


CASES = [(blob, 0.02), (step_edge, 0.02), (checkerboard, 0.05)]


@pytest.mark.parametrize("make,tol", CASES, ids=["blob", "step", "checker"])
def test_meets_tolerance_on_known_fields(make, tol):
    g = make()
    gs = build_lod(g, "adaptive", tolerance=tol)
    e = field_error(g, gs)  # measured again, from scratch, on the set as returned
    assert gs.params["tolerance_met"], gs.params["round_history"]
    assert e["nrmse"] <= tol
    assert gs.params["achieved_nrmse"] == e["nrmse"]
    assert np.all(gs.amplitudes >= 0) and np.all(np.isfinite(gs.amplitudes))


@pytest.mark.parametrize("make,most", [(blob, 0.05), (step_edge, 0.5), (checkerboard, 0.5)],
                         ids=["blob", "step", "checker"])
def test_fewer_than_high_at_highs_error(make, most):
    g = make()
    high = build_lod(g, "high")
    gs = build_lod(g, "adaptive", tolerance=field_error(g, high)["nrmse"])
    assert gs.params["tolerance_met"]
    assert gs.count <= most * high.count, (gs.count, high.count)


def test_max_error_bound():
    g = blob()
    loose = build_lod(g, "adaptive", tolerance=0.05)
    bound = 0.5 * loose.params["achieved_max_abs"]
    gs = build_lod(g, "adaptive", tolerance=0.05, max_error=bound)
    assert gs.params["tolerance_met"]
    assert field_error(g, gs)["max_abs"] <= bound < loose.params["achieved_max_abs"]
    assert gs.count > loose.count


def test_unreachable_tolerance_is_reported_not_claimed():
    g = checkerboard()
    gs = build_lod(g, "adaptive", tolerance=1e-4)
    e = field_error(g, gs)
    assert not gs.params["tolerance_met"]
    assert gs.params["achieved_nrmse"] == e["nrmse"] > 1e-4


def test_counts_shrink_as_tolerance_grows():
    g = blob()
    counts = [build_lod(g, "adaptive", tolerance=t).count for t in (0.01, 0.02, 0.05, 0.1)]
    assert all(a >= b for a, b in zip(counts, counts[1:])), counts
    assert counts[-1] < counts[0] / 2, counts


def test_level_set_and_tiles():
    """Level sets against the kept-shell occupancy; an active tile stays one Gaussian."""
    x, y, z = _xyz()
    phi = (np.sqrt((x - 11.5) ** 2 + (y - 11.5) ** 2 + (z - 11.5) ** 2) - 8.0).astype(np.float32)
    ls = grid_from_dense(phi, np.abs(phi) <= 3, grid_class="level_set")
    gs = build_lod(ls, "adaptive", tolerance=0.2)
    e = field_error(ls, gs)
    assert gs.params["tolerance_met"] and e["nrmse"] <= 0.2 and e["surface_iou"] > 0.9
    assert gs.count < build_lod(ls, "high").count
    assert np.all(gs.values == 1)
    g = blob()
    g.tile_origins, g.tile_sizes = np.array([[-16, 0, 16]], np.int32), np.array([8], np.int32)
    g.tile_values, g.tile_active = np.array([0.1], np.float32), np.array([True])
    gs = build_lod(g, "adaptive", tolerance=0.03)
    assert gs.params["tolerance_met"] and field_error(g, gs)["nrmse"] <= 0.03
    assert gs.n_leaf_groups == len(gs.group_origins) - 1  # the tile is its own group


def test_round_trip():
    g = random_sparse_grid(11, n_leaves=25, span=3, density=0.5)
    g.tile_origins, g.tile_sizes = np.array([[64, 0, 0]], np.int32), np.array([8], np.int32)
    g.tile_values, g.tile_active = np.array([0.4], np.float32), np.array([True])
    ls = random_sparse_grid(3, n_leaves=12, grid_class="level_set")
    for grid in (g, ls, blob()):
        gs = build_lod(grid, "adaptive", tolerance=0.05)
        dec = decode_compact(encode_compact(gs))
        for k in ("group_origins", "group_start", "offsets", "sigmas", "amplitudes", "voxels"):
            np.testing.assert_array_equal(getattr(dec, k), getattr(gs, k), err_msg=k)
        # values: float16 when every one survives within VALUE_TOL x range (encoding.py)
        rng = float(np.ptp(gs.values)) or 1.0
        np.testing.assert_allclose(dec.values, gs.values, rtol=0, atol=VALUE_TOL * rng)
        assert dec.lod == "adaptive"
        assert field_error(grid, dec)["nrmse"] == pytest.approx(gs.params["achieved_nrmse"], rel=0.02)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")
def test_thread_count_independent():
    g = random_sparse_grid(7, n_leaves=40, span=4, density=0.6)
    old = numba.get_num_threads()
    out = []
    try:
        for t in (1, 2):
            numba.set_num_threads(t)
            out.append(build_lod(g, "adaptive", tolerance=0.03))
    finally:
        numba.set_num_threads(old)
    a, b = out
    assert a.count == b.count
    for k in ("group_origins", "offsets", "sigmas", "values", "amplitudes", "voxels"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert a.params["achieved_nrmse"] == b.params["achieved_nrmse"]


def test_bad_options():
    g = blob()
    for kw in (dict(tolerance=-0.1), dict(tolerance=float("nan")), dict(max_error=-1.0)):
        with pytest.raises(ValueError):
            build_lod(g, "adaptive", **kw)
    with pytest.raises(ValueError):
        build_lod(g, "adaptive", "paper")
    with pytest.raises(ValueError):
        build_lod(g, "adaptive", refine=2)


SMOKE = [p for p in shared_data_files() if os.path.basename(p) == "mantaflow_smoke_r128_f040.vdb"]


@pytest.mark.skipif(not SMOKE, reason="shared data absent")
def test_shared_smoke_at_highs_error_with_half_the_gaussians():
    from kernels.vdb import read_vdb

    g = read_vdb(SMOKE[0], grids=["density"]).grids[0]
    high = build_lod(g, "high")
    tol = field_error(g, high)["nrmse"]
    gs = build_lod(g, "adaptive", tolerance=tol)
    assert gs.params["tolerance_met"] and field_error(g, gs)["nrmse"] <= tol
    assert gs.count <= 0.5 * high.count, (gs.count, high.count)


def test_import_operator_builds_the_adaptive_lod(scene, bpy_module):
    """The import dialog's Adaptive LOD with its tolerance, through the real operator."""
    from conftest import SAMPLE

    bpy = bpy_module
    res = bpy.ops.gaussvdb.import_vdb(filepath=SAMPLE, grids="density", lods={"adaptive", "high"},
                                      tolerance=0.12, measure_error=True)
    assert res == {"FINISHED"}
    obj = bpy.context.scene.objects[0]
    assert obj.gaussvdb.lods == "high,adaptive"
    high, adaptive = obj.gaussvdb.stats()["lods"]
    assert adaptive["tolerance"] == pytest.approx(0.12)
    assert adaptive["tolerance_met"] == (adaptive["nrmse"] <= 0.12)
    assert adaptive["count"] < high["count"]


def _dense_fit_sums(st, w):
    """fit._pass' per-Gaussian sums from a dense matrix A (active voxels x Gaussians, each cut at
    its k-sigma ellipsoid): (A^T r, A^T A 1, SSE) with r = reference - A w."""
    rows, refs = [], []
    for c in range(len(st["corg"])):
        bits = np.unpackbits(st["cmask"][c].view(np.uint8), bitorder="little").astype(bool)
        i = np.flatnonzero(bits)
        rows.append(st["corg"][c] + np.stack([i // 64, (i // 8) % 8, i % 8], 1))
        refs.append(st["cref"][c, i])
    p, ref = np.concatenate(rows).astype(np.float64), np.concatenate(refs).astype(np.float64)
    d = (p[:, None, :] - st["cent"][None]) / st["sig"][None]
    q = (d * d).sum(2)
    a = np.where(q <= st["k"] ** 2, np.exp(-0.5 * q), 0.0)
    r = ref - a @ w
    return a.T @ r, a.T @ a.sum(1), float(r @ r)


@pytest.mark.parametrize("lattice", [True, False], ids=["lattice", "off-lattice"])
def test_fit_pass_matches_dense_sums(lattice):
    """The fit's pass (axis terms made once per pair, from tables on the half-voxel lattice) gives
    the normal equations' sums of a dense matrix; the tables and computed terms agree bit for bit."""
    from kernels.lod import fit
    from kernels.lod.mixture import setup

    g = random_sparse_grid(5, n_leaves=6, span=2, density=0.6)
    gs = build_lod(g, "medium")
    st = setup(g, gs)
    if not lattice:
        st["cent"] = st["cent"] + np.random.default_rng(1).uniform(-0.3, 0.3, st["cent"].shape)
    w = np.random.default_rng(2).uniform(0.1, 1.0, len(st["cent"]))
    tables = fit.axis_lattice(st["cent"], st["sig"], st["k"])
    assert (tables[-1] >= 0) == lattice
    npair = len(st["pg"])
    out = []
    for tab in (tables, fit.COMPUTED):
        pnum, pden, cres = np.empty(npair), np.empty(npair), np.empty((len(st["corg"]), 512))
        sse, _ = fit._run(dict(st, tables=tab), w, st["cref"], fit.S1, pnum, pden, cres)
        out.append((np.bincount(st["pg"], pnum, len(w)), np.bincount(st["pg"], pden, len(w)), sse.sum()))
    num, den, sse = _dense_fit_sums(st, w)
    for got in out:
        np.testing.assert_allclose(got[0], num, rtol=1e-9, atol=1e-9 * np.abs(num).max())
        np.testing.assert_allclose(got[1], den, rtol=1e-9)
        assert got[2] == pytest.approx(sse, rel=1e-9)
    for x, y in zip(out[0], out[1]):
        np.testing.assert_array_equal(x, y)


def test_rounds_are_reported_and_a_cancel_stops_between_them():
    """A conversion's progress names each adaptive round (the import's progress bar and Esc work
    within the LOD, not only between LODs); a cancel after the first round stops the build there."""
    from kernels import pipeline

    seen = []
    cg = pipeline.convert_file(SAMPLE, ["density"], ["adaptive"], compute_error=False,
                               progress=lambda f, t: seen.append((f, t)))[0]
    rounds = [t for _, t in seen if ", round " in t]
    assert len(rounds) == cg.lods[0].gset.params["rounds"] >= 2
    assert rounds[0].startswith("density: Adaptive LOD, round 1: ") and "NRMSE" in rounds[0]
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[-1] < 1.0
    texts = []
    with pytest.raises(pipeline.ConversionCancelled):
        pipeline.convert_file(SAMPLE, ["density"], ["adaptive"], compute_error=False,
                              progress=lambda f, t: texts.append(t),
                              cancel=lambda: any(", round " in t for t in texts))
    assert sum(", round " in t for t in texts) == 1
