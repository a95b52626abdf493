"""The background kernel warm-up of the Blender UI: a separate Python process (Blender's own,
``sys.executable``) that compiles the kernels (kernels/warmup.py's jobs) into the cache this
add-on loads from, while Blender stays responsive.

The process imports the kernels under this add-on's own module name (kernels/warmup_boot.py:
numba's entries load only under the names they were compiled under) with the cache root
registration set, and writes its progress to a JSON status file; a finished job leaves a marker
(``warmup.missing`` reads them). One process at a time:

    warmup_service.start()                      # every job not compiled yet (Compile Now)
    warmup_service.ensure(["reader", "lod:medium"])  # join the running one, or start one for these
    warmup_service.progress(["reader"])         # {'done': bool, 'failed': '', 'text': ..., ...}
    warmup_service.wait(jobs, cancel=engine.test_break, report=print)  # a render thread's wait
    warmup_service.compile_ahead(["error"])     # background mode: a second process compiles these
    warmup_service.stop_unless(["render:reference"])  # ... stopped when it holds none of these
    warmup_service.stop()                       # unregister and Blender's exit (atexit)

Background mode (``blender -b``, the bpy module, scripts) starts no warm-up of its own: it
compiles in its own process (``needed`` says no job is awaited there), except what
``compile_ahead`` gives a second process on a cold cache (an import's field error and the
render kernels of the scene's mode, the command line's render kernels), which ``wait`` and
``ready`` then join. Plain Python except
``register_extra``/``unregister_extra`` and the timer (bpy).
"""

import atexit
import os
import subprocess
import sys
import threading
import time

from ...kernels import cachedir, warmup, warmup_pool

WarmupError = warmup.WarmupError
POLL_SECONDS = 0.25
NICE = 10  # the warm-up runs below the UI's priority
_LOCK = threading.RLock()
_state = {"proc": None, "jobs": [], "status": "", "log": "", "error": "", "timer": False,
          "size": (0.0, 0)}


def background() -> bool:
    try:
        import bpy

        return bool(bpy.app.background)
    except ImportError:
        return True


def missing(jobs=None) -> list:
    """The jobs of ``jobs`` (None: all) whose kernels are not in the cache yet (markers only)."""
    return warmup.missing(jobs)


def needed(jobs) -> list:
    """The jobs an action waits for before it runs: in the UI those not compiled yet (it starts
    or joins the warm-up for them); in background mode (it compiles in its own process) only
    those a warm-up started in this process is compiling now (joined, never started; the
    others compile in this process)."""
    todo = missing(jobs)
    if not todo or not background():
        return todo
    with _LOCK:
        return [j for j in todo if j in _state["jobs"]] if running() else []


def compile_ahead(jobs, threads=0) -> list:
    """Background mode, on a cache without the kernels of ``jobs``: compile them in a second
    process (at this process's priority: this one waits for it) while this one compiles what it
    needs first (an import its reader and LODs, a render its import); ``wait`` (or the import's
    ``ready``) then joins it rather than compiling them too. Only where this process is given
    more than one core (``threads``, 0: NUMBA_NUM_THREADS or all; a cluster worker has one),
    and never over a running warm-up. Returns the jobs started."""
    cores = threads or int(os.environ.get("NUMBA_NUM_THREADS") or 0) or os.cpu_count() or 1
    if cores < 2 or not background() or running() or not jobs:
        return []
    return start(jobs, nice=0, processes=1)  # this process compiles on the other core


def stop_unless(jobs) -> bool:
    """Background mode: stop the second process started here when none of its jobs is one of
    ``jobs`` (what it compiles was a guess, an import's of the scene's render mode, and would only
    slow what this process compiles now on the other core). True when it stopped one."""
    if not background():
        return False
    with _LOCK:
        if not running() or any(j in _state["jobs"] for j in jobs):
            return False
        stop()
    return True


def ready(jobs) -> None:
    """kernels.pipeline.convert_steps' ``ready``: in background mode, wait for the jobs a warm-up
    process started by this one compiles now. Nothing in the UI: its modal import waited before
    it began, and nothing else there may wait on a process without progress and Esc."""
    if background():
        wait(jobs)


