"""Screen tiles (particles and field): the per-frame footprints are conservative, and rendering
from the tile lists gives the leaf walk's image."""

import numpy as np
import pytest

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction, generate_rays
from kernels.render.devices import frame_setup
from kernels.render.inputs import accel as accel_mod
from kernels.render.scene.synthetic import gaussian_set


def blob(seed, n=300, spread=6.0, offset=(0.0, 0.0, 0.0)):
    rng = np.random.default_rng(seed)
    c = rng.normal(size=(n, 3)) * spread + np.asarray(offset)
    sig = rng.uniform(0.4, 1.6, size=(n, 3))  # anisotropic, axis-aligned
    v = rng.uniform(0.1, 1.0, size=n)
    return gaussian_set(c, sig, v, 1.0)


def rot(ax, ang):
    c, s = np.cos(ang), np.sin(ang)
    m = np.eye(4)
    i, j = [(1, 2), (0, 2), (0, 1)][ax]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def scene_objects(shift=0.0):
    m1 = np.diag([0.5, 0.5, 0.5, 1.0])
    m1[:3, 3] = shift
    m2 = rot(2, 0.4) @ rot(0, 0.3) @ np.diag([0.3, 0.6, 0.45, 1.0])
    m2[:3, 3] = np.array([1.5, -1.0, 0.5]) + shift
    return [RenderObject(blob(1), m1), RenderObject(blob(2, offset=(2, 1, 0)), m2)]


CAMERAS = {
    "persp": lambda s: Camera.frame_box(np.full(3, -6.0) + s, np.full(3, 6.0) + s, 96, 72,
                                        direction=(0.4, 1.0, -0.3)),
    "ortho": lambda s: Camera.frame_box(np.full(3, -6.0) + s, np.full(3, 6.0) + s, 80, 80,
                                        direction=(1.0, 0.2, 0.1), kind="ortho"),
    # the eye inside the cloud: supports straddle the eye's plane and cover every tile
    "inside": lambda s: Camera(np.array([[1, 0, 0, 0.3 + s], [0, 0, 1, -0.5 + s], [0, -1, 0, 0.2 + s],
                                         [0, 0, 0, 1.0]]), 64, 64),
}


def render(dev, objs, cam, mode, tiles):
    dev.screen_tiles = tiles
    sc = RenderScene(objs, mode=mode, threads=2)
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.0, density=0.8)
    return dev.render(sc, cam, tf)


@pytest.mark.parametrize("mode", ["particles", "field"])
@pytest.mark.parametrize("view", sorted(CAMERAS))
def test_tiles_match_the_leaf_walk(mode, view):
    dev = CPUDevice()
    objs = scene_objects()
    cam = CAMERAS[view](0.0)
    a = render(dev, objs, cam, mode, True)
    b = render(dev, objs, cam, mode, False)
    assert a["Combined"][..., 3].max() > 0.2  # something is drawn
    # the same chords in the same (t, id) order: equal up to rounding of the sweep's batches
    assert np.abs(a["Combined"] - b["Combined"]).max() < 1e-6
    assert np.abs(a["Value"] - b["Value"]).max() < 1e-5


def test_tiles_translated_far():
    """Per-frame projection in float64 relative to the camera: 1e6 units away, same image."""
    dev = CPUDevice()
    s = 1e6
    a = render(dev, scene_objects(), CAMERAS["persp"](0.0), "particles", True)
    b = render(dev, scene_objects(s), CAMERAS["persp"](s), "particles", True)
    assert np.abs(a["Combined"] - b["Combined"]).max() < 1e-4


def test_tile_lists_over_budget_fall_back_to_the_walk(monkeypatch):
    dev = CPUDevice()
    objs = scene_objects()
    cam = CAMERAS["persp"](0.0)
    a = render(dev, objs, cam, "particles", True)
    monkeypatch.setattr(frame_setup, "MAX_TILE_ENTRIES", 10)
    monkeypatch.setattr(accel_mod, "TILE_FANOUT", 0)
    start, *_ = dev._screen_tiles(0, RenderScene(objs), cam, np.ones(dev.gacc.g_mu.shape[0]))
    assert start.shape[0] == 1  # no lists: the kernels walk the leaves
    b = render(dev, objs, cam, "particles", True)
    assert np.abs(a["Combined"] - b["Combined"]).max() < 1e-6


