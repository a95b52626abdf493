"""Particles mode: closed forms, invariances, determinism, extremes."""

import mpmath
import numpy as np
import pytest

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction, generate_rays
from kernels.render.scene.synthetic import gaussian_set
from tests.references import closed_form_alpha, quadrature_pixel

mpmath.mp.dps = 50


@pytest.fixture(scope="module")
def dev():
    return CPUDevice()


def _k():
    from kernels.render.cpu import pixels
    return pixels


def mp_line(o, d, t0, t1):
    o = [mpmath.mpf(x) for x in o]
    d = [mpmath.mpf(x) for x in d]
    def f(t):
        return mpmath.exp(-sum((o[k] + t * d[k]) ** 2 for k in range(3)) / 2)

    a = sum(x * x for x in d)
    ts = -sum(o[k] * d[k] for k in range(3)) / a
    pts = sorted({mpmath.mpf(t0), mpmath.mpf(t1), min(max(ts, t0), t1)})
    return float(mpmath.quad(f, pts))


def test_line_integral_vs_mpmath():
    k = _k()
    rng = np.random.default_rng(1)
    cases = [((0.3, -0.2, 0.1), (1.0, 0.0, 0.0), -5.0, 5.0),
             ((1e4, 0.3, 0.0), (-1.0, 0.0, 0.0), 1e4 - 2, 1e4 + 3),   # far origin (Qmin stable)
             ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 4.0, 6.0),            # same-sign tail
             ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), -6.0, -4.5),
             ((0.5, 0.5, 0.0), (0.0, 0.0, 1.0), 0.1, 0.1 + 1e-5),     # very short segment
             ((0.2, 0.0, 0.0), (3e3, 0.0, 0.0), -1e-3, 1e-3)]        # needle-like / stiff
    for _ in range(20):
        cases.append((tuple(rng.normal(size=3) * 2), tuple(rng.normal(size=3) * 3),
                      float(rng.uniform(-3, 0)), float(rng.uniform(0, 3))))
    for o, d, t0, t1 in cases:
        got = k.line_integral(*o, *d, t0, t1)
        ref = mp_line(o, d, t0, t1)
        assert abs(got - ref) <= 1e-12 + 1e-9 * abs(ref), (o, d, t0, t1, got, ref)


def test_erf_diff_tail_and_series():
    k = _k()
    for u0, u1 in [(5.0, 6.0), (-6.0, -5.0), (3.0, 3.001), (-0.004, 0.003), (8.0, 9.0)]:
        ref = float(mpmath.erf(u1) - mpmath.erf(u0))
        got = k.erf_diff(u0, u1)
        assert abs(got - ref) <= 1e-14 + 1e-10 * abs(ref), (u0, u1, got, ref)


def test_erf_table_matches_mpmath():
    """The tabulated erf the particles sweep uses: within a few ulps everywhere, exact limits."""
    from kernels.render.cpu import vecmath as m

    rng = np.random.default_rng(3)
    us = np.concatenate([rng.uniform(-6.5, 6.5, 3000), np.linspace(-6.1, 6.1, 977), [0.0, -0.0, 1 / 16, 5.999999]])
    for u in us:
        ref = float(mpmath.erf(u))
        assert abs(m.erf_fast(float(u)) - ref) <= 4e-16, (u, m.erf_fast(float(u)), ref)
    assert m.erf_fast(np.inf) == 1.0 and m.erf_fast(-np.inf) == -1.0
    assert np.isnan(m.erf_fast(np.nan))


def single_scene(center=(0, 0, 0), sigma=(1.5, 2.0, 1.0), amp=0.7, value=0.5, mw=None, **kw):
    gs = gaussian_set([center], [sigma], [value], [amp])
    return RenderScene([RenderObject(gs, np.eye(4) if mw is None else mw)], **kw)


