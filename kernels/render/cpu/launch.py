"""The CPU kernels' launcher: one band kernel per render mode (its mode a compile-time constant
down to the per-pixel code, cpu.per_mode), drawn on Python threads (the kernels release the GIL).
CPUDevice calls render_rows."""
from __future__ import annotations

import numpy as np

from ...jit import njit
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
_POOL = {}  # "pool": the threads bands are drawn on (grown to the most threads asked for)


def mode_entry(mode):
    """The band kernel of a mode (Mode or its int)."""
    mode = Mode(int(mode))
    if mode not in _ENTRIES:
        _ENTRIES[mode] = _band_entry(mode)
    return _ENTRIES[mode]


def band_order(row0, row1, threads):
    """The bands of screen-tile rows over [row0, row1) in the order 0, T, 2T, ..., 1, T + 1, ...
    for T threads, split into T contiguous blocks: thread k draws every T-th tile row and all
    sample the whole image or band (an object in the top half of a band would otherwise all go to
    one thread: F12 bands took up to 1.9x one call)."""
    b0 = row0 // TILE
    nb = (row1 - 1) // TILE - b0 + 1 if row1 > row0 else 0
    t = max(1, min(int(threads), nb))
    order = np.concatenate([np.arange(r, nb, t, dtype=np.int64) for r in range(t)]) + b0
    return [blk for blk in np.array_split(order, t) if blk.size]


def render_rows(mode, cam, row0, row1, col0, col1, gauss, objs, accel, xfer, out, threads):
    """Render rows [row0, row1) and columns [col0, col1) into out (packing.Output, indexed from
    0 = row0, col0) in ``mode``, on ``threads`` threads (the kernels release the GIL; every
    pixel is computed alone, so the image does not depend on the count). Python threads, not a
    parallel numba loop: the loop's compilation cost a first frame ~10 s more."""
    from concurrent.futures import ThreadPoolExecutor

    draw = mode_entry(mode)
    blocks = band_order(row0, row1, threads)
    args = (row0, row1, col0, col1, cam, gauss, objs, accel, xfer, out)
    if len(blocks) <= 1:
        for blk in blocks:
            draw(blk, *args)
        return
    pool = _POOL.get("pool")
    if pool is None or pool._max_workers < len(blocks) - 1:
        pool = _POOL["pool"] = ThreadPoolExecutor(len(blocks) - 1, thread_name_prefix="gaussvdb-render")
    done = [pool.submit(draw, blk, *args) for blk in blocks[1:]]
    draw(blocks[0], *args)
    for f in done:
        f.result()
