"""The GPU device's texture tables (kernels/render/gpu/tables.py), read back the way common.glsl
and reference.glsl fetch them, on a real CPU frame (no Blender)."""
import numpy as np
import pytest

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.gpu import tables as L
from kernels.render.scene.synthetic import grid_from_dense


def texel(table, e):
    """common.glsl texel(): texel e of a folded table."""
    return table[e // L.ROW_TEXELS, e % L.ROW_TEXELS]


def scalar(table, e):
    return texel(table, e >> 2)[e & 3]


def test_fold_rows_and_scalars_put_each_element_where_the_shader_reads_it():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(5000, 7))  # two texels per row, rows across the 4096-texel line
    t = L.fold_rows(a)
    assert t.shape == (3, L.ROW_TEXELS, 4) and t.dtype == np.float32
    per = L.texels_per_row(7)
    for i in (0, 1, 2047, 2048, 4999):
        got = np.concatenate([texel(t, i * per + k) for k in range(per)])[:7]
        np.testing.assert_array_equal(got, a[i].astype(np.float32))
    s = rng.integers(-5, 1 << 20, size=70001)
    ts = L.fold_scalars(s)
    for e in (0, 3, 4, 16383, 16384, 70000):
        assert scalar(ts, e) == s[e]


def test_integers_that_a_float32_cannot_hold_are_refused():
    with pytest.raises(ValueError, match="float32 exactly"):
        L.walk_tables(type("A", (), {"node_table": np.array([1 << 24]),
                                     "node_cells": np.zeros((1, 4096))})())


def test_brick_atlas_places_each_voxel_at_its_slot():
    rng = np.random.default_rng(2)
    n = L.ATLAS_SLOTS + 7  # a second row of slots
    b = rng.random((n, 10, 10, 10)).astype(np.float32)
    atlas, (sx, sy, sz) = L.brick_atlas(b)
    assert (sx, sy, sz) == (L.ATLAS_SLOTS, 2, 1)
    assert atlas.shape == (10 * sz, 10 * sy, 10 * sx)
    for cid in (0, 5, L.ATLAS_SLOTS, n - 1):
        base = np.array([cid % sx, cid // sx % sy, cid // (sx * sy)]) * 10  # reference.glsl
        for i, j, k in ((0, 0, 0), (9, 3, 1), (2, 9, 9)):
            x, y, z = base + (i, j, k)
            assert atlas[z, y, x] == b[cid, i, j, k]


@pytest.fixture(scope="module")
def frame():
    v = np.zeros((40, 24, 20))
    v[3:37, 2:22, 4:18] = np.linspace(0.1, 1.0, 34)[:, None, None]
    grid = grid_from_dense(v, (-13, 5, 200), active=v > 0)
    m = np.diag([1.5, 1.0, 0.7, 1.0])
    m[:3, 3] = (2.0, -3.0, 1.0)
    clip = np.array([[1.0, 0.0, 0.0, -4.0], [0.0, 0.0, 1.0, 3.0]])
    scene = RenderScene([RenderObject(grid=grid, matrix_world=m, clip=clip)], mode="reference")
    cam = Camera.frame_box([-20, 0, 190], [30, 30, 230], 16, 16)
    dev = CPUDevice()
    return dev.begin_frame(scene, cam, TransferFunction.from_colormap("viridis", 0, 1))


def test_the_walk_tables_find_every_cell(frame):
    """reference.glsl's cell_at: node grid -> node table -> node cells gives each cell its id."""
    a = frame.accel
    t = L.walk_tables(a)
    objs, per = L.object_rows(frame)
    nmin = texel(objs, 7)[:3].astype(int)
    noff = int(texel(objs, 7)[3])
    ndims = texel(objs, 8)[:3].astype(int)
    cells = L.reference_geometry(frame).textures["cells"]
    for cid, c in enumerate(a.cell_xyz):
        n = np.floor_divide(c, 16)
        r = n - nmin
        nid = int(scalar(t["node_table"], noff + (r[0] * ndims[1] + r[1]) * ndims[2] + r[2]))
        loc = c - n * 16
        assert int(scalar(t["node_cells"], nid * 4096 + (loc[0] * 16 + loc[1]) * 16 + loc[2])) == cid
        np.testing.assert_array_equal(texel(cells, cid)[:3], c)


def test_object_rows_hold_the_matrix_kind_and_clips(frame):
    objs, per = L.object_rows(frame)
    assert per == L.OBJ_TEXELS + 2
    o = frame.objects
    for r in range(3):
        np.testing.assert_allclose(texel(objs, r), o.w2i[0, r], rtol=1e-6)
    assert texel(objs, 6)[3] == 2  # clip count
    np.testing.assert_allclose(texel(objs, L.OBJ_TEXELS + 1), o.clip[0, 1], rtol=1e-6)
    t = L.reference_frame(frame)
    assert t.ints == {"n_obj": 1, "obj_texels": per, "n_lights": frame.transfer.lights.shape[0]}
    assert t.textures["tf_lut"].shape == (1, L.LUT_SIZE, 4)
    cam = [scalar(t.textures["frame"], L.FR_CAM + k) for k in range(21)]
    np.testing.assert_allclose(cam, frame.cam, rtol=1e-6)
