"""Large volumes: each frame builds only the acceleration its mode draws from (a reference frame
no Gaussians, a screen-tile frame no per-leaf lists), and the per-leaf lists are checked against
the memory they need before they are built."""

import tracemalloc

import numpy as np
import pytest
from test_render_frame import blob_object as render_frame_blob

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.inputs import accel
from kernels.render.scene.synthetic import gaussian_set

TF = TransferFunction.from_colormap("viridis", 0.0, 1.0, density=2.0)


def blob_object():
    return render_frame_blob(amplitude=0.3)


def camera():
    return Camera.frame_box([0, 0, 0], [2.4, 2.4, 2.4], 24, 20, direction=(1.0, 0.8, -0.5))


def test_each_mode_builds_only_what_it_draws_from():
    obj = blob_object()
    dev = CPUDevice(threads=2)
    dev.render(RenderScene([obj], mode="reference"), camera(), TF)
    assert dev.gacc is None and dev.vacc is not None  # no Gaussians, no lists, no tiles
    dev = CPUDevice(threads=2)
    dev.render(RenderScene([obj], mode="particles"), camera(), TF)
    assert dev.vacc is None and dev.gacc is not None and not dev.gacc.has_lists
    assert dev._frame is None or dev._frame.accel.t_start.shape[0] > 1  # drawn from screen tiles
    dev.render(RenderScene([obj], mode="paper"), camera(), TF)  # the same geometry: lists added
    assert dev.gacc.has_lists and dev.gacc.cell_items.size > 0


