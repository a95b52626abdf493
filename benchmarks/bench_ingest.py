"""Ingest benchmark: our full read vs the binding's openvdb.readAll, per file, same run.

    python benchmarks/bench_ingest.py [--data DIR] [--repeat N]
"""

import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tools"))

import cli_errors  # noqa: E402  (after the sys.path set-up above)


def best(fn, repeat):
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return min(ts)


def main(argv=None):
    here = os.path.dirname(os.path.abspath(__file__))
    ap = cli_errors.ArgumentParser(prog="gaussvdb bench ingest")
    ap.add_argument("--data", default=os.path.join(here, "..", "..", "shared", "data"))
    ap.add_argument("--repeat", type=cli_errors.positive_int, default=5)
    args = ap.parse_args(argv)
    files = cli_errors.vdb_folder(args.data)
    import bpy

    from kernels.vdb import read_topology, read_vdb
    bpy.utils.expose_bundled_modules()
    import openvdb

    read_vdb(files[0])  # numba warm-up (compiled functions are cached on disk)
    print(f"{'file':34} {'active':>11} {'ours s':>8} {'binding s':>9} {'ratio':>6} "
          f"{'Mvox/s':>7} {'topo s':>7}")
    worst = 0.0
    for f in files:
        ours = best(lambda: read_vdb(f), args.repeat)
        theirs = best(lambda: openvdb.readAll(f), args.repeat)
        topo = best(lambda: read_topology(f), args.repeat)
        n = sum(g.active_voxels for g in read_vdb(f).grids)
        worst = max(worst, ours / theirs)
        print(f"{os.path.basename(f):34} {n:>11,} {ours:8.4f} {theirs:9.4f} {ours / theirs:6.2f} "
              f"{n / ours / 1e6:7.1f} {topo:7.4f}")
    print(f"worst ratio ours/binding: {worst:.2f} (target <= 1.2)")
    sys.stdout.flush()
    os._exit(0)  # skip the binding's noisy nanobind leak report at exit


if __name__ == "__main__":
    sys.exit(cli_errors.run("gaussvdb bench ingest", main, sys.argv[1:]))
