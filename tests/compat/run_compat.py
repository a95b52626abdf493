"""The compatibility suite: the built extension zip, as a user installs it, in another Blender
release (the oldest supported one, from `./gaussvdb compat`). Plain Python in that release's bpy
module: it never imports the working tree, only the installed extension.

    python tests/compat/run_compat.py ZIP [--user DIR]

A fresh user folder (or ``--user DIR``: kept, so a second run finds the compiled kernels there)
gets the zip installed; then a fog grid and a level set are imported at Low and Medium, F12
renders every mode on the CPU and the GPU device, a sequence frame renders, the .blend is saved
and reloaded, and a bad file's import leaves nothing behind. One line per check (PASS/FAIL and
seconds); the last line names the release and the count. Exit status 1 when a check failed.
"""
import argparse
import importlib
import math
import os
import shutil
import sys
import tempfile
import time
import traceback

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")
MODULE = "bl_ext.user_default.gaussvdb"
W, H = 64, 48
MIN_GPU_DB = 40.0  # GPU vs CPU image (llvmpipe gives >= 50 dB; a wrong image is < 20 dB)


def user_folder(path):
    """Blender's user folders under ``path`` (before bpy is imported); an earlier install of the
    extension there is removed, its compiled kernels (``extensions/.user``) kept."""
    os.makedirs(path, exist_ok=True)
    shutil.rmtree(os.path.join(path, "extensions", "user_default", "gaussvdb"), ignore_errors=True)
    for name in ("CONFIG", "SCRIPTS", "EXTENSIONS"):
        os.environ[f"BLENDER_USER_{name}"] = os.path.join(path, name.lower())


class Suite:
    def __init__(self):
        self.results = []  # (name, ok, seconds, note)

    def check(self, name, fn, *args):
        t0 = time.perf_counter()
        try:
            note = fn(*args) or ""
            ok = True
        except Exception as err:  # noqa: BLE001  (every failure is a result line)
            traceback.print_exc()
            note, ok = f"{type(err).__name__}: {err}".splitlines()[0][:200], False
        dt = time.perf_counter() - t0
        self.results.append((name, ok, dt, note))
        print(f"  {'PASS' if ok else 'FAIL'}  {name:<44} {dt:7.1f} s  {note}", flush=True)
        return ok


# -- data -------------------------------------------------------------------------------------
def openvdb():
    import bpy

    if hasattr(bpy.utils, "expose_bundled_modules"):
        bpy.utils.expose_bundled_modules()
    import openvdb as ov

    return ov


def write_grid(path, dense, grid_class="fog volume", background=0.0):
    ov = openvdb()
    g = ov.FloatGrid()
    g.background = float(background)
    g.copyFromArray(np.ascontiguousarray(dense, np.float32), ijk=(0, 0, 0))
    g.name = "density" if grid_class == "fog volume" else "surface"
    g.gridClass = ov.GridClass.FOG_VOLUME if grid_class == "fog volume" else ov.GridClass.LEVEL_SET
    g.transform = ov.createLinearTransform(voxelSize=1.0)
    ov.write(str(path), grids=[g])
    return str(path)


def level_set_file(folder):
    g = np.arange(40)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    phi = np.sqrt((X - 19.8) ** 2 + (Y - 19.6) ** 2 + (Z - 19.7) ** 2) - 12.0
    return write_grid(os.path.join(folder, "sphere_ls.vdb"), np.clip(phi, -3, 3), "level set", 3.0)


def blob(center):
    g = np.arange(24)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    v = np.exp(-((X - center[0]) ** 2 + (Y - center[1]) ** 2 + (Z - center[2]) ** 2) / 30.0)
    return np.where(v > 0.03, v, 0.0)


