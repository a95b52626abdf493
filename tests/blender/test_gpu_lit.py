"""The GPU device's lit volumes in the Gaussian modes (particles: each chord shaded at its closest
approach on the mixture's gradient, the neighbours' part from the CPU per sync; field: the
mixture's analytic gradient at each sample) against the CPU device (llvmpipe here): a written fog
.vdb and the bundled Mantaflow smoke, two LODs each, lit by a sun and a point light, with and
without shadows (PSNR >= LIT_MIN_DB, no fallback, no tile drawn on the CPU); a lit object
overlapping an emission one; and the gradient
threshold on the GPU: the lit image equals the emission one where no sample's (chord's) gradient
passes it and differs where one does."""

import numpy as np
import pytest
from conftest import SAMPLE
from references import psnr

from kernels.render import Camera, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.camera import generate_rays
from kernels.render.scene.lights import Light
from kernels.render.scene.synthetic import gaussian_set

LIT_MIN_DB = 60.0  # GPU (float32) against CPU (float64)
W = 32
TF = TransferFunction.from_colormap("viridis", 0, 1.0, density=0.4)
LODS = ("low", "medium")


def lights(lo, hi):
    """A sun and a point light (beside the box lo..hi, its strength ~ 1 at the box's centre)."""
    c, r = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    p = c + r * np.array([1.2, -0.6, 1.4])
    return (Light("sun", (-1.0, 1.0, -0.3)),
            Light("point", tuple(p), strength=2.0 * float(np.sum((p - c) ** 2))))


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A fog .vdb written here (a lumpy ball), read back, at both LODs."""
    from vdb_fixtures import write_grid

    from kernels.lod import build_lod
    from kernels.vdb import read_vdb

    g = np.arange(24)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    r2 = (X - 11.5) ** 2 + (Y - 12.0) ** 2 + (Z - 11.0) ** 2
    fog = np.exp(-r2 / 40.0) * (1.0 + 0.3 * np.sin(X / 2.5))
    fog = np.where(fog > 0.03, fog, 0.0)
    path = write_grid(tmp_path_factory.mktemp("lit") / "fog.vdb", fog, name="density")
    grid = read_vdb(str(path)).grids[0]
    return grid, {lod: build_lod(grid, lod) for lod in LODS}


@pytest.fixture(scope="module")
def smoke():
    """The bundled Mantaflow smoke's density at both LODs."""
    from kernels.lod import build_lod
    from kernels.vdb import read_vdb

    grid = read_vdb(SAMPLE, grids=["density"]).grids[0]
    return grid, {lod: build_lod(grid, lod) for lod in LODS}


def lit_scene(grid, gs, mode, shading, shadows):
    lo, hi = np.asarray(grid.bbox_min, float), np.asarray(grid.bbox_max, float) + 1.0
    return RenderScene([RenderObject(gs, grid=grid, shading=shading, shadows=shadows)], mode=mode,
                       lights=lights(lo, hi))


def camera(grid):
    lo, hi = np.asarray(grid.bbox_min, float), np.asarray(grid.bbox_max, float) + 1.0
    return Camera.frame_box(lo, hi, W, W, direction=(0.3, 1.0, -0.2))


@pytest.mark.parametrize("shadows", [False, True], ids=["lit", "shadows"])
@pytest.mark.parametrize("lod", LODS)
@pytest.mark.parametrize("mode", ["particles", "field"])
@pytest.mark.parametrize("data", ["written", "smoke"])
def test_lit_gauss_modes_match_cpu(gpu, cpu, request, data, mode, lod, shadows):
    grid, sets = request.getfixturevalue(data)
    cam = camera(grid)
    sc = lit_scene(grid, sets[lod], mode, "lit", shadows)
    want = cpu.render(sc, cam, TF)["Combined"]
    got = gpu.render(sc, cam, TF)["Combined"]
    assert gpu.stats.get("fallback") is None, gpu.stats.get("fallback")
    assert gpu.stats["overflow_tiles"] == 0  # every pixel drawn by the shader
    # what the lights (or the shadows) change: the emission (or unshadowed) image is far off
    before = cpu.render(lit_scene(grid, sets[lod], mode, "lit" if shadows else "emission", False),
                        cam, TF)["Combined"]
    assert np.abs(want - before).max() > 0.02
    db = psnr(got, want)
    print(f"{data} {mode} {lod} {'lit + shadows' if shadows else 'lit'}: GPU vs CPU {db:.1f} dB "
          f"(emission/unshadowed vs lit {psnr(before, want):.1f} dB)")
    assert db >= LIT_MIN_DB, f"{data} {mode} {lod} shadows={shadows}: PSNR {db:.1f} dB"


