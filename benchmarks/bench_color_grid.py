"""Colour by a second grid: what it costs. `./gaussvdb bench color_grid [--file F] [--size N]
[--lod L] [--device cpu|gpu]`

For the Mantaflow fire (density, coloured by temperature; default ../shared/data beside the
repository), per LOD the seconds to form the colour grid's values at the Gaussians, and per mode
the frame time (best of three, set-up included; High LOD unless --lod) coloured by density itself
and by temperature, and their ratio. --device gpu: the GPU device's frames (in the bpy module's
GPU context), and the PSNR of its image coloured by temperature against the CPU device's. A file
that is not there is skipped with a note.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tools"))

from kernels import pipeline  # noqa: E402  (after the sys.path set-up above)
from kernels.render import MODES, Camera, CPUDevice, RenderObject, RenderScene, TransferFunction  # noqa: E402
from kernels.vdb import read_vdb  # noqa: E402

FIRE = os.path.join(os.path.dirname(ROOT), "shared", "data", "mantaflow_fire_r96_f035.vdb")


def psnr(a, b):
    """dB of RGBA image a against b, peak 1 (as the GPU tests measure)."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def best_frame(dev, scene, cam, tf, runs=3):
    dev.render(scene, cam, tf)  # the first frame builds the acceleration
    ts = []
    for _ in range(runs):
        dev.end_frame()
        t0 = time.perf_counter()
        dev.render(scene, cam, tf)
        ts.append(time.perf_counter() - t0)
    return min(ts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--file", default=FIRE)
    ap.add_argument("--grid", default="density")
    ap.add_argument("--color-grid", default="temperature")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--lod", default="high", choices=("low", "medium", "high"))
    ap.add_argument("--device", default="cpu", choices=("cpu", "gpu"))
    a = ap.parse_args(argv)
    if not os.path.isfile(a.file):
        print(f"skipped: {a.file} not found")
        return 0
    for lod in ("low", "medium", "high"):
        cg = pipeline.convert_file(a.file, [a.grid], [lod], color_grid=a.color_grid,
                                   compute_error=False)[0]
        cl = cg.lods[0]
        print(f"{lod:8s} {cl.gset.count:8,d} Gaussians  colour values {cl.seconds_color:.4f} s "
              f"(build {cl.seconds:.4f} s)")
        if lod == a.lod:
            gs = cl.gset
    grids = {g.name: g for g in read_vdb(a.file, [a.grid, a.color_grid]).grids}
    m = cg.index_to_world
    lo, hi = cg.leaf_box
    c = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                  for z in (lo[2], hi[2])]) @ m.T
    wlo, whi = c[:, :3].min(0), c[:, :3].max(0)
    cam = Camera.frame_box(wlo, whi, a.size, a.size, direction=(0.35, 1.0, -0.3))
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.0, density=10.0 / np.linalg.norm(whi - wlo))
    st = cg.color_stats
    ctf = TransferFunction.from_colormap("inferno", st["min"], st["max"], alpha="constant")
    device, run = devices(a.device)
    print(f"{a.lod} LOD, {a.size}x{a.size}, {a.device.upper()} device: frame seconds coloured by "
          f"{a.grid} / by {a.color_grid}")
    for mode in MODES:
        own = RenderScene([RenderObject(gs, m, grid=grids[a.grid])], mode=mode)
        other = RenderScene([RenderObject(gs, m, grid=grids[a.grid], color_tf=ctf,
                                          color_grid=grids[a.color_grid])], mode=mode)
        d0, d1 = device(), device()
        t0, t1 = run(lambda: best_frame(d0, own, cam, tf)), run(lambda: best_frame(d1, other, cam, tf))
        line = f"  {mode:10s} {t0:.3f} / {t1:.3f} s  ({t1 / t0:.2f}x)"
        if a.device == "gpu":
            want = CPUDevice().render(other, cam, tf)["Combined"]
            got = run(lambda: d1.render(other, cam, tf))["Combined"]
            line += (f"  GPU vs CPU {psnr(got, want):.1f} dB, {d1.stats.get('overflow_tiles', 0)} "
                     f"tiles redrawn on the CPU, fallback: {d1.stats.get('fallback')}")
        print(line)
    return 0


def devices(name):
    """(a device factory, a runner): the CPU device, or the GPU device with its GPU context."""
    if name == "cpu":
        return CPUDevice, lambda fn: fn()
    from blender_session import addon_module, start

    start()
    return addon_module("gaussvdb_addon.gpu.device").GPUDevice, addon_module("gaussvdb_addon.gpu.context").run


if __name__ == "__main__":
    sys.exit(main())
