"""The CPU kernels' launcher: one band kernel per render mode (its mode a compile-time constant
down to the per-pixel code, cpu.per_mode), drawn on Python threads (the kernels release the GIL).
CPUDevice calls render_rows."""
from __future__ import annotations

import numpy as np

from ...jit import njit, run_on_threads
from ..inputs.layout import TILE
from ..scene.objects import Mode
from .pixels import render_band
from .vecmath import _jit


def _band_entry(mode):
    """The kernel that draws a list of bands of screen-tile rows in ``mode``: its own compiled
    code, the mode a constant all the way down (per_mode)."""
    MODE = int(mode)  # a closure constant: numba's literal int, and part of the cache key

    @njit(**_jit)
    def draw_bands(bands, row0, row1, col0, col1, cam, gauss, objs, accel, xfer, out):
        for q in range(bands.shape[0]):
            j0 = max(row0, bands[q] * TILE)
            j1 = min(row1, (bands[q] + 1) * TILE)
            render_band(j0 - row0, j0, j1 - j0, col0, col1, MODE, cam, gauss, objs, accel, xfer, out)
    return draw_bands


_ENTRIES = {}  # Mode -> its band kernel (made on first use; compiled, or loaded, on first call)


def mode_entry(mode):
    """The band kernel of a mode (Mode or its int)."""
    mode = Mode(int(mode))
    if mode not in _ENTRIES:
        _ENTRIES[mode] = _band_entry(mode)
    return _ENTRIES[mode]


def render_rows(mode, cam, row0, row1, col0, col1, gauss, objs, accel, xfer, out, threads):
    """Render rows [row0, row1) and columns [col0, col1) into out (packing.Output, indexed from
    0 = row0, col0) in ``mode``, on ``threads`` threads (the kernels release the GIL; every
    pixel is computed alone, so the image does not depend on the count). Python threads, not a
    parallel numba loop: the loop's compilation cost a first frame ~10 s more. Each thread takes
    the next row of screen tiles when it is done with one (a call costs ~12 us), so a band where
    the object covers only some rows still keeps every thread busy to its end."""
    draw = mode_entry(mode)
    b0 = row0 // TILE
    nb = (row1 - 1) // TILE - b0 + 1 if row1 > row0 else 0
    bands = np.arange(b0, b0 + nb, dtype=np.int64).reshape(nb, 1)
    args = (row0, row1, col0, col1, cam, gauss, objs, accel, xfer, out)
    if min(int(threads), nb) <= 1:
        if nb:
            draw(bands.ravel(), *args)
        return
    run_on_threads(nb, lambda q: draw(bands[q], *args), threads)
