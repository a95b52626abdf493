"""Blender (the bpy module) with this working tree enabled as the extension, for the CLI tools.

    from blender_session import start
    bpy = start()          # before anything else imports bpy

Like tests/conftest.py: BLENDER_USER_EXTENSIONS/CONFIG/SCRIPTS point at a private folder whose
`user_default/gaussvdb` is a symlink to the repository root, and `bl_ext.user_default.gaussvdb`
is enabled. The folder is private to this checkout (two checkouts run at once never load each
other's code) and stable, so Blender's set-up is reused from one run to the next. Compiled kernels
go to the per-user cache folder of kernels.cachedir, never into the source tree.
"""
from __future__ import annotations

import hashlib
import importlib
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MODULE = "bl_ext.user_default.gaussvdb"
_STARTED = {}


def session_dir() -> str:
    uid = os.getuid() if hasattr(os, "getuid") else 0
    tree = hashlib.sha1(os.path.realpath(ROOT).encode()).hexdigest()[:12]
    return os.path.join(tempfile.gettempdir(), f"gaussvdb-session-{uid}-{tree}")


def start():
    """Enable the extension from this working tree; returns the bpy module."""
    if "bpy" in _STARTED:
        return _STARTED["bpy"]
    if "bpy" in sys.modules:
        raise RuntimeError("blender_session.start() must run before bpy is imported")
    base = session_dir()
    # GAUSSVDB_BLENDER_EXTENSIONS lets the test suite share its folder (and so numba's cache).
    os.environ["BLENDER_USER_EXTENSIONS"] = os.environ.get("GAUSSVDB_BLENDER_EXTENSIONS") or \
        os.path.join(base, "extensions")
    os.environ["BLENDER_USER_CONFIG"] = os.path.join(base, "config")
    os.environ["BLENDER_USER_SCRIPTS"] = os.path.join(base, "scripts")
    if ROOT not in sys.path:
        sys.path.insert(0, ROOT)
    from kernels.cachedir import user_cache_root

    os.environ.setdefault("GAUSSVDB_CACHE_DIR", user_cache_root())
    repo = os.path.join(os.environ["BLENDER_USER_EXTENSIONS"], "user_default")
    os.makedirs(repo, exist_ok=True)
    link = os.path.join(repo, "gaussvdb")
    if os.path.islink(link) and os.path.realpath(link) != os.path.realpath(ROOT):
        os.unlink(link)  # the checkout was moved
    if not os.path.lexists(link):
        os.symlink(ROOT, link)
    import bpy  # noqa: I001  (bpy first: it puts addon_utils on the path)
    import addon_utils

    mod = addon_utils.enable(MODULE, default_set=True, handle_error=None)
    if mod is None:
        raise RuntimeError("the GaussVDB extension failed to enable")
    _STARTED["bpy"] = bpy
    return bpy


def kernels_module(name: str):
    """``kernels.<name>`` as this process compiles it: the extension's copy once start() ran
    (numba caches a kernel under the module name it was imported as, so reading a file with the
    plain ``kernels`` beside the extension compiled the reader twice, ~7 s of a cold render),
    else the plain package (convert, which never starts Blender)."""
    return importlib.import_module(f"{MODULE}.kernels.{name}" if "bpy" in _STARTED else f"kernels.{name}")


def compile_ahead(modes, threads=0, general=True) -> list:
    """On a cache without the render kernels of ``modes``: compile them now in a second process
    (the add-on's warmup_service.compile_ahead, under the extension's name), in that order, while
    this one reads the file (and builds its LOD); the render then waits for that process's jobs
    of its mode (final_render's wait_for_kernels) instead of compiling them too. ``general``: the
    render's scene may need more than a plain fog volume's kernels (warmup.jobs_for). Returns the
    jobs started. Call after start()."""
    warmup = importlib.import_module(f"{MODULE}.kernels.warmup")
    service = addon_module("gaussvdb_addon.engine.warmup_service")
    return service.compile_ahead(warmup.jobs_for(modes=tuple(modes), general=general), threads)


def addon_module(name: str):
    """A submodule of the enabled extension, e.g. addon_module('gaussvdb_addon.io.importer')."""
    return importlib.import_module(f"{MODULE}.{name}")
