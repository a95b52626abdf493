"""Test set-up: real Blender (the bpy module), isolated from any installed copy of the extension.
The tests are split by layer: kernels/ (no Blender), blender/ (the add-on), e2e/ (the command line).

Kernel tests never touch bpy. Blender tests use the `addon` fixture (the working tree enabled as the
extension `bl_ext.user_default.gaussvdb`) and the `scene` fixture (a factory-fresh empty scene).
"""

import atexit
import os
import shutil
import sys
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA_DIR = os.path.join(os.path.dirname(ROOT), "shared", "data")
SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")
ADDON_MODULE = "bl_ext.user_default.gaussvdb"

# a child process's script: from here on, the functions numba compiles land in `compiled` (their
# qualified names; loading one from the cache is no compile)
COUNT_COMPILES = """
from numba.core import event
compiled = []

class Count(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)

    def on_end(self, ev):
        pass

event.register("numba:compile", Count())
"""
# The suite is split by layer (kernels/, blender/, e2e/); a test may use another layer's helpers
# (test_engine_helpers, ...) and the shared fixtures here, whichever folder pytest collects first.
sys.path[:0] = [os.path.join(ROOT, "tests", d) for d in ("kernels", "blender", "e2e")] + [
    os.path.join(ROOT, "tests")]

# Before any `import bpy`: our own user config and extensions folder, so an installed copy of the
# extension (or of its wheels) never shadows the working tree, and the tests never touch the user's.
# The extensions folder is fixed (not temporary): numba keys its on-disk cache by source path, so a
# stable path lets later sessions reuse the compiled kernels.
_TMP = tempfile.mkdtemp(prefix="gaussvdb-tests-")  # this session's Blender config: removed at exit
atexit.register(shutil.rmtree, _TMP, True)
os.environ["BLENDER_USER_EXTENSIONS"] = os.path.join(ROOT, ".pytest_cache", "blender_extensions")
os.environ["BLENDER_USER_CONFIG"] = os.path.join(_TMP, "config")
os.environ["BLENDER_USER_SCRIPTS"] = os.path.join(_TMP, "scripts")
# Compiled kernels: the per-user cache folder (never the source tree); kernels.cachedir keeps
# each importing identity (`kernels`, `bl_ext...gaussvdb.kernels`) and source version apart.
from kernels.cachedir import user_cache_root  # noqa: E402

os.environ.setdefault("GAUSSVDB_CACHE_DIR", user_cache_root())


def shared_data_files():
    """The real .vdb files beside the repository (may be absent on a bare clone)."""
    if not os.path.isdir(DATA_DIR):
        return []
    return sorted(os.path.join(DATA_DIR, f) for f in os.listdir(DATA_DIR) if f.endswith(".vdb"))


@pytest.fixture(scope="session")
def bpy_module():
    import bpy

    return bpy


@pytest.fixture(scope="session")
def addon(bpy_module):
    """The working tree enabled as the installed extension would be (a linked user repository)."""
    import addon_utils

    repo = os.path.join(os.environ["BLENDER_USER_EXTENSIONS"], "user_default")
    os.makedirs(repo, exist_ok=True)
    link = os.path.join(repo, "gaussvdb")
    if not os.path.lexists(link):
        os.symlink(ROOT, link)
    module = addon_utils.enable(ADDON_MODULE, default_set=True, handle_error=None)
    assert module is not None, "the extension failed to enable"
    yield sys.modules[ADDON_MODULE]
    addon_utils.disable(ADDON_MODULE, default_set=True)


@pytest.fixture(scope="module")
def gpu(addon):
    """The GPU device; skips where no GPU context can be had (the probe is a child process: a
    machine without EGL aborts it, not this one)."""
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu import device, probe

    ok, why = probe.probe()
    if not ok:
        pytest.skip(f"no GPU context here: {why}")
    return device.GPUDevice()


@pytest.fixture(scope="module")
def cpu():
    """A CPU device of the test module's own."""
    from kernels.render import CPUDevice

    return CPUDevice()


@pytest.fixture
def scene(addon, bpy_module):
    """A factory-fresh empty scene (the temporary config has no startup file), add-on kept enabled."""
    bpy_module.ops.wm.read_homefile(use_empty=True)
    return bpy_module.context.scene


def _copy_tree(dst):
    """The working tree's files (tracked, and untracked but not ignored) copied to ``dst``: what a
    fresh clone of it holds, without .venv, caches or build outputs."""
    import shutil
    import subprocess

    shutil.rmtree(dst, ignore_errors=True)
    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT,
                            capture_output=True, check=True).stdout.split(b"\0")
    for rel in filter(None, (p.decode() for p in listed)):
        src = os.path.join(ROOT, rel)
        if os.path.isfile(src):
            os.makedirs(os.path.dirname(os.path.join(dst, rel)), exist_ok=True)
            shutil.copy2(src, os.path.join(dst, rel))
    return dst


def run_cli(root, *args, env=None, timeout=900):
    """``./gaussvdb ARGS`` of the checkout at ``root`` with this interpreter; CompletedProcess."""
    import subprocess

    return subprocess.run([sys.executable, os.path.join(root, "tools", "cli.py"), *args], cwd=root,
                          env=env, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="session")
def fresh_clone(tmp_path_factory):
    """A fresh copy of the working tree in which `render` ran first (the order that used to leave
    extension-named kernel caches for the plain-Python commands), then `convert` and `info`, each
    in its own process with the environment a user has (no Blender folders of the suite's).
    Returns (root, env, {command: CompletedProcess}, tmp). The copy's path is stable per checkout
    so its compiled kernels are reused from one run of the suite to the next."""
    import hashlib

    tag = hashlib.sha1(os.path.realpath(ROOT).encode()).hexdigest()[:12]
    root = _copy_tree(os.path.join(tempfile.gettempdir(), f"gaussvdb-clone-{tag}"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("BLENDER_USER_")}
    tmp = tmp_path_factory.mktemp("clone_out")
    sample = os.path.join(root, "samples", os.path.basename(SAMPLE))
    runs = {}
    runs["render"] = run_cli(root, "render", sample, "--lod", "low", "--mode", "particles",
                             "--size", "64x64", "--out", str(tmp / "a.png"), "--json", env=env)
    runs["convert"] = run_cli(root, "convert", sample, "--lod", "high", "--json", env=env)
    runs["info"] = run_cli(root, "info", sample, env=env)
    return root, env, runs, tmp
