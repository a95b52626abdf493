"""The GPU device's Gaussian modes against the CPU device (llvmpipe here): particles, field and
paper on a fog volume, a level set (field: its surface; particles, paper: a shell), two
overlapping objects and Gaussians of varied, anisotropic sizes (whose 1/sigma codes round)
(PSNR >= 50 dB, Depth and Value passes); rays with more chords than the shader's hit slots, whose
tiles the CPU device draws; a level set whose faces keep one layer of voxels (field_crossing's
single-layer rule); the packed Gaussian words bit for bit through upload and texelFetch."""

import numpy as np
import pytest
from references import GPU_MIN_DB, psnr

from kernels.render import Camera, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.synthetic import gaussian_set

W = 48
TF = TransferFunction.from_colormap("viridis", 0, 1.0, density=0.4)



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


def varied():
    """The fog's lattice with random anisotropic sizes (1/sigma rounds in its 18-bit code)."""
    r2 = lambda c: ((c - 7.5) ** 2).sum(1)  # noqa: E731
    g = np.arange(16)
    c = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3).astype(float)
    c = c[r2(c) < 60]
    rng = np.random.default_rng(3)
    sig = rng.uniform(0.6, 1.1, (len(c), 3))
    amp = 1.0 / ((2 * np.pi) ** 1.5 * sig.prod(1))
    return gaussian_set(c + rng.normal(0, 0.05, c.shape), sig, np.exp(-r2(c) / 30.0), amp)


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
            "two objects": two, "varied sizes": [RenderObject(varied())]}


CAM = Camera.frame_box([0] * 3, [20] * 3, W, W, direction=(1, 0.4, -0.3))


@pytest.mark.parametrize("mode", ["particles", "field", "paper"])
@pytest.mark.parametrize("name", ["fog", "level set", "two objects", "varied sizes"])
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
    assert db >= GPU_MIN_DB, f"{mode}, {name}: PSNR {db:.1f} dB"
    print(f"{mode} {name}: {db:.1f} dB, overflow tiles {gpu.stats.get('overflow_tiles')}")
    # Depth where both reach half opacity; Value where the CPU has one
    d0, d1 = want["Depth"], got["Depth"]
    both = (d0 < 1e9) & (d1 < 1e9)
    assert np.mean((d0 < 1e9) != (d1 < 1e9)) < 0.01
    np.testing.assert_allclose(d1[both], d0[both], rtol=1e-3, atol=1e-3)
    vdb = psnr(got["Value"], want["Value"])
    assert vdb >= GPU_MIN_DB, f"{mode}, {name}: Value PSNR {vdb:.1f} dB"


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
    assert db >= GPU_MIN_DB, f"overflow: PSNR {db:.1f} dB"