def compile_here(jobs=None) -> dict:
    """The jobs (None: all) not compiled yet, run in this process (background mode: nothing to
    keep responsive). {name: seconds}."""
    return warmup.warm(jobs, warmup.status_path(), processes=warmup.default_processes())


# -- the process -----------------------------------------------------------------------------------
def running() -> bool:
    with _LOCK:
        proc = _state["proc"]
        if proc is None:
            return False
        code = proc.poll()  # reaps it once it has exited: no zombie
        if code is None:
            return True
        if code != 0 and not _state["error"]:
            st = warmup.read_status(_state["status"])
            _state["error"] = st.get("error") or _last_line(_state["log"]) or f"exit status {code}"
        _state["proc"] = None
        return False


def _last_line(path) -> str:
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            lines = [ln.strip() for ln in fh if ln.strip()]
        return lines[-1][:300] if lines else ""
    except OSError:
        return ""


def _command(jobs, nice=NICE, processes=1) -> list:
    boot = os.path.join(os.path.dirname(warmup.__file__), "warmup_boot.py")
    return [sys.executable, boot, "--package", warmup_pool.package(), "--cache-root", cachedir.cache_root(),
            "--jobs", ",".join(jobs), "--status", warmup.status_path(), "--nice", str(nice),
            "--processes", str(processes)]


def start(jobs=None, nice=NICE, processes=None) -> list:
    """Start a warm-up process for the jobs of ``jobs`` (None: all) not compiled yet, in that
    order, stopping a running one first; ``nice``: its priority below this process's (0: the
    same, where this process only waits for it); ``processes``: jobs compiled at once (None:
    warmup.default_processes). Returns the jobs it runs ([]: nothing to do, and a running
    process goes on)."""
    with _LOCK:
        todo = missing(jobs)
        if not todo:
            return []
        stop()
        status = warmup.status_path()
        os.makedirs(os.path.dirname(status), exist_ok=True)
        _state["log"] = os.path.join(os.path.dirname(status), "warmup.log")
        kwargs = {}
        if sys.platform == "win32":
            kwargs["creationflags"] = subprocess.CREATE_NO_WINDOW | subprocess.BELOW_NORMAL_PRIORITY_CLASS
        with open(_state["log"], "w", encoding="utf-8") as log:
            proc = subprocess.Popen(_command(todo, nice, processes or warmup.default_processes()),
                                    env=warmup_pool.environment(), stdin=subprocess.DEVNULL,
                                    stdout=log, stderr=subprocess.STDOUT, close_fds=True, **kwargs)
        _state.update(proc=proc, jobs=list(todo), status=status, error="")
        _start_timer()
        return list(todo)


def ensure(jobs) -> list:
    """Make sure the kernels of ``jobs`` get compiled: nothing when they are, join the running
    process when they are what it does next, else start one that runs them first and then what
    the running one had left. Returns the jobs still missing."""
    with _LOCK:
        todo = missing(jobs)
        if not todo:
            return []
        queue = missing(_state["jobs"]) if running() else []
        if queue and set(todo) <= set(queue[:len(todo)]):
            return todo
        rest = [j for j in queue if j not in todo]
        start(todo + rest)
        return todo


def stop() -> None:
    """Terminate the running warm-up process and reap it (markers of finished jobs stay)."""
    with _LOCK:
        proc = _state["proc"]
        _state["proc"] = None
        _state["jobs"] = []
    if proc is None or proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


atexit.register(stop)


def status() -> dict:
    """The running process's status file ({} when none runs or it has not written yet)."""
    with _LOCK:
        proc = _state["proc"]
        if proc is None:
            return {}
        st = warmup.read_status(_state["status"])
        return st if st.get("pid") == proc.pid else {}


def progress(jobs) -> dict:
    """Where the wait for ``jobs`` stands: done (every one compiled), failed (the process ended
    without them: why), fraction, and one line of text for a status bar."""
    todo = missing(jobs)
    jobs = warmup.check_names(jobs)
    if not todo:
        return {"done": True, "failed": "", "fraction": 1.0, "text": ""}
    if not running():
        return {"done": False, "failed": _state["error"] or "the warm-up process stopped",
                "fraction": 0.0, "text": ""}
    st = status()
    current = st.get("name") or todo[0]
    n_done = len(jobs) - len(todo)
    text = (f"Compiling GaussVDB kernels in the background: {current} "
            f"({n_done + 1}/{len(jobs)})")
    return {"done": False, "failed": "", "fraction": n_done / max(len(jobs), 1), "text": text}


