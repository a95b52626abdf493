"""Issue 5: matrix_world is the grid's index-to-world transform; world boxes match Blender's Volume
import (which keeps the object matrix identity and puts the grid transform inside the volume data;
its bounds are the box of the grid's leaf nodes and active tiles, in voxel corners)."""

import importlib
import math
import os

import numpy as np
import pytest
from conftest import ADDON_MODULE, SAMPLE, shared_data_files


def _rot(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def oblique_matrix():
    m = np.eye(4)
    m[:3, :3] = _rot((1, 2, 3), 0.6) @ np.diag([0.5, 0.5, 3.0])
    m[:3, 3] = (1.25, -2.0, 0.75)
    return m


def write_oblique(path, level_set=False):
    from vdb_fixtures import openvdb, write_grid

    m = oblique_matrix()
    if not level_set:
        # Dense 16 x 8 x 24 block on leaf boundaries: its voxel box is its leaf box.
        vals = np.linspace(0.1, 1.0, 16 * 8 * 24, dtype=np.float32).reshape(16, 8, 24)
        return write_grid(path, vals, name="density", origin=(-8, 16, 8), matrix=m)
    ov = openvdb()
    g = ov.createLevelSetSphere(radius=6.0, center=(2.0, -1.0, 3.0), voxelSize=1.0, halfWidth=3.0)
    g.name = "surface"
    g.transform = ov.createLinearTransform(m.T.tolist())
    ov.write(str(path), grids=[g])
    return path


def _corners(lo, hi):
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def world_box(matrix, lo, hi):
    c = _corners(lo, hi)
    w = c @ np.asarray(matrix)[:3, :3].T + np.asarray(matrix)[:3, 3]
    return w.min(0), w.max(0)


def blender_volume_box(bpy, path):
    bpy.ops.object.volume_import(filepath=path)
    vol = bpy.context.active_object
    assert vol.type == "VOLUME" and vol.data.grids.load()
    mw = np.asarray(vol.matrix_world)
    assert np.allclose(mw, np.eye(4))  # Blender: identity object, transform inside the grid
    box = np.array(vol.bound_box)
    lo, hi = world_box(mw, box.min(0), box.max(0))
    bpy.data.objects.remove(vol)
    return lo, hi


def gaussvdb_leaf_box(objs):
    los, his = [], []
    for o in objs:
        lo, hi = world_box(o.matrix_world, o.gaussvdb.leaf_box_min, o.gaussvdb.leaf_box_max)
        los.append(lo)
        his.append(hi)
    return np.min(los, 0), np.max(his, 0)


def _imp():
    return importlib.import_module(ADDON_MODULE + ".gaussvdb_addon.io.importer")


def _schema():
    return importlib.import_module(ADDON_MODULE + ".gaussvdb_addon.io.schema")


@pytest.mark.parametrize("level_set", [False, True], ids=["fog", "level_set"])
def test_oblique_transform_lands_where_blender_puts_the_volume(scene, bpy_module, tmp_path, level_set):
    bpy = bpy_module
    path = str(write_oblique(tmp_path / "oblique.vdb", level_set))
    imp = _imp()
    objs = imp.import_vdb(path, lods=("low", "high"), compute_error=False)
    assert len(objs) == 1
    obj = objs[0]
    m = oblique_matrix()
    np.testing.assert_allclose(np.asarray(obj.matrix_world), m, rtol=0, atol=1e-6)
    np.testing.assert_allclose(_schema().stored_index_to_world(obj), m, rtol=0, atol=1e-12)
    b_lo, b_hi = blender_volume_box(bpy, path)
    g_lo, g_hi = gaussvdb_leaf_box(objs)
    np.testing.assert_allclose(g_lo, b_lo, atol=1e-4)
    np.testing.assert_allclose(g_hi, b_hi, atol=1e-4)
    half_voxel = 0.5 * 3.0  # the longest voxel edge is 3
    # Every Gaussian centre lies in Blender's box; the dense fog block fills its leaves, so the
    # High LOD's 2^3 blocks cover exactly the voxel box = Blender's box (within half a voxel).
    mw = np.asarray(obj.matrix_world)
    attrs = _schema().read_attributes(obj)
    world = attrs["position"].astype(np.float64) @ mw[:3, :3].T + mw[:3, 3]
    assert np.all(world >= b_lo - 1e-4) and np.all(world <= b_hi + 1e-4)
    if not level_set:
        high = attrs["gs_lod"] == 1
        half = np.cbrt(attrs["gs_voxels"][high].astype(np.float64))[:, None] / 2
        c = attrs["position"][high].astype(np.float64)
        lo, hi = world_box(mw, (c - half).min(0), (c + half).max(0))
        assert np.all(np.abs(lo - b_lo) <= half_voxel) and np.all(np.abs(hi - b_hi) <= half_voxel)
    else:
        assert "gs_value" not in obj.data.attributes and obj.gaussvdb.grid_class == "level_set"
        gs = imp.gaussian_set_from_object(obj, "high")  # its signed distances, read back
        assert gs.distances is not None and len(gs.distances) == gs.count and np.all(gs.values == 1)
        obj.data.attributes.remove(obj.data.attributes["gs_distance"])  # as imported before them
        assert imp.gaussian_set_from_object(obj, "high").distances is None


def test_moving_the_object_moves_the_gaussians(scene, bpy_module):
    from mathutils import Matrix

    imp = _imp()
    obj = imp.import_vdb(SAMPLE, grids=["density"], lods=("low",), compute_error=False)[0]
    before = imp.gaussian_set_from_object(obj, "low")
    obj.matrix_world = Matrix.Translation((1.0, 2.0, 3.0)) @ obj.matrix_world
    after = imp.gaussian_set_from_object(obj, "low")
    # Gaussians live in index space: the data is untouched, the object matrix places them.
    np.testing.assert_array_equal(before.offsets, after.offsets)
    assert np.allclose(np.asarray(obj.matrix_world)[:3, 3], (1.0, 2.0, 3.0))


@pytest.mark.parametrize("path", [p for p in shared_data_files() if os.path.getsize(p) < 8e6],
                         ids=os.path.basename)
def test_shared_files_match_blender_volume_box(scene, bpy_module, path):
    bpy = bpy_module
    imp = _imp()
    vdb = importlib.import_module(ADDON_MODULE + ".kernels.vdb")
    every = [g.name for g in vdb.read_topology(path).grids]  # as Blender's box
    objs = imp.import_vdb(path, grids=every, lods=("low",), vector_magnitude=True,
                          compute_error=False)
    b_lo, b_hi = blender_volume_box(bpy, path)
    g_lo, g_hi = gaussvdb_leaf_box(objs)
    voxel = max(np.linalg.norm(np.asarray(o.matrix_world)[:3, :3], axis=0).max() for o in objs)
    np.testing.assert_allclose(g_lo, b_lo, atol=0.5 * voxel)
    np.testing.assert_allclose(g_hi, b_hi, atol=0.5 * voxel)
