"""Lit volumes (RenderObject.shading='lit'): Blinn-Phong on the field's gradient against a numpy
quadrature (the gradient there by finite differences of the mixture), the gradient threshold,
and shadows against the blocker's transmittance."""
import numpy as np
import pytest

from kernels.lod import build_lod
from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.camera import generate_rays
from kernels.render.scene.lights import Light
from kernels.render.scene.synthetic import gaussian_set, grid_from_dense

SUN = Light("sun", (1.0, -0.6, -0.8), (1.0, 0.9, 0.7), 1.5)
SHADING = (0.1, 0.8, 0.3, 16.0)
K = 3.0  # the support radius in sigmas (RenderScene.support_k)

MU = np.array([[0.0, 0.0, 0.0], [3.0, 1.0, -1.0], [-2.0, 2.5, 1.5]])
SIG = np.array([[3.0, 2.5, 3.5], [2.0, 2.0, 2.0], [2.5, 3.0, 2.0]])
W = np.array([1.0, 0.6, 0.5])


def mixture(x, mu, sig, w, truncate=True):
    """The Gaussian mixture at points x (n, 3), truncated at K sigmas as the kernels are."""
    u = (x[:, None, :] - mu[None]) / sig[None]
    q = (u * u).sum(-1)
    e = w[None] * np.exp(-0.5 * q)
    if truncate:
        e = np.where(q < K * K, e, 0.0)
    return e.sum(1)


def fd_gradient(x, mu, sig, w, h=1e-4):
    """Central finite differences of the (untruncated) mixture."""
    g = np.zeros_like(x)
    for c in range(3):
        d = np.zeros(3)
        d[c] = h
        g[:, c] = (mixture(x + d, mu, sig, w, False) - mixture(x - d, mu, sig, w, False)) / (2 * h)
    return g


def blinn_phong(c, grad, d, light, shading, thr):
    """The lit colour of samples c (n, 3) with field gradients grad on rays of direction d."""
    ka, kd, ks, sh = shading
    gm = np.linalg.norm(grad, axis=1)
    n = -grad / np.maximum(gm, 1e-300)[:, None]
    lv = -np.asarray(light.vector, float)
    lv /= np.linalg.norm(lv)
    e = np.asarray(light.color, float) * light.strength
    ndl = n @ lv
    hv = lv - d
    hv /= np.linalg.norm(hv)
    spec = np.where(ndl > 0, ks * np.maximum(n @ hv, 0.0) ** sh, 0.0)
    lit = ka * c + e[None] * (kd * np.maximum(ndl, 0.0)[:, None] * c + spec[:, None])
    return np.where((gm > thr)[:, None], lit, c)


def quadrature(cam, tf, mu, sig, w, light, shading, thr, dt=0.01):
    """Emission-absorption along every pixel ray with lit colours, by fine midpoint steps."""
    o, d = generate_rays(cam)
    out = np.zeros((o.shape[0], 3))
    reach = np.linalg.norm(mu, axis=1).max() + K * sig.max()
    cdist = np.linalg.norm(o[0])
    t = np.arange(cdist - reach, cdist + reach, dt) + 0.5 * dt
    for p in range(o.shape[0]):
        x = o[p] + t[:, None] * d[p]
        s = mixture(x, mu, sig, w)
        rgba = tf(s)
        sigma = tf.density * rgba[:, 3]
        c = blinn_phong(rgba[:, :3], fd_gradient(x, mu, sig, w), d[p], light, shading, thr)
        a = 1.0 - np.exp(-sigma * dt)
        T = np.concatenate([[1.0], np.cumprod(1.0 - a)[:-1]])
        out[p] = ((T * a)[:, None] * c).sum(0)
    return out.reshape(cam.height, cam.width, 3)


def render(dev, objs, mode, cam, tf, **kw):
    scene = RenderScene(objs, mode=mode, passes=(), **kw)
    return dev.render(scene, cam, tf)["Combined"].astype(np.float64)


