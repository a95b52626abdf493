"""The GPU device's Gaussian modes against the CPU device (llvmpipe here): particles, field and
paper on a fog volume, a level set (field: its surface; particles, paper: a shell) and two
overlapping objects (PSNR >= 50 dB, Depth and Value passes), and rays with more chords than the
shader's hit slots, whose tiles the CPU device draws."""
import math

import numpy as np
import pytest

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.synthetic import gaussian_set

W = 48
TF = TransferFunction.from_colormap("viridis", 0, 1.0, density=0.4)
MIN_DB = 50.0


def psnr(a, b):
    mse = float(np.mean((np.asarray(a, np.float64) - b) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


@pytest.fixture(scope="module")
def gpu(addon):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu import device, probe

    ok, why = probe.probe()
    if not ok:
        pytest.skip(f"no GPU context here: {why}")
    return device.GPUDevice()


@pytest.fixture(scope="module")
def cpu():
    return CPUDevice()


def lattice(n, keep, values, sigma=0.8, grid_class="fog_volume", seed=0):
    g = np.arange(n)
    c = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3).astype(float)
    sel = keep(c)
    rng = np.random.default_rng(seed)
    c = c[sel] + rng.normal(0, 0.05, (int(sel.sum()), 3))
    amp = 1.0 / ((2 * np.pi) ** 1.5 * sigma ** 3)
    return gaussian_set(c, sigma, values(c), amp, grid_class=grid_class)


def fog():
    r2 = lambda c: ((c - 7.5) ** 2).sum(1)  # noqa: E731
    return lattice(16, lambda c: r2(c) < 60, lambda c: np.exp(-r2(c) / 30.0))


def shell():
    r = lambda c: np.sqrt(((c - 7.5) ** 2).sum(1))  # noqa: E731
    return lattice(16, lambda c: np.abs(r(c) - 6.0) < 1.0, lambda c: np.ones(len(c)),
                   grid_class="level_set")


def scenes():
    m = np.eye(4)
    m[:3, 3] = (5.0, 2.0, 1.0)
    two = [RenderObject(fog()), RenderObject(shell(), matrix_world=m, level_set_color="z",
                                             tf=TransferFunction.from_colormap("magma", 0, 1.0, density=0.6))]
    return {"fog": [RenderObject(fog())], "level set": [RenderObject(shell(), level_set_color=(0.9, 0.5, 0.2))],
            "two objects": two}


CAM = Camera.frame_box([0] * 3, [20] * 3, W, W, direction=(1, 0.4, -0.3))


@pytest.mark.parametrize("mode", ["particles", "field", "paper"])
@pytest.mark.parametrize("name", ["fog", "level set", "two objects"])
def test_gauss_modes_match_cpu(gpu, cpu, mode, name):
    objs = scenes()[name]
    if mode == "field" and name == "level set":
        objs[0].surface = True  # field mode draws it as a lit opaque surface
    sc = RenderScene(objs, mode=mode)
    want = cpu.render(sc, CAM, TF)
    got = gpu.render(sc, CAM, TF)
    assert gpu.stats.get("fallback") is None, gpu.stats.get("fallback")
    assert gpu.stats["overflow_tiles"] == 0  # every pixel drawn by the shader
    db = psnr(got["Combined"], want["Combined"])
    assert want["Combined"][..., 3].max() > 0.25  # something to compare (paper is the faintest)
    assert db >= MIN_DB, f"{mode}, {name}: PSNR {db:.1f} dB"
    print(f"{mode} {name}: {db:.1f} dB, overflow tiles {gpu.stats.get('overflow_tiles')}")
    # Depth where both reach half opacity; Value where the CPU has one
    d0, d1 = want["Depth"], got["Depth"]
    both = (d0 < 1e9) & (d1 < 1e9)
    assert np.mean((d0 < 1e9) != (d1 < 1e9)) < 0.01
    np.testing.assert_allclose(d1[both], d0[both], rtol=1e-3, atol=1e-3)
    vdb = psnr(got["Value"], want["Value"])
    assert vdb >= MIN_DB, f"{mode}, {name}: Value PSNR {vdb:.1f} dB"


def test_overflowing_rays_drawn_on_cpu(gpu, cpu):
    """A dense blob whose rays hold more open chords than the shader's slots: those tiles come
    from the CPU device, so the image still matches."""
    n = 14
    r2 = lambda c: ((c - 6.5) ** 2).sum(1)  # noqa: E731
    dense = lattice(n, lambda c: r2(c) < 49, lambda c: np.exp(-r2(c) / 40.0), sigma=2.0)
    sc = RenderScene([RenderObject(dense)], mode="particles")
    cam = Camera.frame_box([0] * 3, [13] * 3, 24, 24, direction=(1, 0.4, -0.3))
    want = cpu.render(sc, cam, TF)
    got = gpu.render(sc, cam, TF)
    assert gpu.stats["overflow_tiles"] > 0
    db = psnr(got["Combined"], want["Combined"])
    assert db >= MIN_DB, f"overflow: PSNR {db:.1f} dB"
