"""Issue 8, kernels: numerical stability on stiff and extreme cases against independent references
(mpmath at 50 digits for line integrals, float64 numpy closed forms / brute-force quadrature for
images). Complements test_render_particles.py (which covers the basic closed forms, 1e6 translation,
world scaling in particles mode, re-bucketing and the single-Gaussian huge/tiny density).

Each ``case_*`` function returns (worst error, reference, tolerance); the tests call them on small
inputs, ``benchmarks/bench_stability.py`` on larger sweeps and prints the table."""
import math

import mpmath
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.synthetic import gaussian_set
from tests.references import closed_form_alpha, quadrature_pixel

mpmath.mp.dps = 50
HYP = settings(max_examples=60, deadline=None, derandomize=True)


def _k():
    from kernels.render.cpu import pixels
    return pixels


_DEV = {}


def dev():
    if "d" not in _DEV:
        _DEV["d"] = CPUDevice()
    return _DEV["d"]


# -- references ------------------------------------------------------------------------------------
def mp_erf_diff(u0, u1):
    """erf(u1) - erf(u0) in mpmath (50 digits), through erfc on each side of zero: erf values near
    +-1 would cancel all their digits in the far tails."""
    u0, u1 = mpmath.mpf(float(u0)), mpmath.mpf(float(u1))
    if u0 >= 0:
        return mpmath.erfc(u0) - mpmath.erfc(u1)
    if u1 <= 0:
        return mpmath.erfc(-u1) - mpmath.erfc(-u0)
    return mpmath.erf(u1) - mpmath.erf(u0)


def mp_line_closed(o, d, t0, t1):
    """The line integral of exp(-|o + t d|^2 / 2) over [t0, t1], in 50-digit mpmath (inputs taken
    exactly from their float64 values)."""
    o = [mpmath.mpf(float(x)) for x in o]
    d = [mpmath.mpf(float(x)) for x in d]
    a = sum(x * x for x in d)
    ts = -sum(o[k] * d[k] for k in range(3)) / a
    q = sum((o[k] + ts * d[k]) ** 2 for k in range(3))
    sa = mpmath.sqrt(a / 2)
    u0 = sa * (mpmath.mpf(float(t0)) - ts)
    u1 = sa * (mpmath.mpf(float(t1)) - ts)
    if u0 >= 0:
        e = mpmath.erfc(u0) - mpmath.erfc(u1)
    elif u1 <= 0:
        e = mpmath.erfc(-u1) - mpmath.erfc(-u0)
    else:
        e = mpmath.erf(u1) - mpmath.erf(u0)
    return mpmath.exp(-q / 2) * mpmath.sqrt(mpmath.pi / (2 * a)) * e


def rel_err(got, ref):
    ref = mpmath.mpf(ref)
    if ref == 0:
        return abs(got)
    return float(abs((mpmath.mpf(float(got)) - ref) / ref)) if abs(ref) > mpmath.mpf("1e-300") else \
        (0.0 if abs(got) < 1e-300 else 1.0)


def whiten(center, sigma, o, d):
    c, s = np.asarray(center, float), np.asarray(sigma, float)
    return (np.asarray(o, float) - c) / s, np.asarray(d, float) / s


def const_tf(density, color=(0.3, 0.7, 0.2)):
    return TransferFunction(np.tile(np.array([*color, 1.0], np.float32), (256, 1)), 0, 1, density=density)


def lattice(n, pitch, origin=(0, 0, 0)):
    g = np.arange(n) * pitch
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) + np.asarray(origin, float)


