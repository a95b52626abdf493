"""A frame's state from a device's begin_frame: the kernels' inputs (packing's groups, with this
frame's weights, colours, cell skips and screen-tile lists), the packed camera, its key, and what
a GPU device reads of it besides. Every field a frame carries is declared here."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...mode_names import Mode

NOT_BUILT = "not built"  # gpu_tiles before a GPU device first asks for them


@dataclass(eq=False)
class Frame:
    mode: Mode  # the mode drawn (modes.frame_mode: never a derived mode, particles with a surface as field)
    cam: np.ndarray  # Camera.packed()
    width: int
    height: int
    gauss: tuple  # packing.Gaussians
    objects: tuple  # packing.Objects
    accel: tuple  # packing.Accel
    transfer: tuple  # packing.Transfer
    key: tuple | None = None  # what the frame depends on (CPUDevice.begin_frame reuses it while equal)
    # the caller builds the screen-tile lists (a GPU device: gpu/tiles.py): this frame has none
    # (nor entry bounds), and draws Gaussians (CPUDevice.begin_frame's lists_elsewhere)
    tiles_elsewhere: bool = False
    # the Gaussians' second-grid values for a device that colours each Gaussian by its own (the
    # GPU's g_cval, modes: color GAUSSIANS, from CPUDevice.color_values); None: not read
    color_values: np.ndarray | None = None
    # paper mode's screen-tile lists for a GPU device (gpu.tables_gauss.frame_tiles: built there
    # once per frame; None: too many)
    gpu_tiles: tuple | None | str = NOT_BUILT
