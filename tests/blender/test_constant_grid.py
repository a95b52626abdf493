"""A fog grid whose active voxels all hold one value (Houdini fog, pyopenvdb masks) renders as a
visible, uniform medium in every mode, through the automatic range of the render settings."""

import math

import numpy as np
import pytest
from test_engine_helpers import add_camera, read_image, setup_render
from vdb_fixtures import openvdb, write_constant_fog

N = 24  # voxels per side: 3 x 3 x 3 leaves
W = H = 48
# Interior variation allowed: the voxel renderer is exact; Medium's Gaussians sum to a field that
# ripples over their lattice (measured 16% in alpha here); the paper's closest-hit compositing more.
SPREAD = {"REFERENCE": 0.02, "FIELD": 0.25, "PARTICLES": 0.25, "PAPER": 0.5}


def write_constant(path, value, layout):
    """N^3 active voxels of ``value``: as 27 leaf-sized active tiles (what copyFromArray and
    pruning write) or as 27 dense leaves (voxel by voxel)."""
    if layout == "tiles":
        return write_constant_fog(path, value, shape=(N, N, N))
    ov = openvdb()
    g = ov.FloatGrid()
    g.name = "density"
    acc = g.getAccessor()
    for ijk in np.ndindex(N, N, N):
        acc.setValueOn(ijk, float(value))
    ov.write(str(path), grids=[g])
    return path


def _render(bpy, scene, path, mode, out):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import image_file
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.io import importer

    objs = importer.import_vdb(str(path), lods=("medium",), collection=scene.collection,
                               compute_error=False)
    assert len(objs) == 1
    # orthographic, along +Y, one pixel per voxel: the cube covers pixels 12..35 in x and z
    add_camera(bpy, scene, (N / 2 - 0.5, -60.0, N / 2 - 0.5), (math.pi / 2, 0.0, 0.0),
               ortho_scale=float(W))
    setup_render(scene, W, H)
    s = scene.gaussvdb
    s.mode = mode
    s.auto_range = True
    # optical depth ~1.2 across the cube at full alpha: bright, not saturated. The paper's
    # compositing divides each Gaussian's density by det(Sigma) (64 to 1838 voxel^6 here).
    s.density_unit = "WORLD"
    s.density = 0.05 * (20000.0 if mode == "PAPER" else 1.0)
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    scene.render.film_transparent = True
    stats = image_file.render_scene_to_file(scene, str(out))
    return read_image(bpy, out), stats


@pytest.mark.parametrize("layout,value", [("tiles", 0.5), ("tiles", 1.0), ("leaves", 0.5)])
@pytest.mark.parametrize("mode", ["PARTICLES", "FIELD", "PAPER", "REFERENCE"])
def test_constant_fog_is_visible_and_uniform(bpy_module, scene, tmp_path, mode, layout, value):
    path = write_constant(tmp_path / "const.vdb", value, layout)
    px, stats = _render(bpy_module, scene, path, mode, tmp_path / "const.png")
    lo, hi = stats["value_range"]
    assert hi == pytest.approx(value) and lo < hi  # the one value is the top of the range
    inside = px[16:32, 16:32]
    alpha = inside[..., 3]
    assert alpha.min() > 0.1, f"{mode}: the constant medium is (nearly) invisible: {alpha.min()}"
    assert inside[..., :3].max() > 0.1, f"{mode}: black medium"
    spread = (alpha.max() - alpha.min()) / alpha.mean()
    assert spread < SPREAD[mode], f"{mode}: alpha spread {spread:.3f} over the interior"
    if mode != "PAPER":  # (its closest-hit compositing draws a tile's tails brighter than its core)
        # and next to nothing far outside the cube (a tile's Gaussian has sigma 3.5 voxels)
        assert max(px[:3, :, 3].max(), px[:, :3, 3].max()) < 0.02
