"""The kernels' compiled caches and parallel launches are safe whoever imports them.

- The same kernel files are imported as `kernels` (CLI, benchmarks, tests) and as
  `bl_ext.user_default.gaussvdb.kernels` (the extension); numba pickles module names into its
  cache entries, so the two must never load each other's (kernels/cachedir.py).
- No command writes compiled caches into the source tree.
- No kernel is a numba parallel loop (kernels/jit.py: they compile slowly, and two threads in
  them at once abort the process under numba's workqueue layer); renders on several threads at
  once share the launcher's threads and draw what each draws alone.
"""
import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from conftest import ROOT, SAMPLE

KERNELS = os.path.join(ROOT, "kernels")


def _run(code, env=None, timeout=900):
    env = dict(os.environ, **(env or {}))
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"rc {r.returncode}\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}"
    return r.stdout


def _compiled_files_in(folder):
    out = []
    for d, dirs, files in os.walk(folder):
        dirs[:] = [x for x in dirs if x not in (".venv", ".git", "wheels", "dist")]
        out += [os.path.join(d, f) for f in files if f.endswith((".nbi", ".nbc"))]
    return out


def test_kernel_modules_compile_through_jit():
    """Every kernel module takes njit from kernels.jit (its cache locator applies), never straight
    from numba, and none is a parallel loop (prange, parallel=True: kernels.jit.parallel_for)."""
    bad = []
    for d, _dirs, files in os.walk(KERNELS):
        for f in files:
            if not f.endswith(".py") or f == "jit.py":
                continue
            src = open(os.path.join(d, f), encoding="utf-8").read()
            if re.search(r"from numba import [^\n]*\b(njit|jit|prange)\b", src) or \
                    re.search(r"\bnumba\.(njit|jit)\(", src) or "parallel=True" in src or \
                    re.search(r"\b(prange|parallel_njit)\b", src):
                bad.append(os.path.relpath(os.path.join(d, f), ROOT))
    assert not bad, f"compile through kernels.jit instead: {bad}"


def test_cache_folders_per_identity(tmp_path):
    from kernels import cachedir

    f = os.path.join(KERNELS, "lod", "schemes.py")
    plain = cachedir.folder_for("kernels.lod.schemes", f)
    ext = cachedir.folder_for("bl_ext.user_default.gaussvdb.kernels.lod.schemes", f)
    assert plain != ext and os.path.basename(plain) == os.path.basename(ext)
    assert os.path.basename(os.path.dirname(plain)) == "kernels"
    assert os.path.basename(os.path.dirname(ext)) == "bl_ext.user_default.gaussvdb"
    assert os.path.basename(plain).startswith("lod-")
    # not ours: numba's own locators decide
    assert cachedir.folder_for("numpy.foo", np.__file__) is None
    other = tmp_path / "kernels" / "x.py"
    other.parent.mkdir()
    other.write_text("")
    assert cachedir.folder_for("kernels.x", str(other)) is None
    # an edit to a subpackage's sources moves its kernels to a new folder
    assert cachedir.sources_tag("lod") != cachedir.sources_tag("render")


_READ = """
    import sys, numpy as np
    sys.path.insert(0, {root!r})
    from kernels.vdb import read_vdb
    from kernels.lod import build_lod
    g = read_vdb({path!r}).grids[0]
    gs = build_lod(g, "medium")
    print("SUM", len(gs.sigmas), float(np.asarray(gs.values, np.float64).sum()))
"""

_READ_EXT = """
    import os, sys
    base = {base!r}
    os.environ["BLENDER_USER_EXTENSIONS"] = os.path.join(base, "extensions")
    os.environ["BLENDER_USER_CONFIG"] = os.path.join(base, "config")
    os.environ["BLENDER_USER_SCRIPTS"] = os.path.join(base, "scripts")
    repo = os.path.join(base, "extensions", "user_default")
    os.makedirs(repo, exist_ok=True)
    if not os.path.lexists(os.path.join(repo, "gaussvdb")):
        os.symlink({root!r}, os.path.join(repo, "gaussvdb"))
    import bpy, addon_utils, numpy as np
    assert addon_utils.enable("bl_ext.user_default.gaussvdb", default_set=True, handle_error=None)
    assert "kernels" not in sys.modules
    from bl_ext.user_default.gaussvdb.kernels.vdb import read_vdb
    from bl_ext.user_default.gaussvdb.kernels.lod import build_lod
    g = read_vdb({path!r}).grids[0]
    gs = build_lod(g, "medium")
    print("SUM", len(gs.sigmas), float(np.asarray(gs.values, np.float64).sum()))
"""


@pytest.mark.slow
def test_two_identities_share_one_cache_folder(tmp_path):
    """Plain Python, then the extension, then plain Python again, one cache root: every process
    loads what it can and gets the same Gaussians; both identities keep their own entries."""
    root = os.environ["GAUSSVDB_CACHE_DIR"]
    plain = _READ.format(root=ROOT, path=SAMPLE)
    ext = _READ_EXT.format(root=ROOT, path=SAMPLE, base=str(tmp_path / "blender"))
    outs = [_run(plain), _run(ext), _run(plain)]
    sums = [o[o.index("SUM"):].strip() for o in outs]
    assert sums[0] == sums[1] == sums[2]
    assert os.path.isdir(os.path.join(root, "kernels"))
    assert os.path.isdir(os.path.join(root, "bl_ext.user_default.gaussvdb"))
    assert not _compiled_files_in(ROOT), "compiled kernels were written into the source tree"


_CONCURRENT = """
    import sys, threading, numpy as np
    sys.path.insert(0, {root!r})
    from kernels.render import Camera, RenderObject, RenderScene, TransferFunction, get_device
    from kernels.render.scene.synthetic import gaussian_set, grid_from_dense

    rng = np.random.default_rng(7)
    c = rng.uniform(0, 24, (400, 3))
    gs = gaussian_set(c, rng.uniform(0.6, 2.0, (400, 3)), rng.uniform(0.2, 1.0, 400))
    grid = grid_from_dense(rng.uniform(0, 1, (24, 24, 24)))
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.0, alpha="ramp", density=0.4)
    m = np.eye(4)
    m[:3, 3] = [12, 12, 70]
    cam = Camera(m, 96, 64, "persp", fov_x=0.6)
    scenes = [RenderScene([RenderObject(gaussians=gs)], mode="particles", threads=2),
              RenderScene([RenderObject(grid=grid)], mode="reference", threads=2)]
    solo = [get_device("CPU").render(s, cam, tf)["Combined"] for s in scenes]
    out, errors = {{}}, []

    def work(k):
        try:
            dev = get_device("CPU")
            out[k] = [dev.render(scenes[k % 2], cam, tf)["Combined"] for _ in range(3)]
        except BaseException as e:
            errors.append(repr(e))

    ts = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors, errors
    for k, imgs in out.items():
        for img in imgs:
            assert np.array_equal(img, solo[k % 2]), k
    print("OK", len(out), float(solo[0][..., 3].sum()), float(solo[1][..., 3].sum()))
"""


@pytest.mark.slow
def test_concurrent_renders_under_workqueue():
    """Four threads render at once (particles and reference, 2 threads each) under the workqueue
    layer: no abort, and every image equals the one rendered alone."""
    out = _run(_CONCURRENT.format(root=ROOT), env={"NUMBA_THREADING_LAYER": "workqueue"})
    line = out[out.index("OK"):].split()
    assert line[1] == "4" and float(line[2]) > 1.0 and float(line[3]) > 1.0
