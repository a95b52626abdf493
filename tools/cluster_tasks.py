"""The task bodies a Dask worker runs for `convert` and `render` of a sequence (tools/cluster.py
submits them): one frame each, written to a temporary name and renamed, returning the frame's
JSON item (worker, seconds, peak memory, error).

`convert_frame` needs no Blender (the kernels alone); `render_frame` starts Blender once per
worker process and keeps the prepared scene for the next frames of the same run.

Also a Dask preload: `dask scheduler --preload tools/cluster_tasks.py` and `dask worker ADDRESS
--preload tools/cluster_tasks.py` put the repository on their path: the scheduler unpickles each
task (its function is named by reference), the worker runs it (`kernels` imports). Its numba threads: NUMBA_NUM_THREADS
in its environment, or GAUSSVDB_WORKER_THREADS where numba's own limit must stay higher.
"""
from __future__ import annotations

import os
import socket
import sys
import time
from dataclasses import dataclass

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def use_root(root=None):
    """The repository's code importable here: GAUSSVDB_ROOT on this node, else the driver's
    repository path ``root`` (shared storage), else this file's. A preloaded copy of this file
    runs from the worker's scratch folder, so the driver names the root with every task."""
    root = os.environ.get("GAUSSVDB_ROOT") or root or ROOT
    for p in (os.path.join(root, "tools"), root):
        if p not in sys.path:
            sys.path.insert(0, p)


use_root()

from kernels.convert_options import ConvertOptions  # noqa: E402  (the path set just above)


@dataclass(frozen=True)
class ConvertJob:
    """One frame of a sequence into the disk cache, besides the frame: the run's ConvertOptions
    (grids and lods: the one grid and LOD; the object settings), the folder and this task's
    numba threads. One picklable value: it travels to the workers."""
    options: ConvertOptions
    cache_dir: str
    threads: int = 0  # numba threads per worker; 0: the worker's own setting

    @property
    def grid(self) -> str:
        return self.options.grids[0]

    @property
    def lod(self) -> str:
        return self.options.lods[0]

    def cache_file(self, path) -> str:
        from kernels import sequence as seq

        return os.path.join(self.cache_dir, seq.cache_name(path, self.grid, self.lod, self.options))


def set_threads(n):
    """numba threads for this thread (numba's setting is per thread: a Dask task runs in the
    worker's executor thread, not where the worker started), within numba's launch limit."""
    n = int(n or os.environ.get("GAUSSVDB_WORKER_THREADS") or 0)
    if n:
        import numba

        numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))


def _peak_rss() -> int:
    """This process's resident high-water mark, in bytes (ru_maxrss: KiB on Linux); 0 where
    there is no getrusage (Windows)."""
    try:
        import resource
    except ImportError:
        return 0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024


def _rss() -> int:
    """This process's resident memory now, in bytes (0 where it cannot be read)."""
    try:
        import psutil  # a dependency of distributed

        return int(psutil.Process().memory_info().rss)
    except (ImportError, OSError):
        return 0


