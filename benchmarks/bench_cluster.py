"""A sequence converted and rendered on a Dask LocalCluster against the serial run.

    ./gaussvdb bench cluster [--frames 12] [--lod medium] [--size 640x480] [--upsample K]
                             [--rounds 2] [--json]

The sequence: copies of the Mantaflow smoke (samples/) and fire (shared data, when present)
grids, alternating, in a temporary folder (--upsample K: each resampled K times finer first,
benchmarks/bench_scale.resample, for frames of a realistic size). Each configuration is the
command a user runs, in a process of its own, into an empty output folder: `--workers 2` (one
numba thread each), `--workers 1` (one thread), and the serial run with 2 threads; the rounds
interleave them (the machine's load drifts). Per configuration the median wall seconds (cluster
start-up, each worker's Blender or kernels' loading included), the median span from the first
frame's start to the last frame's end (the frames alone; the serial run has no such figure:
its seconds in-process, which also hold its kernels' loading or its import, so only the whole
commands compare it with a cluster's), each worker's peak resident memory
with what its first frame and the later ones added to it, and the memory it holds between
frames (resident after its second frame and after its last: equal when it does not grow with
the frames drawn), and the seconds of each worker's first frame against its later ones.

Before the rounds, the machine's cost of touching memory for the first time: a fresh process
faults in 256 MB just after another freed as much, and again after the machine has been idle a
few seconds. On a virtual machine whose host reclaims the memory its guest frees (a balloon's
free page reporting), the second is several times the first; it is what each worker pays once
in its first frame, as its heap grows.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
CLI = os.path.join(ROOT, "tools", "cli.py")
SMOKE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")
FIRE = os.path.join(os.path.dirname(ROOT), "shared", "data", "mantaflow_fire_r96_f035.vdb")
CONFIGS = (("workers 2", ["--workers", "2", "--threads", "2"]),
           ("workers 1", ["--workers", "1", "--threads", "1"]),
           ("serial", ["--threads", "2"]))


def parse(argv):
    ap = argparse.ArgumentParser(prog="gaussvdb bench cluster", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--lod", default="medium")
    ap.add_argument("--size", default="640x480", help="render size WxH")
    ap.add_argument("--upsample", type=int, default=1, help="resample each grid K times finer")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--only", choices=("convert", "render"), help="one of the two")
    ap.add_argument("--json", action="store_true")
    return ap.parse_args(argv)


def make_sequence(folder, count, upsample):
    os.makedirs(folder, exist_ok=True)
    sources = [SMOKE, FIRE] if os.path.isfile(FIRE) else [SMOKE]
    if upsample > 1:
        import bench_scale

        big = []
        for k, src in enumerate(sources):
            dst = os.path.join(folder, f"source{k}.vdb.src")
            bench_scale.resample(src, dst, upsample, "density")
            big.append(dst)
        sources = big
    for n in range(1, count + 1):
        shutil.copyfile(sources[(n - 1) % len(sources)], os.path.join(folder, f"m_{n:04d}.vdb"))
    return os.path.join(folder, "m_####.vdb")


def run(argv):
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, CLI, *argv, "--json"], cwd=ROOT, capture_output=True,
                          text=True, timeout=1800)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)}: {proc.stderr[-2000:]}")
    res = json.loads(next(ln for ln in proc.stdout.splitlines() if ln.startswith("{")))
    return wall, res


TOUCH = """
import numpy as np, resource, time
r, t = resource.getrusage(resource.RUSAGE_SELF).ru_stime, time.perf_counter()
np.ones(256 << 20, np.uint8)
print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_stime - r)
"""


def first_touch(idle=4.0):
    """(seconds, system seconds) to fault in 256 MB in a fresh process: just after another
    process freed as much ("warm") and after ``idle`` seconds of rest ("cold")."""
    def once():
        out = subprocess.run([sys.executable, "-c", TOUCH], capture_output=True, text=True,
                             check=True, timeout=120).stdout.split()
        return float(out[0]), float(out[1])

    once()
    warm = once()
    time.sleep(idle)
    return {"warm": warm, "cold": once(), "idle_s": idle}


def frame_seconds(res):
    """(median seconds of each worker's first frame (the serial run's: its first), median of
    the later frames)."""
    first, later, seen = [], [], set()
    for f in sorted(res["frames"], key=lambda i: i.get("started", 0)):
        if "seconds" in f:
            (later if f.get("worker") in seen else first).append(f["seconds"])
            seen.add(f.get("worker"))
    return (statistics.median(first) if first else 0.0,
            statistics.median(later) if later else 0.0)


def memory(res):
    """Per worker: (peak resident bytes, added by its first frame, most added by a later one,
    resident after its second frame (its first when it drew one), resident after its last)."""
    out = {}
    for f in sorted(res["frames"], key=lambda i: i.get("started", 0)):
        w = f.get("worker")
        if not w:
            continue
        peak, first, later, n, second, _ = out.get(w, (0, None, 0, 0, 0, 0))
        added = f["peak_rss_bytes"] - f["rss_before_bytes"]
        held = f.get("rss_after_bytes", 0)
        out[w] = (max(peak, f["peak_rss_bytes"]), added if first is None else first,
                  later if first is None else max(later, added), n + 1,
                  held if n < 2 else second, held)
    return {w: m[:3] + m[4:] for w, m in out.items()}


def main(argv=None):
    a = parse(argv if argv is not None else sys.argv[1:])
    rows = {}
    touch = first_touch()
    with tempfile.TemporaryDirectory(prefix="gaussvdb-bench-cluster-") as tmp:
        pattern = make_sequence(os.path.join(tmp, "seq"), a.frames, a.upsample)
        if hasattr(os, "sync"):  # the frames just written reach the disk before any timing
            os.sync()
        kinds = [a.only] if a.only else ["convert", "render"]
        for r in range(a.rounds):
            for kind in kinds:
                for name, extra in CONFIGS:
                    out = os.path.join(tmp, f"{kind}-{name.replace(' ', '')}-{r}")
                    argv = ([kind, pattern, "--lod", a.lod] + (
                        ["--cache-dir", out] if kind == "convert" else
                        ["--size", a.size, "--out", os.path.join(out, "f_####.png")]) + extra)
                    wall, res = run(argv)
                    span = res.get("seconds_frames", res.get("seconds_total"))
                    row = rows.setdefault((kind, name), {"wall": [], "frames": [], "memory": {},
                                                         "first": [], "later": []})
                    row["wall"].append(wall)
                    row["frames"].append(span)
                    first, later = frame_seconds(res)
                    row["first"].append(first)
                    row["later"].append(later)
                    row["memory"] = memory(res) or row["memory"]
                    shutil.rmtree(out, ignore_errors=True)
    load = [f"{x:.1f}" for x in os.getloadavg()]
    table = []
    for (kind, name), row in rows.items():
        mem = row["memory"]
        table.append({"kind": kind, "config": name, "wall_s": statistics.median(row["wall"]),
                      "wall_all": row["wall"], "frames_s": statistics.median(row["frames"]),
                      "first_frame_s": statistics.median(row["first"]),
                      "later_frame_s": statistics.median(row["later"]),
                      "peak_rss_mb": [round(m[0] / 2**20) for m in mem.values()],
                      "first_frame_added_mb": [round(m[1] / 2**20, 1) for m in mem.values()],
                      "later_frame_added_mb": [round(m[2] / 2**20, 1) for m in mem.values()],
                      "held_mb": [(round(m[3] / 2**20), round(m[4] / 2**20))
                                  for m in mem.values()]})
    speedups = {}
    for kind in {t["kind"] for t in table}:
        by = {t["config"]: t for t in table if t["kind"] == kind}
        for measure in ("wall_s", "frames_s"):
            speedups[f"{kind} {measure}: workers 2 vs workers 1"] = (
                by["workers 1"][measure] / by["workers 2"][measure])
        # the serial run's in-process seconds also hold its kernels' loading (or its import),
        # which a cluster does before its frames' span: only the whole commands compare alike
        speedups[f"{kind} wall_s: workers 2 vs serial (2 threads)"] = (
            by["serial"]["wall_s"] / by["workers 2"]["wall_s"])
    res = {"frames": a.frames, "lod": a.lod, "size": a.size, "upsample": a.upsample,
           "rounds": a.rounds, "cores": os.cpu_count(), "loadavg_end": load, "rows": table,
           "speedups": speedups, "first_touch_256mb": touch}
    if a.json:
        print(json.dumps(res))
        return 0
    print(f"{a.frames} frames ({'upsampled x%d, ' % a.upsample if a.upsample > 1 else ''}"
          f"{a.lod}, render {a.size}), {a.rounds} interleaved rounds, {os.cpu_count()} cores, "
          f"load {' '.join(load)} at the end")
    print("first touch of 256 MB in a fresh process: {:.3f} s ({:.3f} s system) just after "
          "another freed as much, {:.3f} s ({:.3f} s system) after {:.0f} s idle".format(
              *touch["warm"], *touch["cold"], touch["idle_s"]))
    print(f"{'':8} {'config':<10} {'wall s':>7} {'frames s':>9} {'1st fr s':>8} {'later s':>7}  "
          "peak MB / worker   "
          "first frame +MB   later frame +MB    held MB after 2nd, last frame")
    for t in table:
        held = ", ".join(f"{a}->{b}" for a, b in t["held_mb"])
        print(f"{t['kind']:<8} {t['config']:<10} {t['wall_s']:7.2f} {t['frames_s']:9.2f} "
              f"{t['first_frame_s']:8.2f} {t['later_frame_s']:7.2f}  "
              f"{str(t['peak_rss_mb']):<18} {str(t['first_frame_added_mb']):<16} "
              f"{str(t['later_frame_added_mb']):<18} {held}")
    for k, v in sorted(speedups.items()):
        print(f"speed-up {k}: {v:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