# -- cases -------------------------------------------------------------------------------------------
def case_line_integrals(n_random=40, seed=0, short_h=(1e-6, 1e-4, 9.9e-3, 1.01e-2), stiff=True):
    """Stiff line integrals vs mpmath: tiny sigma (fixed weight / fixed mass is a constant factor, so
    the integral itself is what matters), anisotropy 1e3-1e4 along the thin axis and grazing,
    closest point at t = 0, very short segments, off-centre tails. Returns worst relative error."""
    k = _k()
    rng = np.random.default_rng(seed)
    cases = []
    for s in ((1e-3, 1e-6) if stiff else ()):
        for off in (0.0, 0.3 * s, 2.0 * s, 7.0 * s):  # through and off centre
            cases.append(((0.1, off, 0.0), (s, s, s), (-5.0, 0.0, 0.0), (1.0, 0.0, 0.0), 4.0, 6.0))
            cases.append(((0.1, off, 0.0), (s, s, s), (-5.0, 0.0, 0.0), (1.0, 0.0, 0.0), 5.1 - 3 * s, 5.1 + 0.5 * s))
    for an in ((1e3, 1e4) if stiff else ()):
        sig = (1.0, 1.0, 1.0 / an)  # a sheet, thin along z
        cases.append(((0, 0, 0), sig, (0.2, -0.3, -4.0), (0.0, 0.0, 1.0), 0.0, 8.0))          # along thin axis
        cases.append(((0, 0, 0), sig, (-4.0, 0.1, 0.5 / an), (1.0, 0.0, 1e-5), 0.0, 8.0))     # grazing
        cases.append(((0, 0, 0), sig, (-4.0, 0.1, 0.0), (1.0, 0.0, 1.0 / an), 0.0, 8.0))      # oblique
        sig = (1.0 / an, 1.0 / an, 1.0)  # a needle along z
        cases.append(((0, 0, 0), sig, (0.3 / an, 0.0, -4.0), (0.0, 0.0, 1.0), 0.0, 8.0))     # along the needle
        cases.append(((0, 0, 0), sig, (-1.0, 0.2 / an, 0.3), (1.0, 0.0, 0.0), 0.0, 2.0))     # across
    for m in ((0.0, 0.5, 2.0, 4.0) if stiff else ()):  # closest point at t = 0: segments ending / starting there
        cases.append(((0, 0, 0), (1, 1, 1), (0.0, m, 0.0), (1.0, 0.0, 0.0), -3.0, 0.0))
        cases.append(((0, 0, 0), (1, 1, 1), (0.0, m, 0.0), (1.0, 0.0, 0.0), 0.0, 3.0))
        cases.append(((0, 0, 0), (1, 1, 1), (0.0, m, 0.0), (1.0, 0.0, 0.0), -1e-9, 1e-9))
    for h in short_h:  # very short segments (in sigmas), both sides of the series cut at 1e-2
        for tm in (-4.0, -1.0, 0.0, 0.7, 3.0):
            cases.append(((0, 0, 0), (1, 1, 1), (0.0, 0.2, 0.1), (1.0, 0.0, 0.0), tm - h / 2, tm + h / 2))
    for x0 in ((1e2, 1e4, 1e5) if stiff else ()):  # far ray origin (Qmin from the closest point, not c - b^2/a)
        cases.append(((0, 0, 0), (1, 1, 1), (-x0, 0.3, 0.0), (1.0, 0.0, 0.0), x0 - 2, x0 + 3))
    for _ in range(n_random):
        sig = 10.0 ** rng.uniform(-4, 1, 3)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        o = rng.normal(size=3) * sig * rng.uniform(0, 3) - 5 * d
        ta, tb = np.sort(rng.uniform(0, 10, 2))
        cases.append(((0, 0, 0), tuple(sig), tuple(o), tuple(d), ta, tb))
    worst = 0.0
    where = None
    for c, s, o, d, t0, t1 in cases:
        wo, wd = whiten(c, s, o, d)
        got = k.line_integral(*wo, *wd, t0, t1)
        e = rel_err(got, mp_line_closed(wo, wd, t0, t1))
        if e > worst:
            worst, where = e, (c, s, o, d, t0, t1)
    return worst, "mpmath 50 digits (closed form)", 1e-8, where


def case_composite(taus, colors):
    """Drive the kernel's composite() over one ray; returns (T history, L) and checks nothing."""
    k = _k()
    sv = np.zeros(12)
    sv[0] = 1.0
    sv[4] = 1e10
    Ts = [1.0]
    for i, tau in enumerate(taus):
        c = colors[i]
        k.composite(sv, tau, c[0], c[1], c[2], 0.5, float(i), float(i + 1))
        Ts.append(sv[0])
    return np.array(Ts), sv[1:4].copy()


