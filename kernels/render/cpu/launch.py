"""The CPU kernels' launcher: one band kernel per render mode (its mode a compile-time constant
down to the per-pixel code, cpu.per_mode; the plain scenes of reference and particles have their
own, kernel_code), drawn on Python threads (the kernels release the GIL). CPUDevice calls
render_rows."""
from __future__ import annotations

import numpy as np

from ...jit import njit, run_on_threads
from ..inputs.layout import PAR_LOG, TILE, Kind, Shading
from ..scene.objects import Mode
from .per_mode import MODE_BITS, ONE_FOG, PLAIN
from .pixels import render_band
from .vecmath import _jit


def _band_entry(code):
    """The kernel that draws a list of bands of screen-tile rows as ``code`` (kernel_code) says:
    its own compiled code, the code a constant all the way down (per_mode)."""
    MODE = int(code)  # a closure constant: numba's literal int, and part of the cache key

    @njit(**_jit)
    def draw_bands(bands, row0, row1, col0, col1, cam, gauss, objs, accel, xfer, out):
        for q in range(bands.shape[0]):
            j0 = max(row0, bands[q] * TILE)
            j1 = min(row1, (bands[q] + 1) * TILE)
            render_band(j0 - row0, j0, j1 - j0, col0, col1, MODE, cam, gauss, objs, accel, xfer, out)
    return draw_bands


_ENTRIES = {}  # kernel code -> its band kernel (made on first use; compiled, or loaded, on first call)


def kernel_code(mode, objs, accel, xfer) -> int:
    """The band kernel a frame draws with: its mode (Mode or its int), with per_mode.ONE_FOG for
    a reference frame of one fog volume in Emission, not coloured by a second grid, with a linear
    transfer function (the one-fog sampler, cpu.fog, draws all of it; the general piece sampler is
    not compiled), per_mode.PLAIN for a particles frame without lit volumes or surfaces (no
    shading code compiled). (objs, accel, xfer: the frame's packed Objects, Accel, Transfer.)"""
    mode = Mode(int(mode))
    if (mode == Mode.REFERENCE and accel.walk_obj.shape[0] == 1 and objs.kind[0] == Kind.FOG
            and objs.ctf[0] < 0 and objs.lit[0] == Shading.EMISSION
            and xfer.par[objs.tf[0], PAR_LOG] < 0.5):
        return int(mode) | ONE_FOG
    if (mode == Mode.PARTICLES and (objs.lit == Shading.EMISSION).all()
            and (objs.kind != Kind.SURFACE).all()):
        return int(mode) | PLAIN
    return int(mode)


def mode_entry(code):
    """The band kernel of a kernel code (kernel_code; a Mode or its int alone: the general one)."""
    code = int(code)
    Mode(code & MODE_BITS)  # a ValueError for no mode
    if code not in _ENTRIES:
        _ENTRIES[code] = _band_entry(code)
    return _ENTRIES[code]


def render_rows(mode, cam, row0, row1, col0, col1, gauss, objs, accel, xfer, out, threads):
    """Render rows [row0, row1) and columns [col0, col1) into out (packing.Output, indexed from
    0 = row0, col0) in ``mode`` (a kernel_code), on ``threads`` threads (the kernels release the GIL; every
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
