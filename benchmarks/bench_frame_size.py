"""Frame cost against pixel count, through the F12 path and the CLI.

    python benchmarks/bench_frame_size.py [FILES...] [--modes particles,field,paper,reference]
                                          [--lod medium] [--sizes 512x512,1920x1080] [--repeat 1]
                                          [--no-cli] [--json out.json]

Per file (default: the bundled sample) the grid is imported and framed as `gaussvdb render` does.
Per mode and size it prints the F12 render's seconds (``bpy.ops.render.render``: the engine's
bands, set-up included; best of --repeat), the same frame drawn by the device in one call
(bench_render's in-process time: set-up included, kernels loaded), and the F12 time of each size
over the first size's with the pixel ratio beside it. Unless --no-cli, ``gaussvdb render`` is run
in a fresh process per mode and size (best of --repeat): its ``seconds_render``, set against the
in-process time, and its own ratio.
"""
from __future__ import annotations

import argparse
import atexit
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [ROOT, os.path.join(ROOT, "tools")]


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*")
    ap.add_argument("--modes", default="particles,field,paper,reference")
    ap.add_argument("--lod", default="medium")
    ap.add_argument("--sizes", default="512x512,1920x1080")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--no-cli", action="store_true")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    a.sizes = [tuple(int(v) for v in s.lower().split("x")) for s in a.sizes.split(",")]
    a.files = a.files or [os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")]
    return a


ENV = dict(os.environ)  # for the CLI: as before this process's Blender session set its own paths


def cli_seconds(path, mode, lod, size, out):
    cmd = [os.path.join(ROOT, "gaussvdb"), "render", path, "--mode", mode, "--lod", lod,
           "--size", f"{size[0]}x{size[1]}", "--out", out, "--json"]
    res = subprocess.run(cmd, capture_output=True, text=True, check=True, env=ENV)
    return json.loads(res.stdout.strip().splitlines()[-1])["seconds_render"]


def main(argv=None):
    a = parse(argv)
    import cli_grids
    import cmd_render
    from blender_session import addon_module, start

    bpy = start()
    importer = addon_module("gaussvdb_addon.io.importer")
    camera = addon_module("gaussvdb_addon.engine.camera")
    devices = addon_module("gaussvdb_addon.engine.devices")
    image_file = addon_module("gaussvdb_addon.engine.image_file")
    scene_sync = addon_module("gaussvdb_addon.engine.scene_sync")
    tmp = tempfile.mkdtemp(prefix="gaussvdb-bench-")  # the rendered frames: removed at exit
    atexit.register(shutil.rmtree, tmp, True)
    rows = []
    for path in a.files:
        grid = cli_grids.choose_grid(path, None, False)
        bpy.ops.wm.read_homefile(use_empty=True)
        objs = importer.import_vdb(os.path.abspath(path), grids=[grid], lods=(a.lod,),
                                   collection=bpy.context.scene.collection, compute_error=False)
        name = os.path.basename(path)
        print(f"{name} ({grid}, {a.lod}); F12 = bpy.ops.render.render, one call = device.render")
        for mode in a.modes.split(","):
            res = {}
            for w, h in a.sizes:
                args = cmd_render.options(width=w, height=h, mode=mode, lod=a.lod)
                scene = cmd_render.build_scene(bpy, objs, args)
                out = os.path.join(tmp, f"{mode}_{w}x{h}.png")
                f12 = []
                for _ in range(a.repeat):
                    f12.append(image_file.render_scene_to_file(scene, out)["seconds_render"])
                dg = bpy.context.evaluated_depsgraph_get()
                sync = scene_sync.SceneSync(viewport=False)
                rscene = sync.sync(dg)
                tf = sync.transfer_function(scene.gaussvdb)
                cam = camera.scene_camera(scene, dg, w, h)
                dev = devices.final_device()
                dev.sync(rscene)  # this sync's objects are new: not part of the frame's time
                one = []
                for _ in range(a.repeat):
                    dev.end_frame()
                    t = time.perf_counter()
                    dev.render(rscene, cam, tf)
                    one.append(time.perf_counter() - t)
                dev.end_frame()
                res[(w, h)] = (min(f12), min(one))
            (w0, h0), f0 = a.sizes[0], res[a.sizes[0]][0]
            cli0 = None
            for (w, h), (f12, one) in res.items():
                row = dict(file=name, mode=mode, width=w, height=h, f12_s=f12, one_call_s=one,
                           ratio=f12 / f0, pixel_ratio=w * h / (w0 * h0))
                line = (f"  {mode:10s} {w:4d}x{h:<4d} F12 {f12:7.2f} s | one call {one:7.2f} s | "
                        f"F12/one {f12 / one:4.2f} | x{row['ratio']:5.2f} for x{row['pixel_ratio']:4.2f} pixels")
                if not a.no_cli:
                    cli = row["cli_s"] = min(cli_seconds(path, mode, a.lod, (w, h), os.path.join(tmp, "cli.png"))
                                             for _ in range(a.repeat))
                    cli0 = cli0 or cli
                    row["cli_ratio"] = cli / cli0
                    line += (f" | CLI {cli:6.2f} s ({100 * (cli / one - 1):+.0f}% vs one call, "
                             f"x{row['cli_ratio']:5.2f})")
                rows.append(row)
                print(line, flush=True)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
