"""Ingest benchmark: our full read vs the binding's openvdb.readAll, per file, same run, the two
readers interleaved (ours, theirs, ours, ...) so that a change of machine load hits both alike;
minimum and median of each, and the 1-minute load average while the file was measured; then each
reader's peak memory in a fresh process (the resident high-water mark's growth over the read, as a
multiple of the voxel values read: target <= 1.2).

    python benchmarks/bench_ingest.py [--data DIR] [--repeat N] [--scale 2,3 [--source FILE]]

--scale adds copies of --source (default: the shared MNI volume) upsampled by those integer factors
(benchmarks/bench_scale.resample, in a temporary folder removed at exit): the readers at scale.
"""

import argparse
import gc
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tools"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import cli_errors  # noqa: E402  (after the sys.path set-up above)


def interleaved(fns, repeat):
    """[(min, median) seconds] per function, the functions called in turn, repeat rounds."""
    ts = [[] for _ in fns]
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t = time.perf_counter()
            fn()
            ts[k].append(time.perf_counter() - t)
    return [(min(t), statistics.median(t)) for t in ts]


def main(argv=None):
    here = os.path.dirname(os.path.abspath(__file__))
    ap = cli_errors.ArgumentParser(prog="gaussvdb bench ingest")
    ap.add_argument("--data", default=os.path.join(here, "..", "..", "shared", "data"))
    ap.add_argument("--repeat", type=cli_errors.positive_int, default=5)
    ap.add_argument("--peak", nargs=2, metavar=("READER", "FILE"), help=argparse.SUPPRESS)
    ap.add_argument("--scale", default="", help="upsampling factors of --source to add: 2,3")
    ap.add_argument("--source", default=os.path.join(here, "..", "..", "shared", "data",
                                                     "mni152_t1_fog.vdb"))
    args = ap.parse_args(argv)
    if args.peak:
        return _peak(*args.peak)
    files = cli_errors.vdb_folder(args.data)
    import bpy

    from kernels.vdb import read_topology, read_vdb
    bpy.utils.expose_bundled_modules()
    import openvdb

    tmp = tempfile.mkdtemp(prefix="gaussvdb_ingest_")
    try:
        if args.scale:
            from bench_scale import resample

            for f in (int(x) for x in args.scale.split(",")):
                files.append(os.path.join(tmp, f"x{f}_{os.path.basename(args.source)}"))
                resample(args.source, files[-1], f)
        worst = _table(files, args.repeat, read_vdb, read_topology, openvdb)
        _memory_table(files)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"worst ratio ours/binding (medians): {worst:.2f} (target <= 1.0 at scale)")
    sys.stdout.flush()
    os._exit(0)  # skip the binding's noisy nanobind leak report at exit


def _table(files, repeat, read_vdb, read_topology, openvdb):
    read_vdb(files[0])  # numba warm-up (compiled functions are cached on disk)
    print(f"{'file':34} {'active':>11} {'ours min/med s':>15} {'binding min/med s':>18} "
          f"{'ratio':>6} {'Mvox/s':>7} {'topo s':>7} {'load':>5}")
    worst = 0.0
    for f in files:
        (o_min, o_med), (b_min, b_med) = interleaved([lambda: read_vdb(f), lambda: openvdb.readAll(f)],
                                                     repeat)
        topo = min(interleaved([lambda: read_topology(f)], repeat)[0])
        n = sum(g.active_voxels for g in read_vdb(f).grids)
        worst = max(worst, o_med / b_med)
        print(f"{os.path.basename(f):34} {n:>11,} {o_min:7.3f}/{o_med:7.3f} {b_min:9.3f}/{b_med:8.3f} "
              f"{o_med / b_med:6.2f} {n / o_min / 1e6:7.1f} {topo:7.4f} {os.getloadavg()[0]:5.1f}",
              flush=True)
    return worst


def _rss_mb(field):
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith(field)) / 1024


def _peak(reader, path):
    """In this (fresh) process: one read's growth of the resident high-water mark (ours: the second), in MB, and the
    values' MB, as one line of JSON."""
    import bpy

    from kernels.vdb import read_vdb
    bpy.utils.expose_bundled_modules()
    import openvdb

    def read():
        return read_vdb(path) if reader == "ours" else openvdb.readAll(path)

    if reader == "ours":  # a first read loads the compiled kernels; its values go back to the system
        read()  # (the binding needs no warm-up, and its freed heap would hide a second read's growth)
        gc.collect()
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # the high-water mark restarts from the resident size now
    base = _rss_mb("VmRSS")
    got = read()
    peak = _rss_mb("VmHWM") - base
    values = (sum(g.leaf_values.nbytes + (0 if g.leaf_vectors is None else g.leaf_vectors.nbytes)
                  for g in got.grids) / 2**20 if reader == "ours" else None)
    print(json.dumps({"peak_mb": peak, "values_mb": values}))
    sys.stdout.flush()
    os._exit(0)


def _memory_table(files):
    """Each reader's peak in a fresh process per file."""
    print(f"\n{'file':34} {'values MB':>10} {'ours peak MB':>13} {'x values':>9} {'binding MB':>11} "
          f"{'x values':>9}")
    for f in files:
        row = {}
        for reader in ("ours", "binding"):
            p = subprocess.run([sys.executable, os.path.abspath(__file__), "--peak", reader, f],
                               capture_output=True, text=True)
            lines = p.stdout.strip().splitlines()
            row[reader] = json.loads(lines[-1]) if p.returncode == 0 and lines else None
        if None in row.values():
            print(f"{os.path.basename(f):34} (a reader failed)")
            continue
        v = row["ours"]["values_mb"]
        print(f"{os.path.basename(f):34} {v:10.1f} {row['ours']['peak_mb']:13.1f} "
              f"{row['ours']['peak_mb'] / v:9.2f} {row['binding']['peak_mb']:11.1f} "
              f"{row['binding']['peak_mb'] / v:9.2f}", flush=True)


if __name__ == "__main__":
    sys.exit(cli_errors.run("gaussvdb bench ingest", main, sys.argv[1:]))
