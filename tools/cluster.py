"""`convert` and `render` of a sequence on a Dask cluster: `--workers N` (a LocalCluster of N
processes on this machine) or `--scheduler ADDRESS` (a running cluster). One task per frame
(tools/cluster_tasks.py), retried elsewhere when its worker dies; outputs written to a temporary
name and renamed; a frame already done (its cache file made from the same source with the same
options, or its image recorded in the run's JSON with the same inputs) is skipped, so a run
killed half-way resumes. The run's JSON (per frame: worker, seconds, peak memory, error) is
rewritten atomically beside the outputs after each frame and printed at the end; a progress bar
goes to stderr on a terminal only.

Threads: a LocalCluster splits the cores given (--threads, default all) among its workers
(NUMBA_NUM_THREADS in each worker's environment, one Dask thread each), so workers x threads =
cores. Workers started elsewhere set theirs where they start (see README, Cluster runs); the
run warns when a host's workers add up to more threads than it has cores.
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import sys
import time
import uuid

import cli_errors
import cluster_tasks
from cli_errors import InputError, UsageError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RETRIES = 2  # a task that raised is tried this many more times (a dead worker's task: Dask's own)
RUN_JSON = ".run.json"


def add_arguments(parser):
    """--workers / --scheduler on `convert` and `render`."""
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--workers", type=cli_errors.positive_int, metavar="N",
                   help="a sequence: N worker processes on this machine (Dask LocalCluster); "
                        "--threads is then the cores they share")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="a sequence: run its frames on the Dask cluster at ADDRESS "
                        "(tcp://host:8786)")


def wanted(args) -> bool:
    return bool(getattr(args, "workers", None) or getattr(args, "scheduler", None))


# -- the cluster ---------------------------------------------------------------------------------
@contextlib.contextmanager
def connect(workers=None, scheduler=None, cores=0, prog="gaussvdb"):
    """A Dask client: on a new LocalCluster of ``workers`` processes sharing ``cores`` (0: all),
    or on the scheduler at ``scheduler``. Yields (client, numba threads per task, 0 = the
    worker's own)."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise UsageError("--workers/--scheduler need Dask: pip install -r requirements.txt",
                         prog) from None
    logging.getLogger("distributed").setLevel(logging.ERROR)  # its INFO lines are not ours
    if scheduler:
        try:
            client = Client(scheduler, timeout=30)
        except (OSError, TimeoutError) as err:
            raise InputError(f"--scheduler {scheduler}: cannot connect: {cli_errors.one_line(err)}",
                             prog) from None
        with client:
            _warn_oversubscribed(client, prog)
            yield client, 0
        return
    cores = cores or cli_errors.max_threads()
    threads = max(1, cores // workers)
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=logging.ERROR,
                           env={"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": "1"},
                           preload=[os.path.abspath(cluster_tasks.__file__)])
    with cluster, Client(cluster) as client:
        yield client, threads


def dashboard(client):
    """The dashboard's address when one is up (the scheduler has bokeh), else None."""
    with contextlib.suppress(Exception):
        if client.run_on_scheduler(cluster_tasks.has_bokeh):
            return client.dashboard_link
    return None


def _warn_oversubscribed(client, prog):
    """Per host: the numba threads of its workers against its cores (one line when more)."""
    try:
        found = client.run(cluster_tasks.worker_threads)
    except Exception:  # noqa: BLE001  (a worker gone while asked: the check is advisory)
        return
    hosts = {}
    for host, cpus, threads in found.values():
        hosts.setdefault(host, [cpus, 0])[1] += threads
    for host, (cpus, total) in sorted(hosts.items()):
        if total > cpus:
            print(f"{prog}: warning: the workers on {host} run {total} numba threads on {cpus} "
                  "cores; start them with NUMBA_NUM_THREADS=cores/workers", file=sys.stderr)


