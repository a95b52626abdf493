"""`./gaussvdb warmup`: compiles kernels into a cache that a later process of the same identity
(the one `./gaussvdb render` imports the extension under) loads without compiling."""

import json
import os
import subprocess
import sys

from conftest import COUNT_COMPILES, DATA_DIR, ROOT

CLI = [sys.executable, os.path.join(ROOT, "tools", "cli.py"), "warmup"]
SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")

# a later process: the kernels under the render command's identity, the same job, numba's own
# per-dispatcher counts of cache hits and misses (a miss is a compile)
CHECK = """
import json, os, sys
sys.path.insert(0, %(root)r)
sys.path.insert(1, os.path.join(%(root)r, "tools"))
from blender_session import MODULE
from kernels.warmup_boot import import_as
w = import_as(MODULE)
w.run(%(jobs)r)
from numba.core.dispatcher import Dispatcher
hits = misses = 0
for name, mod in list(sys.modules.items()):
    if not name.startswith(MODULE + ".kernels"):
        continue
    for value in vars(mod).values():
        d = getattr(value, "dispatcher", value)
        if isinstance(d, Dispatcher) and d.__module__ == name:
            hits += sum(d.stats.cache_hits.values())
            misses += sum(d.stats.cache_misses.values())
print(json.dumps({"hits": hits, "misses": misses, "module": w.__name__}))
"""


def _env(cache):
    env = dict(os.environ, GAUSSVDB_CACHE_DIR=str(cache))
    env.pop("NUMBA_CACHE_DIR", None)
    return env


def _run_cold(cmd, cache):
    """``cmd`` on the cache root ``cache``: (its last stdout line as JSON, the warm-up's status,
    the warm-up's folder) of the render command's identity."""
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900, env=_env(cache))
    assert r.returncode == 0, r.stderr[-3000:]
    warm = cache / "bl_ext.user_default.gaussvdb" / "warmup"
    return (json.loads(r.stdout.strip().splitlines()[-1]),
            json.loads((warm / "status.json").read_text()), warm)