def case_faces(n_shift=(0.0, 1e-6), size=24, mode="particles"):
    """Orthographic axis-parallel rays exactly on voxel, leaf (x = 8c - 0.5) and node (127.5) faces vs
    rays moved by 1e-6: worst |image difference| and worst error against the numpy closed form."""
    rng = np.random.default_rng(5)
    cs = rng.uniform([116, 116, 0], [140, 140, 12], (60, 3))
    cs[:8, 0] = [119.5, 127.5, 135.5, 127.5, 119.5, 120, 128, 127]  # centres on faces too
    cs[:8, 1] = [127.5, 119.5, 127.5, 135.5, 127.5, 128, 127.5, 120]
    gs = gaussian_set(cs, rng.uniform(0.6, 1.8, (60, 3)), 0.5, 0.3)
    dens = 0.8
    sc = RenderScene([RenderObject(gs)], mode=mode, transmittance_min=0.0, background=(0, 0, 0, 0))
    imgs, errs = [], []
    for sh in n_shift:
        m = np.eye(4)
        # pixel centres at x, y = 116.5 + i (every voxel face; 119.5, 127.5, 135.5 are leaf faces)
        m[:3, 3] = [116.0 + size / 2 + sh, 116.0 + size / 2 + sh, 40.0]
        cam = Camera(m, size, size, "ortho", ortho_scale=float(size))
        img = dev().render(sc, cam, const_tf(dens))["Combined"]
        imgs.append(img)
        if mode == "particles":
            errs.append(np.abs(img[..., 3] - closed_form_alpha(cam, gs, np.eye(4), dens)).max())
    jump = max(np.abs(i - imgs[0]).max() for i in imgs[1:])
    return jump, max(errs) if errs else float("nan"), imgs[0]


def case_ties(n=6, size=None, threads=(1, 2)):
    """Orthographic view along z of an n^3 lattice of equal Gaussians, one ray through every column
    of centres (every entry/exit event ties exactly): error vs closed form, and bitwise 1 vs 2 threads."""
    cs = lattice(n, 2.0, (3, 3, 3))
    gs = gaussian_set(cs, 1.1, 0.5, 0.4)
    size = size or 2 * n
    m = np.eye(4)
    m[:3, 3] = [3 + n - 1.0, 3 + n - 1.0, 100.0]  # pixel centres at 3 + k (the columns are at odd k)
    cam = Camera(m, size, size, "ortho", ortho_scale=float(size))
    tf = const_tf(0.6)
    out = []
    for th in threads:
        sc = RenderScene([RenderObject(gs)], threads=th, transmittance_min=0.0, background=(0, 0, 0, 0))
        out.append(dev().render(sc, cam, tf))
    ref = closed_form_alpha(cam, gs, np.eye(4), 0.6)
    err = np.abs(out[0]["Combined"][..., 3] - ref).max()
    same = all(np.array_equal(out[0][k], o[k]) for o in out[1:] for k in out[0])
    return err, same, ref


def case_inside(kind="persp"):
    """Camera inside a Gaussian (at its centre) and inside a lattice volume: vs the closed form."""
    worst = 0.0
    cs = lattice(5, 1.5, (-3, -3, -3))
    gs = gaussian_set(cs, 1.0, 0.5, 0.5)
    for pos in ((0.0, 0.0, 0.0), (0.75, 0.2, -0.3), (-3.0, -3.0, -3.0)):
        m = np.eye(4)
        m[:3, :3] = np.linalg.qr(np.array([[1, 0.3, 0.2], [0.1, 1, 0.4], [0.3, 0.2, 1.0]]))[0]
        m[:3, 3] = pos
        cam = Camera(m, 12, 10, kind, ortho_scale=4.0, fov_x=1.6)
        sc = RenderScene([RenderObject(gs)], transmittance_min=0.0, background=(0, 0, 0, 0))
        img = dev().render(sc, cam, const_tf(0.7))["Combined"]
        assert np.all(np.isfinite(img))
        ref = closed_form_alpha(cam, gs, np.eye(4), 0.7)
        assert ref.max() > 0.3
        worst = max(worst, np.abs(img[..., 3] - ref).max())
    return worst


