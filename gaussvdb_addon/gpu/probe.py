"""Can this process get a GPU context without aborting? Inside Blender's UI: yes (it draws with
one). In background mode (``blender -b``, the bpy module) a machine without a usable EGL/GL aborts
the whole process when a render engine asks for a context, so a child process tries first: it
renders a 4x4 frame with an engine that asks for one and runs a compute shader there. The answer
is cached per process."""
from __future__ import annotations

import os
import subprocess
import sys

PROBE_SECONDS = 90
_ANSWER = {}
MARK = "GAUSSVDB_GPU_PROBE"  # the child's answer line starts with it

_CHILD = r'''
import bpy, gpu
got = {}
class P(bpy.types.RenderEngine):
    bl_idname = "GAUSSVDB_GPU_PROBE"
    bl_label = "probe"
    bl_use_gpu_context = True
    def render(self, depsgraph):
        if not gpu.capabilities.compute_shader_support_get():
            got["why"] = "no compute shaders"
            return
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
bpy.utils.register_class(P)
sc = bpy.context.scene
sc.render.engine = P.bl_idname
sc.render.resolution_x = sc.render.resolution_y = 4
cam = bpy.data.objects.new("c", bpy.data.cameras.new("c"))
sc.collection.objects.link(cam)
sc.camera = cam
bpy.ops.render.render()
print("GAUSSVDB_GPU_PROBE", "ok" if got.get("ok") else "no", got.get("name") or got.get("why", "no result"))
'''


def _command():
    import bpy

    code = _CHILD
    if bpy.app.binary_path and os.path.basename(bpy.app.binary_path).lower().startswith("blender"):
        return [bpy.app.binary_path, "-b", "--factory-startup", "--python-exit-code", "1",
                "--python-expr", code]
    return [sys.executable, "-c", code]  # the bpy module


def probe():
    """(ok, text): whether a GPU context with compute shaders can be had, and the GPU's name
    (or why not)."""
    if "answer" in _ANSWER:
        return _ANSWER["answer"]
    import bpy

    if not bpy.app.background:
        import gpu

        try:
            ok = gpu.capabilities.compute_shader_support_get()
            answer = (bool(ok), gpu.platform.renderer_get() if ok else "no compute shaders")
        except Exception as err:  # noqa: BLE001  (no GPU module state: say so, not fail)
            answer = (False, str(err))
    else:
        answer = _child()
    _ANSWER["answer"] = answer
    return answer


def _child():
    try:
        res = subprocess.run(_command(), capture_output=True, text=True, timeout=PROBE_SECONDS)
    except (OSError, subprocess.SubprocessError) as err:
        return False, f"the GPU probe did not run ({err})"
    for line in res.stdout.splitlines():
        if line.startswith(MARK):
            _, verdict, name = (line.split(" ", 2) + ["", ""])[:3]
            return verdict == "ok", name.strip()
    lines = [ln for ln in res.stderr.splitlines() if ln.strip() and "EGL Error" not in ln]
    tail = lines[-1].strip() if lines else "no output"
    return False, f"no GPU context: a probe process exited with {res.returncode} ({tail[:120]})"
