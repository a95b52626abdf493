"""How every kernel is compiled: ``njit``/``prange`` (numba, or plain Python without it), the
on-disk cache located per importing identity (see cachedir.py), and ``parallel_njit``, whose
Python calls hold one process-wide lock.

The lock: under numba's workqueue threading layer (what numba falls back to without TBB or
OpenMP, e.g. on stock macOS) two threads inside parallel regions at once abort the process
("Concurrent access has been detected"). The viewport worker and a final render can do exactly
that, so parallel kernels launch one at a time on every layer; the serial, nogil kernels do not
need it. Parallel kernels are entry points: they are called from Python, never from other kernels.

One signature per kernel: numba compiles a kernel again for every distinct argument type its
callers pass, and a literal is a type of its own (f(x, 8) and f(x, n) compile f twice; so do a
read-only and a writable array). Call sites pass np.int64(8), and files map writable.
"""
from __future__ import annotations

import functools
import os
import tempfile
import threading

from . import cachedir

PARALLEL_LOCK = threading.RLock()

try:
    import numba
    from numba import njit, prange
    from numba.core import caching as _caching
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - numba is optional for the reader
    HAVE_NUMBA = False
    prange = range

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


class ParallelKernel:
    """A ``parallel=True`` dispatcher called under PARALLEL_LOCK; attributes (py_func,
    signatures, ...) are the dispatcher's."""

    def __init__(self, dispatcher):
        self.dispatcher = dispatcher
        functools.update_wrapper(self, getattr(dispatcher, "py_func", dispatcher))

    def __call__(self, *args, **kwargs):
        with PARALLEL_LOCK:
            return self.dispatcher(*args, **kwargs)

    def __getattr__(self, name):
        return getattr(self.dispatcher, name)


def parallel_njit(**options):
    """``njit(parallel=True, **options)`` whose Python calls launch one at a time."""
    def wrap(fn):
        return ParallelKernel(njit(parallel=True, **options)(fn))
    return wrap


def threading_layer() -> str:
    """The threading layer numba chose (known after the first parallel launch), or '' ."""
    try:
        return numba.threading_layer()
    except Exception:  # noqa: BLE001  (none chosen yet, or no numba)
        return ""
