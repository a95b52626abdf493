"""Particles mode's Max Optical Depth (tau_max): what each value costs in accuracy and gains in time.

    python benchmarks/bench_tau_max.py [--data DIR] [--size 256] [--taus 0.1,0.3,1.0]
                                       [--time FILE --lod low --time-size 512]

Per shared fog grid and LOD (low, medium, high): the largest per-channel difference and the PSNR
of each tau_max's image against a converged one (tau_max 0.003), same camera and transfer function
as the benchmark report. With --time: frame seconds (the fastest of five after a first) of FILE at
each tau_max, one after the other in this process.
"""
import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
sys.path.insert(0, HERE)

CONVERGED = 0.003
FILES = (("mni152_t1_fog.vdb", None), ("mantaflow_smoke_r128_f040.vdb", "density"),
         ("mantaflow_fire_r96_f035.vdb", "density"))


def _scene(path, grid_name, lod, size):
    from bench_scale import _view

    from kernels import pipeline
    from kernels.render import RenderObject
    from kernels.vdb import read_vdb

    grid = next(g for g in read_vdb(path).grids if g.active_voxels and grid_name in (None, g.name))
    gs = pipeline.convert_lod(grid, lod, compute_error=False).gset
    return RenderObject(gs, np.asarray(grid.index_to_world, np.float64)), _view(grid, size)


def _frame(dev, obj, view, tau, sc=None):
    from kernels.render import RenderScene

    sc = sc or RenderScene([obj], mode="particles", tau_max=tau)
    return dev.render(sc, view["cam"], view["tf"])["Combined"].astype(np.float64)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.path.join(HERE, "..", "..", "shared", "data"))
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--taus", default="0.1,0.3,1.0")
    ap.add_argument("--time", metavar="FILE", help="also time frames of this file")
    ap.add_argument("--lod", default="low")
    ap.add_argument("--time-size", type=int, default=512)
    a = ap.parse_args(argv)
    from kernels.render import CPUDevice

    taus = [float(t) for t in a.taus.split(",")]
    dev = CPUDevice()
    print(f"{'file':32} {'LOD':7} " + " ".join(f"{'tau ' + str(t):>22}" for t in taus))
    for name, gname in FILES:
        for lod in ("low", "medium", "high"):
            obj, view = _scene(os.path.join(a.data, name), gname, lod, a.size)
            ref = _frame(dev, obj, view, CONVERGED)
            cells = []
            for t in taus:
                e = _frame(dev, obj, view, t) - ref
                mse = float((e[..., :3] ** 2).mean())
                psnr = 10 * np.log10(1 / mse) if mse else np.inf
                cells.append(f"{np.abs(e).max():9.1e} {psnr:6.1f} dB")
            print(f"{name:32} {lod:7} " + " ".join(f"{c:>22}" for c in cells), flush=True)
    if a.time:
        from kernels.render import RenderScene

        obj, view = _scene(a.time, None, a.lod, a.time_size)
        for t in taus:
            sc = RenderScene([obj], mode="particles", tau_max=t)
            _frame(dev, obj, view, t, sc)
            best = np.inf
            for _ in range(5):
                t0 = time.perf_counter()
                _frame(dev, obj, view, t, sc)
                best = min(best, time.perf_counter() - t0)
            print(f"{os.path.basename(a.time)} {a.lod} {a.time_size}x{a.time_size} tau_max {t}: "
                  f"{best:.3f} s a frame", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
