"""Level sets as lit opaque surfaces: a sphere written here (signed distance on a narrow band)
against its analytic silhouette, normal and depth; lights; compositing with volumes in front,
behind and around."""
import dataclasses

import numpy as np
import pytest

from kernels.lod import build_lod
from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.lights import Light, pack
from kernels.render.scene.synthetic import gaussian_set, grid_from_dense

N, R, W, SPAN = 40, 12.0, 64, 40.0
C = np.array([19.8, 19.6, 19.7])
PIX = SPAN / W
TF = TransferFunction.from_colormap("viridis", 0, 1, density=0.2)
SUN = np.array([1.0, -1.0, 0.3]) / np.linalg.norm([1.0, -1.0, 0.3])  # towards the light
DIFFUSE_ONLY = (0.0, 1.0, 0.0, 32.0)
WHITE = (1.0, 1.0, 1.0)


@pytest.fixture(scope="module")
def sphere():
    g = np.arange(N)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    phi = np.sqrt((X - C[0]) ** 2 + (Y - C[1]) ** 2 + (Z - C[2]) ** 2) - R
    grid = grid_from_dense(np.clip(phi, -3, 3), active=np.abs(phi) < 3, background=3.0,
                           grid_class="level_set")
    return grid, build_lod(grid, "high")


@pytest.fixture(scope="module")
def dev():
    return CPUDevice()


