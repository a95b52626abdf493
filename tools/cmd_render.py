"""`./gaussvdb render FILE.vdb [--grid G] [--lod PRESET] [--mode particles|field|paper|reference]
[--colormap NAME] [--size WxH] [--out IMG.png|.exr] [--threads N] [--density D] [--json]`

Imports one grid through the importer, frames a camera on its world box, sets the Standard view
transform (colormaps come out exact), renders through the GAUSSVDB engine
(``bpy.ops.render.render(write_still=True)``) and writes the image. Prints a summary, or with
--json one JSON line: seconds_render, seconds_sync, seconds_import, width, height, mode, gaussians,
threads, lod, grid, colormap, out. Exit status 1 with the engine's message when the render fails.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

MODES = ("particles", "field", "paper", "reference")
VIEW = (0.35, 1.0, -0.3)  # viewing direction: from the front, a little from the side and above


def parse(argv):
    p = argparse.ArgumentParser(prog="gaussvdb render", description=__doc__.split("\n\n")[1])
    p.add_argument("file")
    p.add_argument("--grid", default=None, help="grid name (default: the first with active voxels)")
    p.add_argument("--lod", default="medium", help="LOD preset (low, medium, high, variance, merged)")
    p.add_argument("--mode", default="particles", choices=MODES)
    p.add_argument("--colormap", default="viridis")
    p.add_argument("--size", default="640x480", help="WxH pixels")
    p.add_argument("--out", default="render.png", help=".png or .exr (.jpg, .tif also work)")
    p.add_argument("--threads", type=int, default=0, help="CPU threads (0: all)")
    p.add_argument("--density", type=float, default=None, help="extinction per world unit (default: "
                   "10 per voxel-box diagonal, scaled to the grid)")
    p.add_argument("--weights", default="field", choices=("field", "paper"))
    p.add_argument("--transparent", action="store_true", help="transparent film (alpha kept)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    a = p.parse_args(argv)
    try:
        w, h = (int(v) for v in a.size.lower().split("x"))
        assert w > 0 and h > 0
    except (ValueError, AssertionError):
        p.error(f"--size must look like 640x480, not {a.size!r}")
    a.width, a.height = w, h
    return a


def pick_grid(path, grid):
    if grid:
        return grid
    from kernels.vdb import read_topology

    grids = read_topology(path).grids
    live = [g for g in grids if g.active_voxels and g.value_type in ("float", "double", "half")]
    chosen = (live or grids)
    if not chosen:
        raise SystemExit(f"gaussvdb render: no grid in {path}")
    return chosen[0].name


def world_box(obj):
    import numpy as np

    corners = np.array([list(c) for c in obj.bound_box], np.float64)
    mw = np.array(obj.matrix_world, np.float64)
    wc = np.c_[corners, np.ones(8)] @ mw.T
    return wc[:, :3].min(0), wc[:, :3].max(0)


def build_scene(bpy, objs, args):
    """Camera framing the objects' world box, engine settings; returns the scene."""
    import mathutils
    import numpy as np

    from kernels.render import Camera

    scene = bpy.context.scene
    boxes = [world_box(o) for o in objs]
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    cam = Camera.frame_box(lo, hi, args.width, args.height, direction=VIEW)
    data = bpy.data.cameras.new("GaussVDB Camera")
    data.sensor_fit = "AUTO"
    data.sensor_width = 36.0
    data.lens = 18.0 / math.tan(0.5 * cam.fov_x)
    dist = float(np.linalg.norm(cam.cam_to_world[:3, 3] - 0.5 * (lo + hi)))
    data.clip_start = max(1e-4, dist * 1e-3)
    data.clip_end = dist * 10.0
    ob = bpy.data.objects.new("GaussVDB Camera", data)
    # a Matrix built from rows (assigning a nested list directly would be read as columns)
    ob.matrix_world = mathutils.Matrix([list(row) for row in cam.cam_to_world])
    scene.collection.objects.link(ob)
    scene.camera = ob
    r = scene.render
    r.engine = "GAUSSVDB"
    r.resolution_x, r.resolution_y, r.resolution_percentage = args.width, args.height, 100
    r.film_transparent = bool(args.transparent)
    s = scene.gaussvdb
    s.mode = args.mode.upper()
    s.colormap = args.colormap
    if args.threads:
        r.threads_mode, r.threads = "FIXED", args.threads
    if args.density is not None:
        s.density_unit, s.density = "WORLD", args.density
    # else the default: density 10 per object size, about 10 optical-depth units across the box
    for o in objs:
        o.gaussvdb.render_lod = args.lod
        o.gaussvdb.viewport_lod = args.lod
    return scene


def render(args) -> dict:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from blender_session import addon_module, start

    from kernels.render import colormap_names

    if args.colormap.lower() not in colormap_names():
        raise SystemExit(f"gaussvdb render: unknown colormap {args.colormap!r}; have {colormap_names()}")
    if not os.path.isfile(args.file):
        raise SystemExit(f"gaussvdb render: no such file {args.file}")
    grid = pick_grid(args.file, args.grid)
    bpy = start()
    importer = addon_module("gaussvdb_addon.importer")
    final_render = addon_module("gaussvdb_addon.final_render")
    bpy.ops.wm.read_homefile(use_empty=True)
    t0 = time.perf_counter()
    objs = importer.import_vdb(os.path.abspath(args.file), grids=[grid], lods=(args.lod,),
                               weights=args.weights, collection=bpy.context.scene.collection,
                               compute_error=False)
    seconds_import = time.perf_counter() - t0
    if not objs:
        raise SystemExit(f"gaussvdb render: nothing imported from {args.file} (grid {grid})")
    scene = build_scene(bpy, objs, args)
    stats = final_render.render_scene_to_file(scene, os.path.abspath(args.out))
    stats.update(seconds_import=seconds_import, lod=args.lod, grid=grid, colormap=args.colormap,
                 file=os.path.abspath(args.file), out=os.path.abspath(args.out))
    return stats


def main(argv) -> int:
    args = parse(argv)
    try:
        stats = render(args)
    except RuntimeError as err:
        print(f"gaussvdb render: {err}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(stats, sort_keys=True))
    else:
        print(f"{stats['out']}: {stats['width']}x{stats['height']} {stats['mode']}, "
              f"{stats['gaussians']:,} Gaussians ({stats['lod']}), sync {stats['seconds_sync']:.2f} s, "
              f"render {stats['seconds_render']:.2f} s on {stats['threads']} threads")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