def scene_blobs(shift=(0, 0, 0), order=None, split=False):
    cs = np.array([[0, 0, 0], [2.5, 1, 0], [-1, 3, 2], [1, -2, -1.5], [0.5, 0.5, 0.8]], float)
    sig = np.array([[1.3, 1.0, 0.8], [1.0, 1.0, 1.0], [0.7, 1.5, 1.0], [1.2, 1.2, 0.6], [0.9, 0.9, 0.9]])
    vals = np.array([0.2, 0.9, 0.5, 0.7, 0.35])
    amps = np.array([0.8, 0.5, 1.0, 0.6, 0.9])
    if split:  # one Gaussian -> two half-amplitude copies
        cs = np.concatenate([cs, cs[:1]])
        sig = np.concatenate([sig, sig[:1]])
        vals = np.concatenate([vals, vals[:1]])
        amps = np.concatenate([amps, amps[:1]])
        amps[0] *= 0.5
        amps[-1] *= 0.5
    if order is not None:
        cs, sig, vals, amps = cs[order], sig[order], vals[order], amps[order]
    return gaussian_set(cs + np.asarray(shift, float), sig, vals, amps)


def case_translation(d, mode="particles", size=20):
    """Scene and camera translated by d voxels: (a) in index space, matrix brings it back; (b) object
    and camera moved together in the world. Returns the worst image difference."""
    tf = TransferFunction.from_colormap("plasma", 0, 1, density=0.6)
    cam = Camera.frame_box([-5] * 3, [6] * 3, size, size, direction=(1, 0.3, -0.7))
    kw = dict(mode=mode, step=0.25)
    ref = dev().render(RenderScene([RenderObject(scene_blobs())], **kw), cam, tf)["Combined"]
    shift = np.array([d, -d, d])
    m = np.eye(4)
    m[:3, 3] = -shift
    a = dev().render(RenderScene([RenderObject(scene_blobs(shift), m)], **kw), cam, tf)["Combined"]
    m2 = np.eye(4)
    m2[:3, 3] = [d, 0.5 * d, -d]
    cam2 = Camera(cam.cam_to_world.copy(), size, size, "persp", fov_x=cam.fov_x)
    cam2.cam_to_world[:3, 3] += m2[:3, 3]
    b = dev().render(RenderScene([RenderObject(scene_blobs(), m2)], **kw), cam2, tf)["Combined"]
    assert ref[..., 3].max() > 0.3
    return max(np.abs(a - ref).max(), np.abs(b - ref).max())


def case_scale(s, mode):
    """World scaled by s in INDEX space (centres and sigmas x s: the same field on a grid of s times
    more voxels, field weights keep their peak), density / s, field step x s: the same image for
    particles and field; the paper's 1/det(Sigma) scales as s^-6 and breaks it."""
    base = scene_blobs()
    cs0 = np.repeat(base.group_origins, np.diff(base.group_start), 0) + base.offsets.astype(float)

    def make(f):
        return gaussian_set(cs0 * f, base.sigmas.astype(float) * f, base.values, base.amplitudes)

    tf = TransferFunction.from_colormap("viridis", 0, 1, density=0.8)
    cam = Camera.frame_box([-5] * 3, [6] * 3, 16, 16, direction=(1, 0.4, -0.6))
    kw = dict(mode=mode, tau_max=1e-3)  # particles: the mixed-colour cuts follow the (unscaled) leaves
    ref = dev().render(RenderScene([RenderObject(make(1.0))], step=0.05, **kw), cam, tf)["Combined"]
    cs = Camera(np.diag([s, s, s, 1.0]) @ cam.cam_to_world, 16, 16, "persp", fov_x=cam.fov_x)
    tfs = TransferFunction(tf.lut, 0, 1, density=0.8 / s)
    img = dev().render(RenderScene([RenderObject(make(s))], step=0.05 * s, **kw), cs, tfs)["Combined"]
    assert np.all(np.isfinite(img))
    return np.abs(img - ref).max(), ref


def field_pixel_ref(o, d, c, sig, amp, val, tf, t0, t1, n=400001):
    """Fine midpoint quadrature of the field-mode DVR integral along one ray (exact exp per step)."""
    t = np.linspace(t0, t1, n)
    tm = 0.5 * (t[1:] + t[:-1])
    dt = t[1] - t[0]
    x = o[None] + tm[:, None] * d[None]
    q = np.sum(((x - c) / sig) ** 2, 1)
    s = np.where(q < 9, val * amp * np.exp(-q / 2), np.nan)
    rgba = np.nan_to_num(tf(s))
    sg = tf.density * rgba[:, 3]
    T = np.exp(-np.concatenate([[0], np.cumsum(sg * dt)[:-1]]))
    w = T * -np.expm1(-sg * dt)
    return np.concatenate([(w[:, None] * rgba[:, :3]).sum(0), [w.sum()]])


