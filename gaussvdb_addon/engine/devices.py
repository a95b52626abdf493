"""The render devices of the engine: which one a render uses, making one, and the process-wide
ones of final renders (acceleration reused across frames).

    device = devices.final_device("CPU")            # made once a process
    name = devices.chosen_device(engine, scene)     # "GPU" only where it can run, else "CPU"
"""

import sys

_FINAL = {}  # name -> the device of final renders in this process


def new_device(name="CPU"):
    """A CPU (or GPU) device (its kernels cached where registration pointed kernels.cachedir)."""
    from ...kernels.render import get_device as kernel_device

    if name == "GPU":
        from ..gpu import device  # noqa: F401  (registers the GPU device)
    return kernel_device(name)


def final_device(name="CPU"):
    """The process-wide device of final renders (made on first use; a frame loads the kernels
    it needs with load_kernels before it is timed)."""
    if name not in _FINAL:
        _FINAL[name] = new_device(name)
    return _FINAL[name]


def gpu_usable(engine_class):
    """(ok, text): whether a render now can run the GPU device: the probe passed and the
    engine class was registered with a GPU context (gpu_choice)."""
    from ..gpu import probe

    ok, text = probe.probe()
    if ok and not getattr(engine_class, "bl_use_gpu_context", False):
        return False, "the render engine was registered without a GPU context"
    return ok, text


def chosen_device(engine, scene):
    """The device name this render uses: the scene's choice, or CPU with a one-line warning
    when the GPU device cannot run here."""
    if scene.gaussvdb.device != "GPU":
        return "CPU"
    ok, why = gpu_usable(type(engine))
    if ok:
        return "GPU"
    import bpy

    msg = f"GaussVDB: the GPU device is not available ({why}); rendering on the CPU"
    if not bpy.app.background:  # (in background mode the report prints itself)
        print(msg, file=sys.stderr)
    engine.report({"WARNING"}, msg)
    return "CPU"
