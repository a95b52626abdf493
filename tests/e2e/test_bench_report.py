"""`./gaussvdb bench --quick` end to end on the bundled sample, in a temporary data folder, run in a
fresh copy of the working tree right after `render` (see conftest.fresh_clone).

Runs the benchmark as a subprocess (it starts its own Cycles and VTK subprocesses) and checks the
files, the keys of results.json, that errors are finite and ordered sensibly. Never asserts times.
Also: the Pareto front on hand-made points, VTK's matched render of a synthetic blob against our
reference (where the `vtk` module is installed), and the one-line skip where `import vtk` fails.
"""
import importlib.util
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, SAMPLE, run_cli

sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
from report_front import front_rows, pareto_front, why_not, work  # noqa: E402  (after the sys.path line above)

HAS_VTK = importlib.util.find_spec("vtk") is not None

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
        assert r["renderer"] in ("gaussvdb", "cycles", "vtk")
        assert r["dataset"] == "mantaflow_smoke_r128_f040.vdb"
    combos = {(r["lod"], r["mode"]) for r in rows if r["renderer"] == "gaussvdb"}
    for lod in ("low", "high"):
        for mode in ("particles", "field", "paper"):
            assert (lod, mode) in combos
    assert ("voxels", "reference") in combos
    steps = sorted(r["step"] for r in rows if r["mode"] == "reference")
    assert steps == [0.25, 0.5, 1.0, 2.0]
    vtk = sorted(r["step"] for r in rows if r["renderer"] == "vtk")
    assert vtk == ([0.25, 0.5, 1.0] if HAS_VTK else [])
    cyc = [r for r in rows if r["renderer"] == "cycles"]
    assert sorted(r["samples"] for r in cyc) == [4, 16]
    # our rows say what a frame did: segments, the pixels it covers, its threads
    for r in rows:
        if r["renderer"] == "gaussvdb":
            assert r["segments"] > 0 and 0 < r["covered_pixels"] <= 128 * 128 and r["threads"] >= 1, r
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

    def get(lod, mode, step=None):
        return next(r for r in rows if r["lod"] == lod and r["mode"] == mode and r["step"] == step)

    # High LOD beats Low LOD in field mode: the field error and the image error
    assert get("high", "field")["field_nrmse"] < get("low", "field")["field_nrmse"]
    assert get("high", "field")["psnr"] > get("low", "field")["psnr"]
    assert get("high", "field")["max_abs_error"] <= get("low", "field")["max_abs_error"] + 1e-6
    # the voxel renderer at its default step is close to its fine-step self, and closer at finer steps
    assert get("voxels", "reference", 0.5)["psnr"] > 35.0
    curve = [get("voxels", "reference", s)["psnr"] for s in (2.0, 1.0, 0.5, 0.25)]
    assert curve == sorted(curve), curve
    # the front is named in the summary
    report = (quick_run[0] / "report.md").read_text()
    assert "The front: render time vs PSNR" in report
    # Cycles converges towards our reference with samples, and the models match (no gross offset)
    c4, c16 = (next(r for r in rows if r["renderer"] == "cycles" and r["samples"] == n) for n in (4, 16))
    assert c16["psnr"] > c4["psnr"]
    assert c16["psnr"] > 30.0


def test_pareto_front_hand_made():
    # (seconds, psnr): 0 and 2 and 4 are on the front; 1 is slower and worse than 0; 3 is slower than
    # 2 at the same PSNR; 5 has no time; 6 is identical to the reference (None: infinitely accurate)
    pts = [(1.0, 30.0), (2.0, 29.0), (2.0, 40.0), (3.0, 40.0), (5.0, 50.0), (None, 99.0)]
    assert pareto_front(pts) == [0, 2, 4]
    assert pareto_front(pts + [(6.0, None)]) == [0, 2, 4, 6]
    assert pareto_front(pts + [(0.5, None)]) == [6]
    assert pareto_front([]) == []
    # ties in time: only the more accurate one; equal points: the first
    assert pareto_front([(1.0, 20.0), (1.0, 25.0), (1.0, 25.0)]) == [1]
    rows = [{"seconds_render": t, "psnr": p, "n": i} for i, (t, p) in enumerate(pts)]
    assert [r["n"] for r in front_rows(rows)] == [0, 2, 4]


