"""The GPU probe never blocks: its answer is read as soon as the child prints it, a child that
never exits (Blender 4.5's bpy module hangs at interpreter exit) or never answers is stopped, the
reason is one short line, and choosing the GPU device in background mode waits on nothing."""
import json
import os
import subprocess
import sys
import textwrap
import time

HANG = "import time; time.sleep(600)"


def _probe_module():
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu import probe

    return probe


def test_the_answer_comes_as_soon_as_the_child_prints_though_it_never_exits(addon):
    probe = _probe_module()
    child = [sys.executable, "-c", f"print('noise'); print('{probe.MARK} ok Some GPU 1.0', flush=True); {HANG}"]
    t0 = time.perf_counter()
    got = probe.run_child(child, seconds=60, exit_seconds=1)
    took = time.perf_counter() - t0
    assert got == (True, "Some GPU 1.0")
    assert took < 5, f"the probe took {took:.1f} s"


def test_a_child_that_never_answers_is_stopped_with_one_short_line(addon):
    probe = _probe_module()
    t0 = time.perf_counter()
    ok, why = probe.run_child([sys.executable, "-c", f"print('starting', flush=True); {HANG}"], seconds=2)
    assert time.perf_counter() - t0 < 5
    assert not ok and why == "the GPU probe gave no answer within 2 s"


def test_a_child_that_fails_is_reported_in_one_line_without_the_script(addon):
    probe = _probe_module()
    ok, why = probe.run_child([sys.executable, "-c", probe._CHILD.replace("import bpy, gpu", "import bpy_nope")])
    assert not ok and "\n" not in why and len(why) < 300
    assert "ModuleNotFoundError" in why and "GAUSSVDB_GPU_PROBE" not in why, why


CHOOSE_THEN_RENDER = textwrap.dedent(r"""
    import json, os, sys, time
    import bpy, addon_utils
    addon_utils.enable("bl_ext.user_default.gaussvdb", default_set=True, handle_error=None)
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu import probe
    sc = bpy.context.scene
    assert probe.answer() is None
    t0 = time.perf_counter()
    sc.gaussvdb.device = "GPU"  # starts the probe, waits for nothing
    choose = time.perf_counter() - t0
    print("RESULT" + json.dumps({"choose_s": choose, "answered": probe.answer() is not None}))
    sys.stdout.flush()
    os._exit(0)
""")


def test_choosing_the_gpu_device_waits_on_no_child_process(addon, tmp_path):
    env = dict(os.environ, BLENDER_USER_CONFIG=str(tmp_path / "config"),
               BLENDER_USER_SCRIPTS=str(tmp_path / "scripts"))
    proc = subprocess.run([sys.executable, "-c", CHOOSE_THEN_RENDER], env=env, capture_output=True,
                          text=True, timeout=300)
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT")]
    assert line, proc.stdout[-2000:] + proc.stderr[-2000:]
    out = json.loads(line[-1][len("RESULT"):])
    # the child imports Blender (seconds): an update that waited for it could not be this quick
    assert out["choose_s"] < 0.5 and not out["answered"], out
