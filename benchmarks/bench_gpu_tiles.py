"""The GPU device's screen-tile lists: built by the CPU device (numba) and uploaded, or built on
the GPU (compute shaders), in the same run.

    python benchmarks/bench_gpu_tiles.py [FILE.vdb ...] [--size 256] [--mode particles]
                                         [--lod medium] [--repeat 3]

Per file: ms per whole frame (best of --repeat after a warm-up: the CPU-side set-up, the lists,
uploads, the dispatch and the readback) with each kind of list, and the dispatch alone (the lists
kept); ms to build the lists alone (CPU: device.screen_tiles and the tables; GPU: the three passes
and a readback of the entries, which waits for them); the entries, and the GPU's name (llvmpipe
is a software one)."""
from __future__ import annotations

import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tools"))
sys.path.insert(0, HERE)

from bench_render import best_ms, frame_setup, load  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("paths", nargs="*")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--mode", default="particles", choices=("particles", "field", "paper"))
    ap.add_argument("--lod", default="medium")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    from blender_session import addon_module, start

    start()
    gdev = addon_module("gaussvdb_addon.gpu.device")
    tiles = addon_module("gaussvdb_addon.gpu.tiles")
    from kernels.render.gpu import tables_tiles
    context = addon_module("gaussvdb_addon.gpu.context")
    files = a.paths or [os.path.join(os.path.dirname(HERE), "samples", "mantaflow_smoke_r128_f040.vdb")]
    for f in files:
        g, gs, _ = load(f, a.lod)
        sc, cam, tf = frame_setup(g, gs, (a.size, a.size), a.mode)
        res = {}
        for lists in ("CPU", "GPU"):
            dev = gdev.GPUDevice(gpu_tiles=lists == "GPU")

            def whole(dev=dev):
                dev.end_frame()
                return dev.render(sc, cam, tf)

            res[lists] = (context.run(lambda whole=whole: best_ms(whole, a.repeat)), dev)
            draw = context.run(lambda dev=dev: best_ms(lambda: dev.render(sc, cam, tf), a.repeat))
            print(f"  {lists}-built lists: dispatch and readback alone (lists kept) {draw:8.1f} ms")
        (ms_c, _), (ms_g, dg) = res["CPU"], res["GPU"]
        frame = dg.begin_frame(sc, cam, tf)
        lc = best_ms(lambda: tables_tiles.cpu_lists(frame), a.repeat)
        lg = context.run(lambda: best_ms(lambda: tiles.build(frame)[0]["t_ent"].read(), a.repeat))
        print(f"  lists alone: CPU {lc:8.1f} ms, GPU {lg:8.1f} ms")
        print(f"{os.path.basename(f)} {a.mode} {a.lod} {a.size}x{a.size}: CPU-built lists {ms_c:8.1f} ms/frame"
              f" | GPU-built lists {ms_g:8.1f} ms/frame ({dg.stats.get('gpu_tile_entries')} entries,"
              f" built on the {dg.stats.get('tile_lists')}) | {dg.renderer}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
