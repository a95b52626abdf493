"""SciVis colormap tables (256 entries, sRGB-encoded), generated from matplotlib by
``tools/gen_colormaps.py`` and stored in ``colormaps.npz`` next to this file."""
from __future__ import annotations

import os
from functools import lru_cache

import numpy as np

_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "colormaps.npz")


@lru_cache(maxsize=1)
def _tables() -> dict:
    with np.load(_PATH) as z:
        return {k: np.array(z[k], dtype=np.float32) for k in z.files if not k.startswith("_")}


def colormap_names() -> list:
    """Names in a stable order (the order of tools/gen_colormaps.py)."""
    order = ["viridis", "plasma", "inferno", "magma", "cividis", "turbo", "jet", "coolwarm", "grayscale"]
    have = _tables()
    return [n for n in order if n in have] + sorted(n for n in have if n not in order)


def colormap(name: str) -> np.ndarray:
    """(256, 3) float32 sRGB-encoded table (a copy)."""
    t = _tables()
    key = name.lower()
    if key in ("gray", "grey", "greyscale"):
        key = "grayscale"
    if key not in t:
        raise KeyError(f"unknown colormap {name!r}; have {colormap_names()}")
    return t[key].copy()


def srgb_to_linear(c):
    """IEC 61966-2-1 sRGB decoding (the inverse of the PNG encoding under Blender's Standard view)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(np.maximum(c, 0.0), 1.0 / 2.4) - 0.055)


def ramp_stops(name: str, n: int = 32, alpha: str = "ramp"):
    """Stops to fill a Blender ColorRamp (at most 32 elements) from a colormap preset.

    Returns (positions (n,), rgba (n, 4)) with LINEAR rgb (ColorRamp colours are scene-linear)
    and alpha a linear ramp 0 -> 1 (``alpha='ramp'``) or 1 (``'constant'``)."""
    tab = colormap(name)
    pos = np.linspace(0.0, 1.0, n)
    x = pos * (tab.shape[0] - 1)
    rgb = np.stack([np.interp(x, np.arange(tab.shape[0]), tab[:, k]) for k in range(3)], axis=1)
    a = pos.copy() if alpha == "ramp" else np.ones(n)
    return pos, np.concatenate([srgb_to_linear(rgb), a[:, None]], axis=1)
