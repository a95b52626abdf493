"""Where compiled kernels are cached (numba-free, so registration can set it without numba).

numba names a cache file after the source file, not the module, and pickles module names into the
entry. The same file imported as `kernels.x` (CLI, benchmarks, tests) and as
`bl_ext.<repo>.gaussvdb.kernels.x` (the extension) would therefore share entries that only one of
the two can load. So every entry lives under a folder per importing identity and per version of
its subpackage's sources (the kernels call across files; numba only checks a function's own file):

    <root>/<identity>/<subpackage>-<sources hash>/<numba's per-folder subpath>/...

Within a folder, numba keeps an entry while its function's file has the stamp recorded with it;
ours is the file's content (``source_digest``), never its mtime: reinstalling the extension (the
same files written again) keeps every entry, on every numba (numba before 0.68 stamps (mtime,
size); 0.68 hashes the content as we do, with the same value).

The root is never the source tree: ``set_cache_root()`` (the extension passes its user folder),
else ``GAUSSVDB_CACHE_DIR``, else ``NUMBA_CACHE_DIR``, else the user's cache folder.
"""
from __future__ import annotations

import hashlib
import os
import sys

_KERNELS = os.path.dirname(os.path.abspath(__file__))
_state = {"root": None}
_tags: dict[str, str] = {}
_digests: dict[str, bytes] = {}


def user_cache_root() -> str:
    """The platform's per-user cache folder for GaussVDB's kernels."""
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA") or os.path.expanduser("~\\AppData\\Local")
    elif sys.platform == "darwin":
        base = os.path.expanduser("~/Library/Caches")
    else:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
    return os.path.join(base, "gaussvdb", "kernels")


def set_cache_root(path: str | None) -> None:
    """Cache kernels compiled from now on under ``path`` (None: back to the default rule).
    Kernels already imported in this process keep their folder."""
    _state["root"] = os.path.abspath(path) if path else None


def cache_root() -> str:
    return (_state["root"] or os.environ.get("GAUSSVDB_CACHE_DIR")
            or os.environ.get("NUMBA_CACHE_DIR") or user_cache_root())


def identity(module: str, source_file: str) -> str | None:
    """The package that imported the kernels ('kernels', or 'bl_ext.user_default.gaussvdb' for
    the extension), or None when ``source_file`` is not one of ours (numba asks for every cached
    function of the process)."""
    real = os.path.realpath(os.path.abspath(source_file))
    if not real.startswith(os.path.realpath(_KERNELS) + os.sep):
        return None
    if module == "kernels" or module.startswith("kernels."):
        return "kernels"
    head, sep, _ = module.partition(".kernels.")
    return head if sep else None


# the kernel subpackages that hold compiled kernels ("top": the files directly in kernels/)
SUBPACKAGES = ("top", "vdb", "lod", "render")


def sources_tag(subpackage: str) -> str:
    """Hash of the .py files of one kernel subpackage (e.g. 'render'), computed once a process."""
    tag = _tags.get(subpackage)
    if tag is None:
        h = hashlib.sha1()
        folder = os.path.join(_KERNELS, subpackage)
        for here, dirs, names in sorted(os.walk(folder)):  # its subpackages too (render/cpu, ...)
            dirs.sort()
            for name in sorted(names):
                if name.endswith(".py"):
                    rel = os.path.relpath(os.path.join(here, name), folder)
                    with open(os.path.join(here, name), "rb") as fh:
                        h.update(rel.encode() + b"\0" + fh.read())
        tag = _tags[subpackage] = h.hexdigest()[:12]
    return tag


def source_digest(path: str) -> bytes:
    """sha256 of a source file's bytes, read once a process: the stamp of its cached kernels
    (numba 0.68's own value for the same file, so entries it wrote stay valid)."""
    real = os.path.realpath(path)
    digest = _digests.get(real)
    if digest is None:
        with open(real, "rb") as fh:
            digest = _digests[real] = hashlib.sha256(fh.read()).digest()
    return digest


def folder_for(module: str, source_file: str) -> str | None:
    """The cache folder of a kernel defined in ``module`` (file ``source_file``), or None."""
    who = identity(module, source_file)
    if who is None:
        return None
    rel = os.path.relpath(os.path.realpath(source_file), os.path.realpath(_KERNELS))
    sub = rel.split(os.sep)[0] if os.sep in rel else "top"
    return os.path.join(cache_root(), who, f"{sub}-{sources_tag(sub)}")