def release_freed():
    """Hand the heap memory freed by the frame back to the system (glibc's malloc_trim). The
    frame's arrays are gone once it is drawn, but glibc keeps much of what they occupied in its
    arenas, so a worker's resident memory would creep up frame after frame by up to a frame's
    working set. Nothing elsewhere (other C libraries, macOS, Windows)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):  # a C library without malloc_trim (musl)
        pass


def _worker() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"  # called outside a worker (a test)


def _stamp(item, t0, rss0):
    """The worker, seconds, start (epoch: the driver reads the run's span from these), this
    process's peak memory before and after the frame, and its resident memory once the frame is
    done (what the worker holds into its next frame)."""
    seconds = time.perf_counter() - t0
    peak = _peak_rss()
    release_freed()
    item.update(worker=_worker(), seconds=seconds, started=time.time() - seconds,
                rss_before_bytes=rss0, peak_rss_bytes=peak, rss_after_bytes=_rss())
    return item


def convert_frame(job: ConvertJob, frame: int, path: str, root=None) -> dict:
    """One frame into the cache (kernels.pipeline.convert_frame, kernels.sequence.write_frame,
    as `convert --cache-dir` and the add-on): its JSON item; a frame that cannot be converted
    is an item with "error" (not an exception: Dask would retry it)."""
    import warnings

    use_root(root)
    from kernels import pipeline
    from kernels import sequence as seq

    t0, rss0 = time.perf_counter(), _peak_rss()
    set_threads(job.threads)
    out = job.cache_file(path)
    item = {"frame": frame, "file": os.path.basename(path), "vdb_bytes": os.path.getsize(path)}
    with warnings.catch_warnings():  # NaN/Inf voxels made inactive, as the add-on does
        warnings.filterwarnings("ignore", message=".*non-finite", category=RuntimeWarning)
        cg, why = pipeline.convert_frame(path, job.grid, job.lod, job.options)
    if why:
        item["error"] = f"frame {frame}: {why}"
        return _stamp(item, t0, rss0)
    gs = cg.lods[0].gset if cg is not None else None
    values = (cg.values or None) if cg is not None else None
    item.update(gaussians=gs.count if gs is not None else 0,
                cache_bytes=seq.write_frame(out, gs, values, path, job.grid, job.lod),
                cache_file=os.path.basename(out))
    return _stamp(item, t0, rss0)


def load_kernels(job: ConvertJob, root=None, like=None) -> float:
    """A frame's kernels loaded from the cache (compiled on a cold one) in this worker before its
    first frame: the job's conversion and encoding of the warm-up's small file stored as the
    frame ``like`` is (blosc or not: the reader's decoders differ), on every worker at once while
    none has a frame yet (cluster.convert_sequence), rather than in each worker's first frame.
    Returns its seconds."""
    use_root(root)
    from kernels import pipeline, warmup
    from kernels.lod import encode_compact
    from kernels.vdb.info import uses_blosc

    t0 = time.perf_counter()
    set_threads(job.threads)
    fixture = warmup.FIXTURE if like is None or uses_blosc(like) else warmup.CACHE_FIXTURE
    cg, _why = pipeline.convert_frame(fixture, "density", job.lod, job.options)
    if cg is not None:
        encode_compact(cg.lods[0].gset)
    return time.perf_counter() - t0


def frame_figures(path: str, grid: str, threads=0, root=None) -> dict:
    """kernels.sequence.frame_figures of one frame of a sequence to render (its value figures
    and box): the driver gives them all to the render tasks, so no worker reads every frame.
    Read with the kernels of the Blender session this worker's render tasks use (started here
    once): the plain package would load, or compile, the reader a second time."""
    use_root(root)
    from blender_session import kernels_module, start

    set_threads(threads)
    start()
    return kernels_module("sequence").frame_figures(path, [grid])


_PREPARED = {}  # this worker's Blender scene for the run it renders: {run key: prepared}


def render_frame(args, key: str, frame: int, out: str, root=None, known=None) -> dict:
    """Scene frame ``frame`` of the sequence of ``args`` (`render`'s options) drawn to
    ``out`` through a temporary name. The first frame of a run in this process starts Blender
    and prepares the scene as the serial `render` does (tools/render_sequence.prepare; with
    ``known``, the frames' figures frame_figures read), so every worker draws the same camera
    and colour range; the next ones reuse it."""
    use_root(root)
    import cli_errors
    import render_sequence

    from kernels import sequence as seq

    t0, rss0 = time.perf_counter(), _peak_rss()
    set_threads(args.threads)
    prepared, seconds_prepare = _PREPARED.get(key), None
    if prepared is None:
        _PREPARED.clear()  # one run's scene at a time: prepare() starts from an empty file
        try:
            prepared = _PREPARED[key] = render_sequence.prepare(args, known)
        except (cli_errors.InputError, cli_errors.UsageError) as err:  # the run's, not the frame's
            return {"frame": frame, "refusal": str(err)}
        seconds_prepare = time.perf_counter() - t0
    os.makedirs(os.path.dirname(out), exist_ok=True)
    ext = os.path.splitext(out)[1]
    tmp = seq.temporary_name(out) + ext  # the extension picks the image format
    try:
        item, stats = render_sequence.render_frame(prepared, frame, tmp)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    item.update(out=out, warnings=list(stats.get("warnings", ())),
                value_range=stats.get("value_range"))
    if seconds_prepare is not None:  # this worker's Blender start and scene (in "seconds")
        item["seconds_prepare"] = seconds_prepare
    if stats.get("errors"):
        item["error"] = "; ".join(stats["errors"])
    return _stamp(item, t0, rss0)


def worker_threads():
    """(host, cores, numba threads) of this worker process (the driver's oversubscription check)."""
    import numba

    own = os.environ.get("GAUSSVDB_WORKER_THREADS")
    return socket.gethostname(), os.cpu_count(), int(own or numba.config.NUMBA_NUM_THREADS)


def has_bokeh() -> bool:
    """Whether this process (the scheduler) can serve the dashboard."""
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


def dask_setup(worker=None):
    """Dask's preload hook: runs in the worker process before any task (paths are set above).
    What the tasks print (Blender's 'Saved:' lines) goes to stderr: a LocalCluster's workers
    share the command's stdout, which carries its JSON."""
    sys.stdout.flush()
    os.dup2(2, 1)
    if worker is not None:
        quiet_worker(worker)


def quiet_worker(worker):
    """What a Dask worker does besides our tasks, made to cost nothing measurable.
    - Its statistical profiler samples the task's stack every 10 ms, holding the GIL: with one
      thread per worker on every core, it took a fifth of a rendered sequence's time.
    - Its nanny starts it with MALLOC_TRIM_THRESHOLD_=65536, which also fixes glibc's mmap
      threshold at 128 KiB: every array a frame allocates is mapped and faulted in anew (a
      12-frame render on 2 workers: 6.5 s of system time, 3.8 s without). glibc's own adaptive
      limits are restored (at their 64-bit maxima); the tasks hand the frame's memory back
      after each frame themselves (release_freed)."""
    for name in ("profile", "profile-cycle"):
        pc = worker.periodic_callbacks.pop(name, None)
        if pc is not None:
            pc.stop()
    if sys.platform.startswith("linux") and os.environ.get("MALLOC_TRIM_THRESHOLD_"):
        try:
            import ctypes

            libc = ctypes.CDLL(None)
            libc.mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD: arrays under 32 MiB reuse the heap
            libc.mallopt(-1, 64 << 20)  # M_TRIM_THRESHOLD: twice that, as glibc adapts it
        except (OSError, AttributeError):  # a C library without mallopt (musl)
            pass