def test_packed_gaussian_words_survive_upload_and_fetch(gpu, cpu):
    """g_rec's packed words (gpu.tables_gauss.size_words) read back in a compute shader with
    floatBitsToUint are the bits numpy packed: each 16-bit half written out as an exact float."""
    import gpu as gpu_module
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu import compute, context

    from kernels.render.gpu import tables_gauss as L

    sc = RenderScene([RenderObject(varied())], mode="particles")
    fr = cpu.begin_frame(sc, CAM, TF)
    table = L.gauss_tables(fr.mode, fr.gauss)["g_rec"]

    def run():
        info = gpu_module.types.GPUShaderCreateInfo()
        info.image(0, "RGBA32F", "FLOAT_2D", "lo", qualifiers={"WRITE"})
        info.image(1, "RGBA32F", "FLOAT_2D", "hi", qualifiers={"WRITE"})
        info.sampler(0, "FLOAT_2D", "g_rec")
        info.local_group_size(8, 8)
        info.compute_source("""void main() {
  ivec2 p = ivec2(gl_GlobalInvocationID.xy);
  uvec4 u = floatBitsToUint(texelFetch(g_rec, p, 0));
  imageStore(lo, p, vec4(u & 0xffffu));
  imageStore(hi, p, vec4(u >> 16u));
}""")
        sh = gpu_module.shader.create_from_info(info)
        tex = compute.upload({"g_rec": table})["g_rec"]
        h, w = table.shape[:2]
        out = [gpu_module.types.GPUTexture((w, h), format="RGBA32F") for _ in range(2)]
        sh.bind()
        sh.uniform_sampler("g_rec", tex)
        sh.image("lo", out[0])
        sh.image("hi", out[1])
        gpu_module.compute.dispatch(sh, -(-w // 8), -(-h // 8), 1)
        return [compute.read(t) for t in out]

    lo, hi = context.run(run)
    bits = table.view(np.uint32)
    assert table.size >= 8 * fr.gauss.rec.shape[0]  # every Gaussian's 8 words compared
    assert (lo == (bits & 0xFFFF)).all() and (hi == (bits >> 16)).all()


def test_field_sphere_surface_on_the_gpu(gpu, cpu):
    """The written sphere level set at High in field mode (test_render_surface's): the GPU's image
    equals the CPU's (>= 50 dB) and meets the same bounds: silhouette within one pixel, normal
    within 2 degrees at the centre and inside R/2; without signed distances (older files), the
    0.5 occupancy matches too."""
    from dataclasses import replace

    import test_render_surface as S

    grid, gs = S.sphere.__wrapped__()
    for g in (gs, replace(gs, distances=None)):
        sc = S.lit([S.surface(grid, g)], "field")
        want = cpu.render(sc, S.camera(), S.TF)
        got = gpu.render(sc, S.camera(), S.TF)
        assert gpu.stats.get("fallback") is None and gpu.stats["overflow_tiles"] == 0
        db = psnr(got["Combined"], want["Combined"])
        print(f"sphere surface ({'distances' if g.distances is not None else 'occupancy'}): {db:.1f} dB")
        assert db >= GPU_MIN_DB, db
    over, short, centre, half, _ = S.sphere_errors(gpu.render(S.lit([S.surface(grid, gs)], "field"),
                                                              S.camera(), S.TF))
    assert over <= 1.0 and short <= 1.0 and centre < 2.0 and half < 2.0, (over, short, centre, half)


@pytest.fixture(scope="module")
def one_layer_cube(tmp_path_factory):
    """A cube level set whose faces lie 0.9 voxel past a layer of voxel centres: the band keeps one
    layer of voxels under each face (distance 0.1, never 0), so every hit on it is a passage
    through a single layer (cpu.surface.field_crossing's rule), at Medium and High."""
    from vdb_fixtures import write_grid

    from kernels.lod import build_lod
    from kernels.vdb import read_vdb

    g = np.arange(33)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    phi = np.max([np.abs(X - 16.0), np.abs(Y - 16.0), np.abs(Z - 16.0)], axis=0) - 8.9
    path = write_grid(tmp_path_factory.mktemp("layer") / "cube_ls.vdb", np.clip(phi, -3, 3),
                      name="surface", background=3.0, grid_class="level set", tolerance=1e-6)
    grid = read_vdb(str(path)).grids[0]
    return grid, {lod: build_lod(grid, lod) for lod in ("medium", "high")}


@pytest.mark.parametrize("mode", ["field", "particles"])
@pytest.mark.parametrize("lod", ["medium", "high"])
def test_single_layer_surface_matches_the_cpu(gpu, cpu, one_layer_cube, lod, mode):
    """Seen along an axis and obliquely: the CPU hits every pixel inside the cube's faces (no
    holes where the distances never reach 0) and the GPU's image equals it (>= 50 dB)."""
    grid, sets = one_layer_cube
    sc = RenderScene([RenderObject(sets[lod], grid=grid, surface=True)], mode=mode)
    for d in ((0.0, 1.0, 0.0), (0.35, 1.0, -0.3)):
        cam = Camera.frame_box(np.full(3, 6.5), np.full(3, 25.5), 24, 24, direction=d)
        want = cpu.render(sc, cam, TF)
        got = gpu.render(sc, cam, TF)
        assert gpu.stats.get("fallback") is None and gpu.stats["overflow_tiles"] == 0
        if d[0] == 0.0:  # the face fills the frame's middle: no pixel there misses it
            assert (want["Combined"][6:18, 6:18, 3] > 0.99).all()
        db = psnr(got["Combined"], want["Combined"])
        print(f"one-layer cube {lod} {mode} {d}: {db:.1f} dB")
        assert db >= GPU_MIN_DB, f"{lod} {mode} {d}: {db:.1f} dB"
