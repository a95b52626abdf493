"""Compiling the kernels ahead of use: an ordered table of warm-up jobs, each compiling (or
loading from numba's cache) one group of kernels by running a tiny real case.

    from kernels import warmup
    warmup.run()                                    # every job; {name: seconds}
    warmup.run(["reader", "lod:medium"], progress=print)
    warmup.jobs_for(lods=("medium",), error=True)   # ['reader', 'lod:medium', 'error']
    warmup.jobs_for(modes=("reference",))           # ['render:reference']
    warmup.missing(["reader"])                      # the jobs whose kernels are not cached yet

A job that finishes leaves a marker beside the kernels' cache (``marker_dir``): its kernels are
in the cache for this importing identity (cachedir.py), these sources (``cachedir.sources_tag``),
this Python, numba and machine. ``missing`` reads only the markers: no numba import, a few file
checks, so the Blender layer can ask it from a panel or before an import.

``main`` is the warm-up as a command (``warmup_boot.py`` starts it under the identity the caller
names); it reports progress to a JSON status file written atomically (``read_status``).
Plain Python, no bpy.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import signal
import sys
import time

from . import cachedir, lod_names, mode_names

FIXTURE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "warmup.vdb")
# A Mantaflow frame (fog grids raw, velocity zip): the reader compiles its decoders per
# compression, blosc (FIXTURE) or not (this file)
CACHE_FIXTURE = os.path.join(os.path.dirname(FIXTURE), "warmup_cache.vdb")


class WarmupCancelled(Exception):
    """The cancel callback said so between two jobs."""


class WarmupError(Exception):
    """A job failed; the message says which and why in one line."""


# -- the jobs --------------------------------------------------------------------------------------
def fixture_arrays() -> dict:
    """What FIXTURE holds, as arrays (tools/gen_warmup_fixture.py writes them with openvdb): a
    fog volume (voxels above ``fog_tolerance`` active, an active ``tile`` box of leaf-sized tiles
    beside them) and a narrow-band level set, in index space with ``voxel_size``."""
    import numpy as np

    x, y, z = np.meshgrid(*(np.arange(24, dtype=np.float32),) * 3, indexing="ij")
    r = np.sqrt((x - 11.5) ** 2 + (y - 11.5) ** 2 + (z - 11.5) ** 2)
    return dict(fog=np.where(r < 10.0, np.exp(-(r / 6.0) ** 2), 0.0).astype(np.float32),
                fog_tolerance=1e-3, tile=((32, 0, 0), (47, 15, 15), 0.25),
                sdf=np.clip((r - 8.0) * 0.1, -0.3, 0.3).astype(np.float32), sdf_background=0.3,
                voxel_size=0.1)


def _made_grids():
    """The fixture's two grids made from ``fixture_arrays`` without reading the file: the LOD
    and field-error jobs then compile no reader (they run beside an import that compiles it)."""
    import numpy as np

    from .lod.synthetic import grid_from_dense
    from .vdb.griddata import GridData

    a = fixture_arrays()
    m = np.diag([a["voxel_size"]] * 3 + [1.0])
    (x0, y0, z0), (x1, y1, z1), value = a["tile"]
    tiles = [((x, y, z), 8, value, True) for x in range(x0, x1 + 1, 8)
             for y in range(y0, y1 + 1, 8) for z in range(z0, z1 + 1, 8)]
    fog = grid_from_dense(a["fog"], a["fog"] > a["fog_tolerance"], tiles=tiles, index_to_world=m)
    ls = grid_from_dense(a["sdf"], grid_class="level_set", background=a["sdf_background"],
                         index_to_world=m, name="surface")
    return [GridData(**vars(g)) for g in (fog, ls)]


def _job_reader():
    """Read the fixtures as an import does: topology, leaves (blosc, zip, raw; half and full
    floats; vectors), NaN/Inf check, value figures."""
    from . import pipeline, vdb
    from .render.scene.transfer import voxel_stats

    pipeline.read_color_grid(FIXTURE, "density")
    grids = [g for path in (FIXTURE, CACHE_FIXTURE) for g in pipeline.read_grids(path)[0]]
    for grid in grids:  # what convert_steps does before the LODs
        vdb.sanitize_nonfinite(grid)
        pipeline.leaf_box(grid)
        if grid.grid_class != "level_set":
            voxel_stats(grid)


def _job_lod(name):
    def job():
        from . import pipeline

        for grid in _made_grids():  # a fog volume and a level set
            pipeline.convert_lod(grid, name, compute_error=False)
    job.__doc__ = f"Build the {lod_names.label(name)} LOD of the fixture's fog volume and level set."
    return job


def _job_error():
    """The field error an import measures when asked (pipeline.measure_error) of a fog volume and
    a level set, for Low's Gaussians (one per leaf: on pair lists) and High's (lattice classes, as
    a real grid's finer LODs have), the sets made by numpy: no LOD kernel compiled here (the
    import beside compiles those itself)."""
    from .lod import field_error
    from .lod.synthetic import full_block_set

    for grid in _made_grids():
        for lod, edge in (("low", 8), ("high", 2)):
            field_error(grid, full_block_set((16, 8, 8), edge, lod))


# the modes whose plain scenes (reference: one fog volume; particles: no lights, no surfaces)
# compile band kernels of their own (cpu.launch.kernel_code): render:<mode> warms those, and
# render:<mode>:general the others
GENERAL = ("reference", "particles")


def _job_render(mode, variant="plain"):
    def job():
        from .render import CPUDevice

        CPUDevice().load_kernels(modes=(mode,), variants=(variant,))
    job.__doc__ = f"The CPU device's kernels of the {mode_names.LABELS[mode]} render mode."
    if variant == "general":
        job.__doc__ += " Those of its scenes beyond the plain ones (lights, surfaces, ...)."
    return job


def _render_jobs(modes) -> dict:
    return {f"render:{m}": _job_render(m) for m in modes}



# ordered: what a first session needs first (an import with the dialog's defaults: reading, the
# default LOD, its field error; an F12 in the default mode), then the other LODs and modes
JOBS = {"reader": _job_reader,
        f"lod:{lod_names.DEFAULT}": _job_lod(lod_names.DEFAULT),
        "error": _job_error,
        **_render_jobs([mode_names.DEFAULT]),
        **{f"lod:{n}": _job_lod(n) for n in lod_names.PRESETS if n != lod_names.DEFAULT},
        **_render_jobs([m for m in mode_names.MENU_ORDER if m != mode_names.DEFAULT]),
        # last: scenes beyond the plain ones (lit volumes, surfaces, several objects)
        **{f"render:{m}:general": _job_render(m, "general") for m in GENERAL}}
NAMES = tuple(JOBS)


def check_names(names) -> list:
    """``names`` (None: every job, in the table's order) as a list, in their order, each once;
    ValueError names an unknown one."""
    if names is None:
        return list(NAMES)
    names = [names] if isinstance(names, str) else list(names)
    bad = [n for n in names if n not in JOBS]
    if bad:
        raise ValueError(f"unknown warm-up job {bad[0]!r}; choose from {', '.join(NAMES)}")
    return list(dict.fromkeys(names))


def jobs_for(lods=(), error=False, modes=(), general=True) -> list:
    """The jobs a need maps to: an import of ``lods`` (with the field error when ``error``), a
    render in each of ``modes`` (``general``: of any scene; else of one plain fog volume, the
    only scene some renders draw). In the order they are needed (the LODs coarse first)."""
    if isinstance(lods, str):
        lods = (lods,)
    if isinstance(modes, str):
        modes = (modes,)
    names = []
    if lods:
        names.append("reader")
        order = {n: i for i, n in enumerate(lod_names.PRESETS)}
        names += [f"lod:{n}" for n in sorted(lods, key=lambda n: order.get(n, len(order)))]
        if error:
            names.append("error")
    for m in modes:
        names += [f"render:{m}"] + ([f"render:{m}:general"] if general and m in GENERAL else [])
    return check_names(names)


def run(names=None, progress=None, cancel=None, on_done=None) -> dict:
    """Run the jobs ``names`` (None: all) in that order. ``progress(index, count, name)``
    before each, WarmupCancelled when ``cancel()`` is true before one, ``on_done(name, seconds)``
    after each. Returns {name: seconds}."""
    todo = check_names(names)
    seconds = {}
    for i, name in enumerate(todo):
        if cancel is not None and cancel():
            raise WarmupCancelled(f"warm-up cancelled before {name}")
        if progress is not None:
            progress(i, len(todo), name)
        t0 = time.perf_counter()
        try:
            JOBS[name]()
        except Exception as err:  # noqa: BLE001  (one line naming the job)
            raise WarmupError(f"warm-up job {name} failed: {type(err).__name__}: {err}") from err
        seconds[name] = time.perf_counter() - t0
        if on_done is not None:
            on_done(name, seconds[name])
    return seconds


# -- markers: which jobs' kernels are in the cache ---------------------------------------------------
def _identity() -> str:
    """The importing identity of these kernels ('kernels', 'bl_ext.user_default.gaussvdb', ...)."""
    return cachedir.identity(__name__, __file__) or "kernels"


def _numba_version() -> str:
    try:
        from importlib.metadata import version

        return version("numba")
    except Exception:  # noqa: BLE001  (not installed as a distribution)
        return "none"


_KEY = {}


def cache_key() -> str:
    """What the cached kernels depend on besides numba's own checks: the sources of every kernel
    subpackage (the kernels call across them), Python, numba and the machine."""
    if "key" not in _KEY:
        kernels = os.path.dirname(os.path.abspath(__file__))
        subs = sorted(n for n in os.listdir(kernels)
                      if os.path.isfile(os.path.join(kernels, n, "__init__.py")))
        h = hashlib.sha1()
        for sub in subs:
            h.update(f"{sub}={cachedir.sources_tag(sub)};".encode())
        for name in sorted(os.listdir(kernels)):  # the top-level modules (pipeline.py, jit.py)
            if name.endswith(".py"):
                with open(os.path.join(kernels, name), "rb") as fh:
                    h.update(name.encode() + b"\0" + fh.read())
        h.update(f"{sys.version_info[:2]};{_numba_version()};{platform.machine()}".encode())
        _KEY["key"] = h.hexdigest()[:12]
    return _KEY["key"]


def identity_dir(root=None) -> str:
    """The cache folder of this importing identity (every kernel subpackage's entries)."""
    return os.path.join(root or cachedir.cache_root(), _identity())


def marker_dir(root=None) -> str:
    return os.path.join(identity_dir(root), "warmup", cache_key())


def status_path(root=None) -> str:
    return os.path.join(identity_dir(root), "warmup", "status.json")


def _marker(name, root=None) -> str:
    return os.path.join(marker_dir(root), name.replace(":", "-") + ".done")


def is_done(name, root=None) -> bool:
    return os.path.isfile(_marker(name, root))


def missing(names=None, root=None) -> list:
    """The jobs of ``names`` (None: all) whose kernels are not in the cache yet."""
    return [n for n in check_names(names) if not is_done(n, root)]


def mark_done(name, seconds=0.0, root=None) -> None:
    os.makedirs(marker_dir(root), exist_ok=True)
    _write_json(_marker(name, root), {"job": name, "seconds": round(seconds, 3), "time": time.time()})


def cache_size(root=None) -> int:
    """Bytes in this identity's cache folder (the compiled kernels and the warm-up's records)."""
    total = 0
    for here, _dirs, names in os.walk(identity_dir(root)):
        for n in names:
            try:
                total += os.path.getsize(os.path.join(here, n))
            except OSError:
                pass
    return total


# -- the status file -------------------------------------------------------------------------------
def _write_json(path, data) -> None:
    """Written to a temporary file beside ``path``, then renamed over it: readers never see half."""
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(data, fh)
    os.replace(tmp, path)


def read_status(path) -> dict:
    """The status a warm-up process wrote ({} when there is none or it cannot be read)."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


class StatusWriter:
    """The status file of one warm-up run: pid, the jobs, the current one, seconds per job done,
    state ('running', 'done', 'failed', 'cancelled') and error."""

    def __init__(self, path, jobs):
        self.path = path
        self.data = {"pid": os.getpid(), "jobs": list(jobs), "index": 0, "count": len(jobs),
                     "name": "", "seconds": {}, "state": "running", "error": "",
                     "started": time.time(), "updated": time.time()}
        if path:
            os.makedirs(os.path.dirname(path), exist_ok=True)
        self.write()

    def write(self, **changes) -> None:
        self.data.update(changes, updated=time.time())
        if self.path:
            _write_json(self.path, self.data)

    def progress(self, index, count, name) -> None:
        self.write(index=index, count=count, name=name)

    def done(self, name, seconds) -> None:
        self.data["seconds"][name] = round(seconds, 3)
        self.write()


def prune_stale(root=None) -> int:
    """Remove this identity's kernel folders of other versions of the sources (``<sub>-<hash>``
    whose hash is not the current one) and their markers: an update leaves them unused. Returns
    the bytes freed."""
    import shutil

    base = identity_dir(root)
    stale = []
    for name in os.listdir(base) if os.path.isdir(base) else ():
        sub, sep, tag = name.rpartition("-")
        if sep and sub in cachedir.SUBPACKAGES and tag != cachedir.sources_tag(sub):
            stale.append(os.path.join(base, name))
    marks = os.path.join(base, "warmup")
    for name in os.listdir(marks) if os.path.isdir(marks) else ():
        if name != cache_key() and os.path.isdir(os.path.join(marks, name)):
            stale.append(os.path.join(marks, name))
    freed = 0
    for folder in stale:
        for here, _dirs, names in os.walk(folder):
            freed += sum(os.path.getsize(os.path.join(here, n)) for n in names
                         if os.path.isfile(os.path.join(here, n)))
        shutil.rmtree(folder, ignore_errors=True)
    return freed


def default_processes() -> int:
    """How many jobs a warm-up compiles at once: one per core, at most 4 (the longest jobs,
    ~20 s each, then bound the time; each process holds a few hundred MB while it compiles)."""
    return max(1, min(os.cpu_count() or 1, 4))


def _timed(name) -> float:
    t0 = time.perf_counter()
    JOBS[name]()
    return time.perf_counter() - t0


def warm(names=None, status=None, progress=None, cancel=None, on_done=None, force=False,
         processes=1) -> dict:
    """``run`` that skips the jobs already marked done (unless ``force``), marks each job it
    finishes and keeps a status file (``status``: its path, None for none); on ``processes``
    worker processes at once when more than one (warmup_pool.py). Returns {name: seconds} of
    the jobs run."""
    prune_stale()  # an update's old kernels
    todo = check_names(names) if force else missing(names)
    writer = StatusWriter(status, todo)

    def on_progress(i, n, name):
        writer.progress(i, n, name)
        if progress is not None:
            progress(i, n, name)

    def done(name, seconds):
        mark_done(name, seconds)
        writer.done(name, seconds)
        if on_done is not None:
            on_done(name, seconds)

    try:
        if processes > 1 and len(todo) > 1:
            from . import warmup_pool

            seconds = warmup_pool.run(todo, processes, on_progress, cancel, done,
                                      cache_root=cachedir.cache_root(),
                                      errors=(WarmupCancelled, WarmupError))
        else:
            seconds = run(todo, on_progress, cancel, done)
    except WarmupCancelled as err:
        writer.write(state="cancelled", error=str(err))
        raise
    except WarmupError as err:
        writer.write(state="failed", error=str(err))
        raise
    writer.write(state="done", index=len(todo), name="")
    return seconds


def main(argv=None) -> int:
    """The warm-up process: ``--jobs a,b`` (default all), ``--status FILE`` (default
    ``status_path()``), ``--cache-root DIR``; exits 0 when every job is done, 1 when one failed."""
    ap = argparse.ArgumentParser(prog="warmup")
    ap.add_argument("--jobs", default="")
    ap.add_argument("--status", default="")
    ap.add_argument("--cache-root", default="")
    ap.add_argument("--nice", type=int, default=0)
    ap.add_argument("--processes", type=int, default=1, help="jobs compiled at once")
    ap.add_argument("--serve", action="store_true", help="a warmup_pool worker")
    args = ap.parse_args(argv)
    if args.cache_root:
        cachedir.set_cache_root(args.cache_root)
    if args.nice and hasattr(os, "nice"):
        try:
            os.nice(args.nice)  # the UI's process stays responsive while this one compiles
        except OSError:
            pass
    if args.serve:
        from . import warmup_pool

        return warmup_pool.serve(_timed)
    if args.processes > 1 and hasattr(signal, "SIGTERM"):
        # a stop (warmup_service.stop) ends the workers too, not only after their current job
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    names = [n for n in args.jobs.split(",") if n.strip()] or None
    try:
        warm([n.strip() for n in names] if names else None, args.status or status_path(),
             processes=args.processes)
    except (WarmupError, ValueError) as err:
        print(f"gaussvdb warm-up: {err}", file=sys.stderr)
        return 1
    return 0
