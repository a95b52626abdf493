"""The Gaussian modes' GPU tables (no Blender): pixel masks in exact float pieces, the tile lists
and records as the shaders fetch them, the tiles of overflowing rays."""
import numpy as np

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render import gpu_layout_gauss as L
from kernels.render.synthetic import gaussian_set


def test_mask_pieces_round_trip():
    rng = np.random.default_rng(0)
    m = rng.integers(-(1 << 63), (1 << 63) - 1, 200, dtype=np.int64)
    p = L.mask_pieces(m)
    assert (p < 2 ** 22).all() and (p == np.floor(p)).all()
    u = p.astype(np.uint64)
    back = u[:, 0] | (u[:, 1] << np.uint64(22)) | (u[:, 2] << np.uint64(44))
    assert (back.view(np.int64) == m).all()
    for bit in (0, 21, 22, 43, 44, 63):  # the shader's rule: piece bit // 22, bit bit % 22
        want = (m.view(np.uint64) >> np.uint64(bit)) & np.uint64(1)
        got = (p[:, bit // 22].astype(np.int64) >> (bit % 22)) & 1
        assert (got == want.astype(np.int64)).all()


def test_frame_tables_read_back():
    rng = np.random.default_rng(1)
    gs = gaussian_set(rng.uniform(0, 9, (300, 3)), 0.9, rng.uniform(0, 1, 300), 1.0)
    sc = RenderScene([RenderObject(gs)], mode="particles")
    cam = Camera.frame_box([0] * 3, [9] * 3, 24, 24)
    fr = CPUDevice().begin_frame(sc, cam, TransferFunction.from_colormap("viridis", 0, 1))
    t = L.particles_frame(fr).textures
    tex = t["t_ent"].reshape(-1, 4)
    a = fr.accel
    assert (tex[:len(a.t_items), 0] == a.t_items).all()
    start = t["t_start"].ravel()[:len(a.t_start)]
    assert (start == a.t_start).all()
    rec = t["g_rec"].reshape(-1, 4)[:2 * fr.gauss.rec.shape[0]].reshape(-1, 8)
    np.testing.assert_allclose(rec, fr.gauss.rec, rtol=1e-6)
    assert L.unsupported(fr) is None


def test_overflow_tiles():
    d = np.full((20, 20), 5.0, np.float32)
    d[3, 17] = L.OVERFLOW_DEPTH
    d[12, 2] = L.OVERFLOW_DEPTH
    assert L.overflow_tiles(d, 4, 0) == [((4, 8), (16, 20)), ((16, 24), (0, 8))]
