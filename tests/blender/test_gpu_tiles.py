"""The screen-tile lists the GPU builds (gpu/tiles.py, glsl/tiles.glsl) against the CPU's
(cpu.tiles.screen_tiles): per tile every Gaussian the CPU lists is listed, in the order of the
entry bounds, the bounds within float32 rounding, each entry's pixel mask holding the CPU's."""
import numpy as np
import pytest
from test_gpu_gauss import CAM, TF, scenes

from kernels.render import RenderScene


def read_table(tex, n):
    buf = tex.read()
    buf.dimensions = tex.width * tex.height * 4
    return np.frombuffer(buf, np.float32).reshape(-1, 4)[:n].copy()


@pytest.fixture(scope="module")
def mods(addon):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu import context, device, probe, tiles

    ok, why = probe.probe()
    if not ok:
        pytest.skip(f"no GPU context here: {why}")
    return context, device, tiles


@pytest.mark.parametrize("name", ["fog", "two objects"])
def test_gpu_lists_hold_the_cpu_lists(mods, name):
    from kernels.render.gpu import tables_tiles

    context, device, tiles = mods
    dev = device.GPUDevice(gpu_tiles=True)
    frame = dev.begin_frame(RenderScene(scenes()[name], mode="particles"), CAM, TF)
    m = frame.gauss.mu.shape[0]

    def run():
        lists, n = tiles.build(frame)
        return (read_table(lists["t_start"], 10 ** 9).ravel(), read_table(lists["t_ent"], n),
                read_table(lists["t_lb"], m)[:, 0])

    start, ent, lb = context.run(run)
    want = tables_tiles.cpu_lists(frame)
    ws = want["t_start"].reshape(-1)
    we = want["t_ent"].reshape(-1, 4)
    wlb = want["t_lb"].reshape(-1, 4)[:m, 0]
    ntiles = int(np.prod(tables_tiles.tile_grid(frame)))
    fin = np.isfinite(wlb)
    np.testing.assert_allclose(lb[fin], wlb[fin], rtol=1e-5, atol=1e-5)
    assert np.all(lb[fin] <= wlb[fin] + 1e-6 * (np.abs(wlb[fin]) + 1))
    listed = 0
    for t in range(ntiles):
        g_ids = ent[int(start[t]):int(start[t + 1]), 0].astype(int)
        c_ids = we[int(ws[t]):int(ws[t + 1]), 0].astype(int)
        assert set(c_ids) <= set(g_ids), f"tile {t}: {set(c_ids) - set(g_ids)} missing"
        keys = list(zip(lb[g_ids], g_ids))
        bad = [i for i in range(1, len(keys)) if keys[i] < keys[i - 1]]
        assert not bad, f"tile {t}: not in (entry bound, id) order at {bad[:5]} of {len(keys)}"
        gm = {int(e[0]): e[1:] for e in ent[int(start[t]):int(start[t + 1])]}
        for e in we[int(ws[t]):int(ws[t + 1])]:
            got = gm[int(e[0])].astype(np.int64)
            assert np.all((got & e[1:].astype(np.int64)) == e[1:].astype(np.int64)), f"tile {t}: mask"
        listed += len(c_ids)
    assert listed > 100  # lists to compare


def test_lists_past_the_gpu_limit_come_from_the_cpu(mods):
    """More entries than the GPU's lists may hold: the CPU's lists are uploaded instead and the
    image still matches the CPU device."""
    from references import GPU_MIN_DB, psnr

    from kernels.render import CPUDevice

    _, device, tiles = mods
    sc = RenderScene(scenes()["fog"], mode="particles")
    want = CPUDevice().render(sc, CAM, TF)
    dev = device.GPUDevice()
    keep = tiles.MAX_ENTRIES
    tiles.MAX_ENTRIES = 10
    try:
        got = dev.render(sc, CAM, TF)
    finally:
        tiles.MAX_ENTRIES = keep
    assert dev.stats["tile_lists"] == "CPU" and dev.stats["gpu_tile_entries"] > 10
    assert psnr(got["Combined"], want["Combined"]) >= GPU_MIN_DB
    got = dev.render(RenderScene(scenes()["two objects"], mode="particles"), CAM, TF)
    assert dev.stats["tile_lists"] == "GPU"


def test_lists_past_both_limits_go_to_the_cpu_device(mods):
    """Lists too long for the GPU and for the CPU's lists too (a camera inside a dense volume):
    the CPU device draws the frame with its leaf walk, and says so."""
    from bl_ext.user_default.gaussvdb.kernels.render.devices import frame_setup  # the extension's own copy
    from references import GPU_MIN_DB, psnr

    from kernels.render import CPUDevice

    _, device, tiles = mods
    sc = RenderScene(scenes()["fog"], mode="particles")
    want = CPUDevice().render(sc, CAM, TF)
    dev = device.GPUDevice()
    keep = tiles.MAX_ENTRIES, frame_setup.MAX_TILE_ENTRIES
    tiles.MAX_ENTRIES = frame_setup.MAX_TILE_ENTRIES = 10
    try:
        got = dev.render(sc, CAM, TF)
    finally:
        tiles.MAX_ENTRIES, frame_setup.MAX_TILE_ENTRIES = keep
    assert dev.stats["fallback"] == device.NO_LISTS
    assert psnr(got["Combined"], want["Combined"]) >= GPU_MIN_DB
