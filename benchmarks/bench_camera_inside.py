"""A camera inside the volume against one outside, same image size, mode and LOD.

    python benchmarks/bench_camera_inside.py [FILES...] [--modes particles,field] [--lod medium]
                                             [--size 320x240] [--repeat 2]

Per file (default: the bundled sample) the first scalar grid is converted and rendered on the CPU
device with a camera framing its box from outside, and with the same camera moved to the box's
centre (looking the same way). Prints seconds per frame (best of --repeat, kernels loaded, set-up
included), the inside/outside ratio and the screen-tile list entries of each frame (0: the lists
were over budget and the kernels walked the leaves instead).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*")
    ap.add_argument("--modes", default="particles,field")
    ap.add_argument("--lod", default="medium")
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args(argv)
    a.width, a.height = (int(v) for v in a.size.lower().split("x"))
    a.files = a.files or [os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")]
    return a


def frame(dev, scene, cam, tf, repeat):
    best = np.inf
    for _ in range(repeat):
        dev.end_frame()
        t0 = time.perf_counter()
        out = dev.render(scene, cam, tf)
        best = min(best, time.perf_counter() - t0)
    t_start = dev._frame.accel.t_start  # the frame's screen-tile list starts (packing.Accel)
    entries = int(t_start[-1]) if t_start.shape[0] > 1 else 0
    return best, entries, out


def main(argv=None):
    a = parse(argv)
    from kernels.lod import build_lod
    from kernels.render import Camera, RenderObject, RenderScene, TransferFunction, get_device
    from kernels.vdb import read_vdb

    print(f"{'file':<32} {'mode':<10} {'outside s':>9} {'inside s':>9} {'ratio':>6} "
          f"{'entries out':>11} {'entries in':>11}")
    for path in a.files:
        grid = next(g for g in read_vdb(path).grids if g.active_voxels and g.value_type != "vec3s")
        gs = build_lod(grid, a.lod)
        lo = np.asarray(grid.bbox_min, np.float64) @ grid.index_to_world[:3, :3].T + grid.index_to_world[:3, 3]
        hi = np.asarray(grid.bbox_max, np.float64) @ grid.index_to_world[:3, :3].T + grid.index_to_world[:3, 3]
        lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
        outside = Camera.frame_box(lo, hi, a.width, a.height, direction=(0.35, 1.0, -0.3))
        m = outside.cam_to_world.copy()
        m[:3, 3] = 0.5 * (lo + hi)  # same orientation, eye at the box centre
        inside = Camera(m, a.width, a.height, "persp", fov_x=outside.fov_x)
        vals = np.asarray(gs.values, np.float64)
        tf = TransferFunction.from_colormap("viridis", float(vals.min()), float(vals.max()),
                                            density=10.0 / float(np.linalg.norm(hi - lo)))
        for mode in a.modes.split(","):
            dev = get_device("CPU")
            sc = RenderScene([RenderObject(gaussians=gs, matrix_world=grid.index_to_world, grid=grid)],
                             mode=mode)
            dev.render(sc, outside, tf)  # load the kernels and sync once, untimed
            t_out, e_out, _ = frame(dev, sc, outside, tf, a.repeat)
            t_in, e_in, _ = frame(dev, sc, inside, tf, a.repeat)
            print(f"{os.path.basename(path):<32} {mode:<10} {t_out:9.3f} {t_in:9.3f} "
                  f"{t_in / t_out:6.2f} {e_out:11,} {e_in:11,}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
