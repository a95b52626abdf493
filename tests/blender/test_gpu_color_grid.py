"""The GPU device draws volumes coloured by a second grid (colour from one grid, opacity from
another) itself, in every mode, against the CPU device: a written fire-like fixture (density;
temperature with its own topology, a background and a tile) and, where the shared data is, the
Mantaflow fire (density coloured by temperature), each at two LODs (reference mode samples the
voxels: one case); two overlapping objects, one coloured; lit reference volumes (with shadows);
`./gaussvdb render --color-grid --device gpu`.
The colour grid changes the GPU image's colour, not its alpha.

The figure: `.venv/bin/python -m pytest tests/blender/test_gpu_color_grid.py -k shared -s -q
-p no:cacheprovider` prints GPU vs CPU PSNR per mode and LOD on the shared fire."""
import dataclasses
import os

import numpy as np
import pytest
from conftest import DATA_DIR
from references import GPU_MIN_DB, psnr
from test_color_grid_blender import _render
from test_engine_helpers import read_image
from vdb_fixtures import write_fire_like

from kernels.lod import build_lod
from kernels.lod.gridprep import value_range
from kernels.lod.second_grid import attach
from kernels.render import Camera, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.lights import Light
from kernels.vdb import read_vdb

FIRE = os.path.join(DATA_DIR, "mantaflow_fire_r96_f035.vdb")
BACKGROUND = 0.25
CASES = [("reference", "medium")] + [(m, lod) for m in ("particles", "field", "paper")
                                     for lod in ("medium", "high")]


def setup(density, temperature, width, density_scale):
    """Per LOD the Gaussians with their colour values (built once), the camera framing the
    density's voxels, the opacity map over the density and the colour map over the temperature."""
    m = np.asarray(density.index_to_world, float)
    lo, hi = np.asarray(density.bbox_min, float) - 0.5, np.asarray(density.bbox_max, float) + 0.5
    c = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                  for z in (lo[2], hi[2])]) @ m.T
    cam = Camera.frame_box(c[:, :3].min(0), c[:, :3].max(0), width, width * 3 // 4,
                           direction=(0.35, 1.0, -0.3))
    d_lo, d_hi = value_range(density)
    tf = TransferFunction.from_colormap("viridis", d_lo, d_hi,
                                        density=density_scale / float(np.ptp(c[:, :3], 0).max()))
    ctf = TransferFunction.from_colormap("inferno", *value_range(temperature), alpha="constant")
    sets = {}

    def scene(mode, lod, colored=True, beside=False):
        """The fire (coloured by the temperature, or by itself); beside: and a copy coloured by
        itself, moved along x by half the box (overlapping)."""
        gs = sets.get(lod)
        if gs is None:
            gs = sets[lod] = attach(build_lod(density, lod), density, temperature)
        kw = dict(color_tf=ctf, color_grid=temperature) if colored else {}
        objs = [RenderObject(gs, m, grid=density, **kw)]
        if beside:
            mb = m.copy()
            mb[:3, 3] += 0.5 * np.ptp(c[:, :3], 0) * (1, 0, 0)
            objs.insert(0, RenderObject(gs, mb, grid=density))
        return RenderScene(objs, mode=mode)

    return scene, cam, tf


@pytest.fixture(scope="module")
def fire_path(tmp_path_factory):
    return str(write_fire_like(tmp_path_factory.mktemp("fire") / "fire.vdb", BACKGROUND))


@pytest.fixture(scope="module")
def fixture_fire(fire_path):
    density, temperature = read_vdb(fire_path).grids
    return setup(density, temperature, 40, 12.0)


@pytest.fixture(scope="module")
def shared_fire():
    if not os.path.exists(FIRE):
        pytest.skip("the shared mantaflow_fire_r96_f035.vdb is not here")
    grids = {g.name: g for g in read_vdb(FIRE, ["density", "temperature"]).grids}
    return setup(grids["density"], grids["temperature"], 64, 10.0)


def compare(gpu, cpu, setup, mode, lod, **kw):
    """The GPU and CPU images and their PSNR (the GPU drew the frame; the number of its screen
    tiles with rays past the shader's hit slots, redrawn on the CPU, is in gpu.stats)."""
    scene, cam, tf = setup
    sc = scene(mode, lod, **kw)
    want = cpu.render(sc, cam, tf)
    got = gpu.render(sc, cam, tf)
    assert "fallback" not in gpu.stats, gpu.stats.get("fallback")
    assert want["Combined"][..., 3].max() > 0.25  # something to compare
    return got, want, psnr(got["Combined"], want["Combined"])