def case_field_convergence(steps=(1.0, 0.5, 0.25, 0.125)):
    """Field mode as dt -> 0 vs fine quadrature: errors and observed order (log2 of ratios)."""
    c, sig, amp, val = np.array([0.2, 0.1, -0.3]), 1.5, 0.9, 2.0
    gs = gaussian_set([c], [sig], [val], [amp])
    # alpha ramp starting above the field at the support edge: the integrand is continuous
    tf = TransferFunction.from_ramp([0.0, 1.0], [[0.1, 0.3, 1.0, 0.0], [1.0, 0.6, 0.1, 1.0]], 0.2, 1.8, density=0.9)
    m = np.eye(4)
    m[:3, 3] = [0.5, -0.4, 20]
    cam = Camera(m, 1, 1, "ortho", ortho_scale=0.1)
    o = np.array([0.5, -0.4, 20.0])
    ref = field_pixel_ref(o, np.array([0, 0, -1.0]), c, sig, amp, val, tf, 20 - 0.3 - 4.6, 20 - 0.3 + 4.6)
    errs = []
    for h in steps:
        sc = RenderScene([RenderObject(gs)], mode="field", step=h, transmittance_min=0.0,
                         background=(0, 0, 0, 0))
        errs.append(np.abs(dev().render(sc, cam, tf)["Combined"][0, 0] - ref).max())
    errs = np.array(errs)
    # observed order over the whole sweep (piece-wise step rounding makes single ratios noisy)
    order = math.log(errs[0] / errs[-1]) / math.log(steps[0] / steps[-1])
    return errs, order, ref


def case_particles_convergence(tau_maxes=(0.8, 0.4, 0.2, 0.1, 0.05)):
    """Particles mode as the mixed-segment subdivision tau_max -> 0, three overlapping Gaussians of
    very different colours on one ray, vs fine quadrature: errors and observed order."""
    cs = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, 0.9], [-0.1, 0.0, -0.8]])
    sig = np.array([[1.0, 1.0, 1.2], [0.8, 0.8, 1.0], [1.1, 0.9, 0.9]])
    vals = np.array([0.0, 1.0, 0.5])
    gs = gaussian_set(cs, sig, vals, 1.0)
    tf = TransferFunction.from_ramp([0, 0.5, 1], [[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]], 0, 1, density=1.2)
    m = np.eye(4)
    m[:3, 3] = [0.05, 0.02, 20]
    cam = Camera(m, 1, 1, "ortho", ortho_scale=0.1)
    rgba = tf(vals)
    ref = quadrature_pixel(np.array([0.05, 0.02, 20.0]), np.array([0, 0, -1.0]), cs, sig,
                           1.2 * rgba[:, 3], rgba[:, :3], 12, 28, n=400001)
    errs = []
    for tm in tau_maxes:
        sc = RenderScene([RenderObject(gs)], tau_max=tm, transmittance_min=0.0, background=(0, 0, 0, 0))
        errs.append(np.abs(dev().render(sc, cam, tf)["Combined"][0, 0] - ref).max())
    errs = np.array(errs)
    return errs, math.log(errs[0] / errs[-1]) / math.log(tau_maxes[0] / tau_maxes[-1]), ref


# -- tests: kernels -------------------------------------------------------------------------------
def test_stiff_line_integrals_vs_mpmath():
    worst, _, tol, where = case_line_integrals(n_random=10)
    assert worst <= tol, (worst, where)


def test_ulp_scale_segments_relative_accuracy():
    worst, _, _, where = case_line_integrals(n_random=0, short_h=(1e-15, 1e-12, 1e-10), stiff=False)
    assert worst <= 1e-5, (worst, where)


@HYP
@given(st.floats(-30, 30), st.floats(-6, 1.5), st.floats(-3, 3), st.floats(-4, 1))
def test_line_integral_property(tc, log_h, off, log_s):
    """Any segment [tc - h/2, tc + h/2] of a ray at distance off (in sigmas) from a Gaussian of
    sigma 10^log_s, h >= 1e-6 sigma: relative error <= 1e-5, the issue's target (shorter spans: see
    test_ulp_scale_segments_relative_accuracy)."""
    s = 10.0 ** log_s
    h = 10.0 ** log_h
    wo, wd = whiten((0, 0, 0), (s, s, s), (-10.0, off * s, 0.0), (1.0, 0.0, 0.0))
    t0, t1 = 10.0 + tc * s - h * s / 2, 10.0 + tc * s + h * s / 2
    got = _k().line_integral(*wo, *wd, t0, t1)
    assert got >= 0.0
    assert rel_err(got, mp_line_closed(wo, wd, t0, t1)) <= 1e-5


