"""Issue 5: errors and cancels leave the scene untouched and say why."""

import importlib

import numpy as np
import pytest
from conftest import ADDON_MODULE, SAMPLE


def _imp():
    return importlib.import_module(ADDON_MODULE + ".gaussvdb_addon.io.importer")


def _ids(bpy):
    return (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.pointclouds))


def test_bad_file_leaves_scene_untouched(scene, bpy_module, tmp_path):
    bpy = bpy_module
    bad = tmp_path / "bad.vdb"
    bad.write_bytes(b"\x20BDV" + b"\x00" * 60)
    before = _ids(bpy)
    with pytest.raises(RuntimeError, match="bad.vdb"):
        bpy.ops.gaussvdb.import_vdb(filepath=str(bad))
    with pytest.raises(_imp().VDBImportError, match="bad.vdb"):
        _imp().import_vdb(str(bad))
    with pytest.raises(_imp().VDBImportError, match="no such file"):
        _imp().import_vdb(str(tmp_path / "missing.vdb"))
    assert _ids(bpy) == before


def test_no_scalar_grid(scene, bpy_module):
    bpy = bpy_module
    imp = _imp()
    with pytest.raises(imp.VDBImportError, match="no scalar grid.*velocity: vector grid"):
        imp.import_vdb(SAMPLE, grids=["velocity"])
    with pytest.raises(imp.VDBImportError, match="flame: empty grid"):
        imp.import_vdb(SAMPLE, grids=["flame"])
    with pytest.raises(imp.VDBImportError, match="no grid named 'nope'"):
        imp.import_vdb(SAMPLE, grids=["nope"])
    assert _ids(bpy) == (0, 0, 0)


def test_memory_guard(scene, bpy_module):
    bpy = bpy_module
    imp = _imp()
    with pytest.raises(imp.VDBImportError, match="above the limit"):
        imp.import_vdb(SAMPLE, max_bytes=1 << 16)
    assert _ids(bpy) == (0, 0, 0)


def test_cancel_leaves_nothing(scene, bpy_module):
    bpy = bpy_module
    imp = _imp()
    seen = []

    def progress(fraction, text):
        seen.append((fraction, text))

    calls = []

    def cancel():
        calls.append(1)
        return len(calls) >= 3  # cancel in the middle of the LOD builds

    with pytest.raises(imp.ImportCancelled):
        imp.import_vdb(SAMPLE, lods=("low", "medium"), progress=progress, cancel=cancel,
                       compute_error=False)
    assert _ids(bpy) == (0, 0, 0)
    assert seen[0] == (0.0, "reading mantaflow_smoke_r128_f040.vdb") and len(seen) == 3
    assert all(0 <= f <= 1 for f, _ in seen)


def test_failure_while_creating_datablocks_removes_them(scene, bpy_module, monkeypatch):
    bpy = bpy_module
    imp = _imp()

    def broken(objs):
        raise RuntimeError("simulated failure in object.convert")

    datablocks = importlib.import_module(ADDON_MODULE + ".gaussvdb_addon.io.datablocks")
    monkeypatch.setattr(datablocks, "_convert_to_pointclouds", broken)
    with pytest.raises(RuntimeError, match="simulated"):
        imp.import_vdb(SAMPLE, grids=["density"], lods=("low",), compute_error=False)
    assert _ids(bpy) == (0, 0, 0)


def test_bad_options(scene, addon):
    imp = _imp()
    with pytest.raises(imp.VDBImportError, match="unknown LOD preset 'ultra'"):
        imp.import_vdb(SAMPLE, lods=("ultra",))
    with pytest.raises(imp.VDBImportError, match="unknown weights"):
        imp.import_vdb(SAMPLE, weights="magic")
    assert imp.split_names(" density, ,temperature ") == ["density", "temperature"]
    assert imp.split_names("") is None
    assert np.all(imp.order_lods(["high", "low"]) == ["low", "high"])