@pytest.mark.parametrize("mode, lod", CASES)
def test_fixture_coloured_by_a_second_grid_matches_the_cpu_device(gpu, cpu, fixture_fire, mode, lod):
    got, want, db = compare(gpu, cpu, fixture_fire, mode, lod)
    print(f"fixture {mode} {lod}: GPU vs CPU {db:.1f} dB")
    assert gpu.stats.get("overflow_tiles", 0) == 0  # every pixel drawn by the shader
    assert db >= GPU_MIN_DB, f"{mode} {lod}: PSNR {db:.1f} dB"
    hit = want["Depth"] < 1e9
    np.testing.assert_array_equal(got["Depth"] < 1e9, hit)
    vdb = psnr(got["Value"], want["Value"])
    assert vdb >= GPU_MIN_DB, f"{mode} {lod}: Value PSNR {vdb:.1f} dB"


@pytest.mark.parametrize("mode", ["reference", "particles", "field", "paper"])
def test_two_objects_one_coloured_by_a_second_grid(gpu, cpu, fixture_fire, mode):
    """Overlapping objects, the second coloured by the temperature: each object's own colour
    rows (obj_color), and the first's Gaussians without colour values (NaN)."""
    _, _, db = compare(gpu, cpu, fixture_fire, mode, "medium", beside=True)
    print(f"fixture {mode}, two objects: GPU vs CPU {db:.1f} dB")
    assert gpu.stats.get("overflow_tiles", 0) == 0
    assert db >= GPU_MIN_DB, f"{mode}, two objects: PSNR {db:.1f} dB"


@pytest.mark.parametrize("shadows", [False, True])
def test_lit_reference_coloured_by_a_second_grid(gpu, cpu, fixture_fire, shadows):
    """Reference mode shades lit volumes on the GPU: the colour grid's colour, then Blinn-Phong
    (a sun, and shadows), as the CPU device does."""
    scene, cam, tf = fixture_fire
    sc = scene("reference", "medium")
    sc = dataclasses.replace(sc, lights=(Light("sun", (-1.0, 1.0, -0.3)),), objects=[
        dataclasses.replace(o, shading="lit", shadows=shadows) for o in sc.objects])
    _, want, db = compare(gpu, cpu, (lambda *a: sc, cam, tf), "reference", "medium")
    emission = cpu.render(scene("reference", "medium"), cam, tf)["Combined"]
    assert np.abs(want["Combined"] - emission).max() > 0.02  # the light shows
    print(f"fixture reference, lit{' + shadows' if shadows else ''}: GPU vs CPU {db:.1f} dB")
    assert db >= GPU_MIN_DB, f"lit reference: PSNR {db:.1f} dB"


@pytest.mark.parametrize("mode", ["reference", "particles", "field", "paper"])
def test_the_colour_grid_colours_the_gpu_image(gpu, fixture_fire, mode):
    """Coloured by the temperature, the GPU image differs from the one coloured by the density
    itself in colour (most visible pixels), not in alpha: the colour grid is read, not ignored."""
    scene, cam, tf = fixture_fire
    own = gpu.render(scene(mode, "medium", colored=False), cam, tf)["Combined"]
    other = gpu.render(scene(mode, "medium"), cam, tf)["Combined"]
    assert "fallback" not in gpu.stats
    alpha = own[..., 3]
    assert (alpha > 0.05).sum() > 100
    np.testing.assert_allclose(other[..., 3], alpha, atol=2e-5)
    diff = np.abs(other[..., :3] - own[..., :3]).max(-1)
    assert (diff[alpha > 0.05] > 0.02).mean() > 0.5


def test_cli_renders_a_colour_grid_on_the_gpu(gpu, bpy_module, fire_path, tmp_path):
    """`./gaussvdb render --color-grid temperature --device gpu` (F12 through the engine): the GPU
    draws it (no fallback) and its image is the CPU device's."""
    got, stats = _render(fire_path, tmp_path, "gpu", "field", "--color-grid", "temperature",
                         "--device", "gpu")
    want, _ = _render(fire_path, tmp_path, "cpu", "field", "--color-grid", "temperature")
    assert stats["device"] == "GPU" and stats["fallback"] is None
    got, want = read_image(bpy_module, got), read_image(bpy_module, want)
    assert want[..., 3].max() > 0.1
    db = psnr(got, want)
    print(f"command line, field, GPU vs CPU: {db:.1f} dB")
    assert db >= GPU_MIN_DB, f"PSNR {db:.1f} dB"


@pytest.mark.parametrize("mode, lod", CASES)
def test_shared_fire_coloured_by_temperature_matches_the_cpu_device(gpu, cpu, shared_fire, mode, lod):
    """(At High the densest particles rays pass the shader's hit slots, coloured or not: those
    few tiles are the CPU's.)"""
    _, _, db = compare(gpu, cpu, shared_fire, mode, lod)
    print(f"shared fire {mode} {lod}: GPU vs CPU {db:.1f} dB, "
          f"{gpu.stats.get('overflow_tiles', 0)} screen tiles redrawn on the CPU")
    assert gpu.stats.get("overflow_tiles", 0) <= 8
    assert db >= GPU_MIN_DB, f"{mode} {lod}: PSNR {db:.1f} dB"
