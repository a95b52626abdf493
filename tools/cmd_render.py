"""`./gaussvdb render FILE.vdb|'DIR/name_####.vdb' [--frames A-B] [--grid G] [--vector-magnitude] [--lod PRESET]
[--mode particles|field|paper|reference] [--colormap NAME] [--size WxH] [--out IMG.png|.exr]
[--threads N] [--density D] [--log-scale] [--legend] [--clip-plane P,N] [--clip-box LO,HI]
[--view DX,DY,DZ] [--up X,Y,Z] [--level-set surface|shell] [--shading emission|lit] [--shadows] [--color-grid NAME
[--color-map NAME]] [--range MIN,MAX] [--tolerance T] [--device cpu|gpu] [--json]`

Imports one grid through the importer, frames a camera on its active voxels (the same view for
every LOD), sets the Standard view transform (colormaps come out exact), renders through the
GAUSSVDB engine (``bpy.ops.render.render(write_still=True)``) and writes the image. --range fixes
the transfer function's value range (the same colours for every file of a batch). Prints a
summary, or with --json one JSON document and nothing else on stdout (Blender's own lines go to
stderr): seconds_render, seconds_sync, seconds_import, width, height, mode, gaussians,
threads, lod (null for a file in reference mode: it draws the voxels and builds no Gaussians),
grid, colormap, value_range, out, warnings, device (the one that drew: GPU falls back to CPU
with a warning where no GPU context can be had) and gpu (the GPU's name, or null). Warnings
(a log scale over values <= 0) go to stderr.
Options and the grid are checked before Blender starts; a refusal or a failed render is one line
on stderr (tools/cli_errors.py). A '#' pattern or --frames renders a sequence, one image per
frame (tools/render_sequence.py).
"""
from __future__ import annotations

import contextlib
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the sibling tools modules

import cli_errors  # noqa: E402
import cluster  # noqa: E402
import render_sequence  # noqa: E402
from cli_errors import InputError, UsageError  # noqa: E402
from render_setup import (  # noqa: E402, F401
    beyond_plain_fog,
    build_scene,
    check_format,
    convert_options,
    index_box_world,
    quiet_render,
    stdout_to_stderr,
    voxel_box,
)

VIEW = (0.35, 1.0, -0.3)  # viewing direction: from the front, a little from the side and above


def parse(argv):
    from kernels import lod_names, mode_names
    from kernels.lod import PRESETS, WEIGHTS
    from kernels.render import colormap_names

    p = cli_errors.ArgumentParser(prog="gaussvdb render", description=__doc__.split("\n\n")[1])
    p.add_argument("file", help="a .vdb file, or a sequence: 'DIR/name_####.vdb'")
    p.add_argument("--frames", default=None, help="frames of a sequence to render: 35-50 "
                   "(default: every frame found); --out then needs #### for the number")
    p.add_argument("--grid", default=None, help="grid name (default: the first scalar grid with "
                   "active voxels)")
    p.add_argument("--vector-magnitude", action="store_true",
                   help="vec3 grids (velocity) count as their magnitude, as in the importer")
    p.add_argument("--lod", default=lod_names.DEFAULT, choices=PRESETS,
                   help="LOD preset (--mode reference draws the voxels of a file: no LOD is built)")
    p.add_argument("--mode", default=mode_names.DEFAULT, choices=mode_names.NAMES)
    p.add_argument("--colormap", default="viridis", type=str.lower, choices=colormap_names())
    p.add_argument("--size", default=(640, 480), type=cli_errors.size, help="WxH pixels (640x480)")
    p.add_argument("--out", default="render.png", help=".png or .exr (.jpg, .tif also work)")
    p.add_argument("--threads", type=cli_errors.threads, default=0, help="CPU threads (0: all)")
    p.add_argument("--density", type=cli_errors.nonnegative, default=None,
                   help="extinction per world unit (default: 10 over the diagonal of the framed "
                        "box, the same for every LOD)")
    p.add_argument("--range", dest="value_range", type=cli_errors.value_range, default=None,
                   metavar="MIN,MAX", help="the transfer function's value range (default: the "
                   "active voxels' range; a sequence's over its frames): the same colours for every "
                   "file and frame of a batch (a log scale needs MIN > 0; write --range=-1,1 for a "
                   "negative MIN)")
    p.add_argument("--tolerance", type=cli_errors.nonnegative, default=None, metavar="T",
                   help=f"--lod adaptive: the field NRMSE to meet (default {lod_names.DEFAULT_TOLERANCE})")
    p.add_argument("--weights", default=WEIGHTS[0], choices=WEIGHTS)
    p.add_argument("--transparent", action="store_true", help="transparent film (alpha kept)")
    p.add_argument("--log-scale", action="store_true", help="log10 transfer function")
    p.add_argument("--legend", action="store_true", help="draw the colour legend (scalar bar)")
    p.add_argument("--clip-plane", action="append", default=[], type=cli_errors.clip_plane,
                   metavar="PX,PY,PZ,NX,NY,NZ", help="cut the volume by the world plane through P "
                   "with normal N, keeping the side N points to (repeatable)")
    p.add_argument("--clip-box", action="append", default=[], type=cli_errors.clip_box,
                   metavar="X0,Y0,Z0,X1,Y1,Z1", help="keep only the part inside this world box "
                   "(repeatable)")
    p.add_argument("--level-set", default="surface", choices=("surface", "shell"),
                   help="level sets as lit opaque surfaces (headlight) or translucent shells")
    p.add_argument("--shading", default="emission", choices=("emission", "lit"),
                   help="volumes glow (emission-absorption) or are lit by the scene's lights "
                        "(a headlight here) by their gradient")
    p.add_argument("--view", type=cli_errors.direction, default=VIEW, metavar="DX,DY,DZ",
                   help="world viewing direction, camera towards the box (default 0.35,1,-0.3)")
    p.add_argument("--up", type=cli_errors.direction, default=(0.0, 0.0, 1.0), metavar="X,Y,Z",
                   help="the world up of the image (default +Z; 0,1,0 for y-up data)")
    p.add_argument("--shadows", action="store_true",
                   help="lit volumes: a sun from above lights them through the medium (the "
                        "headlight casts no shadows)")
    p.add_argument("--color-grid", default=None, metavar="NAME",
                   help="colour by this other grid of the file (a fire's temperature); the "
                        "opacity stays the transfer function's over --grid")
    p.add_argument("--color-map", default="inferno", type=str.lower, choices=colormap_names(),
                   help="the colormap over --color-grid (default inferno), over its active voxels' range")
    p.add_argument("--device", default="cpu", choices=("cpu", "gpu"),
                   help="render device: the CPU, or compute shaders on the GPU (reference mode; "
                        "the CPU draws what the GPU does not)")
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout and "
                   "nothing else (Blender's lines go to stderr)")
    cluster.add_arguments(p)
    a = p.parse_args(argv)
    a.width, a.height = a.size
    if a.tolerance is not None and a.lod not in lod_names.TOLERANCE_PRESETS:
        raise UsageError(f"--tolerance applies to --lod {', '.join(lod_names.TOLERANCE_PRESETS)}, "
                         f"not {a.lod}", p.prog)
    if a.value_range and a.log_scale and a.value_range[0] <= 0:
        raise UsageError(f"--range {a.value_range[0]:g},{a.value_range[1]:g}: a log scale needs "
                         "MIN > 0", p.prog)
    return a


