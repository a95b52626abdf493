"""The GPU device (compute shaders on Blender's gpu module, llvmpipe here) against the CPU device:
the reference mode on a fog volume, a level-set surface and two overlapping objects (PSNR >= 50 dB,
Depth and Value passes), splat mode (drawn as the reference mode), clip planes, early termination,
a background and lit volumes with shadows; F12 with write_still;
the viewport's draw code into an offscreen; and, with EGL made unavailable, the CPU rendering and
the GPU choice falling back with a warning instead of aborting the process."""
import json
import math
import os

import numpy as np
import pytest
from references import GPU_MIN_DB, psnr
from test_engine_helpers import add_camera, read_image, setup_render
from vdb_fixtures import write_grid

from kernels.lod import build_lod
from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.clip import plane_from_point_normal
from kernels.render.scene.lights import Light
from kernels.render.scene.synthetic import grid_from_dense

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
N, W = 40, 64
TF = TransferFunction.from_colormap("viridis", 0, 1.0, density=0.3)



def grids():
    g = np.arange(N)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    fog = np.exp(-((X - 19.5) ** 2 + (Y - 21) ** 2 + (Z - 18) ** 2) / 120.0) * (1 + 0.3 * np.sin(X / 3.0))
    phi = np.sqrt((X - 19.8) ** 2 + (Y - 19.6) ** 2 + (Z - 19.7) ** 2) - 12.0
    return (grid_from_dense(fog, active=fog > 0.02),
            grid_from_dense(np.clip(phi, -3, 3), active=np.abs(phi) < 3, background=3.0,
                            grid_class="level_set"),
            grid_from_dense(np.full((20, 30, 16), 0.4), (10, 5, 12)))


def scenes():
    fog, ls, box = grids()
    m = np.eye(4)
    m[:3, :3] *= 1.1
    m[:3, 3] = (3.0, 2.0, -1.5)
    sun = (Light("sun", (-1.0, 1.0, -0.3)),)
    surf = dict(is_level_set=True, surface=True, level_set_color="z")
    return {
        "fog": RenderScene([RenderObject(grid=fog)], mode="reference"),
        "level_set": RenderScene([RenderObject(grid=ls, **surf)], mode="reference", lights=sun),
        "two_overlapping": RenderScene([RenderObject(grid=fog), RenderObject(grid=box, matrix_world=m)],
                                       mode="reference"),
        "surface_in_fog_background": RenderScene([RenderObject(grid=ls, **surf), RenderObject(grid=box)],
                                                 mode="reference", background=(0.1, 0.2, 0.3, 1.0)),
        # splat mode is the reference mode over lattices of the Gaussian field (level sets: voxels)
        "splat": RenderScene([RenderObject(build_lod(fog, "medium"), grid=fog),
                              RenderObject(build_lod(ls, "high"), m, grid=ls, **surf)], mode="splat", lights=sun),
        "clip_early_termination": RenderScene(
            [RenderObject(grid=fog, clip=np.atleast_2d(plane_from_point_normal((20, 0, 0), (1, 0, 0))))],
            mode="reference", transmittance_min=0.3),
    }


CAM = Camera.frame_box([0] * 3, [N] * 3, W, W, direction=(0.3, 1.0, -0.2))


@pytest.mark.parametrize("name", list(scenes()))
def test_reference_mode_matches_the_cpu_device(gpu, cpu, name):
    sc = scenes()[name]
    want = cpu.render(sc, CAM, TF)
    got = gpu.render(sc, CAM, TF)
    assert gpu.stats.get("gpu") and "fallback" not in gpu.stats
    assert want["Combined"][..., 3].max() > 0.3  # something to compare
    db = psnr(got["Combined"], want["Combined"])
    print(f"{name}: GPU vs CPU {db:.1f} dB on {gpu.stats['gpu']}")
    assert db >= GPU_MIN_DB, f"{name}: PSNR {db:.1f} dB < {GPU_MIN_DB} dB"
    hit = want["Depth"] < 1e9
    np.testing.assert_array_equal(got["Depth"] < 1e9, hit)
    assert_depths_agree(got["Depth"][hit], want["Depth"][hit], sc)
    np.testing.assert_allclose(got["Value"], want["Value"], atol=1e-4)