def wait(jobs, cancel=None, report=None, interval=POLL_SECONDS) -> str:
    """Start (or join) the warm-up for ``jobs`` and wait for it: 'done', 'cancelled' (``cancel()``
    said so; the warm-up goes on) or 'failed: why' (the caller then compiles in its own process).
    ``report(text)`` whenever the text changes. For a thread that may wait (a render)."""
    jobs = needed(jobs)
    if not jobs:
        return "done"
    if not background():  # background mode joins the running process, never restarts it
        ensure(jobs)
    last, t0 = None, time.perf_counter()
    while True:
        p = progress(jobs)
        result = "done" if p["done"] else f"failed: {p['failed']}" if p["failed"] else \
            "cancelled" if cancel is not None and cancel() else ""
        if result:
            _state["last_wait"] = {"jobs": jobs, "result": result,
                                   "seconds": time.perf_counter() - t0}
            return result
        if report is not None and p["text"] != last:
            report(p["text"])
            last = p["text"]
        time.sleep(interval)


def last_wait() -> dict:
    """The last ``wait`` of this process that had jobs to wait for: jobs, result, seconds."""
    return dict(_state.get("last_wait") or {})


# -- what the preferences and the status bar show ------------------------------------------------
def state_text() -> str:
    """One line: the warm-up's state."""
    if running():
        st = status()
        n = st.get("count") or len(_state["jobs"])
        i = min(int(st.get("index", 0)) + 1, max(n, 1))
        return f"Compiling in the background: {st.get('name') or 'starting'} ({i}/{n})"
    todo = missing()
    if _state["error"]:
        return f"Background compile failed: {_state['error']}"
    if not todo:
        return "All kernels compiled"
    return f"{len(todo)} of {len(warmup.NAMES)} kernel groups not compiled yet"


def cache_folder() -> str:
    return warmup.identity_dir()


def cache_size_text() -> str:
    """The cache folder's size, measured at most every few seconds (a panel draws often)."""
    t, size = _state["size"]
    now = time.monotonic()
    if now - t > 5.0:
        size = warmup.cache_size()
        _state["size"] = (now, size)
    return f"{size / 1e6:.1f} MB"


def draw_status(self, context):
    """STATUSBAR_HT_header: the warm-up's progress while it runs."""
    if not running():
        return
    st = status()
    n = st.get("count") or len(_state["jobs"]) or 1
    i = int(st.get("index", 0))
    self.layout.progress(factor=i / n, type="BAR",
                         text=f"GaussVDB kernels: {st.get('name') or 'starting'} ({i + 1}/{n})")


def _redraw() -> None:
    import bpy

    wm = getattr(bpy.context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            if area.type in ("STATUSBAR", "PREFERENCES"):
                area.tag_redraw()


def _tick():
    """bpy.app.timers: redraws the status bar and preferences while the process runs."""
    alive = running()
    try:
        _redraw()
    except Exception:  # noqa: BLE001  (a window closing under us)
        pass
    if alive:
        return 0.5
    _state["timer"] = False
    return None


def _start_timer() -> None:
    if _state["timer"] or background():
        return
    import bpy

    _state["timer"] = True
    bpy.app.timers.register(_tick, first_interval=0.5, persistent=True)


def _start_if_needed():
    """At registration: every job whose kernels are not in the cache, in the background."""
    if not background() and missing():
        start()
    return None


CLASSES = ()


def register_extra():
    import bpy

    bpy.types.STATUSBAR_HT_header.append(draw_status)
    if not background():
        bpy.app.timers.register(_start_if_needed, first_interval=1.0)


def unregister_extra():
    import bpy

    stop()
    bpy.types.STATUSBAR_HT_header.remove(draw_status)
    for fn in (_tick, _start_if_needed):
        if bpy.app.timers.is_registered(fn):
            bpy.app.timers.unregister(fn)
    _state["timer"] = False
