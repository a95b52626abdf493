"""Render devices, in the manner of Cycles: the engine talks to a ``Device``; ``sync(scene)``
uploads/builds acceleration data once per scene change; ``begin_frame(scene, camera, tf)`` does
the per-frame set-up (weights, colours, empty-space skips, screen-tile lists: frame_setup.py)
once per frame and returns the frame (frame.Frame); ``render(...)`` draws the whole frame or a
region of it (a band of rows, a render border: bands.py) and reuses the frame's set-up while
camera, transfer function and settings are unchanged; ``end_frame()`` frees it; splat mode is
drawn as the reference scene splat_scene makes (modes.py's table says which mode draws what).
The CPU device (cpu_device.py: numba) registers here; a GPU device (gaussvdb_addon/gpu/device.py:
compute shaders on Blender's gpu module) implements the same methods over a CPU device's frame
set-up and registers itself with ``register_device``.

Passes: 'Combined' float32 (H, W, 4), linear, premultiplied alpha, row 0 = bottom;
'Depth' float32 (H, W): world distance along the ray where the accumulated opacity reaches 0.5
(layout.BG_DEPTH where it never does); 'Value' float32 (H, W): opacity-weighted mean data value (0 where
nothing was hit; level sets contribute no value).
"""
from __future__ import annotations

from abc import ABC, abstractmethod

from ..scene.objects import RenderScene
from ..scene.transfer import TransferFunction


class Device(ABC):
    name = "abstract"

    @abstractmethod
    def sync(self, scene: RenderScene) -> None:
        """Build/upload the scene's geometry (objects, placement, support radius): once per key."""

    @abstractmethod
    def begin_frame(self, scene: RenderScene, camera, tf: TransferFunction):
        """The per-frame set-up for this camera, TF and settings (syncs first if the geometry
        changed); a no-op returning the kept state when they equal the last frame's."""

    def end_frame(self) -> None:
        """Drop the frame's set-up (memory); the next render() redoes it."""

    def load_kernels(self, modes=None, *, scene=None, camera=None, tf=None) -> float:
        """Load (or compile) the kernels a frame of ``scene`` needs, or those of ``modes`` (names;
        None: every mode), once per process (seconds): first frames time only themselves."""
        return 0.0

    def band_rows(self, scene: RenderScene) -> tuple:
        """(fewest, multiple): rows a render() call should cover to keep the device busy, and the
        row multiple bands start on."""
        return 1, 1

    @abstractmethod
    def render(self, scene: RenderScene, camera, tf: TransferFunction, *, rows=None, cols=None,
               progress=None, cancel=None) -> dict:
        """Render image rows ``rows = (row0, row1)`` and columns ``cols = (col0, col1)``
        (default all; pixels are exactly those of the whole frame) and return the passes of that
        region, (row1 - row0, col1 - col0). Calls begin_frame. ``progress(fraction)`` is called
        and ``cancel()`` polled between steps of rows; on cancel the rows not yet drawn stay
        transparent and ``self.stats['cancelled']`` is True. ``stats``: seconds_sync,
        seconds_setup (this call's frame set-up, 0 when reused) and seconds_render (the whole
        call, set-up included) as floats, segments (float), cancelled (bool), threads (int)."""


_REGISTRY = {}  # name -> Device class, in the order registered
_USABLE = {}  # name -> callable: whether this machine can run that device (a GPU's probe)


def register_device(name: str, cls, usable=None) -> None:
    """Make ``get_device(name)`` build ``cls``; ``usable()``, when given, says whether this machine
    can run it (available_devices asks it)."""
    _REGISTRY[name] = cls
    if usable is None:
        _USABLE.pop(name, None)
    else:
        _USABLE[name] = usable


def available_devices():
    """Names of the registered devices usable here."""
    return [n for n in _REGISTRY if n not in _USABLE or _USABLE[n]()]


def get_device(name="CPU", **kw) -> Device:
    try:
        return _REGISTRY[name](**kw)
    except KeyError:
        raise ValueError(f"unknown device {name!r}; available: {available_devices()}") from None
