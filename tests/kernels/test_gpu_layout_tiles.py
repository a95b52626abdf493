"""The inputs of the GPU's own screen-tile lists (no Blender): the packed Gaussians and camera
as tiles.glsl reads them, the prefix sum, and the CPU's lists as the fallback tables."""
import numpy as np

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.cpu.tiles import tile_camera
from kernels.render.gpu import tables_gauss as LG
from kernels.render.gpu import tables_tiles as L
from kernels.render.inputs import layout
from kernels.render.scene.synthetic import gaussian_set

TF = TransferFunction.from_colormap("viridis", 0, 1)
CAM = Camera.frame_box([0] * 3, [12] * 3, 24, 16)


def scene():
    rng = np.random.default_rng(3)
    m = np.eye(4)
    m[:3, 3] = (3.0, 1.0, 0.0)
    m[0, 0] = 1.5
    objs = [RenderObject(gaussian_set(rng.uniform(0, 9, (n, 3)), 0.9, rng.uniform(0, 1, n), 1.0),
                         matrix_world=mw) for n, mw in ((200, np.eye(4)), (150, m))]
    return RenderScene(objs, mode="particles")


def deferred_frame():
    dev = CPUDevice()
    return dev, dev.begin_frame(scene(), CAM, TF, lists_elsewhere=True)


def test_inputs_read_back():
    _, fr = deferred_frame()
    t = L.tile_inputs(fr)
    g = t["tl_g"].reshape(-1, 4)
    m = fr.gauss.mu.shape[0]
    np.testing.assert_allclose(g[0:2 * m:2, :3], fr.gauss.mu, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(g[1:2 * m:2, 2], fr.gauss.w, rtol=1e-6)
    assert set(g[1:2 * m:2, 3].astype(int)) == {0, 1}
    par = t["tl_par"].reshape(-1)
    assert tuple(par[:2]) == (24, 16)
    cmat, onorm = tile_camera(fr.cam, [np.linalg.inv(w) for w in fr.objects.w2i])
    o = layout.TLP_SIZE + layout.TLO_SIZE  # the second object's
    np.testing.assert_allclose(par[o:o + 12], cmat[1].ravel(), rtol=1e-6, atol=1e-5)
    assert par[o + 12] == np.float32(onorm[1]) and onorm[1] > 1.4


def test_starts_and_the_deferred_frame():
    assert L.starts(np.array([[2, 0], [3, 1]])).tolist() == [0, 2, 2, 5, 6]
    dev, fr = deferred_frame()
    assert fr.accel.t_start.shape[0] <= 1  # no lists on the CPU: the GPU builds them
    key = fr.key
    full = dev.begin_frame(scene(), CAM, TF)
    assert full.key != key and full.accel.t_start.shape[0] == L.tile_grid(full)[0] * L.tile_grid(full)[1] + 1
    want = LG.tile_tables(full.accel.t_start, full.accel.t_items, full.accel.t_mask)
    got = L.cpu_lists(fr)  # the fallback: the same lists from the deferred frame
    for name in ("t_start", "t_ent"):
        np.testing.assert_array_equal(got[name], want[name])
    np.testing.assert_allclose(got["t_lb"].reshape(-1, 4)[:len(full.gauss.w), 0], full.gauss.rec[:, 7],
                               rtol=1e-6)