# -- running the frames --------------------------------------------------------------------------
class Progress:
    """One line on stderr redrawn per finished frame: frames done, failures, per-worker frames per
    second, ETA. Silent unless stderr is a terminal."""

    def __init__(self, total, label, stream=None):
        self.stream = stream or sys.stderr
        self.on = self.stream.isatty()
        self.total, self.label, self.done, self.failed = total, label, 0, 0
        self.t0 = time.perf_counter()
        self.per_worker = {}

    def update(self, item):
        self.done += 1
        self.failed += bool(item.get("error"))
        w = item.get("worker")
        if w:
            self.per_worker[w] = self.per_worker.get(w, 0) + 1
        self.draw()

    def draw(self):
        if not self.on:
            return
        elapsed = time.perf_counter() - self.t0
        width = 24
        bar = "#" * (width * self.done // max(self.total, 1))
        rates = " ".join(f"{w.rsplit(':', 1)[-1]}:{n / max(elapsed, 1e-9):.2f}/s"
                         for w, n in sorted(self.per_worker.items()))
        eta = elapsed / self.done * (self.total - self.done) if self.done else 0.0
        failed = f", {self.failed} failed" if self.failed else ""
        self.stream.write(f"\r{self.label} [{bar:<{width}}] {self.done}/{self.total} frames{failed}"
                          f"  {rates}  ETA {eta:.0f} s\x1b[K")
        self.stream.flush()

    def close(self):
        if self.on:
            self.stream.write("\n")
            self.stream.flush()


def write_json(path, obj):
    """``obj`` as JSON to ``path`` through a temporary name (a reader never sees half of it)."""
    from kernels import sequence as seq

    tmp = seq.temporary_name(path)
    try:
        with open(tmp, "x") as f:
            json.dump(obj, f, indent=1, sort_keys=True)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def run_frames(client, submit, todo, prog, label, on_item, size=None):
    """Submit ``submit(frame)`` -> (a cluster_tasks function, args) for each frame of ``todo``; call ``on_item``
    with each finished frame's item in the order they finish. A task that still raises after
    its retries, or whose workers all died, becomes an error item naming the frame. A refusal
    (bad options, found by the first worker to prepare) stops the run. ``size(frame)``: the
    frame's file size; the largest frames run first, so the last ones to finish are small and
    no worker waits long for another at the end."""
    from distributed import as_completed

    run = uuid.uuid4().hex[:8]
    futures = {}
    for n in sorted(todo, key=size, reverse=True) if size else todo:  # the first go out at once
        fn, args = submit(n)
        fut = client.submit(fn, *args, key=f"{label}-{n}-{run}", retries=RETRIES, pure=False,
                            priority=size(n) if size else 0)
        futures[fut] = n
    bar = Progress(len(futures), f"{prog}:")
    bar.draw()
    try:
        for fut in as_completed(futures):
            n = futures[fut]
            try:
                item = fut.result()
            except Exception as err:  # noqa: BLE001  (KilledWorker, the task's own exception)
                item = {"frame": n, "error": f"frame {n}: {type(err).__name__}: "
                                             f"{cli_errors.one_line(err)}"}
            if item.get("refusal"):
                for f in futures:
                    f.cancel()
                raise InputError(item["refusal"], prog)
            bar.update(item)
            on_item(item)
    finally:
        bar.close()


def file_size(path) -> int:
    """Bytes of ``path``; 0 when it is not there (a frame held past the last file)."""
    try:
        return os.path.getsize(path)
    except OSError:
        return 0


def sweep(outputs):
    """Remove the temporary files a killed worker left beside these outputs (their frames are
    done by now: a temporary name is never read)."""
    import glob

    for out in outputs:
        for tmp in glob.glob(glob.escape(out) + ".*.tmp*"):
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def _finish(res, items, t_all, report_path, dash):
    items.sort(key=lambda i: i["frame"])
    res["frames"] = items
    res["errors"] = [i["error"] for i in items if i.get("error")]
    res.update(workers=sorted({i["worker"] for i in items if i.get("worker")}), dashboard=dash,
               run_json=report_path, skipped=sum(1 for i in items if i.get("skipped")),
               peak_rss_bytes_max=max((i.get("peak_rss_bytes", 0) for i in items), default=0))
    res["seconds_total"] = time.perf_counter() - t_all
    ran = [i for i in items if "started" in i]
    if ran:  # from the first frame's start to the last frame's end, on the workers' clocks
        res["seconds_frames"] = max(i["started"] + i["seconds"] for i in ran) - min(
            i["started"] for i in ran)
    write_json(report_path, res)
    return res


def _loop(client_args, prog, todo, submit, label, items, flush, record=None, before=None,
          size=None):
    """Run ``todo`` on the cluster (none started when nothing is left to do); each finished
    item, after ``record(item)``, joins ``items`` and the run's JSON is rewritten.
    ``before(client, threads)`` runs first, on the same cluster (what every frame needs)."""
    dash = None
    if not todo:
        return dash
    with connect(*client_args, prog=prog) as (client, threads):
        dash = dashboard(client)
        if dash:
            print(f"{prog}: Dask dashboard at {dash}", file=sys.stderr)
        if before is not None:
            before(client, threads)

        def on_item(item):
            if record:
                record(item)
            items.append(item)
            if item.get("error"):
                print(f"{prog}: error: {cli_errors.one_line(item['error'])}", file=sys.stderr)
            flush()

        run_frames(client, lambda n: submit(n, threads), todo, prog, label, on_item, size)
    return dash


# -- convert ---------------------------------------------------------------------------------------
def convert_sequence(pattern, frames, grid, lod, cache_dir, options, *, workers=None,
                     scheduler=None, cores=0) -> dict:
    """`convert 'DIR/name_####.vdb' --cache-dir DIR` with one task per frame: the same cache
    files and JSON as the serial run (cmd_convert.convert_sequence, the same ConvertOptions
    ``options``), plus per frame the worker and its peak memory, and frames already in the
    cache marked skipped."""
    import cli_grids

    from kernels import sequence as seq

    prog = "gaussvdb convert"
    pat, present, name = cli_grids.sequence_frames(pattern, frames, grid, options.vector_magnitude)
    os.makedirs(cache_dir, exist_ok=True)
    job = cluster_tasks.ConvertJob(options.replace(grids=(name,), lods=(lod,)),
                                   os.path.abspath(cache_dir))
    report_path = job.cache_file(pat.text)[:-len(".npz")] + RUN_JSON
    res = {"pattern": pat.path(0).replace(pat.name(0), pat.text), "grid": name, "lod": lod,
           "weights": options.weights, "cache_dir": os.path.abspath(cache_dir)}
    items, todo = [], []
    t_all = time.perf_counter()
    for n in present:  # done: a cache file read back whole, made from this very source
        path, out = pat.path(n), job.cache_file(pat.path(n))
        found = seq.read_cache(out, seq.fingerprint(path)) if os.path.isfile(out) else None
        if found is not None and found[1].get("grid") == name and found[1].get("lod") == lod:
            items.append({"frame": n, "file": os.path.basename(path), "skipped": True,
                          "vdb_bytes": os.path.getsize(path), "cache_bytes": os.path.getsize(out),
                          "cache_file": os.path.basename(out)})
        else:
            todo.append(n)

    def submit(n, threads):
        return cluster_tasks.convert_frame, (dataclasses.replace(job, threads=threads), n,
                                             pat.path(n), ROOT)

    def flush():
        write_json(report_path, {**res, "frames": sorted(items, key=lambda i: i["frame"]),
                                 "complete": False})

    def load_kernels(client, threads):  # on every worker at once, before the frames
        t0 = time.perf_counter()
        with contextlib.suppress(Exception):  # failed: each worker loads them in its first frame
            client.run(cluster_tasks.load_kernels, dataclasses.replace(job, threads=threads), ROOT,
                       pat.path(todo[0]))
        res["seconds_load"] = time.perf_counter() - t0

    dash = _loop((workers, scheduler, cores), prog, todo, submit, "convert", items, flush,
                 before=load_kernels, size=lambda n: file_size(pat.path(n)))
    sweep(job.cache_file(pat.path(n)) for n in todo)
    res = _finish(res, items, t_all, report_path, dash)
    done = [i for i in items if "cache_bytes" in i]
    res.update(cache_bytes=sum(i["cache_bytes"] for i in done),
               vdb_bytes=sum(i["vdb_bytes"] for i in done), complete=True)
    write_json(report_path, res)
    return res


# -- render ----------------------------------------------------------------------------------------
# options that change no pixel: left out of the key that says a frame is done
_NOT_IN_KEY = {"json", "threads", "workers", "scheduler", "frames"}


def render_key(args, pat, inside) -> str:
    """What a frame's image depends on besides its number: the options, and every frame file
    of the range (the camera frames their union box, the colours span their range)."""
    from kernels import sequence as seq

    opts = {k: v for k, v in sorted(vars(args).items()) if k not in _NOT_IN_KEY}
    sources = [(n, seq.fingerprint(pat.path(n))) for n in inside]
    text = json.dumps([opts, sources], sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()


def render_sequence(args) -> dict:
    """`render 'DIR/name_####.vdb' --out 'out/f_####.png'` with one task per frame: the same
    images and JSON as the serial run (tools/render_sequence.py), each worker preparing the
    scene once; frames whose image the previous run's JSON records with the same key and
    checksum are skipped."""
    import render_sequence as rs

    from kernels import sequence as seq

    prog = "gaussvdb render"
    pat, frames, inside = rs.frames_of(args)
    grid = rs.choose_grid(pat, inside, args)
    key = render_key(args, pat, inside)
    report_path = os.path.abspath(args.out) + RUN_JSON
    os.makedirs(os.path.dirname(report_path), exist_ok=True)
    previous = {}
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        with open(report_path) as f:
            previous = {i["frame"]: i for i in json.load(f)["frames"]}
    res = {"pattern": pat.path(0).replace(pat.name(0), pat.text), "grid": grid, "lod": args.lod,
           "mode": args.mode, "width": args.width, "height": args.height,
           "colormap": args.colormap, "sequence": True}
    items, todo = [], []
    t_all = time.perf_counter()
    for f in frames:
        out = os.path.abspath(rs.out_path(args.out, f))
        old = previous.get(f, {})
        if (old.get("key") == key and not old.get("error") and os.path.isfile(out)
                and old.get("out_fingerprint") == seq.fingerprint(out)):
            items.append({**old, "skipped": True})
        else:
            todo.append(f)

    known = {}  # every frame's figures (the colour range, the camera's box): read once, spread

    def read_figures(client, threads):
        t0 = time.perf_counter()
        futures = client.map(cluster_tasks.frame_figures, [pat.path(n) for n in inside],
                             grid=grid, threads=threads, root=ROOT, retries=RETRIES, pure=False)
        for n, fut in zip(inside, futures):
            with contextlib.suppress(Exception):  # lost: the workers read that frame themselves
                known[n] = fut.result()
        res["seconds_figures"] = time.perf_counter() - t0

    def submit(f, threads):
        a = type(args)(**{**vars(args), "threads": threads or args.threads})
        return cluster_tasks.render_frame, (a, key, f, os.path.abspath(rs.out_path(args.out, f)),
                                            ROOT, known)

    def flush():
        write_json(report_path, {**res, "frames": sorted(items, key=lambda i: i["frame"]),
                                 "complete": False})

    def record(item):  # what a later run compares
        if not item.get("error") and os.path.isfile(item.get("out", "")):
            item.update(key=key, out_fingerprint=seq.fingerprint(item["out"]))

    dash = _loop((args.workers, args.scheduler, 0 if args.scheduler else args.threads), prog,
                 todo, submit, "render", items, flush, record, read_figures,
                 lambda f: file_size(pat.path(f)))
    sweep(os.path.abspath(rs.out_path(args.out, f)) for f in todo)
    warnings = []
    for item in sorted(items, key=lambda i: i["frame"]):
        for msg in item.pop("warnings", ()):
            if msg not in warnings:
                warnings.append(msg)
                print(f"{prog}: warning: {msg}", file=sys.stderr)
    res = _finish(res, items, t_all, report_path, dash)
    res.update(warnings=warnings, complete=True,
               value_range=next((i["value_range"] for i in res["frames"] if i.get("value_range")),
                                None))
    write_json(report_path, res)
    return res