def closed_form_image(cam, center, sigma, amp, density, color, mw=np.eye(4)):
    """Untruncated closed form: tau = density * amp * sqrt(2 pi / a) exp(-Qmin / 2)."""
    o, d = generate_rays(cam)
    w2i = np.linalg.inv(mw)
    oi = o @ w2i[:3, :3].T + w2i[:3, 3]
    di = d @ w2i[:3, :3].T
    wo = (oi - center) / sigma
    wd = di / sigma
    a = np.sum(wd * wd, 1)
    ts = -np.sum(wo * wd, 1) / a
    p = wo + ts[:, None] * wd
    q = np.sum(p * p, 1)
    tau = density * amp * np.sqrt(2 * np.pi / a) * np.exp(-q / 2)
    tau = np.where(ts > 0, tau, 0.0)  # the Gaussian is in front of every camera used here
    al = -np.expm1(-tau)
    img = np.concatenate([al[:, None] * np.asarray(color)[None], al[:, None]], 1)
    return img.reshape(cam.height, cam.width, 4)


@pytest.mark.parametrize("kind", ["ortho", "persp"])
def test_single_gaussian_vs_closed_form(dev, kind):
    c, s, amp, dens = np.array([0.3, -0.2, 0.1]), np.array([1.5, 2.0, 1.0]), 0.7, 0.8
    sc = single_scene(c, s, amp, support_k=9.0)
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.0, alpha="constant", density=dens)
    cam = Camera.frame_box([-6] * 3, [6] * 3, 24, 20, direction=(1, 0.6, -0.4), kind=kind)
    img = dev.render(sc, cam, tf)["Combined"]
    ref = closed_form_image(cam, c, s, amp, dens, tf(0.5)[:3])
    assert ref[..., 3].max() > 0.5
    np.testing.assert_allclose(img, ref, atol=2e-6)


@pytest.mark.parametrize("tau_max", [0.1, 1e9])
def test_separate_supports_composite_exactly(dev, tau_max):
    """Gaussians one behind the other with gaps between their supports: each is its own cluster,
    composited in closed form front to back, whatever tau_max (a merged cluster would mix colours)."""
    cs = np.array([[0, 0, 0], [0.3, 0, 7], [-0.2, 0.1, 14], [0, 0.2, 21]], float)
    vals = np.array([0.1, 0.9, 0.4, 0.7])
    tf = TransferFunction.from_colormap("jet", 0, 1, alpha="constant", density=0.6)
    cam = Camera.frame_box([-1.5, -1.5, -4], [1.5, 1.5, 25], 5, 5, direction=(0, 0, -1), kind="ortho")
    sc = RenderScene([RenderObject(gaussian_set(cs, 1.0, vals, 1.0))], tau_max=tau_max,
                     transmittance_min=0.0)
    img = dev.render(sc, cam, tf)["Combined"]
    ref = np.zeros_like(img, dtype=np.float64)
    T = np.ones(img.shape[:2])
    for i in np.argsort(-cs[:, 2]):  # the camera looks down z: the highest first
        al = closed_form_alpha(cam, gaussian_set(cs[i:i + 1], 1.0, vals[i:i + 1], 1.0), np.eye(4), 0.6)
        ref[..., :3] += (T * al)[..., None] * tf(vals[i])[:3]
        T *= 1 - al
    ref[..., 3] = 1 - T
    assert ref[..., 3].max() > 0.5
    np.testing.assert_allclose(img, ref, atol=2e-6)


def test_truncation_loss_is_bounded(dev):
    """support_k = 3 loses at most erfc(3/sqrt 2) = 0.27% of a chord's optical depth."""
    c, s = np.zeros(3), np.array([1.0, 1.0, 1.0])
    tf = TransferFunction.from_colormap("grayscale", 0, 1, alpha="constant", density=0.05)
    cam = Camera.frame_box([-4] * 3, [4] * 3, 9, 9, direction=(0, 0, -1), kind="ortho")
    img = dev.render(single_scene(c, s, 1.0, support_k=3.0), cam, tf)["Combined"]
    ref = closed_form_image(cam, c, s, 1.0, 0.05, [1, 1, 1])
    mid = img[4, 4, 3]
    assert 0.0 < ref[4, 4, 3] - mid <= 0.0028 * ref[4, 4, 3]