def test_halo_memory_estimate_covers_the_build_and_refuses_only_past_the_available():
    rng = np.random.default_rng(3)
    c = rng.uniform(0, 400, size=(20000, 3))
    gs = gaussian_set(c, rng.uniform(0.5, 4.0, size=(20000, 3)), rng.uniform(0.1, 1, 20000), 1.0)
    acc = accel.build_gaussians([RenderObject(gs)], 3.0)
    ext = acc.g_chi - acc.g_clo + 1
    entries = accel.halo_entries(acc)
    assert entries == int(np.prod(ext, axis=1).sum()) > 100_000
    accel.add_halo_lists(accel.build_gaussians([RenderObject(gs)], 3.0), 3.0)  # compiled before timing
    tracemalloc.start()
    accel.add_halo_lists(acc, 3.0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    nodes, table = accel.halo_nodes(acc)
    assert acc.cell_items.size == entries and acc.n_nodes == nodes
    need = accel.halo_bytes(entries, nodes, table)
    assert 0.25 * need < peak <= need
    accel.check_halo_memory(acc, available=need)  # fits: no refusal
    with pytest.raises(MemoryError, match=r"need about .* GiB .*screen tiles") as err:
        accel.check_halo_memory(acc, available=need - 1)
    assert "\n" not in str(err.value) and "finer" not in str(err.value)


@pytest.fixture(scope="module")
def spread_tiles(tmp_path_factory):
    """150 active 128^3 tiles 512 voxels apart, each with one leaf beside it: 315 M active voxels
    in a 190 kB file. At Low each tile is one Gaussian of sigma 77 voxels, whose 3-sigma support
    meets 195,112 leaf cells."""
    from tests.vdb_fixtures import openvdb

    ov = openvdb()
    g = ov.FloatGrid()
    g.name = "density"
    a = g.getAccessor()
    for i, j, k in np.ndindex(6, 5, 5):
        o = np.array([i, j, k]) * 512
        g.fill(tuple(int(x) for x in o), tuple(int(x) for x in o + 127), 0.2 + 0.02 * ((i + j + k) % 5), True)
        a.setValueOn(tuple(int(x) for x in o + 200), 1.0)
    g.transform = ov.createLinearTransform(voxelSize=0.01)
    path = tmp_path_factory.mktemp("scale") / "spread_tiles.vdb"
    ov.write(str(path), grids=[g])
    from kernels.lod import build_lod
    from kernels.vdb import read_vdb

    grid = read_vdb(str(path)).grids[0]
    return grid, build_lod(grid, "low")


def test_supports_far_wider_than_a_leaf_render_without_refusal(spread_tiles):
    grid, gs = spread_tiles
    obj = RenderObject(gs, np.asarray(grid.index_to_world, np.float64))
    acc = accel.build_gaussians([obj], 3.0)
    # what per-leaf halo lists would hold (the old 25,000,000 limit refused it) ...
    d = accel.drawn_gaussians(gs, sigmas=True)
    mu, sig = d["mu"], d["sig"]
    lo = np.floor_divide(np.floor(mu - 3 * sig + 0.5).astype(np.int64), accel.LEAF)
    hi = np.floor_divide(np.floor(mu + 3 * sig + 0.5).astype(np.int64), accel.LEAF)
    per_leaf = int(np.prod(hi - lo + 1, axis=1).sum())
    assert per_leaf > 25_000_000
    # ... and what the levels hold: at most LEVEL_SPAN^3 per Gaussian
    assert accel.halo_entries(acc) <= accel.LEVEL_SPAN ** 3 * gs.count < per_leaf / 1000
    assert acc.g_lev.max() > 0
    lo_w, hi_w = np.asarray(grid.bbox_min, float), np.asarray(grid.bbox_max, float) + 1
    w = np.asarray(grid.index_to_world, np.float64)
    cam = Camera.frame_box((w @ np.r_[lo_w, 1])[:3], (w @ np.r_[hi_w, 1])[:3], 40, 32,
                           direction=(1.0, 0.7, -0.4))
    tf = TransferFunction.from_colormap("viridis", 0.0, 0.3, density=20.0)
    for mode in ("particles", "field"):
        sc = RenderScene([obj], mode=mode, threads=2, passes=("Value",))
        tiles = CPUDevice(threads=2).render(sc, cam, tf)
        walk_dev = CPUDevice(threads=2, screen_tiles=False)
        walk = walk_dev.render(sc, cam, tf)
        assert walk_dev.gacc.has_lists and walk_dev.gacc.cell_items.size == accel.halo_entries(acc)
        assert tiles["Combined"][..., 3].max() > 0.2, mode
        assert np.abs(tiles["Combined"] - walk["Combined"]).max() < 1e-6, mode
        assert np.abs(tiles["Value"] - walk["Value"]).max() < 1e-5, mode
    paper = CPUDevice(threads=2).render(RenderScene([obj], mode="paper", threads=2), cam, tf)
    assert np.isfinite(paper["Combined"]).all() and paper["Combined"][..., 3].max() > 0


@pytest.mark.parametrize("mode", ["particles", "field", "paper"])
def test_levels_draw_what_per_leaf_lists_draw(mode, monkeypatch):
    """The leaf walk over the levels' grids and over per-leaf lists only (MAX_LEVEL 0: every
    Gaussian in each leaf its support meets) gives the same image: paper mode bitwise, the
    sweeps up to the rounding of where their pieces end."""
    rng = np.random.default_rng(5)
    n = 400
    gs = gaussian_set(rng.normal(size=(n, 3)) * 20, rng.uniform(0.5, 12.0, size=(n, 3)),
                      rng.uniform(0.1, 1.0, n), 0.05)
    objs = [RenderObject(gs, np.diag([0.05, 0.05, 0.05, 1.0])),
            RenderObject(gs, np.diag([0.04, 0.06, 0.05, 1.0]) + np.eye(4, k=3) * 0.5)]
    cam = Camera.frame_box([-4.0] * 3, [4.0] * 3, 32, 28, direction=(1.0, 0.6, -0.3))
    # paper mode divides by det(Sigma) in voxels: a denser TF to draw as much
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.0, density=3e4 if mode == "paper" else 3.0)
    sc = RenderScene(objs, mode=mode, threads=2, passes=("Value",))
    dev = CPUDevice(threads=2, screen_tiles=False)
    levels = dev.render(sc, cam, tf)
    assert dev.gacc.g_lev.max() > 0 and dev.gacc.walk_obj.shape[0] > len(objs)
    entries = dev.gacc.cell_items.size
    monkeypatch.setattr(accel, "MAX_LEVEL", 0)
    dev = CPUDevice(threads=2, screen_tiles=False)
    per_leaf = dev.render(sc, cam, tf)
    assert dev.gacc.g_lev.max() == 0 and dev.gacc.cell_items.size > 3 * entries
    assert levels["Combined"][..., 3].max() > 0.1
    tol = 0.0 if mode == "paper" else 1e-6
    assert np.abs(levels["Combined"] - per_leaf["Combined"]).max() <= tol
    assert np.abs(levels["Value"] - per_leaf["Value"]).max() <= 10 * tol
