"""What every device's render() shares: the region a call draws, the band loop over its rows
(progress and cancel between bands) and the passes it returns."""
from __future__ import annotations

import numpy as np

from ..inputs.layout import BG_DEPTH


def region(frame, rows, cols):
    """(row0, row1, col0, col1) of a render() call's rows and cols (None: all) in the frame."""
    r0, r1 = (0, frame.height) if rows is None else (int(rows[0]), int(rows[1]))
    c0, c1 = (0, frame.width) if cols is None else (int(cols[0]), int(cols[1]))
    if not (0 <= r0 <= r1 <= frame.height and 0 <= c0 <= c1 <= frame.width):
        raise ValueError(f"rows {r0}..{r1} / columns {c0}..{c1} outside the "
                         f"{frame.width}x{frame.height} image")
    return r0, r1, c0, c1


def draw_bands(nr, step, draw, progress=None, cancel=None) -> bool:
    """``draw(a, b)`` over the rows [0, nr) of a region in bands of ``step`` rows, ``cancel()``
    polled before each band and ``progress(b / nr)`` called after it; True when cancelled (the
    rows not yet drawn stay as they are)."""
    a = 0
    while a < nr:
        if cancel is not None and cancel():
            return True
        b = min(nr, a + step)
        draw(a, b)
        a = b
        if progress is not None:
            progress(a / nr)
    return False


def passes(scene, rgba, depth, value) -> dict:
    """The render() result: Combined, and Depth and Value where the scene asks for them."""
    out = {"Combined": rgba}
    if "Depth" in scene.passes:
        out["Depth"] = depth
    if "Value" in scene.passes:
        out["Value"] = value
    return out


def blank(nr, nc):
    """(rgba, depth, value) of a region nothing was drawn into yet: transparent, the background
    depth (BG_DEPTH), no value."""
    return (np.zeros((nr, nc, 4), np.float32), np.full((nr, nc), BG_DEPTH, np.float32),
            np.zeros((nr, nc), np.float32))
