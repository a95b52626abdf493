"""`./gaussvdb demo`: import the bundled sample at every fixed LOD preset (the paper's four and
Merged; Adaptive, which searches for its tolerance, is left to `convert --lod adaptive`) and print
the per-LOD table.

    ./gaussvdb demo [--file F.vdb] [--grids density,temperature] [--weights field|paper]
                    [--size 320x240] [--out DIR] [--json]

Runs in real Blender (the bpy module) with this working tree enabled as the extension
(tools/blender_session.py), through the same importer the File > Import operator calls.
It first renders the first grid's voxels (reference mode, the grid imported alone), then that
grid at every LOD (particles mode, viridis) under the same camera and density, to PNGs in
out/demo/, each with its PSNR against the voxels' image.
"""

import argparse
import json
import math
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


def render_reference(bpy, importer, path, opts, args):
    """The first grid drawn from its voxels (reference mode), imported alone (no Gaussians, so
    nothing but the reader and the mode's kernels to compile): the demo's first image, the one
    each LOD's image is compared with, and the camera and density every image shares.
    (object, its box, PNG path, line), or None without renders."""
    if args.size is None:
        return None
    import cmd_render
    from blender_session import addon_module
    from render_setup import index_box_world, voxel_box

    t0 = time.perf_counter()
    alone = importer.import_vdb(path, options=opts.replace(lods=(), compute_error=False),
                                collection=bpy.context.scene.collection)
    if not alone:
        return None
    obj = alone[0]
    for other in alone[1:]:
        bpy.data.objects.remove(other)
    lo, hi = voxel_box(path, obj.gaussvdb.grid_name)
    box = lambda o: index_box_world(o, lo, hi)  # noqa: E731 - the voxels' world box, for every image
    width, height = args.size
    scene = cmd_render.build_scene(bpy, [obj], cmd_render.options(width=width, height=height,
                                                                   mode="reference"), box=box)
    os.makedirs(args.out, exist_ok=True)
    out = os.path.join(os.path.abspath(args.out), f"{obj.gaussvdb.grid_name}_reference.png")
    image_file = addon_module("gaussvdb_addon.engine.image_file")
    cmd_render.quiet_render(image_file, scene, out)
    obj.hide_render = True
    return obj, box, out, f"{out} (the voxels, reference mode; {time.perf_counter() - t0:.2f} s)"


def render_pngs(bpy, objs, args, reference) -> tuple:
    """Render the first imported grid at every LOD it holds (particles mode, viridis) under the
    reference image's camera and density; returns (the lines to print, the reference's first;
    {LOD: its image's PSNR against the reference, dB})."""
    if reference is None or not objs:
        return [], {}
    import cmd_render
    from blender_session import addon_module

    image_file = addon_module("gaussvdb_addon.engine.image_file")
    _alone, box, ref_png, ref_line = reference
    obj = objs[0]
    for other in objs[1:]:
        other.hide_render = True
    width, height = args.size
    opts = cmd_render.options(width=width, height=height, lod=obj.gaussvdb.render_lod)
    scene = cmd_render.build_scene(bpy, [obj], opts, box=box)
    # Warm-up at a tiny size: the first render loads (or, on a first run, compiles) the kernels.
    r = scene.render
    r.resolution_x, r.resolution_y = 16, 12
    t0 = time.perf_counter()
    cmd_render.quiet_render(image_file, scene, os.path.join(os.path.abspath(args.out), "warmup.png"))
    lines = [ref_line, f"(render warm-up {time.perf_counter() - t0:.2f} s: kernels loaded or compiled)"]
    r.resolution_x, r.resolution_y = width, height
    reference = _pixels(bpy, ref_png)
    db = {}
    for name in addon_module("gaussvdb_addon.io.schema").lod_names(obj):
        obj.gaussvdb.render_lod = name
        path = os.path.join(os.path.abspath(args.out), f"{obj.gaussvdb.grid_name}_{name}.png")
        stats = cmd_render.quiet_render(image_file, scene, path)
        db[name] = psnr(_pixels(bpy, path), reference)
        lines.append(f"{path} ({stats.get('gaussians', 0):,} Gaussians, "
                     f"{stats.get('seconds_render', 0.0):.2f} s, {db[name]:.1f} dB against the voxels)")
    return lines, db


def _pixels(bpy, path):
    """An image file's pixels, premultiplied RGBA in [0, 1]."""
    import numpy as np

    img = bpy.data.images.load(path)
    try:
        px = np.empty(img.size[0] * img.size[1] * 4, np.float32)
        img.pixels.foreach_get(px)
    finally:
        bpy.data.images.remove(img)
    px = px.reshape(-1, 4).astype(np.float64)
    return np.concatenate([px[:, :3] * px[:, 3:], px[:, 3:]], 1)


def psnr(a, b) -> float:
    """Peak signal-to-noise ratio (dB) of image ``a`` against ``b`` (values in [0, 1])."""
    import numpy as np

    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def run(args) -> dict:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import cmd_render
    from blender_session import addon_module, compile_ahead, start

    bpy = start()
    if args.size is not None:  # the renders' kernels compile beside the import's (a cold cache):
        # the reference mode's first, for the first image, while this process compiles the reader
        compile_ahead(["reference", cmd_render.options().mode], general=False)
    importer = addon_module("gaussvdb_addon.io.importer")
    lod = addon_module("kernels.lod")
    bpy.ops.wm.read_homefile(use_empty=True)
    path = os.path.abspath(args.file)
    opts = importer.ConvertOptions(grids=args.grids, weights=args.weights)
    try:
        reference = render_reference(bpy, importer, path, opts, args)
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
                             bytes=int(s["bytes"]), seconds=s["seconds"], nrmse=s.get("nrmse"),
                             error_seconds=s.get("error_seconds")))
    versions = dict(blender=bpy.app.version_string, openvdb=_openvdb_version(bpy))
    renders, image_psnr = render_pngs(bpy, objs, args, reference)
    return dict(file=path, versions=versions, rows=rows, skipped=skipped, warmup_seconds=warmup,
                import_seconds=total, message=importer.status_message(objs, skipped),
                renders=renders, image_psnr=image_psnr)


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