@HYP
@given(st.floats(-25, 25), st.floats(-6, 1.5))
def test_erf_diff_property(u0, log_h):
    """erf(u1) - erf(u0) for |u| <= 25 (erfc(25) = 8e-274: clear of float64 underflow), h >= 1e-6:
    relative error <= 1e-5 (the issue's target; the short-span series loses ~(h m)^4 / 2000 for a
    midpoint m far in the tail: 5e-7 at m = 20, h = 5e-3, see the bench)."""
    u1 = u0 + 10.0 ** log_h
    got = _k().erf_diff(u0, u1)
    assert got >= 0.0 and rel_err(got, mp_erf_diff(u0, u1)) <= 1e-5


@HYP
@given(st.lists(st.one_of(st.floats(0, 1e7), st.floats(0, 1e-10), st.sampled_from([0.0, 1e-300, 1e300])),
                min_size=1, max_size=30),
       st.lists(st.tuples(*[st.floats(0, 1)] * 3), min_size=30, max_size=30))
def test_composite_transmittance_bounded_monotone(taus, colors):
    """T stays in [0, 1] and never increases; L >= 0, finite and <= (1 - T) max c; against float64
    sums of T_i c_i (1 - e^-tau_i) computed here."""
    T, L = case_composite(taus, colors)
    assert np.all(np.isfinite(T)) and np.all(np.isfinite(L))
    assert np.all((T >= 0) & (T <= 1)) and np.all(np.diff(T) <= 0)
    cmax = max(max(c) for c in colors[:len(taus)])
    opacity = float(-mpmath.expm1(-mpmath.fsum([mpmath.mpf(t) for t in taus])))
    assert np.all(L >= 0) and np.all(L <= opacity * cmax * (1 + 1e-12) + 1e-300)
    ref = np.zeros(3)
    Tr = 1.0
    for tau, c in zip(taus, colors):
        a = float(-mpmath.expm1(-mpmath.mpf(tau)))
        ref += Tr * a * np.asarray(c)
        Tr *= math.exp(-tau)
    np.testing.assert_allclose(L, ref, rtol=1e-12, atol=1e-300)


def test_near_zero_density_linear_regime():
    """tau = 1e-12 .. 1e-300: L = tau c exactly (expm1), no cancellation to zero."""
    for tau in (1e-12, 1e-20, 1e-300):
        T, L = case_composite([tau], [(0.5, 0.25, 1.0)])
        np.testing.assert_allclose(L, tau * np.array([0.5, 0.25, 1.0]), rtol=1e-12)
        assert T[-1] == 1.0 - tau or T[-1] == 1.0


@pytest.mark.parametrize("mode", ["particles", "field"])
def test_huge_density_overlapping_saturates_to_colour(mode):
    """kappa w ~ 1e6 .. 1e12 over an overlapping lattice of two colours: alpha -> 1, every pixel a
    convex mix of the colours (never above the brightest), no NaN/Inf in any pass."""
    cs = lattice(4, 1.5)
    vals = np.where(np.arange(len(cs)) % 2 == 0, 0.0, 1.0)
    gs = gaussian_set(cs, 1.0, vals, 1.0)
    tf = TransferFunction.from_ramp([0, 1], [[1.0, 0.2, 0.0, 1.0], [0.0, 0.3, 0.9, 1.0]], 0, 1,
                                    density=1e6, interpolation="LINEAR")
    cam = Camera.frame_box(cs.min(0) - 2, cs.max(0) + 2, 16, 16, direction=(1, 0.6, -0.4))
    for dens in (1e6, 1e12):
        tf.density = dens
        out = dev().render(RenderScene([RenderObject(gs)], mode=mode, background=(0.5, 0.5, 0.5, 0.0)),
                           cam, tf)
        for k, v in out.items():
            assert np.all(np.isfinite(v)), k
        c = out["Combined"]
        hit = c[..., 3] > 0.999999
        assert hit.sum() > 20
        assert np.all(c[..., :3][hit] <= np.array([1.0, 0.3, 0.9]) + 1e-6)
        assert np.all(c[..., :3] >= 0) and np.all(c[..., 3] <= 1.0 + 1e-7)