def test_translation_1e6_voxels_invariant(dev):
    tf = TransferFunction.from_colormap("plasma", 0, 1, density=0.6)
    cs = np.array([[0, 0, 0], [2.5, 1, 0], [-1, 3, 2], [1, -2, -1.5]], float)
    vals = [0.2, 0.9, 0.5, 0.7]
    base = RenderScene([RenderObject(gaussian_set(cs, 1.3, vals))])
    cam = Camera.frame_box([-6] * 3, [6] * 3, 24, 24, direction=(1, 0.3, -0.7))
    ref = dev.render(base, cam, tf)["Combined"]
    assert ref[..., 3].max() > 0.3
    # (a) Gaussians 1e6 voxels away in index space, matrix_world brings them back
    shift = np.array([1e6, -1e6, 1e6])
    m = np.eye(4)
    m[:3, 3] = -shift
    far_idx = RenderScene([RenderObject(gaussian_set(cs + shift, 1.3, vals), m)])
    np.testing.assert_allclose(dev.render(far_idx, cam, tf)["Combined"], ref, atol=1e-4)
    # (b) object and camera both moved 1e6 voxels in the world (voxel size 0.5)
    vs = 0.5
    m2 = np.diag([vs, vs, vs, 1.0])
    m2[:3, 3] = [1e6 * vs, 2e6 * vs, -1e6 * vs]
    tf2 = TransferFunction(tf.lut, tf.vmin, tf.vmax, density=tf.density / vs)
    sc = RenderScene([RenderObject(gaussian_set(cs, 1.3, vals), m2)])
    cam2 = Camera(cam.cam_to_world.copy(), 24, 24, "persp", fov_x=cam.fov_x)
    cam2.cam_to_world[:3, 3] = cam.cam_to_world[:3, 3] * vs + m2[:3, 3]
    np.testing.assert_allclose(dev.render(sc, cam2, tf2)["Combined"], ref, atol=1e-4)


@pytest.mark.parametrize("s", [1e-3, 7.0, 1e3])
def test_world_scaling_invariant(dev, s):
    """Scaling the world by s (anisotropic, rotated object matrix) and the density by 1/s."""
    tf = TransferFunction.from_colormap("magma", 0, 1, density=0.9)
    cs = np.array([[0, 0, 0], [1.5, 0.5, 0], [0.5, 2, 1]], float)
    rot = np.array([[0.8, -0.6, 0], [0.6, 0.8, 0], [0, 0, 1.0]]) @ np.diag([1.0, 2.0, 0.5])
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = [3, -1, 2]
    gs = gaussian_set(cs, [1.0, 0.7, 1.6], [0.3, 0.8, 0.6])
    cam = Camera.frame_box([-2, -4, 0], [8, 4, 5], 20, 16, direction=(-0.3, 1, -0.5))
    ref = dev.render(RenderScene([RenderObject(gs, m)]), cam, tf)["Combined"]
    S = np.diag([s, s, s, 1.0])
    cam_s = Camera(S @ cam.cam_to_world, 20, 16, "persp", fov_x=cam.fov_x)
    tf_s = TransferFunction(tf.lut, 0, 1, density=0.9 / s)
    img = dev.render(RenderScene([RenderObject(gs, S @ m)]), cam_s, tf_s)["Combined"]
    assert ref[..., 3].max() > 0.2
    np.testing.assert_allclose(img, ref, atol=1e-5)


def lattice(n=6, pitch=2.0, sigma=1.2, seed=0):
    rng = np.random.default_rng(seed)
    g = np.arange(n) * pitch
    cs = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return cs, sigma, rng.uniform(0, 1, len(cs))


def test_thread_count_bitwise_deterministic(dev):
    cs, s, v = lattice()
    tf = TransferFunction.from_colormap("turbo", 0, 1, density=0.7)
    cam = Camera.frame_box(cs.min(0) - 3, cs.max(0) + 3, 32, 24, direction=(1, 0.7, -0.4))
    sc = RenderScene([RenderObject(gaussian_set(cs, s, v))], threads=1)
    a = dev.render(sc, cam, tf)
    sc.threads = 2
    b = dev.render(sc, cam, tf)
    assert a["Combined"][..., 3].max() > 0.3
    for k in a:
        assert np.array_equal(a[k], b[k]), k