def camera(w=W):
    """Orthographic along +y through the sphere's centre, image up +z, SPAN wide."""
    m = np.eye(4)
    m[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    m[:3, 3] = [C[0], -30.0, C[2]]
    return Camera(m, w, w, "ortho", ortho_scale=SPAN)


def offsets(w=W):
    """(x, z) offsets of the pixel centres from the sphere's axis, and their radius."""
    p = (np.arange(w) + 0.5) / w * SPAN - 0.5 * SPAN
    xx, zz = np.meshgrid(p, p)
    return xx, zz, np.hypot(xx, zz)


def surface(grid, gs=None, mode="reference", **kw):
    return RenderObject(gs, grid=grid, is_level_set=True, surface=True, level_set_color=WHITE, **kw)


def lit(objs, mode, lights=(Light("sun", -SUN),), shading=DIFFUSE_ONLY):
    return RenderScene(objs, mode=mode, lights=lights, shading=shading, transmittance_min=0)


def normal_error_deg(img):
    """Angle between the normal read back from a diffuse-only, strength-1 sun (I = n . l) and the
    sphere's analytic normal, per pixel."""
    xx, zz, r = offsets()
    n = np.stack([xx / R, -np.sqrt(np.maximum(1 - (r / R) ** 2, 0)), zz / R], -1)
    want = np.arccos(np.clip(n @ SUN, -1, 1))
    got = np.arccos(np.clip(img[..., 0].astype(np.float64), 0, 1))
    return np.degrees(np.abs(got - want))


def test_reference_sphere_silhouette_normal_depth(dev, sphere):
    grid, _ = sphere
    out = dev.render(lit([surface(grid)], "reference"), camera(), TF)
    a = out["Combined"][..., 3]
    assert set(np.unique(a)) <= {0.0, 1.0}  # opaque: hit or miss
    _, _, r = offsets()
    hit = a == 1.0
    assert not (hit & (r > R + PIX)).any() and (hit | (r > R - PIX)).all()  # within one pixel
    err = normal_error_deg(out["Combined"])
    assert err[r < 1.5].max() < 2.0, err[r < 1.5].max()
    assert err[r < R / 2].max() < 2.0
    depth = 30.0 + C[1] - np.sqrt(np.maximum(R ** 2 - r ** 2, 0))
    assert np.abs(out["Depth"] - depth)[r < R / 2].max() < 0.05
    assert (out["Depth"][~hit] == 1e10).all() and (out["Value"] == 0).all()


def sphere_errors(out):
    """A rendered sphere against the analytic one: (pixels the silhouette reaches past R, pixels
    it falls short of R, the normal's largest error in degrees at the centre (r < 1.5) and inside
    R/2, the largest |depth error| inside R/2, voxels)."""
    hit = out["Combined"][..., 3] == 1.0
    _, _, r = offsets()
    over = (r[hit & (r > R)].max(initial=R) - R) / PIX
    short = (R - r[~hit & (r < R)].min(initial=R)) / PIX
    err = normal_error_deg(out["Combined"])
    depth = 30.0 + C[1] - np.sqrt(np.maximum(R ** 2 - r ** 2, 0))
    return over, short, err[r < 1.5].max(), err[r < R / 2].max(), np.abs(out["Depth"] - depth)[r < R / 2].max()


def test_field_sphere_silhouette_and_normal(dev, sphere):
    """Field (and particles) mode at High: the zero of the normalised mixture of the Gaussians'
    signed distances is within one pixel of the analytic silhouette (0.46 px past it, 0.16 px
    short), its normal (the least-squares fit of the distances) within 2 degrees of the analytic
    one at the centre (0.16) and inside R/2 (0.61), its depth within 0.4 voxel there (0.3).
    Medium: 1.6 px past the silhouette, 1.3 degrees at the centre, 3.9 inside R/2 (the 0.5
    occupancy: 1.7 px, 6.5 degrees, 26 holes inside R/2). Low (a Gaussian per leaf): no surface
    worth the name either way (13 px short, 24 degrees at the centre)."""
    grid, gs = sphere
    assert gs.distances is not None and len(gs.distances) == gs.count
    out = dev.render(lit([surface(grid, gs)], "field"), camera(), TF)
    assert set(np.unique(out["Combined"][..., 3])) <= {0.0, 1.0}
    over, short, centre, half, depth = sphere_errors(out)
    assert over <= 1.0 and short <= 1.0, (over, short)
    assert centre < 2.0 and half < 2.0, (centre, half)
    assert depth < 0.4, depth
    particles = dev.render(lit([surface(grid, gs)], "particles"), camera(), TF)["Combined"]
    np.testing.assert_array_equal(particles, out["Combined"])  # surfaces draw by the field sampler
    medium = dev.render(lit([surface(grid, build_lod(grid, "medium"))], "field"), camera(), TF)
    over, short, centre, half, depth = sphere_errors(medium)
    assert over <= 2.0 and short <= 1.0 and centre < 2.0 and half < 5.0 and depth < 2.0, \
        (over, short, centre, half, depth)


def test_field_sphere_without_distances_is_the_mixtures_half_level(dev, sphere):
    """Gaussians without signed distances (files written before them): the High LOD mixture's 0.5
    occupancy. The shell of the narrow band holds the Gaussians, so that level lies about half its
    width (sqrt(3)/2 voxel) outside the zero level: the silhouette is that much wider, never
    narrower; the normal is the blurred mixture's."""
    grid, gs = sphere
    old = dataclasses.replace(gs, distances=None)
    out = dev.render(lit([surface(grid, old)], "field"), camera(), TF)
    over, short, centre, _, _ = sphere_errors(out)
    assert short <= 1.0 and over <= (0.5 * np.sqrt(3) + PIX) / PIX, (over, short)
    assert centre < 8.0
    err = normal_error_deg(out["Combined"])
    assert err[offsets()[2] < R / 2].mean() < 5.0


def blinn_phong(albedo, shading, light_at):
    """The analytic Blinn-Phong colour of the sphere at the pixel centres: light_at(point) gives
    (unit direction towards the light, irradiance) at the surface point."""
    ka, kd, ks, sh = shading
    xx, zz, r = offsets()
    n = np.stack([xx / R, -np.sqrt(np.maximum(1 - (r / R) ** 2, 0)), zz / R], -1)
    p = C + R * n
    ldir, e = light_at(p)
    v = np.array([0.0, -1.0, 0.0])  # towards the camera
    h = ldir + v
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    ndl = np.maximum((n * ldir).sum(-1), 0)[..., None]
    spec = ks * np.maximum((n * h).sum(-1), 0)[..., None] ** sh * (ndl > 0)
    return ka * albedo + e[..., None] * (kd * ndl * albedo + spec)


def test_headlight_and_point_light(dev, sphere):
    """No lights: a headlight (irradiance 1 along the view). A point light of power P: P / (4 pi
    d^2) at distance d. Both against the analytic Blinn-Phong colour inside half the radius."""
    grid, _ = sphere
    shading = (0.1, 0.8, 0.2, 32.0)
    albedo = np.array([0.2, 0.5, 0.9])
    ob = RenderObject(grid=grid, is_level_set=True, surface=True, level_set_color=tuple(albedo))
    _, _, r = offsets()
    core = r < R / 2
    img = dev.render(RenderScene([ob], mode="reference", shading=shading), camera(), TF)["Combined"]
    want = blinn_phong(albedo, shading, lambda p: (np.broadcast_to([0.0, -1.0, 0.0], p.shape),
                                                   np.ones(p.shape[:-1])))
    np.testing.assert_allclose(img[core, :3], want[core], atol=1e-2)  # ~1 degree in the highlight
    d = 20.0
    pos = C - np.array([0.0, R + d, 0.0])
    pt = Light("point", pos, (1, 1, 1), 4 * np.pi * d * d)  # irradiance 1 at the nearest point

    def at_point(p):
        v = pos - p
        d2 = (v * v).sum(-1)
        return v / np.sqrt(d2)[..., None], d * d / d2

    img = dev.render(RenderScene([ob], mode="reference", shading=shading, lights=(pt,)), camera(),
                     TF)["Combined"]
    np.testing.assert_allclose(img[core, :3], blinn_phong(albedo, shading, at_point)[core], atol=1e-2)
    assert pack(()).shape == (1, 8) and pack((pt,))[0, 0] == 1.0
    with pytest.raises(ValueError, match="kind"):
        Light("torch")


def fog_box(lo, hi, value=0.6):
    """A constant fog block over [lo, hi) voxels (its own grid)."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    return grid_from_dense(np.full(hi - lo, value), lo)


@pytest.mark.parametrize("mode", ["reference", "field"])
def test_volumes_in_front_behind_and_around(dev, sphere, mode):
    grid, gs = sphere
    cam = camera()
    _, _, r = offsets()
    core = r < R / 2

    def vol(g):
        if mode == "reference":
            return RenderObject(grid=g)
        cs = np.argwhere(np.ones(g.bbox_max - g.bbox_min + 1, bool)) + g.bbox_min
        sig = 0.8
        v = float(g.leaf_values[0, 0])
        return RenderObject(gaussian_set(cs.astype(float), sig, v, 1 / ((2 * np.pi) ** 1.5 * sig ** 3)))

    def img(objs):
        return dev.render(lit(objs, mode), cam, TF)

    alone = img([surface(grid, gs)])
    # behind: the surface ends the ray, nothing behind it shows
    behind = img([surface(grid, gs), vol(fog_box((0, 34, 0), (40, 40, 40)))])
    np.testing.assert_array_equal(behind["Combined"][core], alone["Combined"][core])
    # in front: fog over the surface, T_fog times the lit surface
    front_vol = vol(fog_box((0, 0, 0), (40, 4, 40)))  # its supports end before the surface
    fog_only = img([front_vol])
    fog = fog_only["Combined"]
    front = img([surface(grid, gs), front_vol])
    T = 1.0 - fog[..., 3:]
    assert 0.2 < T[core].mean() < 0.9
    np.testing.assert_allclose(front["Combined"][core], (fog + T * alone["Combined"])[core], atol=2e-4)
    # Depth: where the fog reaches opacity 0.5 first, the fog's; elsewhere the surface's
    thick = fog[..., 3] >= 0.5
    want = np.where(thick, fog_only["Depth"], alone["Depth"])
    np.testing.assert_allclose(front["Depth"][core], want[core], atol=1e-4)
    # around: the fog fills the box the sphere sits in; its part in front of the surface shows
    around = img([surface(grid, gs), vol(fog_box((0, 0, 0), (40, 40, 40), 0.05))])
    a = around["Combined"]
    assert (a[core, 3] == 1.0).all()
    assert (np.abs(a[core, :3] - alone["Combined"][core, :3]) > 1e-3).any()
    # the surface depth, to float32 rounding (the GPU marches the fog in other steps)
    np.testing.assert_allclose(around["Depth"][core], alone["Depth"][core], rtol=3e-7)


def test_paper_mode_and_shell_option_keep_the_shell(dev, sphere):
    grid, gs = sphere
    shell = RenderObject(gs, grid=grid, is_level_set=True, level_set_color=WHITE)
    for mode in ("paper", "field"):
        want = dev.render(lit([shell], mode), camera(24), TF)["Combined"]
        assert want[..., 3].max() < 1.0  # translucent
        if mode == "paper":
            got = dev.render(lit([surface(grid, gs)], mode), camera(24), TF)["Combined"]
            np.testing.assert_array_equal(got, want)


def test_bench_surface_on_a_written_sphere(tmp_path):
    """`./gaussvdb bench surface FILE` on a sphere level set written with openvdb: the field surface
    at High against the voxels' reference surface, in its JSON."""
    import json
    import os

    from conftest import ROOT, run_cli
    from vdb_fixtures import write_grid

    g = np.arange(N)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    phi = np.sqrt((X - C[0]) ** 2 + (Y - C[1]) ** 2 + (Z - C[2]) ** 2) - R
    path = write_grid(tmp_path / "sphere.vdb", np.clip(phi, -3, 3), name="surface", background=3.0,
                      grid_class="level set", tolerance=0.0)
    out = tmp_path / "surface.json"
    proc = run_cli(ROOT, "bench", "surface", str(path), "--size", "96x96", "--lods", "high", "--json",
                   str(out), env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr[-3000:]
    (row,) = json.loads(out.read_text())
    assert row["lod"] == "high" and row["gaussians"] > 0 and row["target"] == 35.0
    assert row["psnr"] > 30.0, row
