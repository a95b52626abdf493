"""How every kernel is compiled: ``njit`` (numba, or plain Python without it), the
on-disk cache located per importing identity (see cachedir.py), and ``parallel_for``, which runs
a serial kernel over chunks of a range on Python threads.

Parallel loops are Python threads over nogil kernels, not numba's ``parallel=True``: a prange
loop compiles its body again as a gufunc through numba's parfor passes, and those cost a cold
start about 40% of its compile seconds (the field error 20 s against 8 s serial, a reference
frame 29 s against 21 s). A kernel ``k(lo, hi, ...)`` does indices lo..hi-1 of its loop;
``parallel_for(k, n, ...)`` splits [0, n) into chunks that the threads take in turn, so every
index is computed by the same code whatever the thread count and the result does not depend on it.
Nor is there numba's threading layer to guard: under its workqueue layer (no TBB or OpenMP, e.g.
stock macOS) two threads inside parallel regions at once abort the process, which a viewport
render beside a final render did.

One signature per kernel: numba compiles a kernel again for every distinct argument type its
callers pass, and a literal is a type of its own (f(x, 8) and f(x, n) compile f twice; so do a
read-only and a writable array). Call sites pass np.int64(8), and files map writable.
"""
from __future__ import annotations

import os
import tempfile
import threading

import numpy as np

from . import cachedir

try:
    import numba
    from numba import njit
    from numba.core import caching as _caching
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - numba is optional for the reader
    HAVE_NUMBA = False

    def njit(*args, **kwargs):
        return (lambda f: f) if not args or not callable(args[0]) else args[0]


if HAVE_NUMBA:
    class KernelCacheLocator(_caching._SourceFileBackedLocatorMixin, _caching._CacheLocator):
        """numba cache locator for GaussVDB's kernels: <cachedir.folder_for>/<numba's subpath>,
        stamped with the source file's content. Falls back to a private temporary folder if that
        one cannot be written."""

        def __init__(self, py_func, py_file, folder):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            # the real path: the extension is often a symlink to a checkout, under several folders
            self._cache_path = os.path.join(
                folder, self.get_suitable_cache_subpath(os.path.realpath(py_file)))

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            # the content, never the mtime (cachedir.source_digest): a reinstall keeps the entries
            return cachedir.source_digest(self._py_file)

        @classmethod
        def from_function(cls, py_func, py_file):
            folder = cachedir.folder_for(py_func.__module__, py_file)
            if folder is None or not os.path.exists(py_file):
                return None  # not ours: numba's own locators decide
            for base in (folder, os.path.join(tempfile.gettempdir(),
                                              f"gaussvdb-kernels-{_uid()}", os.path.basename(folder))):
                self = cls(py_func, py_file, base)
                try:
                    self.ensure_cache_path()
                    return self
                except OSError:
                    continue
            return None

    if KernelCacheLocator not in _caching.CacheImpl._locator_classes:
        _caching.CacheImpl._locator_classes.insert(0, KernelCacheLocator)


def _uid():
    return os.getuid() if hasattr(os, "getuid") else 0


_POOL = {}  # "pool": the threads parallel_for runs chunks on (grown to the most threads asked for)
_POOL_LOCK = threading.Lock()


def num_threads() -> int:
    """The calling thread's numba thread count (numba.set_num_threads, NUMBA_NUM_THREADS): how many
    threads parallel_for uses; 1 without numba."""
    return int(numba.get_num_threads()) if HAVE_NUMBA else 1


def thread_pool(helpers: int):
    """The shared pool of helper threads, with at least ``helpers`` of them."""
    from concurrent.futures import ThreadPoolExecutor

    with _POOL_LOCK:
        pool = _POOL.get("pool")
        if pool is None or pool._max_workers < helpers:
            pool = _POOL["pool"] = ThreadPoolExecutor(helpers, thread_name_prefix="gaussvdb-kernels")
        return pool


def run_on_threads(tasks: int, work, threads: int | None = None):
    """Calls ``work(t)`` for t in 0..tasks-1 on up to ``threads`` threads (default num_threads(),
    the caller one of them), each thread taking the next t when done with one; re-raises the first
    exception once all are done."""
    import itertools

    threads = num_threads() if threads is None else int(threads)
    helpers = max(1, min(threads, tasks)) - 1
    if helpers == 0:
        for t in range(tasks):
            work(t)
        return
    taken = itertools.count()  # (next() on it is atomic under the GIL)

    def loop():
        for t in iter(lambda: next(taken), None):
            if t >= tasks:
                return
            work(t)

    done = [thread_pool(helpers).submit(loop) for _ in range(helpers)]
    try:
        loop()
    finally:
        for f in done:
            # a helper still queued (the pool busy, or this a pool thread itself) has nothing
            # left to take: cancelled, never waited for
            if not f.cancel():
                f.result()


def parallel_for(kernel, n: int, *args, threads: int | None = None, chunks_per_thread: int = 4):
    """``kernel(lo, hi, *args)`` over chunks of [0, n) on up to ``threads`` threads: a serial
    kernel compiled with nogil=True that does indices lo..hi-1 of its loop. Chunks are about
    n / (threads * chunks_per_thread) indices, so uneven work still keeps every thread busy."""
    n = int(n)
    if n <= 0:
        return
    threads = num_threads() if threads is None else max(1, int(threads))
    nchunk = min(n, threads * chunks_per_thread) if threads > 1 else 1
    if nchunk == 1:
        kernel(np.int64(0), np.int64(n), *args)
        return
    edges = [n * c // nchunk for c in range(nchunk + 1)]
    run_on_threads(nchunk, lambda c: kernel(np.int64(edges[c]), np.int64(edges[c + 1]), *args), threads)
