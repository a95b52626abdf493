"""The Gaussian modes' GPU tables (no Blender): pixel masks in exact float pieces, the tile lists
and records as the shaders fetch them, the tiles of overflowing rays."""
import numpy as np

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.gpu import tables_gauss as L
from kernels.render.scene.synthetic import gaussian_set


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
    g = decode(t["g_rec"], fr.gauss.rec.shape[0])
    rec = fr.gauss.rec
    np.testing.assert_allclose(g["mu"], rec[:, 0:3], rtol=1e-6)
    np.testing.assert_allclose(g["bound"], rec[:, 7], rtol=1e-6)
    np.testing.assert_allclose(g["w"], rec[:, 6], rtol=1e-6)
    np.testing.assert_allclose(g["iv"], rec[:, 3:6], rtol=2.0 ** -14)  # 13 mantissa bits, rounded
    assert L.unsupported(fr) is None


def decode(table, m):
    """The shader's gauss_at in numpy: (m,) fields of the first m Gaussians of a g_rec table."""
    w = table.reshape(-1, 4)[:2 * m].reshape(m, 8)
    x, y = w[:, 4].view(np.uint32), w[:, 5].view(np.uint32)
    code = (np.stack([x >> 16, x & 0xFFFF, y >> 16], -1) << 3) | (np.stack([y, y >> 3, y >> 6], -1) & 7)
    iv = ((code + (112 << 13)) << 10).astype(np.uint32).view(np.float32)
    return {"mu": w[:, 0:3], "bound": w[:, 3], "iv": iv, "w": w[:, 6], "val": w[:, 7],
            "has_val": ((y >> 13) & 1) == 1, "ob": (y >> 9) & 15, "words": w}


def test_gaussians_in_32_bytes():
    """Every per-Gaussian table the modes upload, counted: at most 32 bytes a Gaussian; the
    packed words are normal floats (no NaN, Inf or denormal a GPU could alter); values, NaN
    flags and objects read back."""
    rng = np.random.default_rng(2)
    n = 200
    vals = rng.uniform(0, 1, n)
    vals[::7] = np.nan
    a = gaussian_set(rng.uniform(0, 9, (n, 3)), rng.uniform(0.3, 3.0, (n, 3)), vals, 1.0)
    b = gaussian_set(rng.uniform(0, 9, (50, 3)), 0.7, np.zeros(50), 1.0)
    sc = RenderScene([RenderObject(a), RenderObject(b)], mode="particles")
    cam = Camera.frame_box([0] * 3, [9] * 3, 24, 24)
    tf = TransferFunction.from_colormap("viridis", 0, 1)
    assert L.bytes_per_gaussian() <= 32
    for mode in ("particles", "field", "paper"):
        sc.mode = mode
        fr = CPUDevice().begin_frame(sc, cam, tf)
        t = L.gpu_layout.MODE_TABLES[mode][1](fr).textures
        m = fr.gauss.rec.shape[0]
        assert [k for k in t if k.startswith("g_")] == list(L.GAUSS_COLUMNS)  # the Gaussians' tables
        texels = t["g_rec"].size // 4
        assert 2 * m <= texels < 2 * m + L.gpu_layout.ROW_TEXELS
        g = decode(t["g_rec"], m)
        f = np.abs(g["words"][:, 4:6])
        assert (np.isfinite(f) & (f >= np.finfo(np.float32).tiny)).all()
        assert (g["ob"] == fr.gauss.obj).all()
        nan = np.isnan(fr.gauss.val)
        assert nan.any() and (g["has_val"] == ~nan).all()
        np.testing.assert_array_equal(g["val"], np.where(nan, 0.0, fr.gauss.val).astype(np.float32))
        if mode == "paper":
            np.testing.assert_allclose(g["bound"], fr.gauss.w * fr.gauss.volfac, rtol=1e-6)


def test_sizes_beyond_the_size_codes_go_to_cpu():
    gs = gaussian_set([[1.0, 1.0, 1.0], [3.0, 3.0, 3.0]], [[0.5] * 3, [1e5] * 3], [0.5, 0.5], 1.0)
    sc = RenderScene([RenderObject(gs)], mode="particles")
    fr = CPUDevice().begin_frame(sc, Camera.frame_box([0] * 3, [4] * 3, 16, 16),
                                 TransferFunction.from_colormap("viridis", 0, 1))
    assert "size codes" in L.unsupported(fr)


def test_overflow_tiles():
    d = np.full((20, 20), 5.0, np.float32)
    d[3, 17] = L.OVERFLOW_DEPTH
    d[12, 2] = L.OVERFLOW_DEPTH
    assert L.overflow_tiles(d, 4, 0) == [((4, 8), (16, 20)), ((16, 24), (0, 8))]


def test_lit_particles_upload_their_centre_gradients():
    """Lit volumes in particles mode: the geometry tables hold each Gaussian's centre gradient and
    own field weight (Gaussians.grad, 16 bytes a Gaussian, texel g); unlit frames and field mode
    (which sums the gradient per sample) upload none, and lit frames stay on the GPU."""
    rng = np.random.default_rng(4)
    gs = gaussian_set(rng.uniform(0, 9, (300, 3)), 0.9, rng.uniform(0, 1, 300), 1.0)
    cam = Camera.frame_box([0] * 3, [9] * 3, 24, 24)
    tf = TransferFunction.from_colormap("viridis", 0, 1)
    for mode, shading in (("particles", "lit"), ("particles", "emission"), ("field", "lit")):
        sc = RenderScene([RenderObject(gs, shading=shading, shadows=True)], mode=mode)
        fr = CPUDevice().begin_frame(sc, cam, tf)
        geo = L.gpu_layout.MODE_TABLES[mode][0](fr).textures
        assert L.lit(fr) == (shading == "lit") and L.unsupported(fr) is None
        if mode == "particles" and shading == "lit":
            m = fr.gauss.rec.shape[0]
            assert fr.gauss.grad.shape == (m, 4) and np.abs(fr.gauss.grad[:, :3]).max() > 0
            np.testing.assert_array_equal(geo["g_grad"].reshape(-1, 4)[:m],
                                          fr.gauss.grad.astype(np.float32))
        else:
            assert "g_grad" not in geo