@pytest.fixture(scope="module")
def dev():
    """The device under test (tests/blender/test_gpu_twins.py runs these tests on the GPU's)."""
    return CPUDevice()


@pytest.fixture(scope="module")
def blob():
    cam = Camera.frame_box([-8.0] * 3, [8.0] * 3, 20, 20, direction=(0.3, 1.0, -0.2))
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.2, density=0.4)
    return cam, tf


@pytest.mark.parametrize("n", [1, 3], ids=["one-gaussian", "mixture"])
def test_lit_field_matches_quadrature(dev, blob, n):
    """A sun lights one Gaussian (and a mixture of three): the field mode's lit image matches the
    numerical integral along each ray with the normal from finite differences of the mixture (so
    the kernels' analytic gradient is the mixture's)."""
    cam, tf = blob
    mu, sig, w = MU[:n], SIG[:n], W[:n]
    gs = gaussian_set(mu, sig, w)
    obj = RenderObject(gs, shading="lit")
    img = render(dev, [obj], "field", cam, tf, lights=(SUN,), shading=SHADING, lit_threshold=0.0)
    ref = quadrature(cam, tf, mu, sig, w, SUN, SHADING, 0.0)
    unlit = render(dev, [RenderObject(gs)], "field", cam, tf, lights=(SUN,), shading=SHADING)
    scale = ref.max()
    err = np.abs(img[..., :3] - ref).max() / scale
    assert err < 0.01, err
    # the lighting is what the comparison sees: the unlit image is far from the reference
    assert np.abs(unlit[..., :3] - ref).max() / scale > 0.1


def test_particles_lit_one_gaussian(dev, blob):
    """Particles mode shades a lit volume's chord once, at its closest approach to the Gaussian's
    centre, on the mixture's gradient there (here the Gaussian's own): with no overlap the pixel is
    alpha x Blinn-Phong(colour, gradient at that point), alpha unchanged."""
    cam, tf = blob
    mu, sig, w = MU[:1], SIG[:1], W[:1]
    gs = gaussian_set(mu, sig, w)
    kw = dict(lights=(SUN,), shading=SHADING, lit_threshold=0.0)
    lit = render(dev, [RenderObject(gs, shading="lit")], "particles", cam, tf, **kw)
    emit = render(dev, [RenderObject(gs)], "particles", cam, tf, **kw)
    np.testing.assert_array_equal(lit[..., 3], emit[..., 3])
    o, d = generate_rays(cam)
    u, v = (o - mu) / sig, d / sig
    ts = -(u * v).sum(1) / (v * v).sum(1)
    p = o + ts[:, None] * d
    x = (p - mu) / sig
    grad = -w[0] * np.exp(-0.5 * (x * x).sum(1))[:, None] * x / sig
    a = emit[..., 3].reshape(-1)
    hit = a > 1e-3
    c = emit[..., :3].reshape(-1, 3)[hit] / a[hit, None]
    want = a[hit, None] * np.concatenate([blinn_phong(c[i:i + 1], gi[None], di, SUN, SHADING, 0.0)
                                          for i, (gi, di) in enumerate(zip(grad[hit], d[hit]))])
    got = lit[..., :3].reshape(-1, 3)[hit]
    tol = getattr(dev, "arith_tol", 1e-6)  # float64 arithmetic, float32 out; the GPU's float32 arithmetic
    assert np.abs(got - want).max() < tol * max(1.0, want.max()), np.abs(got - want).max()
    assert np.abs(got - emit[..., :3].reshape(-1, 3)[hit]).max() > 0.05 * want.max()  # it is lit