def test_paper_mode_overshoots_where_ours_saturates():
    """The paper's C += T c A exceeds the colour at huge density (shown, not endorsed)."""
    gs = gaussian_set(lattice(3, 1.5), 1.0, 1.0, 1.0)
    tf = const_tf(1e3, (0.5, 0.5, 0.5))
    m = np.eye(4)
    m[:3, 3] = [1.5, 1.5, 30]
    cam = Camera(m, 3, 3, "ortho", ortho_scale=1.0)
    ours = dev().render(RenderScene([RenderObject(gs)], background=(0, 0, 0, 0)), cam, tf)["Combined"]
    paper = dev().render(RenderScene([RenderObject(gs)], mode="paper", background=(0, 0, 0, 0)), cam, tf)["Combined"]
    np.testing.assert_allclose(ours[1, 1], [0.5, 0.5, 0.5, 1.0], atol=1e-6)
    assert paper[1, 1, 0] > 2.0


@pytest.mark.parametrize("mode", ["particles", "field"])
@pytest.mark.parametrize("dens", [0.3, 3.0, 1e3])
def test_early_termination_changes_little(mode, dens):
    cs = lattice(5, 1.5)
    gs = gaussian_set(cs, 1.0, np.linspace(0, 1, len(cs)), 1.0)
    tf = TransferFunction.from_colormap("turbo", 0, 1, density=dens)
    cam = Camera.frame_box(cs.min(0) - 2, cs.max(0) + 2, 16, 16, direction=(1, 1, -1))
    sc = RenderScene([RenderObject(gs)], mode=mode, transmittance_min=0.0, background=(0.2, 0.4, 0.6, 1.0))
    full = dev().render(sc, cam, tf)["Combined"]
    sc.transmittance_min = 1e-3
    early = dev().render(sc, cam, tf)["Combined"]
    assert np.abs(full - early).max() <= 1e-3


# -- tests: traversal -----------------------------------------------------------------------------
@pytest.mark.parametrize("mode", ["particles", "field"])
def test_rays_on_voxel_leaf_node_faces(mode):
    jump, err, img = case_faces(mode=mode)
    assert img[..., 3].max() > 0.3
    assert jump <= 1e-4, jump          # continuous: no holes, no double counts on the faces
    if mode == "particles":
        assert err <= 1e-6, err        # and exact against the closed form


def test_exact_ties_lattice_nothing_dropped_bitwise():
    err, same, ref = case_ties()
    assert ref.max() > 0.5
    assert err <= 1e-6, err
    assert same


@pytest.mark.parametrize("kind", ["persp", "ortho"])
def test_camera_inside_gaussian_and_volume(kind):
    assert case_inside(kind) <= 1e-6


def test_rays_along_box_faces_and_missing():
    """Ortho rays sliding exactly along the node box's faces (0 * inf in a naive slab test) and rays
    just outside: finite, and the background where nothing is hit."""
    gs = gaussian_set([[3.0, 3.0, 3.0]], 0.5, 1.0, 1.0)  # node box q in [0, 128): index [-0.5, 127.5)
    for pos, look in (((-0.5, 3.0, 50.0), None), ((3.0, -0.5, 50.0), None), ((-0.5 - 1e-9, 3.0, 50.0), None),
                      ((127.5, 127.5, 50.0), None), ((-0.5, -0.5, 3.0), "x")):
        m = np.eye(4)
        if look == "x":
            m[:3, :3] = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]  # camera -z = +x: slides along y = z = -0.5
        m[:3, 3] = pos
        for kind in ("ortho", "persp"):
            cam = Camera(m, 5, 5, kind, ortho_scale=1e-3, fov_x=1e-3)
            out = dev().render(RenderScene([RenderObject(gs)], background=(0.1, 0.2, 0.3, 1.0)), cam, const_tf(1.0))
            for v in out.values():
                assert np.all(np.isfinite(v))
            np.testing.assert_allclose(out["Combined"][..., :3], np.broadcast_to([0.1, 0.2, 0.3], (5, 5, 3)), atol=1e-7)


# -- tests: invariances ---------------------------------------------------------------------------
@pytest.mark.parametrize("d", [1e5, 1e7])
def test_translation_invariance(d):
    assert case_translation(d) <= 1e-4