# -- the checks -------------------------------------------------------------------------------
def install(zip_path, user):
    import bpy

    r = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                 enable_on_install=True)
    assert r == {"FINISHED"}, r
    mod = sys.modules.get(MODULE)
    assert mod is not None, "installed but not enabled"
    assert os.path.realpath(mod.__file__).startswith(os.path.realpath(user)), mod.__file__
    import numba

    return f"numba {numba.__version__} from the zip's wheels"


def gaussvdb_objects():
    import bpy

    return [o for o in bpy.data.objects if o.type == "POINTCLOUD"]


def import_file(path, lod):
    import bpy

    before = set(gaussvdb_objects())
    r = bpy.ops.gaussvdb.import_vdb(filepath=path, lods={lod}, measure_error=False)
    assert r == {"FINISHED"}, r
    new = [o for o in gaussvdb_objects() if o not in before]
    assert len(new) == 1, f"{len(new)} objects"
    n = len(new[0].evaluated_get(bpy.context.evaluated_depsgraph_get()).data.points)
    assert n > 0, "no Gaussians"
    new[0].name = f"{os.path.splitext(os.path.basename(path))[0]}_{lod}"
    return new[0], n


def import_at(path, lods, out):
    notes = []
    for lod in lods:
        obj, n = import_file(path, lod)
        out[lod] = (obj, n)
        notes.append(f"{lod.title()} {n:,}")
    assert out[lods[0]][1] < out[lods[-1]][1], "Medium should hold more Gaussians than Low"
    return ", ".join(notes) + " Gaussians"