def test_unknown_job_is_one_line(tmp_path):
    r = subprocess.run(CLI + ["--jobs", "lod:nope", "--cache-dir", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1
    assert "unknown warm-up job 'lod:nope'" in r.stderr


def test_warmup_then_a_later_process_compiles_nothing(tmp_path):
    cache = tmp_path / "kernels"
    r = subprocess.run(CLI + ["--jobs", "lod:low", "--cache-dir", str(cache)], capture_output=True,
                       text=True, timeout=900, env=_env(tmp_path / "elsewhere"))
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "bl_ext.user_default.gaussvdb" in lines[0] and "1 of 1 jobs to run" in lines[0]
    assert any(ln.strip().startswith("[1/1] lod:low") and ln.endswith(" s") for ln in lines)
    assert os.path.isdir(cache / "bl_ext.user_default.gaussvdb")
    # the marker: a second run has nothing to do
    again = subprocess.run(CLI + ["--jobs", "lod:low", "--cache-dir", str(cache)],
                           capture_output=True, text=True, timeout=300)
    assert "0 of 1 jobs to run" in again.stdout.splitlines()[0], again.stdout
    out = subprocess.run([sys.executable, "-c", CHECK % {"root": ROOT, "jobs": ["lod:low"]}],
                         capture_output=True, text=True, timeout=600, env=_env(cache))
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["module"] == "bl_ext.user_default.gaussvdb.kernels.warmup"
    assert got["hits"] > 0 and got["misses"] == 0, got


def test_render_on_an_empty_cache_compiles_its_render_kernels_in_a_second_process(tmp_path):
    """`./gaussvdb render` on an empty cache: the render mode's kernels compile in the warm-up
    process it starts beside the import (its status and marker say so), and the render waits
    for them rather than compiling them again (its own compile seconds stay near zero; a
    reference frame compiles ~10 s here)."""
    cache = tmp_path / "kernels"
    out = tmp_path / "x.png"
    stats, status, warm = _run_cold(
        [sys.executable, os.path.join(ROOT, "tools", "cli.py"), "render", SAMPLE, "--mode",
         "reference", "--size", "32x24", "--threads", "2", "--out", str(out), "--json"], cache)
    assert status["jobs"] == ["render:reference"] and status["state"] == "done", status
    assert any(p.name == "render-reference.done" for p in warm.rglob("*.done"))
    assert stats["seconds_compile"] < 2.0 and out.is_file()


# a Blender import (background mode) on an empty cache, with the field error
IMPORT = """
import json, os, sys
sys.path.insert(0, %(root)r)
sys.path.insert(1, os.path.join(%(root)r, "tools"))
from blender_session import MODULE, addon_module, start
bpy = start()
objs = addon_module("gaussvdb_addon.io.importer").import_vdb(%(file)r, lods=("low",))
from numba.core.dispatcher import Dispatcher
mixture = sys.modules[MODULE + ".kernels.lod.mixture"]
calls = {"hits": 0, "misses": 0}
for value in vars(mixture).values():
    d = getattr(value, "dispatcher", value)
    if isinstance(d, Dispatcher) and d.__module__ == mixture.__name__:
        calls["hits"] += sum(d.stats.cache_hits.values())
        calls["misses"] += sum(d.stats.cache_misses.values())
stats = addon_module("gaussvdb_addon.io.importer").object_stats(objs[0])
service = addon_module("gaussvdb_addon.engine.warmup_service")
jobs, running = list(service._state["jobs"]), service.running()
# an F12 in another mode than the scene's at the import: that process is stopped, not waited for
scene = bpy.context.scene
scene.gaussvdb.mode = "REFERENCE"
scene.render.engine = "GAUSSVDB"
scene.render.resolution_x, scene.render.resolution_y = 16, 12
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
cam.location = (0.0, -20.0, 0.0)
cam.rotation_euler = (1.5708, 0.0, 0.0)
scene.collection.objects.link(cam)
scene.camera = cam
bpy.ops.render.render()
print(json.dumps(dict(calls, nrmse=stats[0].get("nrmse"), jobs=jobs, running=running,
                      running_after=service.running())))
"""


def test_jobs_on_two_processes_leave_what_a_later_process_loads(tmp_path):
    """`--processes 2`: two jobs compile at once, each in a worker process of its own under the
    render command's identity; both leave their markers, and a later process loads their
    kernels without compiling."""
    cache = tmp_path / "kernels"
    jobs = ["lod:low", "render:paper"]
    r = subprocess.run(CLI + ["--jobs", ",".join(jobs), "--cache-dir", str(cache), "--processes", "2"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert sorted(ln.split()[1] for ln in r.stdout.splitlines() if ln.strip().startswith("[")) == jobs
    status = json.loads((cache / "bl_ext.user_default.gaussvdb" / "warmup" / "status.json").read_text())
    assert status["state"] == "done" and sorted(status["seconds"]) == jobs, status
    out = subprocess.run([sys.executable, "-c", CHECK % {"root": ROOT, "jobs": jobs}],
                         capture_output=True, text=True, timeout=600, env=_env(cache))
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["hits"] > 0 and got["misses"] == 0, got


def test_an_import_on_an_empty_cache_compiles_the_field_error_in_a_second_process(tmp_path):
    """An import in background mode (a script, `blender -b`) on an empty cache: the field
    error's kernels, then the render kernels of the scene's mode, compile in a warm-up process
    started beside the reader and the LOD (its status and marker say so); the import loads the
    error's from there rather than compiling them too (numba's cache hits, no miss, in the
    error's module); an F12 in another mode stops that process and compiles its own."""
    cache = tmp_path / "kernels"
    got, status, warm = _run_cold([sys.executable, "-c", IMPORT % {"root": ROOT, "file": SAMPLE}],
                                  cache)
    assert got["jobs"] == status["jobs"] == ["error", "render:particles"], (got, status)
    assert "error" in status.get("seconds", {}), status
    assert any(p.name == "error.done" for p in warm.rglob("*.done")), list(warm.rglob("*"))
    assert got["nrmse"] is not None and 0.0 < got["nrmse"] < 1.0, got
    assert got["hits"] > 0 and got["misses"] == 0, got
    if got["running"]:  # still compiling the particles kernels when the F12 began
        assert not got["running_after"], got


# the import's warm-up jobs, then imports of large files in the same process: what numba compiles
AFTER_WARM_UP = """
import json, sys
sys.path.insert(0, %(root)r)
from kernels import pipeline, warmup
warmup.run(["reader", "lod:medium", "error"])
%(count)sleaves = [len(g.leaf_origins) for f in %(files)r for g in pipeline.read_grids(f)[0]]
for f in %(files)r + [%(sample)r]:
    pipeline.convert_file(f, lods=("medium",), compute_error=True)
print(json.dumps({"compiled": compiled, "leaves": leaves}))
"""


def test_the_import_s_warm_up_covers_large_files(tmp_path):
    """The warm-up's files are small (a few dozen leaves); a real grid's import (thousands of
    leaves: the reader's threads, the field error's lattice classes), blosc-compressed (the
    written fixtures) or not (the bundled Mantaflow sample), runs no kernel they left
    uncompiled."""
    import numpy as np

    from tests.vdb_fixtures import write_grid

    x, y, z = np.meshgrid(*(np.linspace(-1.0, 1.0, 80),) * 3, indexing="ij")
    fog = write_grid(tmp_path / "fog.vdb", np.exp(-3.0 * (x * x + y * y + z * z)), tolerance=1e-3)
    files = [str(fog)] + [f for f in (os.path.join(DATA_DIR, "teapot_ls_256.vdb"),) if os.path.exists(f)]
    r = subprocess.run([sys.executable, "-c", AFTER_WARM_UP % {"root": ROOT, "files": files,
                                                                   "sample": SAMPLE,
                                                                   "count": COUNT_COMPILES}],
                       capture_output=True, text=True, timeout=900, env=_env(tmp_path / "cache"))
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert min(got["leaves"]) >= 512, got["leaves"]
    assert got["compiled"] == [], got["compiled"]


# the particles mode's warm-up, then a frame of a real grid's Gaussians: what numba compiles
FRAME_AFTER_WARM_UP = """
import json, sys
sys.path.insert(0, %(root)r)
import numpy as np
from kernels import pipeline, warmup
from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
warmup.run(["render:particles"])
cg = pipeline.convert_file(%(file)r, ["density"], lods=("medium",), compute_error=False)[0]
%(count)slo, hi = cg.leaf_box
img = CPUDevice(threads=2).render(RenderScene([RenderObject(cg.lods[0].gset, np.eye(4))]),
                                  Camera.frame_box(list(lo), list(hi), 32, 24),
                                  TransferFunction.from_colormap("viridis", 0.0, 1.0))
print(json.dumps({"compiled": compiled, "alpha": float(img["Combined"][..., 3].max())}))
"""


def test_the_render_warm_up_covers_a_real_grid_s_frame(tmp_path):
    """The particles job draws numpy-made Gaussians (no LOD kernel): a real grid's LOD, drawn
    after it, runs the kernels it compiled (the same array types, layouts included)."""
    r = subprocess.run([sys.executable, "-c", FRAME_AFTER_WARM_UP % {"root": ROOT, "file": SAMPLE,
                                                                         "count": COUNT_COMPILES}],
                       capture_output=True, text=True, timeout=900, env=_env(tmp_path / "cache"))
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert got["alpha"] > 0.1, got  # the smoke was drawn
    assert got["compiled"] == [], got["compiled"]
