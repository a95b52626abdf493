"""The GPU tables of volumes coloured by a second grid (kernels/render/gpu/tables_color.py and the
reference atlas's colour bricks), read back as glsl/color.glsl and reference.glsl fetch them, on
real CPU frames of two objects, one coloured by a second grid (no Blender)."""
import numpy as np
import pytest
from test_gpu_layout import scalar, texel

from kernels.lod import build_lod
from kernels.lod.second_grid import attach
from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.gpu import tables as L
from kernels.render.gpu import tables_color as C
from kernels.render.scene.synthetic import grid_from_dense

TF = TransferFunction.from_colormap("viridis", 0, 1)
CTF = TransferFunction.from_colormap("inferno", 0.0, 2.0)


def frames(mode):
    """A frame of [a plain fog, the fog coloured by a second grid (background 0.3)] and the
    coloured object's RenderObject."""
    v = np.zeros((24, 16, 16))
    v[2:22, 2:14, 2:14] = np.linspace(0.1, 1.0, 20)[:, None, None]
    fog = grid_from_dense(v, active=v > 0)
    heat = grid_from_dense(2.0 * v[::-1], active=v[::-1] > 0, background=0.3)
    gs = attach(build_lod(fog, "medium"), fog, heat)
    m = np.eye(4)
    m[:3, 3] = (30.0, 0.0, 0.0)
    other = RenderObject(gs, m, grid=fog, color_tf=CTF, color_grid=heat)
    sc = RenderScene([RenderObject(build_lod(fog, "low"), grid=fog), other], mode=mode)
    cam = Camera.frame_box([0] * 3, [56, 16, 16], 16, 8)
    return CPUDevice().begin_frame(sc, cam, TF), other


@pytest.mark.parametrize("mode", ["reference", "particles", "field", "paper"])
def test_object_colour_rows(mode):
    fr, _ = frames(mode)
    t = C.frame_tables(fr)
    assert C.defines(t)[0] == "COLOR_GRID"
    np.testing.assert_array_equal(texel(t["obj_color"], 0)[:2], [-1, 0.0])
    row, bg = texel(t["obj_color"], 1)[:2]
    assert row == fr.objects.ctf[1] >= 1  # (after the opacity maps)
    np.testing.assert_array_equal(fr.transfer.lut[int(row)], CTF.lut.astype(np.float32))
    assert bg == np.float32(0.3)
    assert "g_cval" not in t  # the device adds the Gaussians' colour values (particles, paper)


def test_gaussian_colour_values():
    fr, other = frames("particles")
    cv = np.arange(fr.gauss.mu.shape[0], dtype=np.float64) + 0.5
    cv[3] = np.nan
    fr.color_values = cv
    t = C.frame_tables(fr)
    assert C.defines(t) == ("COLOR_GRID", "COLOR_VALUES")
    for g in (0, 3, 7, len(cv) - 1):
        np.testing.assert_array_equal(scalar(t["g_cval"], g), np.float32(cv[g]))


def test_no_colour_grid_no_tables():
    v = np.ones((8, 8, 8))
    sc = RenderScene([RenderObject(grid=grid_from_dense(v))], mode="reference")
    fr = CPUDevice().begin_frame(sc, Camera.frame_box([0] * 3, [8] * 3, 8, 8), TF)
    assert C.frame_tables(fr) == {} and C.defines({}) == ()


def test_reference_atlas_holds_the_colour_bricks_after_the_grids():
    """Cell c's colour brick sits at brick c + cbrick0 of the atlas (reference.glsl's brick_base)."""
    fr, _ = frames("reference")
    a = fr.accel
    t = L.reference_geometry(fr)
    n = a.bricks.shape[0]
    assert t.ints["cbrick0"] == n and a.cbricks.shape == a.bricks.shape
    atlas, sx, sy = t.textures["atlas"], t.ints["atlas_sx"], t.ints["atlas_sy"]
    coloured = np.flatnonzero(a.cbricks.reshape(n, -1).any(1))
    assert coloured.size and coloured.size < n  # the first object's cells have none
    for b in (0, coloured[0], coloured[-1], n - 1):
        for src, bid in ((a.bricks, b), (a.cbricks, b + n)):
            base = np.array([bid % sx, bid // sx % sy, bid // (sx * sy)]) * 10
            for i, j, k in ((0, 0, 0), (9, 3, 1), (4, 9, 8)):
                x, y, z = base + (i, j, k)
                assert atlas[z, y, x] == src[b, i, j, k]
