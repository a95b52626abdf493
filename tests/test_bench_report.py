"""`./gaussvdb bench --quick` end to end on the bundled sample, in a temporary data folder, run in a
fresh copy of the working tree right after `render` (see conftest.fresh_clone).

Runs the benchmark as a subprocess (it starts its own Cycles subprocess through the bpy module) and
checks the files, the keys of results.json, that errors are finite and ordered sensibly. Never
asserts times.
"""
import json
import math
import os
import shutil

import pytest
from conftest import SAMPLE, run_cli

KEYS = ("dataset", "grid", "class", "lod", "mode", "gaussians", "bytes", "seconds_convert",
        "seconds_render", "field_nrmse", "psnr", "ssim", "renderer", "samples")


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory, fresh_clone):
    """`bench --quick` in the fresh clone, after `render`, `convert` and `info` ran there."""
    root, env, _runs, _tmp = fresh_clone
    data = tmp_path_factory.mktemp("data")
    out = tmp_path_factory.mktemp("bench")
    shutil.copy(SAMPLE, data)
    r = run_cli(root, "bench", "--quick", "--data", str(data), "--out", str(out), env=env)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "Traceback" not in r.stderr
    with open(out / "results.json") as f:
        return out, json.load(f), r.stderr


@pytest.mark.slow
def test_files(quick_run):
    out, _res, log = quick_run
    for name in ("results.json", "report.md", "error_vs_time.png",
                 "contact_mantaflow_smoke_r128_f040.png"):
        assert (out / name).stat().st_size > 0, name
    for png in ("error_vs_time.png", "contact_mantaflow_smoke_r128_f040.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (out / "report.md").read_text()
    assert "Table 1" in report and "Error vs time" in report and "error_vs_time.png" in report
    assert "density" in report
    assert "13/13" in log or "[####" in log  # the progress bar


@pytest.mark.slow
def test_keys_and_meta(quick_run):
    _, res, _ = quick_run
    meta, rows = res["meta"], res["rows"]
    assert meta["cpu_count"] == os.cpu_count() and meta["when"] and meta["quick"] is True
    assert rows
    for r in rows:
        for k in KEYS:
            assert k in r, (k, r)
        assert r["renderer"] in ("gaussvdb", "cycles")
        assert r["dataset"] == "mantaflow_smoke_r128_f040.vdb"
    combos = {(r["lod"], r["mode"]) for r in rows if r["renderer"] == "gaussvdb"}
    for lod in ("low", "high"):
        for mode in ("particles", "field", "paper"):
            assert (lod, mode) in combos
    assert ("voxels", "reference") in combos
    cyc = [r for r in rows if r["renderer"] == "cycles"]
    assert sorted(r["samples"] for r in cyc) == [4, 16]
    # the vector grid and the empty/constant grids are listed, not silently dropped
    skipped = {s["grid"] for s in res["skipped"]}
    assert {"velocity", "flame"} <= skipped


@pytest.mark.slow
def test_errors_finite_and_ordered(quick_run):
    _, res, _ = quick_run
    rows = res["rows"]
    for r in rows:
        for k in ("psnr", "ssim", "max_abs_error", "seconds_render"):
            assert r[k] is not None and math.isfinite(r[k]), (k, r)
        assert -1.0 <= r["ssim"] <= 1.0
        if r["renderer"] == "gaussvdb" and r["lod"] != "voxels":
            assert math.isfinite(r["field_nrmse"]) and r["gaussians"] > 0 and r["bytes"] > 0

    def get(lod, mode):
        return next(r for r in rows if r["lod"] == lod and r["mode"] == mode)

    # High LOD beats Low LOD in field mode: the field error and the image error
    assert get("high", "field")["field_nrmse"] < get("low", "field")["field_nrmse"]
    assert get("high", "field")["psnr"] > get("low", "field")["psnr"]
    assert get("high", "field")["max_abs_error"] <= get("low", "field")["max_abs_error"] + 1e-6
    # the voxel renderer at its default step is close to its fine-step self
    assert get("voxels", "reference")["psnr"] > 35.0
    # Cycles converges towards our reference with samples, and the models match (no gross offset)
    c4, c16 = (next(r for r in rows if r["renderer"] == "cycles" and r["samples"] == n) for n in (4, 16))
    assert c16["psnr"] > c4["psnr"]
    assert c16["psnr"] > 30.0