def assert_depths_agree(got, want, sc):
    """Depths agree to 1e-4, but for rays that graze a surface, which may differ by two steps.
    A surface hit is the first sample whose signed distance is <= 0, refined by bisection over
    the step before it. The GPU samples in float32, the CPU in float64 (and numba's and
    llvmpipe's code differ with the CPU's instruction set), so a sample whose distance lies within
    rounding of 0 can count as inside on one device only: that ray's crossing is then found in the
    step before or after, both inside the two steps around that sample. Such rays are rare (1 of
    356 hit pixels on one AVX-512 machine, with 0.21 of a 0.5-voxel step apart): at most 1% may."""
    voxel = max(np.linalg.norm(ob.matrix_world[:3, :3] @ ob.grid.index_to_world[:3, :3], axis=0).max()
                for ob in sc.objects)  # a voxel's longest world edge
    bound = 2.0 * sc.step * voxel
    close = np.isclose(got, want, rtol=1e-4, atol=1e-2)
    far = np.abs(got - want)[~close]
    assert far.size <= max(1, close.size // 100), f"{far.size} of {close.size} depths differ"
    assert np.all(far <= bound), f"depths differ by {far.max():.3f} > two steps ({bound:.3f})"


def test_bands_and_regions_are_pixels_of_the_whole_frame(gpu):
    sc = scenes()["two_overlapping"]
    full = gpu.render(sc, CAM, TF)["Combined"]
    steps = []
    part = gpu.render(sc, CAM, TF, rows=(5, 50), cols=(7, 61), progress=steps.append, cancel=lambda: False)
    np.testing.assert_array_equal(part["Combined"], full[5:50, 7:61])
    assert steps[-1] == 1.0


def test_the_gpu_device_is_registered_where_the_probe_passes(gpu):
    from bl_ext.user_default.gaussvdb.kernels.render import available_devices, get_device

    assert available_devices() == ["CPU", "GPU"]
    assert get_device("GPU").name == "GPU"


@pytest.mark.parametrize("shadows", [False, True])
def test_lit_volumes_match_the_cpu_device(gpu, cpu, shadows):
    fog, _, box = grids()
    lights = (Light("sun", (-1.0, 1.0, -0.3)), Light("point", (50.0, -20.0, 60.0), strength=3000.0))

    def scene(shading, shadows):
        return RenderScene([RenderObject(grid=fog, shading=shading, shadows=shadows),
                            RenderObject(grid=box, shading=shading, shadows=shadows)],
                           mode="reference", lights=lights)

    # what the lights (or the shadows) change: emission (or lit without shadows)
    before = cpu.render(scene("lit" if shadows else "emission", False), CAM, TF)["Combined"]
    want = cpu.render(scene("lit", shadows), CAM, TF)["Combined"]
    got = gpu.render(scene("lit", shadows), CAM, TF)["Combined"]
    assert "fallback" not in gpu.stats
    assert np.abs(want - before).max() > 0.02
    db = psnr(got, want)
    print(f"lit{' + shadows' if shadows else ''}: GPU vs CPU {db:.1f} dB")
    assert db >= GPU_MIN_DB, f"PSNR {db:.1f} dB"


def test_a_frame_the_gpu_cannot_draw_goes_to_the_cpu(gpu):
    """A Gaussian wider than the GPU's 1/sigma codes hold: the device draws the frame on the CPU
    (the same image) and says why."""
    from kernels.render.scene.synthetic import gaussian_set

    gs = gaussian_set([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0]], [[1.0] * 3, [1e5] * 3], [1.0, 0.5], [1.0, 1.0])
    sc = RenderScene([RenderObject(gs)], mode="particles")
    cam = Camera.frame_box([-3] * 3, [3] * 3, 8, 8)
    got = gpu.render(sc, cam, TF)["Combined"]
    assert gpu.stats["fallback"] == "a Gaussian too small or large for the GPU's size codes"
    np.testing.assert_array_equal(got, CPUDevice().render(sc, cam, TF)["Combined"])


