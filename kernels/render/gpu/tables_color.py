"""The GPU tables of the volumes coloured by a second grid (packing.Objects.ctf >= 0; read by
glsl/color.glsl), plain numpy:

- obj_color (gpu_layout.fold_rows, one texel per object, layout.OCOL): colour map's
  transfer-function row (-1: coloured by its own grid), the colour grid's background
  (packing.Objects.cbg).
- g_cval (gpu_layout.fold_scalars, particles and paper): each Gaussian's colour value (the CPU
  device's colours come from them: frame_setup.gauss_weights), NaN where it has none.
- Reference mode: the colour grids' bricks (packing.Accel.cbricks, on the same cells) go in the
  voxel atlas after the grid's own (gpu_layout.reference_geometry; cell c's at brick
  c + cbrick0, an int).

The shaders get COLOR_GRID (obj_color) and COLOR_VALUES (g_cval) defined with them (defines)."""
from __future__ import annotations

import numpy as np

from ..inputs.layout import OCOL_CBG, OCOL_CTF, OCOL_SIZE
from . import tables as gpu_layout

DEFINES = {"obj_color": "COLOR_GRID", "g_cval": "COLOR_VALUES"}


def colored(frame) -> bool:
    """Whether an object of the frame is coloured by a second grid."""
    return bool((np.asarray(frame.objects.ctf) >= 0).any())


def frame_tables(frame) -> dict:
    """obj_color, and for the Gaussian modes g_cval (the frame's ``color_values``, the Gaussians'
    second values in the frame's order), when an object is coloured by a second grid; else {}."""
    if not colored(frame):
        return {}
    o = frame.objects
    n = o.w2i.shape[0]
    rows = np.zeros((n, OCOL_SIZE))
    rows[:, OCOL_CTF] = np.asarray(o.ctf)[:n]
    rows[:, OCOL_CBG] = np.where(rows[:, OCOL_CTF] >= 0, np.asarray(o.cbg)[:n], 0.0)
    out = {"obj_color": gpu_layout.fold_rows(rows)}
    cv = frame.color_values
    if cv is not None:
        out["g_cval"] = gpu_layout.fold_scalars(np.asarray(cv, np.float32))
    return out


def defines(tables) -> tuple:
    """The shader's #defines for these tables (names)."""
    return tuple(d for n, d in DEFINES.items() if n in tables)

