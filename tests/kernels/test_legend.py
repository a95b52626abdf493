"""The colour legend raster (kernels/render/scene/legend.py) and the voxel figures behind auto ranges
(kernels/render/transfer.voxel_stats); no Blender here, except openvdb for a real grid."""

import math

import numpy as np
import pytest

from kernels.render import TransferFunction, voxel_stats
from kernels.render.scene.legend import (
    CORNERS,
    GLYPH_H,
    LegendEntry,
    composite,
    corner_origin,
    legend_patch,
    text_mask,
    ticks,
)


def _entry(name="viridis", lo=0.0, hi=2.0, log=False, title="density"):
    tf = TransferFunction.from_colormap(name, lo, hi, log_scale=log)
    return LegendEntry(title, tf.lut, tf.vmin, tf.vmax, tf.log_scale)


def test_text_mask_glyphs_differ_and_scale():
    one, two = text_mask("1"), text_mask("2")
    assert one.shape == (GLYPH_H, 5) and one.any() and not np.array_equal(one, two)
    assert text_mask("DENSITY", 3).shape == (3 * GLYPH_H, 3 * (6 * 7 - 1))
    assert np.array_equal(text_mask("a"), text_mask("A"))  # titles in capitals
    assert not np.array_equal(text_mask("e"), text_mask("E"))  # the exponent's own glyph


@pytest.mark.parametrize("lo,hi", [(0.0, 1.0), (0.0, 2.3), (-3.0, 7.0), (1e-6, 1e29), (0.2, 0.21)])
def test_linear_ticks_are_nice_and_inside(lo, hi):
    tk = ticks(lo, hi)
    assert len(tk) >= 2
    assert all(-1e-9 <= f <= 1 + 1e-9 for f, _ in tk)
    fr = [f for f, _ in tk]
    assert fr == sorted(fr)
    labels = [t for _, t in tk]
    assert len(set(labels)) == len(labels)
    if hi > 1e6:
        assert any("e+" in t for t in labels)


def test_log_ticks_are_decades():
    tk = ticks(1e-3, 10.0, log_scale=True)
    assert [t for _, t in tk] == ["0.001", "0.01", "0.1", "1", "10"]
    np.testing.assert_allclose([f for f, _ in tk], np.linspace(0, 1, 5))
    wide = ticks(1e-30, 1e30, log_scale=True)
    assert 2 <= len(wide) <= 6 and all("e" in t for _, t in wide[:1])


def test_patch_shows_the_lut_frame_and_labels():
    e = _entry("plasma", 0.0, 2.0)
    p = legend_patch([e], 200)
    assert p.dtype == np.float32 and p.shape[0] == 200 and p.shape[2] == 4
    assert np.all(p[..., :3] <= p[..., 3:4] + 1e-6)  # premultiplied
    # the opaque bar: one column whose colours run through the LUT from top (vmax) to bottom
    opaque = (p[..., 3] > 0.999) & (p[..., :3].max(-1) < 0.999)
    col = np.argmax(opaque.sum(0))
    rows = np.flatnonzero(opaque[:, col])
    bar = p[rows, col, :3]
    assert len(rows) > 100
    np.testing.assert_allclose(bar[0], e.lut[-1, :3], atol=0.02)
    np.testing.assert_allclose(bar[-1], e.lut[0, :3], atol=0.02)
    # white text and frame, on a translucent dark panel elsewhere
    white = np.all(p[..., :4] > 0.99, axis=-1)
    assert white.sum() > 200
    assert math.isclose(float(p[1, -2, 3]), 0.55, abs_tol=1e-6)


def test_two_entries_sit_side_by_side():
    one = legend_patch([_entry()], 160)
    two = legend_patch([_entry(), _entry("magma", 1e-3, 1e29, True, "level")], 160)
    assert two.shape[0] == one.shape[0] and two.shape[1] > 1.8 * one.shape[1] - 20


