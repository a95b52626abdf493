"""Lit volumes' cost: per mode, ms per frame for Emission, Lit (no shadows) and Lit with shadows
from one sun, on the bundled sample (or given .vdb files), and the ratios to Emission.

    python benchmarks/bench_lit.py [FILES...] [--size 256] [--lod medium] [--modes particles,field,reference]
                                   [--repeat 2] [--threads 0] [--device cpu|gpu]

Whole frames (the per-frame set-up, which builds the shadow grid, included), best of --repeat
after a warm-up. Particles mode shades each lit chord once (cpu.gauss.lit_member) on gradients
computed once per sync (cpu.lit.lit_gradients: in the first frame, outside the best-of timing).
Targets: Lit <= 1.5x, shadows <= 4x. --device gpu: the GPU device (compute shaders on Blender's gpu
module; its frames' set-up, shadow grids included, runs on the CPU device); a frame it hands to
the CPU is said.
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

import cli_errors  # noqa: E402  (after the sys.path set-up above)
from bench_render import load, world_box  # noqa: E402

from kernels.lod import PRESETS  # noqa: E402
from kernels.render import MODES, Camera, CPUDevice, RenderObject, RenderScene, TransferFunction  # noqa: E402
from kernels.render.scene.lights import Light  # noqa: E402

SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")
SUN = Light("sun", (0.4, 0.3, -1.0), (1.0, 0.95, 0.9), 1.0)
VARIANTS = (("emission", "emission", False), ("lit", "lit", False), ("shadows", "lit", True))


def frame_ms(dev, scene, cam, tf, repeat):
    dev.render(scene, cam, tf)  # warm-up (and JIT load)
    best = 1e9
    for _ in range(repeat):
        dev.end_frame()
        t = time.perf_counter()
        dev.render(scene, cam, tf)
        best = min(best, time.perf_counter() - t)
    return 1e3 * best


def main(argv=None):
    ap = cli_errors.ArgumentParser(prog="bench_lit", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("paths", nargs="*")
    ap.add_argument("--size", type=cli_errors.positive_int, default=256)
    ap.add_argument("--lod", default="medium", choices=PRESETS)
    ap.add_argument("--modes", default=["particles", "field", "reference"], type=cli_errors.names(MODES))
    ap.add_argument("--repeat", type=cli_errors.positive_int, default=2)
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (0: all)")
    ap.add_argument("--device", default="cpu", choices=("cpu", "gpu"))
    a = ap.parse_args(argv)
    dev = CPUDevice(threads=a.threads or None)
    if a.device == "gpu":
        from blender_session import addon_module, start

        start()
        dev = addon_module("gaussvdb_addon.gpu.device").GPUDevice(threads=a.threads or None)
    for path in a.paths or [SAMPLE]:
        g, gs, _ = load(path, a.lod)
        m = np.asarray(g.index_to_world, float)
        lo, hi = world_box(g, m)
        vals = np.asarray(gs.values, float)
        vmin, vmax = float(np.nanmin(vals)), float(np.nanmax(vals))
        tf = TransferFunction.from_colormap("viridis", vmin, vmax if vmax > vmin else vmin + 1,
                                            density=4.0 / float(np.max(hi - lo)))
        cam = Camera.frame_box(lo, hi, a.size, a.size, direction=(1.0, 1.0, -0.6))
        print(f"{os.path.basename(path)}: {int(np.asarray(gs.group_start)[-1])} Gaussians ({a.lod}), "
              f"{a.size}x{a.size}, one sun, {dev.name} device")
        for mode in a.modes:
            ms = {}
            for name, shading, shadows in VARIANTS:
                obj = RenderObject(gs, m, grid=g, shading=shading, shadows=shadows)
                ms[name] = frame_ms(dev, RenderScene([obj], mode=mode, lights=(SUN,)), cam, tf, a.repeat)
                if dev.stats.get("fallback"):
                    print(f"  {mode} {name}: drawn by the CPU device ({dev.stats['fallback']})")
            print(f"  {mode:10s} emission {ms['emission']:8.1f} ms | lit {ms['lit']:8.1f} ms "
                  f"({ms['lit'] / ms['emission']:.2f}x) | lit + shadows {ms['shadows']:8.1f} ms "
                  f"({ms['shadows'] / ms['emission']:.2f}x)")
        if getattr(dev, "renderer", None):
            print(f"  on {dev.renderer}")
    return 0


if __name__ == "__main__":
    sys.exit(cli_errors.run("bench_lit", main, sys.argv[1:]))