@pytest.mark.parametrize("view", sorted(CAMERAS))
def test_footprints_are_conservative(view):
    """Brute force: every pixel whose ray meets a support finds that Gaussian in its tile's list
    with the pixel's mask bit set, and the ray enters no earlier than its lower bound."""
    dev = CPUDevice()
    objs = scene_objects()
    cam = CAMERAS[view](0.0)
    sc = RenderScene(objs)
    dev.sync(sc)
    A = dev.gacc
    start, items, masks, lb = dev._screen_tiles(0, sc, cam, np.ones(A.g_mu.shape[0]))
    assert start.shape[0] > 1
    W, H, T = cam.width, cam.height, 8
    tile_of = np.repeat(np.arange(start.shape[0] - 1), np.diff(start))
    bits = np.arange(T * T)

    def listed(g):
        """Pixels whose tile lists g with the pixel's mask bit set."""
        out = np.zeros(W * H, bool)
        for q in np.flatnonzero(items == g):
            on = bits[((masks[q] >> bits) & 1) == 1]
            x = (tile_of[q] % -(-W // T)) * T + on % T
            y = (tile_of[q] // -(-W // T)) * T + on // T
            ok = (x < W) & (y < H)
            out[y[ok] * W + x[ok]] = True
        return out

    o, d = generate_rays(cam)
    k2 = sc.support_k ** 2
    tight = 0
    for g in range(0, A.g_mu.shape[0], 7):
        w2i = dev.w2i[A.g_obj[g]]
        oi = o @ w2i[:3, :3].T + w2i[:3, 3]
        di = d @ w2i[:3, :3].T
        w = (oi - A.g_mu[g]) * A.g_inv[g]
        v = di * A.g_inv[g]
        a = (v * v).sum(1)
        ts = -(w * v).sum(1) / a
        q = ((w + ts[:, None] * v) ** 2).sum(1)
        hw = np.sqrt(np.maximum(k2 - q, 0) / a)
        hit = (q < k2) & (ts + hw > 0)
        if not hit.any():
            continue
        assert listed(g)[hit].all(), g
        assert (ts - hw)[hit].min() >= lb[g] - 1e-9, g
        tight += 1
    assert tight > 10


def test_supports_straddling_the_eye_plane_cover_only_what_they_can():
    """An eye inside a volume: supports that straddle the eye's plane far off to the side reach
    no pixel and are listed in no tile; one around the eye covers them all; one straddling the
    plane beside the eye covers only the side it is on."""
    dev = CPUDevice()
    # camera at the origin looking along -z, 64 x 64, 60 degrees; 3-sigma supports
    cam = Camera(np.eye(4), 64, 64, "persp", fov_x=np.radians(60.0))
    centres = np.array([[50.0, 0.0, 0.0], [0.0, -40.0, 0.5], [0.2, 0.1, 0.3], [1.2, 0.0, -1.0]])
    sc = RenderScene([RenderObject(gaussian_set(centres, 0.5, 1.0, 1.0))], support_k=3.0)
    dev.sync(sc)
    start, items, masks, lb = dev._screen_tiles(0, sc, cam, np.ones(4))
    assert start.shape[0] == 65
    g = [int(np.argmin(np.abs(dev.gacc.g_mu - c).sum(1))) for c in centres]  # ids by position
    per_g = np.bincount(items, minlength=4)
    assert per_g[g[0]] == 0 and per_g[g[1]] == 0  # off to the side: nothing
    assert per_g[g[2]] == 64  # around the eye: every tile
    tiles = np.repeat(np.arange(64), np.diff(start))[items == g[3]]
    # its front part spans u >= -0.3 (x / -z); the bound is -0.437: image columns 8 and up
    assert 0 < tiles.size < 64 and (tiles % 8).min() == 1


def test_tile_budget_grows_with_the_set_within_the_memory(monkeypatch):
    """A set of many small supports (x4 High: 24 M Gaussians, ~36 M entries) keeps its screen
    tiles instead of falling back to per-leaf lists (42 GiB there); the memory still caps it."""
    monkeypatch.setattr(accel_mod, "available_bytes", lambda: 16 << 30)
    assert accel_mod.tile_budget(24_000_000, 24_000_000) == 8 * 24_000_000
    assert accel_mod.tile_budget(1000, 24_000_000) == 24_000_000  # the fixed budget stays a floor
    monkeypatch.setattr(accel_mod, "available_bytes", lambda: 256 << 20)
    assert accel_mod.tile_budget(24_000_000, 24_000_000) == 24_000_000
    monkeypatch.setattr(accel_mod, "available_bytes", lambda: None)
    assert accel_mod.tile_budget(24_000_000, 10) == 10


def test_tile_list_sort_is_numpys_stable_argsort():
    """The tile lists' own merge sort orders ids as np.argsort(kind="mergesort") does: by entry
    bound, ties (equal, +-inf, NaN last) in id order, and touches nothing outside its range."""
    from kernels.render.cpu.tiles import _sort_by_lb

    rng = np.random.default_rng(1)
    for trial in range(200):
        n = int(rng.integers(2, 300))
        lb = (rng.choice(np.array([0.0, 1.0, 2.0, np.inf, -np.inf, np.nan, 0.5]), n + 50) if trial % 2
              else rng.normal(size=n + 50))
        ids = np.sort(rng.choice(n + 50, n, replace=False)).astype(np.int32)
        items = np.concatenate([[7], ids, [3]]).astype(np.int32)
        _sort_by_lb(items, np.int64(1), np.int64(1 + n), lb)
        assert np.array_equal(items[1:1 + n], ids[np.argsort(lb[ids], kind="mergesort")]), trial
        assert items[0] == 7 and items[-1] == 3
