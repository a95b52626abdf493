"""The Blender side shared by `./gaussvdb render` of one file (cmd_render.py) and of a sequence
(render_sequence.py): the import's ConvertOptions from the command line, the camera framing
the grid and the engine settings, and the render to a file with its figures returned.

The command line frames a box that no LOD changes (a file: its grid's active voxels; a sequence:
every frame's leaves), and its default density is relative to that box, so every LOD of a file
renders the same view.
"""
from __future__ import annotations

import contextlib
import io
import math
import os
import sys

import cli_errors
from cli_errors import UsageError


def convert_options(args, grid):
    """The ConvertOptions of the command line's import of ``grid`` (no field error: a render
    does not show it)."""
    from kernels import lod_names
    from kernels.convert_options import ConvertOptions

    tolerance = getattr(args, "tolerance", None)
    return ConvertOptions(grids=(grid,), lods=(args.lod,), weights=args.weights,
                          vector_magnitude=args.vector_magnitude, compute_error=False,
                          color_grid=getattr(args, "color_grid", None),
                          tolerance=lod_names.DEFAULT_TOLERANCE if tolerance is None else tolerance)


def beyond_plain_fog(args) -> bool:
    """Whether the options ask more of a reference frame than one fog volume in Emission with a
    linear transfer function (a log scale, lit shading, a colour grid: the general voxel
    sampler, blender_session.compile_ahead). A level-set file is known only once read."""
    return bool(getattr(args, "log_scale", False) or getattr(args, "shading", "") == "lit"
                or getattr(args, "color_grid", None))


def world_box(obj):
    import numpy as np

    corners = np.array([list(c) for c in obj.bound_box], np.float64)
    mw = np.array(obj.matrix_world, np.float64)
    wc = np.c_[corners, np.ones(8)] @ mw.T
    return wc[:, :3].min(0), wc[:, :3].max(0)


def voxel_box(path, grid):
    """Index-space box (voxel corners) of ``grid``'s active voxels in ``path``, from the topology:
    what the camera frames, whatever LOD is drawn (a LOD's Gaussians span another box)."""
    import numpy as np
    from blender_session import kernels_module

    g = next(g for g in kernels_module("vdb").read_topology(path, [grid]).grids if g.name == grid)
    return np.asarray(g.bbox_min, np.float64) - 0.5, np.asarray(g.bbox_max, np.float64) + 0.5


def index_box_world(obj, lo, hi):
    """World box of the index-space box lo..hi of ``obj`` (its matrix_world is the grid's
    index-to-world transform)."""
    import numpy as np

    corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    wc = corners @ np.array(obj.matrix_world, np.float64).T
    return wc[:, :3].min(0), wc[:, :3].max(0)


def build_scene(bpy, objs, args, box=None):
    """Camera framing the objects' world box (``box(obj)``, default their bounds), engine
    settings; returns the scene. Given a ``box``, the default density (10, per object size) is
    made per world unit over that box's diagonal: the engine's object size is the drawn LOD's box,
    which would give each LOD another opacity."""
    import mathutils
    import numpy as np

    from kernels.render import Camera

    scene = bpy.context.scene
    boxes = [(box or world_box)(o) for o in objs]
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    cam = Camera.frame_box(lo, hi, args.width, args.height, direction=args.view, up=args.up)
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
    s.device = getattr(args, "device", "cpu").upper()
    s.mode = args.mode.upper()
    s.colormap = args.colormap
    s.show_legend = bool(args.legend)
    s.log_scale = bool(args.log_scale)
    if args.threads:
        r.threads_mode, r.threads = "FIXED", args.threads
    if getattr(args, "value_range", None):  # --range: the same colours for every file and frame
        s.auto_range = False
        s.value_min, s.value_max = args.value_range
    if args.density is not None:
        s.density_unit, s.density = "WORLD", args.density
    elif box is not None:  # about 10 optical-depth units across the framed box, for every LOD
        s.density_unit, s.density = "WORLD", s.density / float(np.linalg.norm(hi - lo))
    # else the default: density 10 per object size, about 10 optical-depth units across the box
    if args.shadows:  # the headlight casts no shadows: a strength-1 sun, mostly from above
        sun = bpy.data.objects.new("GaussVDB Sun", bpy.data.lights.new("GaussVDB Sun", "SUN"))
        sun.data.energy = 1.0
        sun.rotation_euler = (0.5, -0.4, 0.0)  # its light travels along its local -Z
        scene.collection.objects.link(sun)
    clips = clip_collection(bpy, scene, args)
    from blender_session import addon_module

    schema = addon_module("gaussvdb_addon.io.schema")
    for o in objs:
        if args.lod in schema.lod_names(o):  # (a grid imported alone, for reference mode, holds none)
            o.gaussvdb.render_lod = args.lod
            o.gaussvdb.viewport_lod = args.lod
        o.gaussvdb.clip_collection = clips
        o.gaussvdb.level_set_style = args.level_set.upper()
        o.gaussvdb.shading = args.shading.upper()
        o.gaussvdb.shadows = bool(args.shadows)
        o.gaussvdb.color_colormap = getattr(args, "color_map", None) or "inferno"
    return scene


