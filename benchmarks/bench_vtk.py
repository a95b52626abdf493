"""Our `reference` mode against VTK's fixed-point ray caster at the same sample distances, in
interleaved rounds: on a shared machine either renderer's time moves by up to 1.6x between runs,
so one run of each (the report's voxel rows) can tip the ratio either way.

    python benchmarks/bench_vtk.py [--data DIR] [--files mni,smoke,fire] [--rounds 5] [--repeat 9]

Per fog file's density grid (the report's camera, transfer function, 512x512 and threads): each
round renders ours at every step (the median of --repeat renders after one sync), then VTK at
every step (its subprocess: benchmarks/vtk_ref.py, the median of --repeat after a warm-up). Prints,
per step, the median over rounds of each side, its fastest round and VTK seconds / ours (> 1:
ours faster). Needs the `vtk` module (`pip install vtk`).
"""
import argparse
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
sys.path.insert(0, HERE)

from bench_report import VTK_STEPS, parse, render, setup_view  # noqa: E402
from report_external import run_vtk  # noqa: E402

FILES = ("mni152_t1_fog.vdb", "mantaflow_smoke_r128_f040.vdb", "mantaflow_fire_r96_f035.vdb")


def compare(dev, path, a, rounds, repeat):
    """{step: (our seconds per round, VTK seconds per round)} for path's density grid."""
    from kernels.render import RenderObject
    from kernels.vdb import read_vdb

    g = read_vdb(path, grids=["density"]).grids[0]
    view = setup_view(g, a)
    objs = [RenderObject(None, view["m"], grid=g)]
    times = {s: ([], []) for s in VTK_STEPS}
    for _ in range(rounds):
        for s in VTK_STEPS:
            times[s][0].append(render(dev, objs, "reference", view["cam"], view["tf"], a.threads, s, repeat)[1])
        with tempfile.TemporaryDirectory() as work:
            info, _ = run_vtk(g, view, a, work, VTK_STEPS, repeat)
        for row in info["rows"]:
            times[row["step"]][1].append(row["seconds_render"])
    return times


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=os.path.join(HERE, "..", "..", "shared", "data"))
    ap.add_argument("--files", default="mni,smoke,fire", help="comma-separated substrings of FILES")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    from kernels.render import CPUDevice

    a = parse(["--threads", str(args.threads)])  # the report's image size and view settings
    dev = CPUDevice()
    dev.load_kernels()
    for name in FILES:
        if not any(f in name for f in args.files.split(",")):
            continue
        times = compare(dev, os.path.join(args.data, name), a, args.rounds, args.repeat)
        cells = []
        for s, (ours, vtk) in times.items():
            o, v = float(np.median(ours)), float(np.median(vtk))
            cells.append(f"step {s:g}: ours {o * 1e3:.0f} ms (fastest {min(ours) * 1e3:.0f}), VTK {v * 1e3:.0f} ms "
                         f"(fastest {min(vtk) * 1e3:.0f}), VTK/ours {v / o:.2f}")
        print(f"{name}: " + "; ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