def options(**overrides):
    """The render options with the command line's defaults, for callers that set up a scene
    without one (the demo, benchmarks, tests): e.g. options(width=48, height=36, lod="low")."""
    a = parse(["-"])
    for k, v in overrides.items():
        setattr(a, k, v)
    return a


def render(args) -> dict:
    import cli_grids
    from blender_session import addon_module, compile_ahead, start

    from kernels.vdb import check_header

    check_header(args.file)  # a missing file or not a .vdb file: refused before Blender starts
    bpy = start()  # then the grid checks read with the extension's kernels (compiled once)
    compile_ahead([args.mode], args.threads, beyond_plain_fog(args))
    grid = cli_grids.choose_grid(args.file, args.grid, args.vector_magnitude)
    if args.color_grid:
        cli_grids.check_color_grid(args.file, args.color_grid, args.vector_magnitude)
    importer = addon_module("gaussvdb_addon.io.importer")
    image_file = addon_module("gaussvdb_addon.engine.image_file")
    check_format(image_file, args.out)
    bpy.ops.wm.read_homefile(use_empty=True)
    options = convert_options(args, grid)
    if args.mode == "reference":  # it draws the voxels: no Gaussians to build (nor to compile)
        options = options.replace(lods=())
    t0 = time.perf_counter()
    try:
        objs = importer.import_vdb(os.path.abspath(args.file), options=options,
                                   collection=bpy.context.scene.collection)
    except importer.VDBImportError as err:
        raise InputError(f"{args.file}: {err}") from err
    seconds_import = time.perf_counter() - t0
    lo, hi = voxel_box(args.file, grid)
    scene = build_scene(bpy, objs, args, box=lambda obj: index_box_world(obj, lo, hi))
    stats = quiet_render(image_file, scene, os.path.abspath(args.out))
    stats.update(seconds_import=seconds_import, lod=options.lods[0] if options.lods else None,
                 grid=grid, colormap=args.colormap,
                 color_grid=args.color_grid,
                 file=os.path.abspath(args.file), out=os.path.abspath(args.out))
    return stats


def main(argv) -> int:
    args = parse(argv)
    if args.color_grid and (args.frames or "#" in os.path.basename(args.file)):
        raise UsageError("--color-grid colours one file, not a sequence", "gaussvdb render")
    if args.frames or "#" in os.path.basename(args.file):
        if cluster.wanted(args):  # one task per frame on a Dask cluster (tools/cluster.py)
            stats = cluster.render_sequence(args)
        else:
            with stdout_to_stderr() if args.json else contextlib.nullcontext():
                stats = render_sequence.render(args)
        if args.json:
            print(json.dumps(stats, sort_keys=True))
        else:
            for item in stats["frames"]:
                if "gaussians" not in item:  # a frame that failed on a cluster (said on stderr)
                    continue
                print(f"{item['out']}: frame {item['frame']}, {item['gaussians']:,} Gaussians, "
                      f"sync {item['seconds_sync']:.2f} s, render {item['seconds_render']:.2f} s")
        return 1 if stats["errors"] else 0
    if cluster.wanted(args):
        raise UsageError("--workers/--scheduler render a sequence ('DIR/name_####.vdb')",
                         "gaussvdb render")
    with stdout_to_stderr() if args.json else contextlib.nullcontext():
        stats = render(args)
    for msg in stats.get("warnings", ()):
        print(f"gaussvdb render: warning: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps(stats, sort_keys=True))
    else:
        drawn = f"{stats['gaussians']:,} Gaussians ({stats['lod']})" if stats["lod"] else "voxels"
        print(f"{stats['out']}: {stats['width']}x{stats['height']} {stats['mode']}, "
              f"{drawn}, sync {stats['seconds_sync']:.2f} s, "
              f"render {stats['seconds_render']:.2f} s on "
              f"{stats['gpu'] if stats.get('gpu') else str(stats['threads']) + ' threads'}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    sys.exit(cli_errors.run("gaussvdb render", main, sys.argv[1:]))
