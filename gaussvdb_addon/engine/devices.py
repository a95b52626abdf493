"""The render devices of the engine: which one a render uses, making one, and the process-wide
ones of final renders (their kernels loaded once, acceleration reused across frames).

    device, seconds = devices.final_device("CPU")   # made and loaded now: seconds > 0
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
    """(the process-wide device of final renders, seconds spent loading its kernels now): 0.0
    when it was made before, so a frame's timings never hold the loading."""
    dev = _FINAL.get(name)
    if dev is not None:
        return dev, 0.0
    dev = new_device(name)
    seconds = dev.load_kernels()
    _FINAL[name] = dev
    return dev, seconds


def is_loaded(name) -> bool:
    """Whether final renders on ``name`` have their device (no kernels to load first)."""
    return name in _FINAL


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