def test_lit_gradients_are_the_other_gaussians_field():
    """Gaussians.grad: at each centre, the gradient of the other Gaussians' field (against finite
    differences) and the Gaussian's own weight; objects do not see each other."""
    from kernels.render.cpu.lit import lit_gradients

    rng = np.random.default_rng(3)
    mu = rng.uniform(-6, 18, (40, 3))
    sig = rng.uniform(0.8, 3.0, (40, 3))
    fw = rng.uniform(0.2, 1.0, 40)
    first = np.array([0, 25, 40])
    got = lit_gradients(mu, 1.0 / sig, fw, first, 8.0)  # 8 sigma: truncation below 1e-13
    for a, b in zip(first[:-1], first[1:]):
        for g in range(a, b):
            others = [j for j in range(a, b) if j != g]
            want = fd_gradient(mu[g:g + 1], mu[others], sig[others], fw[others], h=1e-5)[0]
            np.testing.assert_allclose(got[g, :3], want, atol=1e-7 * max(1.0, np.abs(want).max()))
    np.testing.assert_array_equal(got[:, 3], fw)


def test_particles_lit_close_to_field_lit(dev):
    """On a smooth fog volume at Medium, lit particles stay close to lit field mode (both shade on
    the mixture's gradient): far closer than the unlit particles image is."""
    g = np.arange(24)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    dense = np.exp(-((X - 11.5) ** 2 + (Y - 12.0) ** 2 + (Z - 11.0) ** 2) / 40.0).astype(np.float32)
    grid = grid_from_dense(dense, active=dense > 0.05)
    gs = build_lod(grid, "medium")
    cam = Camera.frame_box([0.0] * 3, [24.0] * 3, 40, 40, direction=(0.3, 1.0, -0.2))
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.0, density=0.3)
    kw = dict(lights=(SUN,), shading=SHADING)
    field = render(dev, [RenderObject(gs, shading="lit")], "field", cam, tf, **kw)
    lit = render(dev, [RenderObject(gs, shading="lit")], "particles", cam, tf, **kw)
    emit = render(dev, [RenderObject(gs)], "particles", cam, tf, **kw)
    e_lit = np.abs(lit[..., :3] - field[..., :3]).mean()
    e_emit = np.abs(emit[..., :3] - field[..., :3]).mean()
    print("lit particles vs lit field", e_lit, "unlit", e_emit)
    assert e_lit < 0.35 * e_emit, (e_lit, e_emit)


def test_threshold_leaves_homogeneous_regions_unlit(dev, blob):
    """Pixels whose ray meets no sample with a gradient above the threshold are bit-identical to
    the emission image; those that meet gradients well above it differ."""
    cam, tf = blob
    mu, sig, w = MU[:1], np.full((1, 3), 3.0), W[:1]
    gs = gaussian_set(mu, sig, w)
    frac = 0.05
    thr = frac * (tf.vmax - tf.vmin)
    kw = dict(lights=(SUN,), shading=SHADING, lit_threshold=frac)
    lit = render(dev, [RenderObject(gs, shading="lit")], "field", cam, tf, **kw)
    emi = render(dev, [RenderObject(gs)], "field", cam, tf, **kw)
    o, d = generate_rays(cam)
    t = np.linspace(np.linalg.norm(o[0]) - 12, np.linalg.norm(o[0]) + 12, 4001)
    gmax = np.zeros(o.shape[0])
    for p in range(o.shape[0]):
        x = o[p] + t[:, None] * d[p]
        inside = (((x - mu[0]) / sig[0]) ** 2).sum(1) < K * K
        g = np.linalg.norm(fd_gradient(x, mu, sig, w), axis=1)
        gmax[p] = g[inside].max() if inside.any() else 0.0
    gmax = gmax.reshape(cam.height, cam.width)
    same = np.all(lit == emi, axis=-1)
    low, high = gmax < 0.8 * thr, gmax > 1.25 * thr
    assert low.sum() > 20 and high.sum() > 20
    assert same[low].all()
    assert not same[high].any()
    # a threshold nothing reaches: the lit image is the emission image
    kw["lit_threshold"] = 1e9
    assert np.array_equal(render(dev, [RenderObject(gs, shading="lit")], "field", cam, tf, **kw), emi)


def ball_grid(n=16, s=2.5):
    x = np.arange(n) - (n - 1) / 2
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return grid_from_dense(np.exp(-(X * X + Y * Y + Z * Z) / (2 * s * s)))


def placed(m_shift):
    m = np.eye(4)
    m[:3, 3] = m_shift
    return m