def test_viewport_draw_code_draws_the_device_image(gpu):
    """viewport.draw_texture (what view_draw calls with the GPU device) into an offscreen inside
    a GPU context: its pixels are the device's image."""
    import gpu as gpu_module
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import viewport
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu import context
    from mathutils import Matrix

    sc = scenes()["surface_in_fog_background"]
    want = gpu.render(sc, CAM, TF)["Combined"]

    def draw():
        tex = gpu.render_texture(sc, CAM, TF)
        off = gpu_module.types.GPUOffScreen(W, W, format="RGBA32F")
        with off.bind():
            fb = gpu_module.state.active_framebuffer_get()
            fb.clear(color=(0.0, 0.0, 0.0, 0.0))
            with gpu_module.matrix.push_pop(), gpu_module.matrix.push_pop_projection():
                gpu_module.matrix.load_identity()
                proj = Matrix.Identity(4)  # region pixels -> clip space, as in view_draw
                proj[0][0], proj[1][1], proj[0][3], proj[1][3] = 2.0 / W, 2.0 / W, -1.0, -1.0
                gpu_module.matrix.load_projection_matrix(proj)
                viewport.draw_texture(tex, W, W)
            buf = fb.read_color(0, 0, W, W, 4, 0, "FLOAT")
        off.free()
        buf.dimensions = W * W * 4
        return np.frombuffer(buf, np.float32).reshape(W, W, 4).copy()

    px = context.run(draw)
    err = np.abs(px - want).max()
    assert err < 1e-3, f"viewport pixels differ from the device image by {err}"


def _fog_file(tmp_path):
    g = np.arange(24)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    v = np.exp(-((X - 11.5) ** 2 + (Y - 12) ** 2 + (Z - 11) ** 2) / 40.0)
    return write_grid(tmp_path / "fog.vdb", np.where(v > 0.03, v, 0.0))


def test_f12_write_still_with_the_gpu_device(gpu, bpy_module, scene, tmp_path):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import image_file
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.io import importer

    importer.import_vdb(str(_fog_file(tmp_path)), lods=("low",), collection=scene.collection,
                        compute_error=False)
    add_camera(bpy_module, scene, (11.5, -60.0, 11.5), (math.pi / 2, 0.0, 0.0), ortho_scale=30.0)
    setup_render(scene, 48, 40)
    scene.gaussvdb.mode = "REFERENCE"
    scene.render.film_transparent = True
    images = {}
    for device in ("CPU", "GPU"):
        scene.gaussvdb.device = device
        out = tmp_path / f"{device}.exr"
        stats = image_file.render_scene_to_file(scene, str(out))  # render.render(write_still=True)
        assert out.exists() and stats["device"] == device
        images[device] = read_image(bpy_module, out)
    assert stats["gpu"]
    assert images["CPU"][..., 3].max() > 0.3
    db = psnr(images["GPU"], images["CPU"])
    print(f"F12 GPU vs CPU {db:.1f} dB")
    assert db >= GPU_MIN_DB, f"PSNR {db:.1f} dB"


def test_without_egl_the_cpu_renders_and_the_gpu_choice_falls_back(tmp_path):
    """EGL made unavailable: asking for a GPU context would abort Blender; the probe's child
    aborts instead, the render goes to the CPU with a one-line warning, exit status 0."""
    from conftest import run_cli

    src = _fog_file(tmp_path)
    env = dict(os.environ, __EGL_VENDOR_LIBRARY_FILENAMES="/nonexistent.json",
               GAUSSVDB_BLENDER_EXTENSIONS=os.environ["BLENDER_USER_EXTENSIONS"])
    for device in ("cpu", "gpu"):
        out = tmp_path / f"{device}.png"
        proc = run_cli(ROOT, "render", str(src), "--mode", "reference", "--lod", "low", "--size",
                       "32x24", "--device", device, "--out", str(out), "--json", env=env)
        assert proc.returncode == 0, proc.stderr[-2000:]
        stats = json.loads(proc.stdout.strip().splitlines()[-1])
        assert stats["device"] == "CPU" and out.exists()
        warned = [ln for ln in (proc.stdout + proc.stderr).splitlines() if "GPU device is not available" in ln]
        assert len(warned) == (1 if device == "gpu" else 0), proc.stdout + proc.stderr
