"""The child processes of bench_cold_start.py: one measurement each, in a fresh process on the
cache folder the parent chose (GAUSSVDB_CACHE_DIR). Run as

    python benchmarks/cold_start_child.py KIND ARGS... --result FILE.json

KIND: kernels-import LOD | kernels-frame MODE WxH | blender-import LOD | blender-f12 MODE WxH PNG |
compat-import LOD ZIP | compat-f12 MODE WxH PNG ZIP | cli ARGV... | speed MODES WxH REPEAT. The
figures (steps, compile seconds, functions) go to FILE.
"""
from __future__ import annotations

import json
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for _p in (ROOT, os.path.join(ROOT, "tools")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import cli_errors  # noqa: E402  (after the sys.path set-up above)

SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")


# -- the child processes ------------------------------------------------------------------------

class CompileCounter:
    """numba's "numba:compile" events: seconds with nested compiles counted once, and every
    function compiled (nested ones too)."""

    def __init__(self):
        from numba.core import event

        self.depth, self.seconds, self.functions, self._t = 0, 0.0, 0, 0.0
        listener = self

        class _L(event.Listener):
            def on_start(self, ev):
                listener.functions += 1
                if listener.depth == 0:
                    listener._t = time.perf_counter()
                listener.depth += 1

            def on_end(self, ev):
                listener.depth -= 1
                if listener.depth == 0:
                    listener.seconds += time.perf_counter() - listener._t

        event.register("numba:compile", _L())

    def snap(self):
        return self.seconds, self.functions


class Phases:
    """Timed steps of one child: name -> seconds, compile seconds, functions compiled."""

    def __init__(self):
        self.counter = CompileCounter()
        self.steps = {}

    def run(self, name, fn):
        c0, f0 = self.counter.snap()
        t0 = time.perf_counter()
        out = fn()
        c1, f1 = self.counter.snap()
        self.steps[name] = dict(seconds=time.perf_counter() - t0, compile_seconds=c1 - c0,
                                functions=f1 - f0)
        return out


def _load(lod):
    from kernels.lod import build_lod
    from kernels.vdb import read_vdb

    grids = list(read_vdb(SAMPLE).grids)
    g = next((x for x in grids if x.grid_class in ("fog_volume", "level_set")), grids[0])
    return g, build_lod(g, lod)


def child_kernels_import(ph, lod):
    ph.run("python import", lambda: __import__("kernels.lod") and __import__("kernels.vdb"))
    ph.run("import", lambda: _load(lod))


def child_kernels_frame(ph, mode, size):
    g, gs = ph.run("load", lambda: _load("medium"))

    def frame():
        sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
        from bench_render import frame_setup

        from kernels.render import CPUDevice

        sc, cam, tf = frame_setup(g, gs, size, mode)
        return CPUDevice().render(sc, cam, tf)

    ph.run("frame", frame)


def _blender(ph):
    from blender_session import start

    bpy = ph.run("start blender", start)
    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy


def _operator_import(bpy, lod):
    res = bpy.ops.gaussvdb.import_vdb(filepath=SAMPLE, lods={lod})
    if "FINISHED" not in res:
        raise RuntimeError(f"import operator: {res}")
    return [o for o in bpy.context.scene.objects if o.type == "POINTCLOUD"]


def _installed(zip_path):
    """Blender with the zip installed into a user folder beside the cache (a fresh one on a
    fresh cache; installed again, its kernels kept, on the warm run), as run_compat does; then
    the step counter, whose numba comes with the zip."""
    sys.path.insert(0, os.path.join(ROOT, "tests", "compat"))
    import run_compat

    user = os.path.join(os.environ["GAUSSVDB_CACHE_DIR"], "user")
    run_compat.user_folder(user)
    import bpy

    run_compat.install(zip_path, user)
    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy, Phases()


def child_blender_import(ph, lod, bpy=None):
    bpy = bpy or _blender(ph)
    ph.run("import", lambda: _operator_import(bpy, lod))


def child_blender_f12(ph, mode, size, out, bpy=None):
    import cmd_render

    bpy = bpy or _blender(ph)
    objs = ph.run("import", lambda: _operator_import(bpy, "medium"))
    opts = cmd_render.options(width=size[0], height=size[1], mode=mode, lod="medium")
    scene = cmd_render.build_scene(bpy, objs, opts)
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = out
    scene.render.use_file_extension = False
    ph.run("f12", lambda: bpy.ops.render.render(write_still=True))
    if not os.path.isfile(out):
        raise RuntimeError("F12 wrote no image")


def child_cli(ph, argv):
    """tools/cli.py ARGV in this process (the whole process is the measure)."""
    import runpy

    def run():
        sys.argv = [os.path.join(ROOT, "tools", "cli.py"), *argv]
        try:
            runpy.run_path(sys.argv[0], run_name="__main__")
        except SystemExit as stop:
            if stop.code not in (0, None):
                raise RuntimeError(f"cli.py {' '.join(argv)}: exit {stop.code}") from None

    ph.run("command", run)


def child_speed(ph, modes, size, repeat):
    """Medium import, then per mode a first frame and the best of ``repeat`` whole frames (ms)."""
    g, gs = ph.run("import", lambda: _load("medium"))
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    from bench_render import frame_setup

    from kernels.render import CPUDevice

    dev = CPUDevice()
    ms = {}
    for mode in modes:
        sc, cam, tf = frame_setup(g, gs, size, mode)
        ph.run(f"first {mode}", lambda sc=sc, cam=cam, tf=tf: dev.render(sc, cam, tf))
        best = float("inf")
        for _ in range(repeat):
            dev.end_frame()  # whole frames: the per-frame set-up included
            t0 = time.perf_counter()
            dev.render(sc, cam, tf)
            best = min(best, time.perf_counter() - t0)
        ms[mode] = 1e3 * best
    t0 = time.perf_counter()
    for _ in range(repeat):  # the import again, kernels loaded: the LOD build's own seconds
        _load("medium")
    ph.steps["import again"] = dict(seconds=(time.perf_counter() - t0) / repeat)
    return ms


def child_main(argv):
    kind, rest, result = argv[0], argv[1:-2], argv[-1]
    if os.environ.get("GAUSSVDB_BENCH_SOURCES"):  # --only stamps: the kernels of a copy
        sys.path.insert(0, os.environ["GAUSSVDB_BENCH_SOURCES"])
    if os.environ.get("GAUSSVDB_BENCH_MTIME_STAMP"):
        mtime_stamps()
    extra = {}
    bpy = None
    if kind.startswith("compat-"):  # the installed zip (its numba is there once installed)
        bpy, ph = _installed(rest[-1])
        kind = "blender-" + kind[len("compat-"):]
    else:
        ph = Phases()
    if kind == "kernels-import":
        child_kernels_import(ph, rest[0])
    elif kind == "kernels-frame":
        child_kernels_frame(ph, rest[0], cli_errors.size(rest[1]))
    elif kind == "blender-import":
        child_blender_import(ph, rest[0], bpy)
    elif kind == "blender-f12":
        child_blender_f12(ph, rest[0], cli_errors.size(rest[1]), rest[2], bpy)
    elif kind == "cli":
        child_cli(ph, rest)
    elif kind == "speed":
        extra["ms_per_frame"] = child_speed(ph, rest[0].split(","), cli_errors.size(rest[1]),
                                            int(rest[2]))
    else:
        raise SystemExit(f"unknown child {kind}")
    with open(result, "w") as fh:
        json.dump(dict(steps=ph.steps, compile_seconds=ph.counter.seconds,
                       functions=ph.counter.functions, **extra), fh)
    sys.stdout.flush()
    sys.stderr.flush()
    # a second process the add-on started (an import's compile_ahead) stops here, as at a normal
    # exit (atexit), not on into the next case's timing
    from blender_session import MODULE

    service = sys.modules.get(f"{MODULE}.gaussvdb_addon.engine.warmup_service")
    if service is not None:
        service.stop()
    os._exit(0)  # the figures are written: skip tearing down Blender and numba


def mtime_stamps():
    """numba < 0.68's source stamp, (mtime, size), for every locator that takes numba's own: what
    numba 0.62.1 (the extension's wheel on Intel macOS) does."""
    from numba.core import caching

    def stamp(self):
        st = os.stat(self._py_file)
        return st.st_mtime, st.st_size

    caching._SourceFileBackedLocatorMixin.get_source_stamp = stamp


if __name__ == "__main__":
    child_main(sys.argv[1:])