def shadow_ratio(dev, mode, receiver, blocker, density, cam):
    """Receiver pixels' brightness with the blocker at `density` over that with it at 0 (ambient
    and specular off, every sample lit: the ratio is the blocker's transmittance)."""
    tf = TransferFunction.from_colormap("grayscale", 0.0, 1.0, density=0.5)
    black = np.zeros((256, 4))
    black[:, 3] = np.linspace(0.0, 1.0, 256)
    imgs = []
    for dens in (0.0, density):
        btf = TransferFunction(black, 0.0, 1.0, density=dens)
        objs = [RenderObject(*receiver, shading="lit", shadows=True),
                RenderObject(*blocker, tf=btf)]
        imgs.append(render(dev, objs, mode, cam, tf, lights=(Light("sun", (-1.0, 0.0, 0.0)),),
                           shading=(0.0, 1.0, 0.0, 1.0), lit_threshold=0.0))
    a, b = imgs[0][..., 0], imgs[1][..., 0]
    sel = a > 0.05 * a.max()
    assert sel.sum() > 30
    return b[sel] / a[sel]


def test_shadows_reference_slab(dev):
    """Reference mode: a 4-voxel slab of extinction D between the sun and a lit ball darkens every
    lit pixel by exp(-4 D) (the slab is off the camera's view)."""
    g = ball_grid()
    slab = grid_from_dense(np.ones((4, 56, 56)))
    receiver = (build_lod(g, "low"), placed((-7.5, -7.5, -7.5)), g)
    blocker = (build_lod(slab, "low"), placed((30.0, -28.0, -28.0)), slab)
    cam = Camera.frame_box([-5.0] * 3, [5.0] * 3, 24, 24, direction=(0.0, 1.0, 0.0))
    r = shadow_ratio(dev, "reference", receiver, blocker, 0.3, cam)
    np.testing.assert_allclose(r, np.exp(-4 * 0.3), rtol=0.02)


def test_shadows_field_gaussian(dev):
    """Field mode: a wide Gaussian blocker (sigma 10, extinction D at its centre) between the sun
    and a small lit Gaussian: the shadow ray's optical depth is D sqrt(2 pi) 10 exp(-b^2 / 200)
    (b: the ray's distance from the blocker's centre, at most ~5 voxels here)."""
    recv = (gaussian_set([[0.0, 0.0, 0.0]], 1.5, [1.0]), np.eye(4))
    blk = (gaussian_set([[0.0, 0.0, 0.0]], 10.0, [1.0]), placed((45.0, 0.0, 0.0)))
    cam = Camera.frame_box([-3.0] * 3, [3.0] * 3, 24, 24, direction=(0.0, 1.0, 0.0))
    dens = 0.04
    tau0 = dens * np.sqrt(2 * np.pi) * 10.0 * 0.9973  # the support cuts at 3 sigma
    r = shadow_ratio(dev, "field", recv, blk, dens, cam)
    assert r.min() > np.exp(-tau0) * 0.98 and r.max() < np.exp(-tau0 * np.exp(-25 / 200)) * 1.02


def test_switching_shading_on_one_device_redraws_the_frame():
    """Lit and shadows are part of the frame's state: the same device, camera and geometry with
    the shading switched draws the new shading (not the kept frame)."""
    v = np.zeros((24, 24, 24))
    v[4:20, 4:20, 4:20] = 0.8
    grid = grid_from_dense(v, active=v > 0)
    cam = Camera.frame_box([0] * 3, [24] * 3, 24, 24)
    tf = TransferFunction.from_colormap("viridis", 0, 1, density=0.5)
    dev = CPUDevice()
    images = [dev.render(RenderScene([RenderObject(grid=grid, shading=s, shadows=sh)], mode="reference",
                                     lights=(SUN,)), cam, tf)["Combined"]
              for s, sh in (("emission", False), ("lit", False), ("lit", True))]
    assert np.abs(images[1] - images[0]).max() > 0.01
    assert np.abs(images[2] - images[1]).max() > 0.01
