"""The compiled packer of the drawn Gaussians (kernels/render/inputs/gauss_pack.py, accel.build_gaussians)
against the plain numpy formulas it replaced: bit for bit, dropped Gaussians included."""
import numpy as np
import pytest

from kernels.render import RenderObject
from kernels.render.inputs import accel
from kernels.render.scene.synthetic import gaussian_set


def numpy_drawn(gs, k, max_level):
    """The numpy passes the packer replaced: group origin + offset, drop what is never drawn, the
    k-sigma leaf box and its walk level."""
    start = np.asarray(gs.group_start, np.int64)
    mu = np.repeat(np.asarray(gs.group_origins, np.int64).reshape(-1, 3), np.diff(start), axis=0)
    mu = mu.astype(np.float64) + np.asarray(gs.offsets, np.float64)
    sig = np.asarray(gs.sigmas, np.float64)
    amp = np.asarray(gs.amplitudes, np.float64)
    keep = np.all(sig > 0, axis=1) & np.all(np.isfinite(mu), axis=1) & np.isfinite(amp) & (amp != 0)
    mu, sig, amp = mu[keep], sig[keep], amp[keep]
    clo = np.floor_divide(np.floor(mu - k * sig + 0.5).astype(np.int64), accel.LEAF)
    chi = np.floor_divide(np.floor(mu + k * sig + 0.5).astype(np.int64), accel.LEAF)
    lev = np.zeros(len(mu), np.int64)
    lo, hi = clo.copy(), chi.copy()
    for level in range(1, max_level + 1):
        big = (hi - lo).max(axis=1, initial=0) >= accel.LEVEL_SPAN
        lev[big] = level
        lo[big] = np.floor_divide(clo[big], accel.LEVEL_CELLS ** level)
        hi[big] = np.floor_divide(chi[big], accel.LEVEL_CELLS ** level)
    bounds = ((mu.min(0), mu.max(0)), ((mu - k * sig).min(0), (mu + k * sig).max(0)))
    return dict(mu=mu, inv=1.0 / sig, amp=amp, val=np.asarray(gs.values, np.float64)[keep],
                lev=lev, clo=lo, chi=hi), bounds


@pytest.fixture(scope="module")
def mixed_set():
    """Gaussians of every size (a level's worth of leaves and more) over several leaves, with
    some that are never drawn: zero and NaN sigma, NaN and zero amplitude, an infinite centre."""
    rng = np.random.default_rng(7)
    n = 4000
    c = rng.uniform(-300, 300, (n, 3))
    s = np.exp(rng.uniform(np.log(0.3), np.log(400.0), (n, 3)))
    a = rng.uniform(0.1, 2.0, n)
    s[5] = (0.0, 1.0, 1.0)
    s[17, 1] = np.nan
    a[23], a[31] = np.nan, 0.0
    gs = gaussian_set(c, s, rng.uniform(0, 1, n), a)
    gs.offsets = np.asarray(gs.offsets).copy()
    gs.offsets[40] = (np.inf, 0.0, 0.0)
    return gs


@pytest.mark.parametrize("max_level", [0, 1, accel.MAX_LEVEL])
def test_packer_matches_the_numpy_formulas_bit_for_bit(mixed_set, max_level):
    k = 3.0
    ref, ref_bounds = numpy_drawn(mixed_set, k, max_level)
    got = accel.drawn_gaussians(mixed_set, k, max_level)
    assert len(ref["mu"]) == len(mixed_set.amplitudes) - 5  # the five never drawn are left out
    for name, want in ref.items():
        assert np.array_equal(got[name], want, equal_nan=True), name
    if max_level:
        assert got["lev"].max() >= 1  # the wide ones went up a level
    for (a, b), (c, d) in zip(got["bounds"], ref_bounds):
        assert np.array_equal(a, c) and np.array_equal(b, d)
    assert all(np.array_equal(x, y) for p, q in zip(accel.gaussian_bounds(mixed_set, k), ref_bounds)
               for x, y in zip(p, q))


def test_two_objects_pack_one_after_the_other(mixed_set):
    small = gaussian_set([[0.0, 0.0, 0.0], [9.0, 1.0, 2.0]], 0.8, [0.5, 0.7])
    acc = accel.build_gaussians([RenderObject(mixed_set), RenderObject(small)], 3.0)
    ref, _ = numpy_drawn(mixed_set, 3.0, accel.MAX_LEVEL)
    m = len(ref["mu"])
    assert list(acc.g_first) == [0, m, m + 2]
    assert np.array_equal(acc.g_mu[:m], ref["mu"]) and np.array_equal(acc.g_obj, [0] * m + [1, 1])
    # the bounding spheres are relative to each object's own reference point
    assert np.allclose(acc.g_sph[m:, :3] + acc.obj_ref[1], [[0, 0, 0], [9, 1, 2]], atol=1e-5)
    assert np.allclose(acc.g_volfac[m:], 1.0 / 0.8 ** 6)


def test_a_set_with_nothing_drawn_has_no_bounds():
    gs = gaussian_set([[0.0, 0.0, 0.0]], 1.0, [1.0], [0.0])
    assert accel.gaussian_bounds(gs, 3.0) is None
    assert accel.drawn_gaussians(gs)["mu"].shape == (0, 3)


def test_test_records_are_centres_and_inverse_sigmas(mixed_set):
    from kernels.render.inputs import packing

    acc = accel.build_gaussians([RenderObject(mixed_set)], 3.0)
    rec = packing.test_records(acc)
    want = np.zeros((acc.g_mu.shape[0], 8))
    want[:, 0:3], want[:, 3:6] = acc.g_mu, acc.g_inv
    assert np.array_equal(rec, want) and rec.flags.c_contiguous


@pytest.mark.parametrize("chunk", [1 << 20, 7])
def test_bounds_alone_equal_the_packers_bit_for_bit(mixed_set, chunk):
    """gaussian_bounds (numpy, no kernel: a reference frame's sync) gives the packer's bounds to
    the bit, over group runs of any length (chunk 7 splits the set into hundreds of runs)."""
    from kernels.render.inputs import gauss_pack

    whole = accel.drawn_gaussians(mixed_set, 3.0)["bounds"]
    start = np.asarray(mixed_set.group_start, np.int64)
    alone = gauss_pack._bounds(start, np.asarray(mixed_set.group_origins, np.int64).reshape(-1, 3),
                               np.asarray(mixed_set.offsets), np.asarray(mixed_set.sigmas),
                               np.asarray(mixed_set.amplitudes), 3.0, chunk=chunk)
    for got, want in zip(alone, whole):
        for x, y in zip(got, want):
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes()
    assert [a.tobytes() for b in accel.gaussian_bounds(mixed_set, 3.0) for a in b] == \
        [a.tobytes() for b in whole for a in b]