@pytest.mark.parametrize("view", [(0.0, 0.0, -1.0), (1.0, 0.7, -0.4)])
def test_overlapping_mixture_vs_brute_force(dev, view):
    """Halo lists + (t, id) event sweep + tau subdivision vs quadrature; an axis-aligned
    orthographic view of a lattice has exact event ties."""
    cs, s, v = lattice(4, 2.0, 1.3)
    tf = TransferFunction.from_colormap("jet", 0, 1, density=0.5)
    cam = Camera.frame_box(cs.min(0) - 3, cs.max(0) + 3, 7, 5, direction=view, kind="ortho")
    sc = RenderScene([RenderObject(gaussian_set(cs, s, v))], tau_max=0.02, transmittance_min=0.0)
    img = dev.render(sc, cam, tf)["Combined"].reshape(-1, 4)
    o, d = generate_rays(cam)
    rgba = tf(v)
    kap, col = 0.5 * rgba[:, 3], rgba[:, :3]
    for p in [0, 8, 17, 23, 34]:
        ref = quadrature_pixel(o[p], d[p], cs, s, kap, col, 5.0, 45.0)
        np.testing.assert_allclose(img[p], ref, atol=2e-4, err_msg=str(p))
    assert img[17, 3] > 0.5


def test_rebucketing_leaves_same_image(dev):
    """Shifting the index grid by a non-multiple of the leaf size changes every leaf/halo list."""
    cs, s, v = lattice(5, 1.7, 1.1, seed=3)
    tf = TransferFunction.from_colormap("viridis", 0, 1, density=1.1)
    cam = Camera.frame_box(cs.min(0) - 3, cs.max(0) + 3, 20, 20, direction=(0.2, 1, -0.3))
    ref = dev.render(RenderScene([RenderObject(gaussian_set(cs, s, v))], tau_max=0.01), cam, tf)["Combined"]
    for sh in ([3, 5, 1], [-4, 0, 7]):
        m = np.eye(4)
        m[:3, 3] = -np.array(sh, float)
        img = dev.render(RenderScene([RenderObject(gaussian_set(cs + sh, s, v), m)], tau_max=0.01),
                         cam, tf)["Combined"]
        # exact up to the mixed-colour subdivision (tau x spread <= tau_max), whose cuts follow
        # the leaves; the leaf/halo lists themselves lose nothing
        np.testing.assert_allclose(img, ref, atol=2e-4)


def test_huge_and_tiny_density(dev):
    c = np.zeros(3)
    cam = Camera.frame_box([-3] * 3, [3] * 3, 9, 9, direction=(0, 0, -1), kind="ortho")
    sc = single_scene(c, (1, 1, 1), 1.0, value=0.8, background=(0, 0, 0, 0))
    big = TransferFunction.from_colormap("viridis", 0, 1, alpha="constant", density=1e6)
    img = dev.render(sc, cam, big)["Combined"]
    col = big(0.8)[:3]
    assert abs(img[4, 4, 3] - 1.0) < 1e-6
    np.testing.assert_allclose(img[4, 4, :3], col, rtol=1e-6)
    assert np.all(img[..., :3] <= col.max() + 1e-7)
    tiny = TransferFunction.from_colormap("viridis", 0, 1, alpha="constant", density=1e-12)
    img = dev.render(sc, cam, tiny)["Combined"]
    ref = closed_form_image(cam, c, np.ones(3), 1.0, 1e-12, col)
    np.testing.assert_allclose(img[4, 4], ref[4, 4], rtol=3e-3)  # k = 3 truncation only
    assert 0 < img[4, 4, 3] < 1e-11