def test_why_no_gaussian_on_the_front():
    """The front summary's reason: the fastest Gaussian configuration's work per covered pixel
    against the fastest voxel step's (ns per segment per thread from the frame's time)."""
    def row(mode, lod, t, segs, px, step=None, renderer="gaussvdb"):
        return dict(renderer=renderer, mode=mode, lod=lod, step=step, samples=None, seconds_render=t,
                    psnr=40.0, segments=segs, covered_pixels=px, threads=2)

    rows = [row("particles", "high", 2.0, 4e6, 1000), row("particles", "low", 0.5, 1e6, 1000),
            row("field", "low", 0.9, 9e6, 1000), row("reference", "voxels", 0.1, 2e5, 1000, step=2.0),
            row("reference", "voxels", 0.2, 4e5, 1000, step=1.0), row("vtk", "voxels", 0.05, None, 0, 1.0, "vtk")]
    assert work(rows[1]) == (1000.0, 1000.0)  # 1e6 segments over 1000 pixels; 0.5 s x 2 threads / 1e6
    assert work(rows[-1]) is None  # a peer's row: no device statistics
    assert why_not(rows) == ("particles/low 0.50 s: 1,000 Gaussian segments a covered pixel, 1000 ns each; "
                             "reference step 2 0.10 s: 200 samples, 1000 ns each")
    assert why_not(rows[:3]) is None  # no voxel row to compare with


def _blob_view(size=48):
    """A smooth blob grid, its view and a CLI-shaped args namespace for the bench helpers."""
    import bench_report

    from kernels.render.scene.synthetic import grid_from_dense

    n = 24
    x = np.arange(n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    vol = np.exp(-((X - 12) ** 2 + (Y - 11) ** 2 + (Z - 12.5) ** 2) / (2 * 4.0 ** 2)).astype(np.float32)
    vol[vol < 0.02] = 0
    m = np.diag([0.1, 0.1, 0.1, 1.0])
    m[:3, 3] = (1.0, -2.0, 0.5)
    g = grid_from_dense(vol, origin=(3, 5, -4))
    g.index_to_world = m
    a = bench_report.parse(["--size", f"{size}x{size}", "--threads", "2"])
    return g, bench_report.setup_view(g, a), a


@pytest.mark.skipif(not HAS_VTK, reason="the vtk module is not installed (the bench skips VTK too)")
def test_vtk_matches_reference(tmp_path):
    import bench_report
    from metrics import image_errors
    from report_external import run_vtk

    from kernels.render import CPUDevice, RenderObject

    g, view, a = _blob_view()
    ref, *_ = bench_report.render(CPUDevice(), [RenderObject(None, view["m"], grid=g)], "reference",
                                  view["cam"], view["tf"], 2, step=bench_report.REF_STEP)
    info, imgs = run_vtk(g, view, a, str(tmp_path), (1.0, 0.5), repeat=1)
    assert sorted(imgs) == [0.5, 1.0] and info["threads"] == 2
    assert ref[..., :3].max() > 0.05  # the blob is visible
    for step, img in imgs.items():
        assert img.shape == ref.shape
        e = image_errors(ref, img)
        # same camera, transfer function and opacity model: close, and only slightly brighter
        assert e["psnr"] > 38.0, (step, e)
        assert 0.97 < e["brightness"] < 1.08, (step, e)
        # an upside-down or mirrored image would fail this
        assert e["ssim"] > 0.98, (step, e)


def test_vtk_missing_is_one_line(tmp_path):
    """Where `import vtk` fails, vtk_ref.py says so in one line and exits 3 (the bench then skips)."""
    fake = tmp_path / "site" / "vtk"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('libvtk: cannot open shared object file')\n")
    job = tmp_path / "job.json"
    job.write_text(json.dumps({"out_dir": str(tmp_path / "out")}))
    env = dict(os.environ, PYTHONPATH=str(tmp_path / "site"))
    r = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "vtk_ref.py"), str(job)],
                       capture_output=True, text=True, env=env, timeout=120, check=False)
    assert r.returncode == 3, r.stderr
    assert "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == ["VTK: not available (libvtk: cannot open shared object file)"]
