"""Large volumes: each frame builds only the acceleration its mode draws from (a reference frame
no Gaussians, a screen-tile frame no per-leaf lists), and the per-leaf lists are checked against
the memory they need before they are built."""

import tracemalloc

import numpy as np
import pytest

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction, accel
from kernels.render.synthetic import gaussian_set, grid_from_dense

TF = TransferFunction.from_colormap("viridis", 0.0, 1.0, density=2.0)


def blob_object():
    n = 24
    x = np.arange(n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    vol = np.exp(-((X - 12) ** 2 + (Y - 11) ** 2 + (Z - 12.5) ** 2) / (2 * 5.0 ** 2)).astype(np.float32)
    vol[vol < 0.05] = 0
    c = np.stack(np.meshgrid(x[::2] + 0.5, x[::2] + 0.5, x[::2] + 0.5, indexing="ij"), -1).reshape(-1, 3)
    v = vol[::2, ::2, ::2].reshape(-1)
    keep = v > 0
    gs = gaussian_set(c[keep], 1.2, v[keep], 0.3)
    return RenderObject(gs, np.diag([0.1, 0.1, 0.1, 1.0]), grid=grid_from_dense(vol))


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
    c = rng.uniform(0, 200, size=(3000, 3))
    gs = gaussian_set(c, rng.uniform(0.5, 9.0, size=(3000, 3)), rng.uniform(0.1, 1, 3000), 1.0)
    acc = accel.build_gaussians([RenderObject(gs)], 3.0)
    ext = acc.g_chi - acc.g_clo + 1
    entries = accel.halo_entries(acc)
    assert entries == int(np.prod(ext, axis=1).sum()) > 100_000
    accel.add_halo_lists(accel.build_gaussians([RenderObject(gs)], 3.0), 3.0)  # compiled before timing
    tracemalloc.start()
    accel.add_halo_lists(acc, 3.0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert acc.cell_items.size == entries
    assert 0.5 * accel.halo_bytes(entries) < peak <= accel.halo_bytes(entries)
    accel.check_halo_memory(acc, available=accel.halo_bytes(entries))  # fits: no refusal
    with pytest.raises(MemoryError, match=r"need about .* GiB .*screen tiles") as err:
        accel.check_halo_memory(acc, available=accel.halo_bytes(entries) - 1)
    assert "\n" not in str(err.value) and "finer" not in str(err.value)
