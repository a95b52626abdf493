"""Cycles (CPU) renders of a .vdb grid matched to the GAUSSVDB emission-absorption model.

Run as a subprocess (it imports bpy, which must not share a process with a bpy session already
set up differently):

    python benchmarks/cycles_ref.py JOB.json

JOB.json: {"vdb", "grid", "width", "height", "cam_to_world" (4x4 rows), "fov_x", "clip": [start, end],
"vmin", "vmax", "density", "positions" (K), "colors" (K x 4, linear RGBA), "samples": [n, ...],
"out_dir", "volume_biased" (bool, default false), "threads" (0: all)}.
Writes OUT_DIR/cycles_<n>.npy (float32 (H, W, 4), linear, premultiplied, row 0 = bottom, like the
GAUSSVDB 'Combined' pass) per sample count and OUT_DIR/cycles.json with the seconds per render.

How the models are matched (see docs/choosing_lod.md):
- GAUSSVDB: extinction sigma(x) = density * alpha(v(x)) per world unit, emission = c(v(x)) * sigma(x),
  no scattering; L = integral T(t) c sigma dt over the ray, premultiplied alpha 1 - T.
- Cycles: the Volume output gets Emission(Color = c, Strength = density * alpha) + Volume Absorption
  (Color black, Density = density * alpha). Cycles' absorption coefficient is (1 - Color) * Density
  and a volume Emission closure emits Color * Strength per unit length, so both coefficients equal
  ours. v(x) comes from an Attribute node reading the grid, Map Range (vmin..vmax -> 0..1, clamped),
  ColorRamp (linear interpolation, the same stops our TransferFunction is built from).
- Same camera: the object matrix of our Camera, lens = 18 mm / tan(fov/2) on a 36 mm AUTO sensor.
- Same sampling of the data: the volume is loaded at full float precision, no value clipping,
  trilinear (material volume_interpolation LINEAR), object transform identity (the .vdb's own
  index-to-world transform places it, as in our world).
- Same pixel footprint: our renderer samples pixel centres, so Cycles gets a 0.01 px box filter.
- Film transparent, no world, no lights, volume bounces 0, no denoising, no adaptive sampling, fixed
  seed; the EXR is scene-linear RGBA (premultiplied), read back from the written file.
"""
from __future__ import annotations

import json
import math
import os
import sys
import tempfile
import time


def _isolate():
    base = os.path.join(tempfile.gettempdir(), f"gaussvdb-cycles-{os.getuid() if hasattr(os, 'getuid') else 0}")
    for k in ("CONFIG", "SCRIPTS", "EXTENSIONS"):
        os.environ.setdefault(f"BLENDER_USER_{k}", os.path.join(base, k.lower()))