@pytest.mark.parametrize("mode", ["particles", "field"])
def test_lit_and_emission_objects_overlapping(gpu, cpu, written, mode):
    """Two overlapping objects, a lit one with shadows (rotated and scaled: the normal goes through
    its world matrix) and an emission one: the GPU's image equals the CPU's."""
    grid, sets = written
    m = np.eye(4)
    c, s = np.cos(0.5), np.sin(0.5)
    m[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([1.2, 0.9, 1.0])
    m[:3, 3] = (8.0, -3.0, 2.0)
    lo, hi = np.full(3, -4.0), np.full(3, 36.0)
    sc = RenderScene([RenderObject(sets["medium"], matrix_world=m, shading="lit", shadows=True),
                      RenderObject(sets["low"], tf=TransferFunction.from_colormap("magma", 0, 1.0, density=0.3))],
                     mode=mode, lights=lights(lo, hi))
    cam = Camera.frame_box(lo, hi, W, W, direction=(0.3, 1.0, -0.2))
    want = cpu.render(sc, cam, TF)["Combined"]
    got = gpu.render(sc, cam, TF)["Combined"]
    assert gpu.stats.get("fallback") is None and gpu.stats["overflow_tiles"] == 0
    db = psnr(got, want)
    print(f"two objects {mode}: GPU vs CPU {db:.1f} dB")
    assert db >= LIT_MIN_DB, db


# -- the gradient threshold: one Gaussian, a sun (test_render_lit's set-up) --------------------
SUN = Light("sun", (1.0, -0.6, -0.8), (1.0, 0.9, 0.7), 1.5)
SHADING = (0.1, 0.8, 0.3, 16.0)
MU, SIG, WT = np.zeros((1, 3)), np.full((1, 3), 3.0), np.ones(1)
K = 3.0


def chord_gradient(o, d):
    """Particles: |gradient| of the Gaussian at each ray's closest approach to its centre."""
    u, v = (o - MU) / SIG, d / SIG
    ts = -(u * v).sum(1) / (v * v).sum(1)
    x = (o + ts[:, None] * d - MU) / SIG
    inside = (x * x).sum(1) < K * K
    g = WT[0] * np.exp(-0.5 * (x * x).sum(1))[:, None] * x / SIG
    return np.where(inside, np.linalg.norm(g, axis=1), 0.0)


def sample_gradient(o, d):
    """Field: the largest |gradient| of the Gaussian inside its support along each ray."""
    t = np.linspace(np.linalg.norm(o[0]) - 12, np.linalg.norm(o[0]) + 12, 4001)
    out = np.zeros(o.shape[0])
    for p in range(o.shape[0]):
        x = (o[p] + t[:, None] * d[p] - MU) / SIG
        q = (x * x).sum(1)
        g = WT[0] * np.exp(-0.5 * q) * np.sqrt(q) / SIG[0, 0]
        out[p] = g[q < K * K].max() if (q < K * K).any() else 0.0
    return out


@pytest.mark.parametrize("mode", ["particles", "field"])
def test_gpu_lights_only_above_the_threshold(gpu, mode):
    """Pixels whose ray meets no sample (particles: no chord) with a gradient above the threshold
    equal the GPU's emission image; those meeting gradients well above it differ (so the GPU does
    not ignore the lights, nor light homogeneous regions)."""
    cam = Camera.frame_box([-8.0] * 3, [8.0] * 3, 20, 20, direction=(0.3, 1.0, -0.2))
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.2, density=0.4)
    frac = 0.05
    thr = frac * (tf.vmax - tf.vmin)
    gs = gaussian_set(MU, SIG, WT)

    def draw(shading):
        sc = RenderScene([RenderObject(gs, shading=shading)], mode=mode, lights=(SUN,), shading=SHADING,
                         lit_threshold=frac, passes=())
        img = gpu.render(sc, cam, tf)["Combined"]
        assert gpu.stats.get("fallback") is None and gpu.stats["overflow_tiles"] == 0
        return img

    lit, emi = draw("lit"), draw("emission")
    o, d = generate_rays(cam)
    gmax = (chord_gradient if mode == "particles" else sample_gradient)(o, d).reshape(cam.height, cam.width)
    diff = np.abs(lit - emi).max(-1)
    low, high = gmax < 0.8 * thr, (gmax > 1.25 * thr) & (emi[..., 3] > 1e-3)
    assert low.sum() > 20 and high.sum() > 20, (low.sum(), high.sum())
    assert diff[low].max() <= 1e-6, diff[low].max()  # (the same arithmetic: equal up to rounding)
    assert (diff[high] > 1e-4).all(), np.sort(diff[high])[:5]
    np.testing.assert_array_equal(lit[..., 3], emi[..., 3])  # lights change colours only
