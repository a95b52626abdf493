"""NaN/Inf voxels are made inactive before conversion, counted exactly, and nothing else changes."""

import numpy as np

from kernels.lod import build_lod
from kernels.vdb import count_nonfinite, read_vdb, sanitize_nonfinite
from tests.vdb_fixtures import write_grid, write_nan_inf


def test_nonfinite_voxels_deactivated_and_counted(tmp_path):
    vals = np.empty((8, 8, 8))
    grid = read_vdb(write_nan_inf(tmp_path / "bad.vdb")).grids[0]
    before = grid.active_voxels
    masks_before = grid.leaf_masks.copy()
    assert count_nonfinite(grid) == 3
    assert sanitize_nonfinite(grid) == 3
    assert grid.active_voxels == before - 3 == vals.size - 3
    assert count_nonfinite(grid) == 0 and sanitize_nonfinite(grid) == 0
    # exactly three bits cleared, all of them where the values are not finite
    cleared = np.unpackbits((masks_before & ~grid.leaf_masks).view(np.uint8), bitorder="little")
    assert cleared.sum() == 3
    assert not np.isfinite(grid.leaf_values.reshape(-1)[cleared.astype(bool)]).any()
    for lod in ("low", "medium", "high"):
        gs = build_lod(grid, lod)
        assert np.isfinite(gs.values).all() and np.isfinite(gs.amplitudes).all()
        assert int(gs.voxels.sum()) == vals.size - 3


def test_finite_grid_untouched(tmp_path):
    grid = read_vdb(write_grid(tmp_path / "ok.vdb", np.ones((8, 8, 8), np.float32))).grids[0]
    masks = grid.leaf_masks
    assert sanitize_nonfinite(grid) == 0
    assert grid.leaf_masks is masks


def test_build_lod_never_emits_nonfinite_even_unsanitized(tmp_path):
    """build_lod drops NaN/Inf voxels itself (and counts them), without touching the caller's grid."""
    grid = read_vdb(write_nan_inf(tmp_path / "bad.vdb")).grids[0]
    masks = grid.leaf_masks.copy()
    for lod in ("low", "high"):
        gs = build_lod(grid, lod)
        assert np.isfinite(gs.values).all() and np.isfinite(gs.amplitudes).all()
        assert gs.params["nonfinite_voxels"] == 3
        assert int(gs.voxels.sum()) == grid.active_voxels - 3
    np.testing.assert_array_equal(grid.leaf_masks, masks)
