"""Can this process get a GPU context without aborting? Inside Blender's UI: yes (it draws with
one). In background mode (``blender -b``, the bpy module) a machine without a usable EGL/GL aborts
the whole process when a render engine asks for a context, so a child process tries first: it
renders a 4x4 frame with an engine that asks for one and runs a compute shader there.

The child runs once per process, on a thread of its own: ``start()`` returns at once, ``answer()``
never waits, ``probe()`` waits (at a render, never in a property update). The answer is read as
soon as the child prints it: some Blender releases (4.5) hang at interpreter exit, so the child
ends itself with ``os._exit`` and a child that does not is stopped."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

PROBE_SECONDS = 90  # the child imports Blender: seconds on a loaded machine
EXIT_SECONDS = 2  # after its answer, how long the child may take to end before it is stopped
MARK = "GAUSSVDB_GPU_PROBE"  # the child's answer line starts with it

_STATE = {"answer": None, "thread": None}
_LOCK = threading.Lock()

# Only what Blender 4.5-5.2 all have: create-info compute shaders (4.5+ require GPUs with them).
_CHILD = r'''
import os, sys
import bpy, gpu
got = {}
class P(bpy.types.RenderEngine):
    bl_idname = "GAUSSVDB_GPU_PROBE"
    bl_label = "probe"
    bl_use_gpu_context = True
    def render(self, depsgraph):
        try:
            info = gpu.types.GPUShaderCreateInfo()
            info.image(0, "RGBA32F", "FLOAT_2D", "img", qualifiers={"WRITE"})
            info.compute_source("void main() { imageStore(img, ivec2(gl_GlobalInvocationID.xy), vec4(1.0)); }")
            info.local_group_size(1, 1)
            sh = gpu.shader.create_from_info(info)
            tex = gpu.types.GPUTexture((1, 1), format="RGBA32F")
            sh.bind()
            sh.image("img", tex)
            gpu.compute.dispatch(sh, 1, 1, 1)
            buf = tex.read()
            buf.dimensions = 4
            got["ok"] = buf[0] == 1.0
            got["name"] = gpu.platform.renderer_get()
        except Exception as err:
            got["why"] = f"{type(err).__name__}: {err}"
bpy.utils.register_class(P)
sc = bpy.context.scene
sc.render.engine = P.bl_idname
sc.render.resolution_x = sc.render.resolution_y = 4
cam = bpy.data.objects.new("c", bpy.data.cameras.new("c"))
sc.collection.objects.link(cam)
sc.camera = cam
bpy.ops.render.render()
print("GAUSSVDB_GPU_PROBE", "ok" if got.get("ok") else "no", got.get("name") or got.get("why", "no result"))
sys.stdout.flush()
os._exit(0)
'''


def _command():
    import bpy

    if bpy.app.binary_path and os.path.basename(bpy.app.binary_path).lower().startswith("blender"):
        return [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1",
                "--python-expr", _CHILD]
    return [sys.executable, "-c", _CHILD]  # the bpy module


def start():
    """Begin probing (once per process) and return at once."""
    if not _background():
        return
    with _LOCK:
        if _STATE["answer"] is None and _STATE["thread"] is None:
            _STATE["thread"] = threading.Thread(target=_run, args=(_command(),),
                                                name="gaussvdb-gpu-probe", daemon=True)
            _STATE["thread"].start()


def answer():
    """(ok, text) once known, else None; never waits."""
    if _STATE["answer"] is None and not _background():
        _STATE["answer"] = _in_ui()
    return _STATE["answer"]


def probe(timeout=PROBE_SECONDS + EXIT_SECONDS + 5):
    """(ok, text): whether a GPU context with compute shaders can be had, and the GPU's name
    (or why not). Waits for the child's answer: call it where a render needs one."""
    if answer() is None:
        start()
        _STATE["thread"].join(timeout)
    return _STATE["answer"] or (False, f"the GPU probe gave no answer within {timeout:.0f} s")


def _background():
    import bpy

    return bpy.app.background


def _in_ui():
    import gpu

    try:
        return True, gpu.platform.renderer_get()
    except Exception as err:  # noqa: BLE001  (no GPU module state: say so, not fail)
        return False, f"{type(err).__name__}: {err}"[:120]


def _run(cmd, seconds=PROBE_SECONDS):
    _STATE["answer"] = run_child(cmd, seconds)


def run_child(cmd, seconds=PROBE_SECONDS, exit_seconds=EXIT_SECONDS):
    """Run the probe command ``cmd``; (ok, text) from its MARK line as soon as it prints it, or a
    one-line reason. The child is stopped if it is still running ``exit_seconds`` after its
    answer, or ``seconds`` after its start."""
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                errors="replace")
    except OSError as err:
        return False, f"the GPU probe did not run ({err})"[:160]
    timed_out = threading.Event()
    timer = threading.Timer(seconds, lambda: (timed_out.set(), proc.kill()))
    timer.start()
    verdict, last = None, ""
    try:
        for line in proc.stdout:  # ends at the child's exit, or when the timer stops it
            if line.startswith(MARK):
                _, ok, name = (line.split(" ", 2) + ["", ""])[:3]
                verdict = (ok == "ok", name.strip()[:120])
                break
            if line.strip() and "EGL Error" not in line:
                last = line.strip()
        if verdict is not None:
            try:
                proc.wait(exit_seconds)
            except subprocess.TimeoutExpired:
                proc.kill()
    finally:
        timer.cancel()
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        proc.stdout.close()
    if verdict is not None:
        return verdict
    if timed_out.is_set():
        return False, f"the GPU probe gave no answer within {seconds:.0f} s"
    return False, f"no GPU context: a probe process exited with {proc.returncode} ({last[:120] or 'no output'})"
