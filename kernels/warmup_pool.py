"""The warm-up's jobs (warmup.py) on several processes at once: numba compiles in one thread, so
a second core compiles other jobs only in another process.

    from kernels import warmup_pool
    warmup_pool.run(["reader", "render:particles"], processes=2, progress=..., on_done=...)

``run`` starts ``processes`` workers (``warmup_boot.py --serve``: the same Python, the kernels
imported under this module's own identity, so their cache entries are the ones the caller
loads) and hands each the next job of the list, in order, as soon as it is free: what a first
session needs still comes first. A worker reads one job name per line on its standard input and
answers one JSON line; it exits when its input closes, so workers never outlive a coordinator
that is killed. Plain Python, no numba here (the workers import it).
"""
from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import threading

POLL_SECONDS = 0.25


def package() -> str:
    """The package the kernels are imported under ('' for plain ``kernels``): what
    ``warmup_boot.py --package`` takes."""
    name = __name__.rsplit(".", 1)[0]  # '<package>.kernels' or 'kernels'
    return name.rsplit(".", 1)[0] if "." in name else ""


def _worker_command(cache_root, nice) -> list:
    boot = os.path.join(os.path.dirname(os.path.abspath(__file__)), "warmup_boot.py")
    return [sys.executable, boot, "--package", package(), "--serve", "--cache-root", cache_root,
            "--nice", str(nice)]


def environment() -> dict:
    """This process's environment with its module path as PYTHONPATH: a child of the same
    Python finds numpy, numba (in Blender: the extension's wheels) and blosc where this one does."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p and os.path.isdir(p))
    return env


def serve(run_job, stdin=None, stdout=None) -> int:
    """A worker's loop: ``run_job(name)`` (its seconds) for each job name read, one JSON line
    answered per job ({"job", "seconds"} or {"job", "error"}); returns at the end of the input."""
    stdin = stdin or sys.stdin
    stdout = stdout or sys.stdout
    for line in stdin:
        name = line.strip()
        if not name:
            break
        try:
            answer = {"job": name, "seconds": run_job(name)}
        except Exception as err:  # noqa: BLE001  (the coordinator says which job, in one line)
            answer = {"job": name, "error": f"{type(err).__name__}: {err}"}
        stdout.write(json.dumps(answer) + "\n")
        stdout.flush()
    return 0


class _Worker:
    def __init__(self, command, answers):
        self.job = None
        # (stderr: the coordinator's, so a worker's failure reaches its log)
        self.proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, bufsize=1, env=environment())
        threading.Thread(target=self._read, args=(answers,), daemon=True).start()

    def _read(self, answers):
        for line in self.proc.stdout:
            try:
                answer = json.loads(line)
            except ValueError:
                continue  # not an answer (a library printing on stdout)
            if isinstance(answer, dict) and "job" in answer:
                answers.put((self, answer))
        answers.put((self, None))  # the worker ended

    def give(self, name):
        self.job = name
        self.proc.stdin.write(name + "\n")
        self.proc.stdin.flush()

    def close(self, kill=False):
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        if kill and self.proc.poll() is None:
            self.proc.kill()
        try:
            self.proc.wait(timeout=None if not kill else 10)
        except subprocess.TimeoutExpired:
            pass


def run(names, processes, progress=None, cancel=None, on_done=None, *, cache_root, nice=0,
        errors=(RuntimeError, RuntimeError)) -> dict:
    """Run the jobs ``names`` on ``processes`` worker processes; warmup.run's callbacks
    (``progress(index, count, 'a + b')``: the jobs under way). ``errors``: the exception types
    raised for a cancel and for a failed job. Returns {name: seconds}."""
    cancelled, failed = errors
    todo = list(names)
    answers = queue.Queue()
    workers = [_Worker(_worker_command(cache_root, nice), answers)
               for _ in range(max(1, min(processes, len(todo))))]
    seconds, started = {}, 0
    ok = False
    try:
        while len(seconds) < len(names):
            for w in workers:
                if w.job is None and todo:
                    if cancel is not None and cancel():
                        raise cancelled(f"warm-up cancelled before {todo[0]}")
                    w.give(todo.pop(0))
                    started += 1
                    if progress is not None:
                        busy = " + ".join(x.job for x in workers if x.job)
                        progress(started - 1, len(names), busy)
            try:
                w, answer = answers.get(timeout=POLL_SECONDS)
            except queue.Empty:
                continue
            if answer is None:
                raise failed(f"warm-up job {w.job} failed: its process ended "
                             f"(exit status {w.proc.wait()})")
            if "error" in answer:
                raise failed(f"warm-up job {answer['job']} failed: {answer['error']}")
            seconds[answer["job"]] = float(answer["seconds"])
            w.job = None
            if on_done is not None:
                on_done(answer["job"], seconds[answer["job"]])
        ok = True
    finally:
        for w in workers:  # a worker exits when its input closes; killed on an error or cancel
            w.close(kill=not ok)
    return seconds