def test_rays_missing_box_give_background(dev):
    sc = single_scene((0, 0, 0), (1, 1, 1), 1.0, background=(0.2, 0.4, 0.6, 0.5))
    tf = TransferFunction.from_colormap("viridis", 0, 1, density=1.0)
    m = np.eye(4)
    m[:3, 3] = [100.0, 0, 5]  # looking away from the Gaussian, and parallel to axes
    for kind in ("persp", "ortho"):
        cam = Camera(m, 8, 6, kind, ortho_scale=3.0)
        out = dev.render(sc, cam, tf)
        np.testing.assert_allclose(out["Combined"], np.tile([0.1, 0.2, 0.3, 0.5], (6, 8, 1)), atol=1e-7)
        assert np.all(out["Depth"] == 1e10) and np.all(out["Value"] == 0)


def test_early_termination(dev):
    cs, s, v = lattice(6, 1.5, 1.0)
    tf = TransferFunction.from_colormap("inferno", 0, 1, alpha="constant", density=3.0)
    cam = Camera.frame_box(cs.min(0) - 2, cs.max(0) + 2, 16, 16, direction=(1, 1, -1))
    sc = RenderScene([RenderObject(gaussian_set(cs, s, v))], transmittance_min=0.0)
    full = dev.render(sc, cam, tf)["Combined"]
    segs_full = dev.stats["segments"]
    sc.transmittance_min = 1e-3
    early = dev.render(sc, cam, tf)["Combined"]
    assert dev.stats["segments"] < segs_full
    d = np.abs(full - early).max()
    assert 0 < d < 1e-3


def test_values_depth_passes(dev):
    sc = single_scene((0, 0, 0), (1, 1, 1), 1.0, value=0.25)
    tf = TransferFunction.from_colormap("viridis", 0, 1, alpha="constant", density=5.0)
    m = np.eye(4)
    m[:3, 3] = [0, 0, 10]
    cam = Camera(m, 5, 5, "ortho", ortho_scale=1.0)
    out = dev.render(sc, cam, tf)
    assert abs(out["Value"][2, 2] - 0.25) < 1e-6
    # T = 0.5 where the optical depth from the front reaches ln 2 (closed form, k = 3 support)
    from math import erf, log, sqrt
    tot = 5.0 * sqrt(2 * np.pi) * erf(3 / sqrt(2))
    target = log(2.0)
    lo, hi = -3.0, 3.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if 5.0 * sqrt(np.pi / 2) * (erf(3 / sqrt(2)) - erf(mid / sqrt(2))) < target:
            hi = mid
        else:
            lo = mid
    assert tot > target
    assert abs(out["Depth"][2, 2] - (10.0 - 0.5 * (lo + hi))) < 1e-5


@pytest.mark.parametrize("mode", ["particles", "field"])
def test_ray_through_more_gaussians_than_scratch(dev, mode):
    """700 Gaussians on one line: rays along it meet more than the kernels' initial per-ray scratch
    (256 hits), which grows and retraces; alpha still matches the closed form (particles) and the
    field render stays deterministic and finite."""
    n = 700
    c = np.zeros((n, 3))
    c[:, 2] = np.arange(n) * 0.4
    gs = gaussian_set(c, [0.5, 0.5, 0.5], np.full(n, 0.5), np.full(n, 0.002))
    sc = RenderScene([RenderObject(gs, np.eye(4))], mode=mode, transmittance_min=0.0)
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.0, alpha="constant", density=1.0)
    cam = Camera.frame_box([-1.5, -1.5, -1], [1.5, 1.5, n * 0.4], 7, 7, direction=(0.0, 0.001, -1.0),
                           kind="ortho")
    o, d = generate_rays(cam)
    mid = (cam.height // 2) * cam.width + cam.width // 2
    w = c - o[mid]
    dist2 = np.sum(w * w, 1) - (w @ d[mid]) ** 2
    assert np.sum(dist2 < (3 * 0.5) ** 2) > 256  # the central ray really overflows the scratch
    img = dev.render(sc, cam, tf)["Combined"]
    assert np.all(np.isfinite(img)) and img[..., 3].max() > 0.5
    if mode == "particles":
        np.testing.assert_allclose(img[..., 3], closed_form_alpha(cam, gs, np.eye(4), 1.0), atol=1e-6)
    else:
        np.testing.assert_array_equal(img, dev.render(sc, cam, tf)["Combined"])
