"""Render benchmark: per .vdb file in a folder, 512x512 (default), per mode at the Medium LOD.

    python benchmarks/bench_render.py [DATA_DIR_OR_FILES...] [--size 512] [--modes particles,field,reference]
                                      [--lod medium] [--repeat 2] [--threads 1,2] [--json out.json]
                                      [--device cpu|gpu]

Reports ms per frame (best of --repeat, after one warm-up), M segments (particles/paper: closed-
form Gaussian segments; field: Gaussian terms evaluated per sample; reference: trilinear samples)
per second per core, and the 1 -> 2 thread speedup. Falls back to a synthetic smoke blob when no
file is given and samples/ is empty (said in the output).

--device gpu: per file, mode and LOD, ms per frame of the GPU device (compute shaders on Blender's
gpu module; whole frames: the CPU-side set-up, uploads and readback included, and the dispatch
alone with the frame's tables kept, as the viewport redraws) at 512x512 and 1920x1080, the bytes
of the scene's tables on the GPU, and the CPU device's ms per frame (all threads) in the same
run. Says when the GPU is a software one (llvmpipe). Modes not on the GPU yet are listed as such.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))

import cli_errors  # noqa: E402  (after the sys.path set-up above)

from kernels.lod import PRESETS  # noqa: E402
from kernels.render import MODES, Camera, CPUDevice, RenderObject, RenderScene, TransferFunction  # noqa: E402


def load(path, lod):
    from kernels.lod import build_lod
    from kernels.vdb import read_vdb

    grids = list(read_vdb(path).grids)
    g = next((x for x in grids if x.grid_class in ("fog_volume", "level_set")), grids[0])
    t = time.perf_counter()
    gs = build_lod(g, lod)
    return g, gs, time.perf_counter() - t


def synthetic():
    from kernels.render.scene.synthetic import gaussian_set, grid_from_dense

    n = 64
    x = np.arange(n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    vol = np.exp(-((X - 32) ** 2 + (Y - 32) ** 2 + (Z - 28) ** 2) / (2 * 12.0 ** 2)).astype(np.float32)
    vol[vol < 0.05] = 0
    grid = grid_from_dense(vol)
    c = np.stack(np.meshgrid(x[::2] + 0.5, x[::2] + 0.5, x[::2] + 0.5, indexing="ij"), -1).reshape(-1, 3)
    v = vol[::2, ::2, ::2].reshape(-1)
    keep = v > 0
    sig = 0.6 * 2
    gs = gaussian_set(c[keep], sig, v[keep], 8 / ((2 * np.pi) ** 1.5 * sig ** 3))
    return grid, gs


def frame_setup(g, gs, size, mode, density=None):
    """The scene, camera and transfer function of one case at size (w, h)."""
    m = np.asarray(getattr(g, "index_to_world", np.eye(4)), float)
    lo, hi = world_box(g, m)
    dens = density or 4.0 / float(np.max(hi - lo))
    vmin, vmax = (0.0, 1.0)
    vals = np.asarray(gs.values, float)
    if np.isfinite(vals).any():
        vmin, vmax = float(np.nanmin(vals)), float(np.nanmax(vals))
    tf = TransferFunction.from_colormap("viridis", vmin, vmax if vmax > vmin else vmin + 1, density=dens)
    cam = Camera.frame_box(lo, hi, size[0], size[1], direction=(1.0, 1.0, -0.6))
    sc = RenderScene([RenderObject(gs, m, grid=g, is_level_set=g.grid_class == "level_set")], mode=mode)
    return sc, cam, tf


def best_ms(fn, repeat):
    fn()  # warm-up (shader compile, uploads, JIT load)
    best = 1e9
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return 1e3 * best


def gpu_rows(cases, a):
    """The GPU device against the CPU device, per file, mode and size (see the docstring)."""
    from blender_session import addon_module, start

    from kernels.render.devices.modes import gpu_modes

    start()
    gdev = addon_module("gaussvdb_addon.gpu.device")
    context = addon_module("gaussvdb_addon.gpu.context")
    cpu, gpu = CPUDevice(), gdev.GPUDevice()
    rows = []
    for name, g, gs, _ in cases:
        for mode in a.modes:
            if mode not in gpu_modes():  # (splat: drawn as the reference mode)
                print(f"{name}: {mode} is not on the GPU device yet")
                continue
            for size in ((512, 512), (1920, 1080)):
                sc, cam, tf = frame_setup(g, gs, size, mode, a.density)

                def whole():
                    gpu.end_frame()
                    return gpu.render(sc, cam, tf)

                def timed():
                    return (best_ms(whole, a.repeat), best_ms(lambda: gpu.render(sc, cam, tf), a.repeat))

                ms_frame, ms_draw = context.run(timed)
                ms_cpu = best_ms(lambda: (cpu.end_frame(), cpu.render(sc, cam, tf)), a.repeat)
                soft = any(k in (gpu.renderer or "").lower() for k in ("llvmpipe", "softpipe", "swrast"))
                row = dict(file=name, mode=mode, lod=a.lod, width=size[0], height=size[1],
                           gpu=gpu.renderer, software=soft, ms_gpu_frame=ms_frame, ms_gpu_draw=ms_draw,
                           gpu_scene_bytes=gpu.stats.get("gpu_bytes"), ms_cpu=ms_cpu,
                           cpu_threads=cpu.stats.get("threads"))
                rows.append(row)
                print(f"{name} {mode} {a.lod} {size[0]}x{size[1]}: GPU {ms_frame:8.1f} ms/frame "
                      f"(dispatch {ms_draw:8.1f} ms), scene {row['gpu_scene_bytes'] / 2**20:7.2f} MiB | "
                      f"CPU {ms_cpu:8.1f} ms ({row['cpu_threads']} threads) | {gpu.renderer}"
                      f"{' (software)' if soft else ''}")
    return rows


def world_box(grid, m):
    lo = np.asarray(grid.bbox_min, float) - 0.5
    hi = np.asarray(grid.bbox_max, float) + 0.5
    c = np.array([[x, y, z, 1] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) @ m.T
    return c[:, :3].min(0), c[:, :3].max(0)


def main(argv=None):
    ap = cli_errors.ArgumentParser(prog="gaussvdb bench render", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("paths", nargs="*")
    ap.add_argument("--size", type=cli_errors.positive_int, default=512)
    ap.add_argument("--modes", default=["particles", "field", "reference"], type=cli_errors.names(MODES))
    ap.add_argument("--lod", default="medium", choices=PRESETS)
    ap.add_argument("--repeat", type=cli_errors.positive_int, default=2)
    ap.add_argument("--threads", default=[1, 2], type=cli_errors.positive_ints)
    ap.add_argument("--density", type=cli_errors.nonnegative, default=None,
                    help="extinction per world unit (default 4 / box size)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--device", default="cpu", choices=("cpu", "gpu"))
    a = ap.parse_args(argv)
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    files = []
    for p in a.paths or [os.path.join(here, "samples")]:
        files += sorted(glob.glob(os.path.join(p, "*.vdb"))) if os.path.isdir(p) else [p]
    cases = []
    for f in files:
        g, gs, tl = load(f, a.lod)
        cases.append((os.path.basename(f), g, gs, tl))
    if not cases:
        print("no .vdb files: using a synthetic 64^3 blob (say so when quoting these figures)")
        g, gs = synthetic()
        cases.append(("synthetic", g, gs, 0.0))
    if a.device == "gpu":
        rows = gpu_rows(cases, a)
        if a.json:
            with open(a.json, "w") as fh:
                json.dump(rows, fh, indent=1)
        return 0
    threads = a.threads
    dev = CPUDevice()
    rows = []
    for name, g, gs, tl in cases:
        m = np.asarray(getattr(g, "index_to_world", np.eye(4)), float)
        lo, hi = world_box(g, m)
        dens = a.density or 4.0 / float(np.max(hi - lo))
        is_ls = g.grid_class == "level_set"
        vmin, vmax = (0.0, 1.0)
        vals = np.asarray(gs.values, float)
        if np.isfinite(vals).any():
            vmin, vmax = float(np.nanmin(vals)), float(np.nanmax(vals))
        tf = TransferFunction.from_colormap("viridis", vmin, vmax if vmax > vmin else vmin + 1, density=dens)
        cam = Camera.frame_box(lo, hi, a.size, a.size, direction=(1.0, 1.0, -0.6))
        print(f"{name}: {g.grid_class}, {int(np.asarray(gs.group_start)[-1])} Gaussians "
              f"({a.lod}, built in {tl:.2f} s), "
              f"{len(g.leaf_origins)} leaves, {a.size}x{a.size}")
        for mode in a.modes:
            sc = RenderScene([RenderObject(gs, m, grid=g, is_level_set=is_ls)], mode=mode)
            dev.sync(sc)
            sync_s = dev.stats["seconds_sync"]
            res = {}
            for th in threads:
                sc.threads = th
                dev.render(sc, cam, tf)  # warm-up (and JIT load)
                best = 1e9
                for _ in range(a.repeat):
                    dev.end_frame()  # time whole frames: the per-frame set-up included
                    t = time.perf_counter()
                    out = dev.render(sc, cam, tf)
                    best = min(best, time.perf_counter() - t)
                res[th] = (best, dev.stats["segments"])
            t1 = res[threads[0]][0]
            segs = res[threads[0]][1]
            row = dict(file=name, mode=mode, sync_s=sync_s, coverage=float((out["Combined"][..., 3] > 0.01).mean()),
                       **{f"ms_{th}t": 1e3 * res[th][0] for th in threads},
                       msegs_per_s_per_core=segs / t1 / threads[0] / 1e6, segments=segs)
            if len(threads) > 1:
                row["speedup"] = t1 / res[threads[-1]][0]
            rows.append(row)
            print(f"  {mode:10s} sync {sync_s*1e3:7.0f} ms | "
                  + " | ".join(f"{th} thr {1e3*res[th][0]:8.1f} ms" for th in threads)
                  + f" | {row['msegs_per_s_per_core']:6.2f} M seg/s/core | speedup {row.get('speedup', 1):.2f} "
                  f"| coverage {row['coverage']:.2f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(cli_errors.run("gaussvdb bench render", main, sys.argv[1:]))