def clip_collection(bpy, scene, args):
    """The --clip-plane/--clip-box cuts as Empties in one collection (a plane: an Empty whose +Z
    is the normal; a box: a Cube Empty scaled to the half extents), or None."""
    import mathutils

    planes, boxes = args.clip_plane, args.clip_box
    if not (planes or boxes):
        return None
    coll = bpy.data.collections.new("GaussVDB Clip")
    scene.collection.children.link(coll)
    for k, (p, n) in enumerate(planes):
        e = bpy.data.objects.new(f"Clip Plane {k + 1}", None)
        e.empty_display_type = "SINGLE_ARROW"
        rot = mathutils.Vector(n).normalized().to_track_quat("Z", "Y")
        e.matrix_world = mathutils.Matrix.LocRotScale(mathutils.Vector(p), rot, None)
        coll.objects.link(e)
    for k, (lo, hi) in enumerate(boxes):
        e = bpy.data.objects.new(f"Clip Box {k + 1}", None)
        e.empty_display_type = "CUBE"
        e.location = [0.5 * (a + b) for a, b in zip(lo, hi)]
        e.scale = [0.5 * (b - a) for a, b in zip(lo, hi)]
        coll.objects.link(e)
    return coll


@contextlib.contextmanager
def stdout_to_stderr():
    """Everything written to stdout inside goes to stderr, Blender's C code (its "Saved: '...'"
    line) included: file descriptor 1 itself is pointed at 2, then restored, so that --json
    leaves stdout to one JSON document."""
    import ctypes

    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    libc.fflush(None)
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        sys.stdout.flush()
        libc.fflush(None)  # C stdio buffers a pipe: what Blender printed leaves before fd 1 returns
        os.dup2(saved, 1)
        os.close(saved)


def check_format(image_file, out):
    """--out against the image types the engine writes (image_file.FORMATS: one list)."""
    ext = os.path.splitext(out)[1].lower()
    if ext not in image_file.FORMATS:
        raise UsageError(f"--out {out}: cannot write {ext or 'a file without extension'} images; "
                         f"use {', '.join(sorted(image_file.FORMATS))}", "gaussvdb render")


def quiet_render(image_file, scene, out) -> dict:
    """Render to ``out``. The engine prints the traceback of a failed render (for the Blender
    console); here the failure is one line, so that print is kept back unless --debug."""
    buf = io.StringIO()
    try:
        with contextlib.redirect_stderr(buf):
            return image_file.render_scene_to_file(scene, out)
    except RuntimeError as err:
        raise RuntimeError(f"render of {out} failed: {cli_errors.one_line(err)}") from err
    finally:
        if cli_errors.debug_enabled() or "Traceback" not in buf.getvalue():
            sys.stderr.write(buf.getvalue())  # warnings and notes pass through