def frame_camera(objs):
    import bpy
    from mathutils import Vector

    pts = [o.matrix_world @ Vector(c) for o in objs for c in o.bound_box]
    lo = [min(p[i] for p in pts) for i in range(3)]
    hi = [max(p[i] for p in pts) for i in range(3)]
    mid = [(a + b) / 2 for a, b in zip(lo, hi)]
    scene = bpy.context.scene
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 1.3 * max(hi[0] - lo[0], hi[2] - lo[2])
    cam.data.clip_end = 10 * (hi[1] - lo[1]) + 100
    cam.location = (mid[0], lo[1] - 2 * (hi[1] - lo[1]) - 10, mid[2])
    cam.rotation_euler = (math.pi / 2, 0.0, 0.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.resolution_x, scene.render.resolution_y = W, H
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True


def read_image(path):
    import bpy

    img = bpy.data.images.load(path, check_existing=False)
    px = np.empty(len(img.pixels), np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(H, W, 4)


def f12(folder, name, mode, device):
    import bpy

    image_file = importlib.import_module(MODULE + ".gaussvdb_addon.engine.image_file")
    scene = bpy.context.scene
    scene.gaussvdb.mode = mode
    scene.gaussvdb.device = device
    path = os.path.join(folder, f"{name}_{mode.lower()}_{device.lower()}.exr")
    stats = image_file.render_scene_to_file(scene, path)
    img = read_image(path)
    assert img[..., 3].max() > 0.05, "an empty image"
    return img, stats


def psnr(a, b):
    mse = float(np.mean((np.clip(a, 0, 1) - np.clip(b, 0, 1)) ** 2))
    return 99.0 if mse == 0 else 10 * math.log10(1.0 / mse)


def render_mode(folder, mode, images):
    img, stats = f12(folder, "scene", mode, "CPU")
    assert stats["device"] == "CPU", stats["device"]
    images[mode] = img
    return f"{stats['gaussians']:,} Gaussians, {stats['seconds_render']:.2f} s render"


def render_mode_gpu(folder, mode, images, gpu_name):
    img, stats = f12(folder, "scene", mode, "GPU")
    assert stats["device"] == "GPU" and stats["gpu"], f"drawn by {stats['device']}"
    db = psnr(img, images[mode])
    assert db >= MIN_GPU_DB, f"GPU vs CPU {db:.1f} dB < {MIN_GPU_DB} dB"
    cpu_part = f", {stats['fallback']} on the CPU" if stats.get("fallback") else ""
    gpu_name[0] = stats["gpu"]
    return f"{db:.1f} dB vs CPU{cpu_part}, {stats['seconds_render']:.2f} s render"


def sequence_frame(folder):
    import bpy

    seq = os.path.join(folder, "seq")
    os.makedirs(seq, exist_ok=True)
    for frame, c in ((1, (8, 12, 11)), (2, (16, 12, 11))):
        write_grid(os.path.join(seq, f"blob_{frame:04d}.vdb"), blob(c))
    scene = bpy.context.scene
    shown = [o for o in gaussvdb_objects() if not o.hide_render]
    for o in shown:
        o.hide_render = True
    try:
        before = set(gaussvdb_objects())
        r = bpy.ops.gaussvdb.import_vdb(filepath=os.path.join(seq, "blob_0001.vdb"), lods={"low"},
                                        measure_error=False, use_sequence=True)
        assert r == {"FINISHED"}, r
        new = [o for o in gaussvdb_objects() if o not in before]
        assert len(new) == 1, f"{len(new)} objects for a 2-frame sequence"
        cam, scene.camera = scene.camera, None
        frame_camera(new)
        imgs = []
        for frame in (1, 2):
            scene.frame_set(frame)
            img, stats = f12(folder, f"seq{frame}", "REFERENCE", "CPU")
            assert stats["frame"] == frame
            imgs.append(img)
        # the blob moves along x: the image's centre of mass moves right
        xs = [float((img[..., 3].sum(0) * np.arange(W)).sum() / img[..., 3].sum()) for img in imgs]
        assert xs[1] > xs[0] + 2, f"frame 2 not shown (centres {xs[0]:.1f}, {xs[1]:.1f} px)"
        bpy.data.objects.remove(new[0])
        bpy.data.objects.remove(scene.camera)
        scene.camera = cam
        scene.frame_set(1)
        return f"centre of mass moved {xs[1] - xs[0]:.1f} px"
    finally:
        for o in shown:
            o.hide_render = False


def save_and_reload(folder, images):
    import bpy

    path = os.path.join(folder, "saved.blend")
    names = sorted((o.name, len(o.data.points)) for o in gaussvdb_objects())
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    assert not gaussvdb_objects()
    bpy.ops.wm.open_mainfile(filepath=path)
    got = sorted((o.name, len(o.data.points)) for o in gaussvdb_objects())
    assert got == names, f"{got} != {names}"
    img, _ = f12(folder, "reloaded", "REFERENCE", "CPU")
    diff = float(np.abs(img - images["REFERENCE"]).max())
    assert diff == 0.0, f"the reloaded scene renders differently (max {diff:.3g})"
    return f"{len(got)} objects, the same image"


def rollback(folder):
    """Two files in one import, the second cut short: all are read before any object is made, so
    the good file leaves nothing behind either."""
    import bpy

    with open(SAMPLE, "rb") as f:
        data = f.read()
    for name, size in (("good.vdb", len(data)), ("truncated.vdb", len(data) // 2)):
        with open(os.path.join(folder, name), "wb") as f:
            f.write(data[:size])
    counts = lambda: (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.pointclouds),  # noqa: E731
                      len(bpy.data.collections), len(bpy.data.materials))
    before = counts()
    try:
        bpy.ops.gaussvdb.import_vdb(filepath=os.path.join(folder, "good.vdb"), directory=folder,
                                    files=[{"name": "good.vdb"}, {"name": "truncated.vdb"}],
                                    lods={"low"}, measure_error=False, use_sequence=False)
    except RuntimeError as err:
        msg = str(err).strip().splitlines()[-1]
    else:
        raise AssertionError("a truncated file imported without an error")
    assert "truncated.vdb" in msg, msg
    assert counts() == before, f"{counts()} != {before}"
    return "nothing left behind: " + msg[:80]


def compile_now():
    """Compile Now in background mode (a farm node's set-up) runs its jobs on worker processes of
    this Python, which find numba in the installed extension's wheels (the module path handed on):
    two jobs left to do, both compiled, their markers left."""
    import bpy
    from bl_ext.user_default.gaussvdb.kernels import warmup

    todo = ["lod:low", "lod:merged"]
    for name in warmup.NAMES:
        if name not in todo:
            warmup.mark_done(name)
    assert warmup.missing() == todo, warmup.missing()
    assert "FINISHED" in bpy.ops.gaussvdb.compile_kernels()
    assert warmup.missing() == [], warmup.missing()
    status = warmup.read_status(warmup.status_path())
    assert sorted(status.get("seconds", {})) == todo, status
    return f"{len(todo)} jobs on {warmup.default_processes()} worker processes"


# -- main -------------------------------------------------------------------------------------
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("zip")
    ap.add_argument("--user", help="user folder to install into and keep (default: a fresh one)")
    args = ap.parse_args(argv)
    zip_path = os.path.abspath(args.zip)
    tmp = tempfile.mkdtemp(prefix="gaussvdb-compat-")
    user = os.path.abspath(args.user) if args.user else os.path.join(tmp, "user")
    user_folder(user)
    t0 = time.perf_counter()
    import bpy

    t_bpy = time.perf_counter() - t0
    release = f"Blender {bpy.app.version_string}"
    print(f"GaussVDB compatibility suite: {release} (bpy module, Python "
          f"{'.'.join(map(str, sys.version_info[:3]))}, numpy {np.__version__}; import bpy "
          f"{t_bpy:.1f} s)\nzip: {os.path.basename(zip_path)}; user folder: "
          f"{'kept' if args.user else 'fresh'}", flush=True)
    suite = Suite()
    data = os.path.join(tmp, "data")
    os.makedirs(data)
    try:
        bpy.ops.wm.read_homefile(use_empty=True)
        if not suite.check("install and enable the built zip", install, zip_path, user):
            return report(suite, release)
        fog, ls, images, gpu_name = {}, {}, {}, [None]
        suite.check("import a fog grid at Low, Medium", import_at, SAMPLE, ("low", "medium"), fog)
        suite.check("import a level set at Low, Medium", import_at, level_set_file(data),
                    ("low", "medium"), ls)
        for lod_objs in (fog, ls):
            if "low" in lod_objs:
                lod_objs["low"][0].hide_render = True
        shown = [o for o in gaussvdb_objects() if not o.hide_render]
        if shown:
            frame_camera(shown)
        from bl_ext.user_default.gaussvdb.kernels import mode_names

        modes = [m.upper() for m in mode_names.NAMES]
        for mode in modes:
            suite.check(f"F12 {mode.lower()} on the CPU", render_mode, tmp, mode, images)
        from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu import probe

        ok, why = probe.probe()
        if not ok:
            suite.check("a GPU context for the GPU device", lambda: (_ for _ in ()).throw(
                RuntimeError(why)))
        else:
            for mode in modes:
                if mode in images:
                    suite.check(f"F12 {mode.lower()} on the GPU device", render_mode_gpu, tmp, mode,
                                images, gpu_name)
        bpy.context.scene.gaussvdb.device = "CPU"
        suite.check("a sequence frame", sequence_frame, data)
        if "REFERENCE" in images:
            suite.check("save and reload the .blend", save_and_reload, tmp, images)
        suite.check("a bad file's import rolls back", rollback, data)
        suite.check("Compile Now on worker processes", compile_now)
        if gpu_name[0]:
            print(f"GPU device ran on: {gpu_name[0]}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return report(suite, release)


def report(suite, release):
    failed = [r for r in suite.results if not r[1]]
    total = sum(r[2] for r in suite.results)
    print(f"{release}: {len(suite.results) - len(failed)} passed, {len(failed)} failed "
          f"({total:.0f} s){''.join(f'; FAILED {r[0]}' for r in failed)}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # Blender 4.5's bpy module can hang at interpreter exit