def build_scene(bpy, job):
    import mathutils

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    vol = bpy.data.volumes.new("vdb")
    vol.filepath = os.path.abspath(job["vdb"])
    vol.grids.load()
    vol.render.precision = "FULL"
    vol.render.clipping = 0.0
    vol.render.space = "OBJECT"
    vol.render.step_size = 0.0  # automatic: from the voxel size
    ob = bpy.data.objects.new("vdb", vol)
    scene.collection.objects.link(ob)

    mat = bpy.data.materials.new("gaussvdb_match")
    mat.use_nodes = True
    mat.cycles.volume_interpolation = "LINEAR"
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    out.target = "CYCLES"
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = job["grid"]
    mr = nt.nodes.new("ShaderNodeMapRange")
    mr.data_type = "FLOAT"
    mr.interpolation_type = "LINEAR"
    mr.clamp = True
    mr.inputs["From Min"].default_value = float(job["vmin"])
    mr.inputs["From Max"].default_value = float(job["vmax"])
    mr.inputs["To Min"].default_value = 0.0
    mr.inputs["To Max"].default_value = 1.0
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    cr = ramp.color_ramp
    cr.color_mode = "RGB"
    cr.interpolation = "LINEAR"
    pos, cols = job["positions"], job["colors"]
    els = cr.elements
    while len(els) > 1:
        els.remove(els[-1])
    els[0].position = float(pos[0])
    els[0].color = [float(c) for c in cols[0]]
    for p, c in zip(pos[1:], cols[1:]):
        e = els.new(float(p))
        e.color = [float(x) for x in c]
    mul = nt.nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    mul.inputs[1].default_value = float(job["density"])
    emit = nt.nodes.new("ShaderNodeEmission")
    absn = nt.nodes.new("ShaderNodeVolumeAbsorption")
    absn.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    add = nt.nodes.new("ShaderNodeAddShader")
    L = nt.links
    L.new(attr.outputs["Factor"], mr.inputs["Value"])
    L.new(mr.outputs["Result"], ramp.inputs["Factor"])
    L.new(ramp.outputs["Alpha"], mul.inputs[0])
    L.new(ramp.outputs["Color"], emit.inputs["Color"])
    L.new(mul.outputs["Value"], emit.inputs["Strength"])
    L.new(mul.outputs["Value"], absn.inputs["Density"])
    L.new(emit.outputs["Emission"], add.inputs[0])
    L.new(absn.outputs["Volume"], add.inputs[1])
    L.new(add.outputs["Shader"], out.inputs["Volume"])
    vol.materials.append(mat)

    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = "PERSP"
    cam_data.sensor_fit = "AUTO"
    cam_data.sensor_width = 36.0
    cam_data.lens = 18.0 / math.tan(0.5 * float(job["fov_x"]))
    cam_data.clip_start, cam_data.clip_end = (float(x) for x in job["clip"])
    cam = bpy.data.objects.new("cam", cam_data)
    cam.matrix_world = mathutils.Matrix([list(map(float, r)) for r in job["cam_to_world"]])
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.world = None

    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = int(job["width"]), int(job["height"]), 100
    r.film_transparent = True
    r.use_persistent_data = True  # sync (volume load, octree) once; timed renders are warm
    if job.get("threads"):
        r.threads_mode, r.threads = "FIXED", int(job["threads"])
    c = scene.cycles
    c.device = "CPU"
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.pixel_filter_type = "BOX"
    c.filter_width = 0.01
    c.seed = 0
    c.volume_bounces = 0
    c.max_bounces = 0
    c.transparent_max_bounces = 8
    c.volume_biased = bool(job.get("volume_biased", False))
    c.volume_step_rate = float(job.get("volume_step_rate", 1.0))
    c.volume_max_steps = int(job.get("volume_max_steps", 4096))
    vs = scene.view_settings
    vs.view_transform, vs.look, vs.exposure, vs.gamma = "Standard", "None", 0.0, 1.0
    im = r.image_settings
    im.file_format = "OPEN_EXR"
    im.color_depth = "32"
    im.color_mode = "RGBA"
    im.exr_codec = "NONE"
    return scene


def render_all(job) -> dict:
    _isolate()
    import bpy
    import numpy as np

    scene = build_scene(bpy, job)
    os.makedirs(job["out_dir"], exist_ok=True)
    w, h = int(job["width"]), int(job["height"])
    rows = []
    # warm-up at a tiny size: the scene sync (volume load, NanoVDB, octree); kept (persistent data)
    scene.render.resolution_percentage = 10
    scene.cycles.samples = 1
    scene.render.filepath = os.path.join(job["out_dir"], "warmup.exr")
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    warm = time.perf_counter() - t0
    scene.render.resolution_percentage = 100
    for n in job["samples"]:
        scene.cycles.samples = int(n)
        path = os.path.join(job["out_dir"], f"cycles_{int(n)}.exr")
        scene.render.filepath = path
        t0 = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        dt = time.perf_counter() - t0
        rows.append({"samples": int(n), "seconds_render": dt})
        print(json.dumps(rows[-1]), flush=True)
    # read back only after all renders: loading an image into bpy.data tags the depsgraph, and the
    # next render would then re-sync the whole scene (about 13 s here) instead of reusing it
    for n in job["samples"]:
        path = os.path.join(job["out_dir"], f"cycles_{int(n)}.exr")
        img = bpy.data.images.load(path, check_existing=False)
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
        bpy.data.images.remove(img)
        os.remove(path)
        np.save(os.path.join(job["out_dir"], f"cycles_{int(n)}.npy"), px.reshape(h, w, 4))
    info = {"rows": rows, "seconds_warmup": warm, "volume_biased": bool(scene.cycles.volume_biased),
                "blender": bpy.app.version_string, "threads": scene.render.threads}
    with open(os.path.join(job["out_dir"], "cycles.json"), "w") as f:
        json.dump(info, f, indent=1)
    return info


def main(argv):
    with open(argv[0]) as f:
        job = json.load(f)
    render_all(job)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