def test_translation_invariance_field_1e6():
    assert case_translation(1e6, "field") <= 1e-4


@pytest.mark.parametrize("s", [0.1, 10.0])
def test_world_scale_invariance_field_and_paper_fails(s):
    err, ref = case_scale(s, "particles")
    assert ref[..., 3].max() > 0.2 and err <= 5e-5
    # field: step scaled with the world, but the sample grid restarts at leaf faces (8 voxels, not
    # scaled), so only the quadrature error of step 0.05 voxel separates the two
    err, ref = case_scale(s, "field")
    assert err <= 1e-3
    err_p, ref_p = case_scale(s, "paper")
    assert err_p > 0.05  # the paper's 1/det(Sigma) is not scale-correct


@pytest.mark.parametrize("mode", ["particles", "field", "particles-permute"])
def test_split_and_permute_same_image(mode):
    permute_only = mode.endswith("-permute")
    mode = mode.split("-")[0]
    tf = TransferFunction.from_colormap("magma", 0, 1, density=0.9)
    cam = Camera.frame_box([-4] * 3, [5] * 3, 16, 16, direction=(0.3, 1, -0.4))
    sc = lambda gs: RenderScene([RenderObject(gs)], mode=mode, tau_max=0.02)  # noqa: E731
    ref = dev().render(sc(scene_blobs()), cam, tf)["Combined"]
    assert ref[..., 3].max() > 0.3
    if not permute_only:
        split = dev().render(sc(scene_blobs(split=True)), cam, tf)["Combined"]
        np.testing.assert_allclose(split, ref, atol=1e-6, err_msg="split")
        if mode == "particles":
            return  # permutation: the xfail variant
    for seed in range(3):
        perm = np.random.default_rng(seed).permutation(5)
        img = dev().render(sc(scene_blobs(order=perm)), cam, tf)["Combined"]
        np.testing.assert_allclose(img, ref, atol=1e-6, err_msg=f"perm {perm}")


# -- tests: convergence -----------------------------------------------------------------------------
def test_field_mode_converges_second_order():
    errs, order, ref = case_field_convergence()
    assert ref[3] > 0.3
    assert np.all(np.diff(errs) < 0) and errs[-1] < 1e-3
    assert order > 1.5, order


def test_particles_mode_converges_as_tau_max_shrinks():
    errs, order, ref = case_particles_convergence()
    assert ref[3] > 0.5
    assert errs[-1] < errs[0] and errs[-1] < 2e-3
    assert order > 1.2, (errs, order)


@pytest.mark.parametrize("m", [5.0, 12.0, 20.0, 26.0])
@pytest.mark.parametrize("h", [1e-6, 1e-4, 5e-3])
def test_short_span_far_in_the_tails(m, h):
    """Short spans far out in the tails: the midpoint series must track mpmath (relative 1e-8)."""
    for sign in (1.0, -1.0):
        u0, u1 = sign * m - 0.5 * h, sign * m + 0.5 * h
        got = _k().erf_span(u0, u1, h)
        want = mp_erf_diff(u0, u1)
        assert got >= 0.0 and rel_err(got, want) <= 1e-8, (u0, u1, got, want)


def test_huge_gaussian_is_listed_at_its_level_not_per_leaf():
    """A Gaussian thousands of leaves wide (a root tile, a world scaled far past its voxels) is
    listed in a few cells of a coarse level, never in billions of leaf cells: the leaf walk draws
    it as the screen tiles do, in moments."""
    import time

    big = gaussian_set([[0.0, 0.0, 0.0], [4.0, 4.0, 4.0]], [[5000.0, 5000.0, 5000.0], [1.0, 1.0, 1.0]])
    scene = RenderScene([RenderObject(big, np.eye(4))], mode="particles")
    cam = Camera.frame_box([-6.0] * 3, [10.0] * 3, 8, 8)
    tf = TransferFunction.from_colormap("grayscale", 0.0, 1.0)
    t0 = time.perf_counter()
    dev = CPUDevice(screen_tiles=False)
    walk = dev.render(scene, cam, tf)["Combined"]
    assert time.perf_counter() - t0 < 5.0 and dev.gacc.cell_items.size <= 27 + 8
    tiles = CPUDevice().render(scene, cam, tf)["Combined"]
    assert tiles[..., 3].max() > 0 and np.abs(walk - tiles).max() < 1e-6
