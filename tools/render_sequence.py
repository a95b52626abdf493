"""`./gaussvdb render 'DIR/fluid_data_####.vdb' --frames 35-50 --out 'out/frame_####.png'`:
a numbered sequence rendered frame by frame (cmd_render.py hands over when the file is a
'#' pattern or --frames is given).

The sequence is imported once (one frame converted, every frame's value figures read, so the
automatic range is the range over the frames rendered), scene frame N shows file N, the camera
frames the box of every frame, and each frame converts on demand as the timeline reaches it.
A missing frame holds the previous one (a warning), an unreadable one is an error naming it and
the next frames still render (exit status 1 at the end). --json prints one JSON object with
per-frame figures.
"""
from __future__ import annotations

import os
import sys
import time

import cli_errors
from cli_errors import InputError, UsageError
from render_setup import (
    beyond_plain_fog,
    build_scene,
    check_format,
    convert_options,
    index_box_world,
    quiet_render,
)


def frames_of(args):
    """(Pattern, frames to render, frames on disk among them) from the command line; refused
    before Blender starts."""
    from kernels import sequence as seq

    pat = seq.parse(os.path.abspath(args.file))
    if pat is None:
        raise InputError(f"{args.file}: no frame number or #### in the file name")
    present = pat.scan()
    if args.frames:
        try:
            frames = seq.parse_frames(args.frames)
        except ValueError as err:
            raise UsageError(f"--frames: {err}", "gaussvdb render") from None
    else:
        frames = present
    if not present:
        raise InputError(f"no frames of {pat.text} in {pat.directory}")
    inside = [n for n in present if frames[0] <= n <= frames[-1]]
    if not inside:
        raise InputError(f"no frames of {pat.text} between {frames[0]} and {frames[-1]} in "
                         f"{pat.directory} (frames {present[0]}-{present[-1]} exist)")
    if len(frames) > 1 and "#" not in os.path.basename(args.out):
        raise UsageError(f"--out {args.out}: several frames need #### in the name for the frame "
                         "number", "gaussvdb render")
    return pat, frames, inside


def out_path(pattern_text, frame):
    from kernels import sequence as seq

    pat = seq.parse(pattern_text)
    return pat.path(frame) if pat is not None and "#" in os.path.basename(pattern_text) else pattern_text


def choose_grid(pat, inside, args):
    """The grid to render: the named one or the first usable one of the first frame that has
    one (a flame grid may be empty in the first frames)."""
    import cli_grids

    last = None
    for n in inside:
        try:
            return cli_grids.choose_grid(pat.path(n), args.grid, args.vector_magnitude)
        except (InputError, ValueError) as err:
            last = err
    raise last


def sequence_box(obj):
    """World box of every frame (the stored union of the frames' leaf boxes)."""
    return index_box_world(obj, obj.gaussvdb.leaf_box_min, obj.gaussvdb.leaf_box_max)


def prepare(args, known=None) -> dict:
    """Blender started, the sequence imported and the scene built as `render` draws it: what
    rendering any one of its frames needs (a cluster worker prepares it once for its frames).
    ``known``: {frame: kernels.sequence.frame_figures} of the frames, read once by the cluster's
    tasks rather than again by every worker."""
    from blender_session import addon_module, compile_ahead, start

    pat, frames, inside = frames_of(args)
    bpy = start()  # first: the file checks read with the extension's kernels (one compile)
    compile_ahead([args.mode], args.threads, beyond_plain_fog(args))
    grid = choose_grid(pat, inside, args)
    importer = addon_module("gaussvdb_addon.io.importer")
    sequence_import = addon_module("gaussvdb_addon.io.sequence_import")
    image_file = addon_module("gaussvdb_addon.engine.image_file")
    check_format(image_file, args.out)
    bpy.ops.wm.read_homefile(use_empty=True)
    t0 = time.perf_counter()
    try:
        objs = sequence_import.import_sequence(
            pat.path(inside[0]), [inside[0], inside[-1]], options=convert_options(args, grid),
            collection=bpy.context.scene.collection, known=known)
    except importer.VDBImportError as err:
        raise InputError(f"{args.file}: {err}") from err
    seconds_import = time.perf_counter() - t0
    vol = objs[0].gaussvdb.source_volume
    # scene frame N shows file N; frames past the last file hold it (the warning says so)
    vol.frame_start, vol.frame_offset = inside[0], inside[0] - 1
    vol.frame_duration = max(frames[-1], inside[-1]) - inside[0] + 1
    vol.sequence_mode = "CLIP"
    scene = build_scene(bpy, objs, args, box=sequence_box)
    # The engine keeps converted frames for playback, up to the scene's memory budget (2 GB by
    # default). A render draws each frame once, in order: with no budget only the frame being
    # drawn stays (a frame held past the last file is that same entry), so a process rendering
    # many frames (a cluster worker) holds one frame's Gaussians, not every frame it has drawn.
    # A frame cache of an earlier run in this process is dropped with it.
    scene.gaussvdb.sequence_memory = 0.0
    addon_module("gaussvdb_addon.engine.sequence_frames").CACHE.clear()
    return {"pattern": pat, "frames": frames, "grid": grid, "scene": scene,
            "image_file": image_file, "seconds_import": seconds_import}


def render_frame(prepared, frame, out):
    """Scene frame ``frame`` of a prepared sequence drawn to ``out``: (per-frame figures, the
    render's stats: its warnings, errors and value_range)."""
    scene = prepared["scene"]
    scene.frame_set(frame)
    t1 = time.perf_counter()
    stats = quiet_render(prepared["image_file"], scene, out)
    item = {"frame": frame, "out": out, "seconds": time.perf_counter() - t1,
            "seconds_sync": stats["seconds_sync"], "seconds_render": stats["seconds_render"],
            "gaussians": stats["gaussians"]}
    return item, stats


def render(args) -> dict:
    prepared = prepare(args)
    pat, frames, scene = prepared["pattern"], prepared["frames"], prepared["scene"]
    per_frame, warnings, errors = [], [], []
    t_all = time.perf_counter()
    for f in frames:
        out = os.path.abspath(out_path(args.out, f))
        os.makedirs(os.path.dirname(out), exist_ok=True)
        item, stats = render_frame(prepared, f, out)
        for msg in stats.get("warnings", ()):
            if msg not in warnings:
                warnings.append(msg)
                print(f"gaussvdb render: warning: {msg}", file=sys.stderr)
        for msg in stats.get("errors", ()):
            errors.append(msg)
            item["error"] = msg
            print(f"gaussvdb render: error: {cli_errors.one_line(msg)}", file=sys.stderr)
        per_frame.append(item)
    total = time.perf_counter() - t_all
    return {"pattern": pat.path(0).replace(pat.name(0), pat.text), "grid": prepared["grid"],
            "lod": args.lod, "mode": scene.gaussvdb.mode.lower(), "width": args.width,
            "height": args.height, "colormap": args.colormap,
            "seconds_import": prepared["seconds_import"], "seconds_total": total,
            "seconds_per_frame": total / len(frames), "frames": per_frame,
            "value_range": stats.get("value_range"), "warnings": warnings, "errors": errors,
            "sequence": True}
