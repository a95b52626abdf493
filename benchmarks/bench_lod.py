"""LOD benchmark over a data folder: every grid of every .vdb, every preset.

Columns as the paper's Table 1 (file, grid, LOD, Gaussians, size) plus ours: compact bytes and
bytes per Gaussian, the paper's storage model, read and convert seconds (best of --repeat, warm
JIT), M active voxels/s for read + convert, field NRMSE (level sets: occupancy NRMSE and IoU).

  ./gaussvdb bench lod [--data DIR] [--presets low,medium,high] [--weights field] [--repeat 3]
                      [--tolerances 0.05,0.02,0.01]
  ./gaussvdb bench lod --data ../shared/data
`adaptive` gives one row per tolerance (LOD `adaptive@T`), and one at High's NRMSE (`adaptive@high`)
when `high` runs too; its rows add the ratios of Gaussians and convert time to High's.
DIR defaults to ../shared/data relative to the repository root.
"""
from __future__ import annotations

import glob
import json
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for _p in (ROOT, os.path.join(ROOT, "tools")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import cli_errors  # noqa: E402  (after the sys.path set-up above)


def _best(fn, repeat):
    best, out = float("inf"), None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def warm_up(presets=None):
    """Compile the kernels of `presets` (default: all but adaptive, whose compile is the longest)."""
    import numpy as np

    from kernels.lod import PRESETS, build_lod, encode_compact, field_error
    from kernels.lod.synthetic import random_sparse_grid

    for cls in ("fog_volume", "level_set"):
        g = random_sparse_grid(0, n_leaves=3, grid_class=cls)
        g.tile_origins, g.tile_sizes = np.array([[64, 0, 0]], np.int32), np.array([8], np.int32)
        g.tile_values, g.tile_active = np.array([0.0], np.float32), np.array([True])
        for p in presets or [p for p in PRESETS if p != "adaptive"]:
            gs = build_lod(g, p, tolerance=0.05)
            encode_compact(gs)
            field_error(g, gs)


def _jobs(presets, tolerances):
    """(label, preset, thresholds) per row; adaptive: one per tolerance, `high` first."""
    jobs = [(p, p, {}) for p in presets if p != "adaptive"]
    if "adaptive" in presets:
        jobs += [(f"adaptive@{t:g}", "adaptive", dict(tolerance=t)) for t in tolerances]
        if "high" in presets:
            jobs.append(("adaptive@high", "adaptive", None))  # tolerance = High's NRMSE
    return jobs


def run(data, presets, weights, repeat, error=True, files=None, tolerances=(0.05, 0.02, 0.01)):
    from kernels.lod import encode_compact, encoded_nbytes, paper_model_bytes
    from kernels.pipeline import convert_lod, measure_error
    from kernels.vdb import read_vdb

    rows = []
    paths = sorted(glob.glob(os.path.join(data, "*.vdb")))
    if files:
        paths = [p for p in paths if any(f in os.path.basename(p) for f in files)]
    for path in paths:
        names = [g.name for g in read_vdb(path, topology_only=True).grids]
        for name in names:
            t_read, vdb = _best(lambda: read_vdb(path, grids=[name]), repeat)
            g = vdb.grids[0]
            if not g.active_voxels:
                continue
            high = None
            for label, p, th in _jobs(presets, tolerances):
                if th is None:
                    if high is None or high.get("nrmse") is None:
                        continue
                    th = dict(tolerance=high["nrmse"])
                t_conv, gs = _best(lambda: convert_lod(g, p, weights=weights, compute_error=False,
                                                       thresholds=th).gset, repeat)
                nb = encoded_nbytes(encode_compact(gs))
                row = dict(file=os.path.basename(path), grid=name, cls=g.grid_class, lod=label,
                           active_voxels=int(g.active_voxels), leaves=len(g.leaf_origins),
                           gaussians=gs.count, spheres=gs.n_spheres, bytes=nb,
                           bytes_per_gaussian=nb / max(gs.count, 1),
                           paper_model_bytes=paper_model_bytes(gs), seconds_read=t_read,
                           seconds_convert=t_conv,
                           mvox_s=g.active_voxels / (t_read + t_conv) / 1e6,
                           mvox_s_convert=g.active_voxels / t_conv / 1e6)
                if error:
                    e = measure_error(g, gs)
                    row.update(nrmse=e["nrmse"], max_abs=e["max_abs"], iou=e.get("surface_iou"))
                if p == "adaptive":
                    row.update(tolerance=gs.params["tolerance"], met=gs.params["tolerance_met"])
                    if high is not None:
                        row.update(x_high_gaussians=gs.count / max(high["gaussians"], 1),
                                   x_high_convert=t_conv / max(high["seconds_convert"], 1e-9))
                if p == "high":
                    high = row
                rows.append(row)
                print(fmt_row(row), flush=True)
    return rows


HEADER = ("| file | grid | class | LOD | active voxels | Gaussians | bytes | B/G | paper-model bytes "
          "| s read | s convert | M vox/s (read+conv) | M vox/s (conv) | NRMSE | max error | IoU "
          "| met | x High Gaussians | x High convert |\n"
          "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|")


def fmt_row(r):
    iou = "" if r.get("iou") is None else f"{r['iou']:.3f}"
    nr = "" if r.get("nrmse") is None else f"{r['nrmse']:.4f}"
    mx = "" if r.get("max_abs") is None else f"{r['max_abs']:.3g}"
    met = "" if "met" not in r else ("yes" if r["met"] else "NO")
    xg = "" if "x_high_gaussians" not in r else f"{r['x_high_gaussians']:.2f}"
    xt = "" if "x_high_convert" not in r else f"{r['x_high_convert']:.0f}"
    return (f"| {r['file']} | {r['grid']} | {r['cls']} | {r['lod']} | {r['active_voxels']:,} "
            f"| {r['gaussians']:,} | {r['bytes']:,} | {r['bytes_per_gaussian']:.2f} "
            f"| {r['paper_model_bytes']:,} | {r['seconds_read']:.3f} | {r['seconds_convert']:.3f} "
            f"| {r['mvox_s']:.2f} | {r['mvox_s_convert']:.2f} | {nr} | {mx} | {iou} | {met} | {xg} "
            f"| {xt} |")


def main(argv=None) -> int:
    from kernels.lod import PRESETS, WEIGHTS

    ap = cli_errors.ArgumentParser(prog="gaussvdb bench lod", description="LOD table over a data folder")
    ap.add_argument("--data", default=os.path.join(os.path.dirname(ROOT), "shared", "data"))
    ap.add_argument("--presets", default=list(PRESETS), type=cli_errors.names(PRESETS))
    ap.add_argument("--weights", default="field", choices=WEIGHTS)
    ap.add_argument("--repeat", type=cli_errors.positive_int, default=3)
    ap.add_argument("--tolerances", default="0.05,0.02,0.01",
                    help="adaptive: comma-separated field NRMSE tolerances")
    ap.add_argument("--files", help="comma-separated substrings of file names")
    ap.add_argument("--no-error", action="store_true")
    ap.add_argument("--json", help="also write the rows to this JSON file")
    a = ap.parse_args(argv)
    try:
        tols = [cli_errors.nonnegative(t) for t in a.tolerances.split(",")]
    except Exception as err:  # noqa: BLE001 - argparse's type error, as a usage error
        raise cli_errors.UsageError(f"argument --tolerances: {err}", ap.prog) from None
    cli_errors.vdb_folder(a.data)  # a missing or empty folder is refused before the warm-up
    warm_up(a.presets)
    print(HEADER, flush=True)
    rows = run(a.data, a.presets, a.weights, a.repeat, not a.no_error,
               a.files.split(",") if a.files else None, tols)
    print_file_totals(rows)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


def print_file_totals(rows):
    """Per file and preset: all grids' active voxels over the sum of their reads and conversions
    (each grid read on its own, so this is a lower bound on a whole-file job's rate)."""
    tot = {}
    for r in rows:
        v, t = tot.get((r["file"], r["lod"]), (0, 0.0))
        tot[(r["file"], r["lod"])] = (v + r["active_voxels"], t + r["seconds_read"] + r["seconds_convert"])
    print("\n| file | LOD | active voxels (all grids) | s read + convert | M vox/s |\n|---|---|---:|---:|---:|")
    for (f, lod), (v, t) in tot.items():
        print(f"| {f} | {lod} | {v:,} | {t:.3f} | {v / t / 1e6:.1f} |")


if __name__ == "__main__":
    sys.exit(cli_errors.run("gaussvdb bench lod", main, sys.argv[1:]))