@pytest.mark.parametrize("corner", CORNERS)
def test_composite_places_the_patch_in_its_corner(corner):
    h, w = 200, 300
    img = np.zeros((h, w, 4), np.float32)
    img[..., 1] = 0.5
    img[..., 3] = 0.5  # premultiplied half-transparent green
    p = legend_patch([_entry()], 60)
    out = composite(img.copy(), p, corner)
    changed = np.any(np.abs(out - img) > 1e-6, axis=-1)
    ys, xs = np.nonzero(changed)
    top = corner.startswith("top")  # row 0 is the bottom row
    assert (ys.min() > h / 2) if top else (ys.max() < h / 2)
    assert (xs.max() < w / 2) if corner.endswith("left") else (xs.min() > w / 2)
    x0, y0 = corner_origin(w, h, p.shape, corner)
    # "over", premultiplied: out = legend + (1 - legend alpha) * image, at the patch's bottom row
    src = p[-1, 0]
    np.testing.assert_allclose(out[y0, x0], src + (1 - src[3]) * img[y0, x0], atol=1e-6)


def test_bad_corner_is_a_one_line_error():
    with pytest.raises(ValueError, match="legend corner must be one of"):
        corner_origin(10, 10, (2, 2), "middle")


def test_voxel_stats_of_a_real_grid(tmp_path):
    import bpy  # noqa: F401  (openvdb comes with bpy)
    from vdb_fixtures import write_grid

    from kernels.vdb import read_vdb

    rng = np.random.default_rng(7)
    dense = rng.uniform(-0.5, 1.0, (20, 12, 9)).astype(np.float32)
    dense[3, 3, 3] = 4.0
    path = write_grid(tmp_path / "signed.vdb", dense)
    g = read_vdb(str(path)).grids[0]
    st = voxel_stats(g)
    act = dense[dense != 0]
    assert st["voxels"] == act.size == g.active_voxels
    assert st["nonpositive"] == int((act <= 0).sum())
    assert st["min"] == pytest.approx(float(act.min())) and st["max"] == pytest.approx(4.0)
    assert st["positive_min"] == pytest.approx(float(act[act > 0].min()))


def test_voxel_stats_counts_tiles_by_volume(tmp_path):
    import bpy  # noqa: F401
    from vdb_fixtures import openvdb

    from kernels.vdb import read_vdb

    ov = openvdb()
    grid = ov.FloatGrid()
    grid.name = "density"
    grid.fill((0, 0, 0), (15, 15, 15), -2.0, True)  # a 16^3 active tile of -2
    grid.getAccessor().setValueOn((40, 0, 0), 3.0)
    ov.write(str(tmp_path / "tile.vdb"), grids=[grid])
    g = read_vdb(str(tmp_path / "tile.vdb")).grids[0]
    st = voxel_stats(g)
    assert st["voxels"] == g.active_voxels == 16 ** 3 + 1
    assert st["nonpositive"] == 16 ** 3 and st["min"] == -2.0 and st["max"] == 3.0


@pytest.mark.parametrize("dtype", [np.float32, np.float16, np.float64, np.int32])
def test_voxel_stats_equal_a_per_voxel_count(dtype):
    """NaN, +-Inf, zeros and negatives among the active voxels, inactive voxels holding other
    values, chunks that split the leaves, each value type: the figures equal a plain count."""
    from types import SimpleNamespace

    rng = np.random.default_rng(11)
    n = 37
    vals = rng.uniform(-2.0, 3.0, (n, 512))
    vals[rng.random(vals.shape) < 0.05] = 0.0
    if np.dtype(dtype).kind == "f":
        vals[0, :4] = [np.nan, np.inf, -np.inf, 1e-7]
    vals = vals.astype(dtype)
    masks = rng.integers(0, 2**63, (n, 8), dtype=np.uint64) | np.uint64(1)
    masks[5] = 0  # a leaf without active voxels
    on = np.unpackbits(masks.view(np.uint8), axis=1, bitorder="little").astype(bool)
    grid = SimpleNamespace(leaf_masks=masks, leaf_values=vals, tile_active=np.array([True, False]),
                           tile_sizes=np.array([8, 16]), tile_values=np.array([-1.0, 99.0]))
    st = voxel_stats(grid, chunk=10)
    act = np.concatenate([vals[on].astype(np.float64), [-1.0]])
    fin = act[np.isfinite(act)]
    assert st["voxels"] == int(on.sum()) + 8**3
    assert st["nonpositive"] == int((~(act[:-1] > 0)).sum()) + 8**3
    assert st["min"] == fin.min() and st["max"] == fin.max()
    assert st["positive_min"] == act[act > 0].min()
