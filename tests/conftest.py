"""Test set-up: real Blender (the bpy module), isolated from any installed copy of the extension.

Kernel tests never touch bpy. Blender tests use the `addon` fixture (the working tree enabled as the
extension `bl_ext.user_default.gaussvdb`) and the `scene` fixture (a factory-fresh empty scene).
"""

import os
import sys
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA_DIR = os.path.join(os.path.dirname(ROOT), "shared", "data")
SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")
ADDON_MODULE = "bl_ext.user_default.gaussvdb"

# Before any `import bpy`: our own user config and extensions folder, so an installed copy of the
# extension (or of its wheels) never shadows the working tree, and the tests never touch the user's.
# The extensions folder is fixed (not temporary): numba keys its on-disk cache by source path, so a
# stable path lets later sessions reuse the compiled kernels.
_TMP = tempfile.mkdtemp(prefix="gaussvdb-tests-")
os.environ["BLENDER_USER_EXTENSIONS"] = os.path.join(ROOT, ".pytest_cache", "blender_extensions")
os.environ["BLENDER_USER_CONFIG"] = os.path.join(_TMP, "config")
os.environ["BLENDER_USER_SCRIPTS"] = os.path.join(_TMP, "scripts")
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(ROOT, ".pytest_cache", "numba"))


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


@pytest.fixture
def scene(addon, bpy_module):
    """A factory-fresh empty scene (the temporary config has no startup file), add-on kept enabled."""
    bpy_module.ops.wm.read_homefile(use_empty=True)
    return bpy_module.context.scene
