"""`./gaussvdb demo`: import the bundled sample at every fixed LOD preset (the paper's four and
Merged; Adaptive, which searches for its tolerance, is left to `convert --lod adaptive`) and print
the per-LOD table.

    ./gaussvdb demo [--file F.vdb] [--grids density,temperature] [--weights field|paper]
                    [--size 320x240] [--out DIR] [--json]

Runs in real Blender (the bpy module) with this working tree enabled as the extension
(tools/blender_session.py), through the same importer the File > Import operator calls.
Then it renders the first grid at every LOD (particles mode, viridis) to PNGs in out/demo/.
"""

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the sibling tools modules

import cli_errors  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")


def png_size(text):
    """--size: WxH, or 0 for no renders."""
    return None if text == "0" else cli_errors.size(text)


def parse(argv):
    from kernels.lod import WEIGHTS

    ap = cli_errors.ArgumentParser(prog="gaussvdb demo", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--file", default=SAMPLE, help="a .vdb file (default: the bundled sample)")
    ap.add_argument("--grids", default="", help="comma-separated grid names (default: every scalar grid)")
    ap.add_argument("--weights", default=WEIGHTS[0], choices=WEIGHTS)
    ap.add_argument("--size", default=(320, 240), type=png_size,
                    help="PNG size WxH of the renders (0: no renders)")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "demo"), help="folder for the PNGs")
    ap.add_argument("--json", action="store_true", help="print the table as JSON")
    return ap.parse_args(argv)


def render_pngs(bpy, objs, args) -> list:
    """Render the first imported grid at every LOD it holds (particles mode, viridis); returns paths."""
    if args.size is None or not objs:
        return []
    import cmd_render
    from blender_session import addon_module

    image_file = addon_module("gaussvdb_addon.engine.image_file")
    obj = objs[0]
    for other in objs[1:]:
        other.hide_render = True
    width, height = args.size
    opts = cmd_render.options(width=width, height=height, lod=obj.gaussvdb.render_lod)
    scene = cmd_render.build_scene(bpy, [obj], opts)
    os.makedirs(args.out, exist_ok=True)
    # Warm-up at a tiny size: the first render loads (or, on a first run, compiles) the kernels.
    r = scene.render
    r.resolution_x, r.resolution_y = 16, 12
    t0 = time.perf_counter()
    cmd_render.quiet_render(image_file, scene, os.path.join(os.path.abspath(args.out), "warmup.png"))
    paths = [f"(render warm-up {time.perf_counter() - t0:.2f} s: kernels loaded or compiled)"]
    r.resolution_x, r.resolution_y = width, height
    for name in addon_module("gaussvdb_addon.io.schema").lod_names(obj):
        obj.gaussvdb.render_lod = name
        path = os.path.join(os.path.abspath(args.out), f"{obj.gaussvdb.grid_name}_{name}.png")
        stats = cmd_render.quiet_render(image_file, scene, path)
        paths.append(f"{path} ({stats.get('gaussians', 0):,} Gaussians, "
                     f"{stats.get('seconds_render', 0.0):.2f} s)")
    return paths


def run(args) -> dict:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import cmd_render
    from blender_session import addon_module, compile_ahead, start

    bpy = start()
    if args.size is not None:  # the renders' kernels compile beside the import's (a cold cache),
        # after the first LOD's: this process then compiles the reader and the field error
        compile_ahead([cmd_render.options().mode], general=False, lod="low")
    importer = addon_module("gaussvdb_addon.io.importer")
    lod = addon_module("kernels.lod")
    bpy.ops.wm.read_homefile(use_empty=True)
    path = os.path.abspath(args.file)
    opts = importer.ConvertOptions(grids=args.grids, weights=args.weights)
    try:
        t0 = time.perf_counter()  # warm-up: numba loads (or, on a first run, compiles) its kernels
        importer.convert_file(path, options=opts.replace(lods=("low",)))
        warmup = time.perf_counter() - t0
        t0 = time.perf_counter()
        skipped = []
        fixed = tuple(p for p in lod.PRESETS if p != "adaptive")
        objs = importer.import_vdb(path, options=opts.replace(lods=fixed),
                                   collection=bpy.context.scene.collection, skipped=skipped)
        total = time.perf_counter() - t0
    except importer.VDBImportError as err:
        raise cli_errors.InputError(f"{args.file}: {err}") from err
    rows = []
    for obj in objs:
        for s in importer.object_stats(obj):
            rows.append(dict(grid=obj.gaussvdb.grid_name, lod=s["lod"], gaussians=s["count"],
                             bytes=s["bytes"], seconds=s["seconds"], nrmse=s.get("nrmse"),
                             error_seconds=s.get("error_seconds")))
    versions = dict(blender=bpy.app.version_string, openvdb=_openvdb_version(bpy))
    return dict(file=path, versions=versions, rows=rows, skipped=skipped, warmup_seconds=warmup,
                import_seconds=total, message=importer.status_message(objs, skipped),
                renders=render_pngs(bpy, objs, args))


def _openvdb_version(bpy):
    try:
        if hasattr(bpy.utils, "expose_bundled_modules"):
            bpy.utils.expose_bundled_modules()
        import openvdb

        return getattr(openvdb, "LIBRARY_VERSION", None) and ".".join(map(str, openvdb.LIBRARY_VERSION)) \
            or getattr(openvdb, "__version__", "?")
    except ImportError:
        return "not bundled"


def table(result) -> str:
    lines = [f"Blender {result['versions']['blender']}, OpenVDB {result['versions']['openvdb']}",
             f"{result['file']}", ""]
    head = f"{'grid':<12} {'LOD':<9} {'Gaussians':>10} {'bytes':>11} {'seconds':>8} {'field NRMSE':>12}"
    lines += [head, "-" * len(head)]
    for r in result["rows"]:
        err = "-" if r["nrmse"] is None else f"{100 * r['nrmse']:.2f}%"
        lines.append(f"{r['grid']:<12} {r['lod']:<9} {r['gaussians']:>10,} {r['bytes']:>11,} "
                     f"{r['seconds']:>8.3f} {err:>12}")
    for name, why in result["skipped"]:
        lines.append(f"skipped {name}: {why}")
    timing = (f"import (every LOD, field errors included): {result['import_seconds']:.2f} s "
              f"(warm-up {result['warmup_seconds']:.2f} s)")
    lines += ["", timing, f"status bar: {result['message']}"]
    lines += [p if p.startswith("(") else f"rendered {p}" for p in result["renders"]]
    return "\n".join(lines)


def main(argv) -> int:
    args = parse(argv)
    from kernels.vdb import check_header

    check_header(args.file)  # a missing file or not a .vdb file: refused before Blender starts
    result = run(args)
    print(json.dumps(result, indent=1, default=str) if args.json else table(result))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, ROOT)
    sys.exit(cli_errors.run("gaussvdb demo", main, sys.argv[1:]))
