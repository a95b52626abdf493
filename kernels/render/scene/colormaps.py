"""SciVis colormap tables (256 entries, sRGB-encoded), generated from matplotlib by
``tools/gen_colormaps.py`` and stored in ``colormaps.npz`` next to this file; the names are
kernels/colormap_names.py's. And the ColorRamp that reproduces a table (``stops_from_table``).

A ColorRamp holds at most 32 elements and interpolates its (scene-linear) colours linearly. The 32
stops are chosen greedily on the 256-entry sRGB table (insert a stop where the ramp deviates most
from the table, measured in sRGB after the ramp's linear interpolation), their colours fitted by
weighted least squares (``fit_stop_colors``), so the ramp reproduces the table far better than 32
evenly spaced stops: under the Standard view transform the rendered colours match the table within
1/255 for the smooth maps (viridis, plasma, inferno, magma, cividis, coolwarm, grayscale: at most
0.84/255 before 8-bit rounding; turbo 1.2/255 and jet 2.3/255 have kinks; see ``ramp_error``).
Alpha is a linear ramp 0 -> 1 over the value range (``alpha='ramp'``: low values thin, high values
dense) or 1 everywhere (``alpha='constant'``).
"""
from __future__ import annotations

import os
from functools import lru_cache

import numpy as np

from ... import colormap_names as names

_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "colormaps.npz")
MAX_STOPS = names.RAMP_STOPS


@lru_cache(maxsize=1)
def _tables() -> dict:
    with np.load(_PATH) as z:
        return {k: np.array(z[k], dtype=np.float32) for k in z.files if not k.startswith("_")}


def colormap_names() -> list:
    """The names the tables hold, in kernels/colormap_names.py's order."""
    have = _tables()
    return [n for n in names.NAMES if n in have] + sorted(n for n in have if n not in names.NAMES)


def colormap(name: str) -> np.ndarray:
    """(256, 3) float32 sRGB-encoded table (a copy)."""
    t = _tables()
    key = names.canonical(name)
    if key not in t:
        raise KeyError(f"unknown colormap {name!r}; have {colormap_names()}")
    return t[key].copy()


def srgb_to_linear(c):
    """IEC 61966-2-1 sRGB decoding (the inverse of the PNG encoding under Blender's Standard view)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    """sRGB encoding; negative light encodes as 0."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, None)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)


# -- the ColorRamp of a table ---------------------------------------------------------------------
def _ramp_eval_srgb(table_lin, knots, x):
    """sRGB of a ramp with stops at table indices ``knots`` (sorted), linear interpolation in
    linear space, evaluated at table positions ``x`` (float indices)."""
    return linear_to_srgb(np.stack([np.interp(x, knots, table_lin[knots, k]) for k in range(3)], 1))


def choose_stops(table_srgb, n=MAX_STOPS):
    """Greedy knot insertion: indices (sorted, n of them, first and last included) into the table."""
    table_srgb = np.asarray(table_srgb, np.float64)
    k = table_srgb.shape[0]
    n = max(2, min(int(n), k))
    lin = srgb_to_linear(table_srgb)
    x = np.arange(k, dtype=np.float64)
    knots = [0, k - 1]
    while len(knots) < n:
        err = np.abs(_ramp_eval_srgb(lin, np.array(knots), x) - table_srgb).max(axis=1)
        err[knots] = -1.0
        knots.append(int(np.argmax(err)))
        knots.sort()
    return np.array(knots, np.int64)


def fit_stop_colors(table_srgb, knots, iters=8):
    """Linear-space stop colours (len(knots), 3) for fixed knots: least squares weighted by the
    slope of the sRGB curve (so the error is measured as displayed), then Lawson reweighting
    towards the minimax fit. Halves the error of stops copied from the table."""
    tab = np.asarray(table_srgb, np.float64)
    k = tab.shape[0]
    x = np.arange(k, dtype=np.float64)
    eye = np.eye(len(knots))
    basis = np.stack([np.interp(x, knots, eye[j]) for j in range(len(knots))], axis=1)
    lin = srgb_to_linear(tab)
    lo, hi = np.maximum(lin - 1e-4, 0.0), lin + 1e-4
    slope = (linear_to_srgb(hi) - linear_to_srgb(lo)) / (hi - lo)
    out = np.zeros((len(knots), 3))
    for c in range(3):
        u = np.ones(k)
        for _ in range(max(1, iters)):
            w = slope[:, c] * np.sqrt(u)
            sol = np.linalg.lstsq(basis * w[:, None], lin[:, c] * w, rcond=None)[0]
            err = np.abs(linear_to_srgb(basis @ sol) - tab[:, c])
            u = u * (err + 1e-3 / 255.0)
            u /= u.mean()
        out[:, c] = np.clip(sol, 0.0, None)
    return out


def stops_from_table(table_srgb, n=MAX_STOPS, alpha="ramp"):
    """(positions (n,), rgba (n, 4) LINEAR colour) for a ColorRamp reproducing an sRGB table."""
    table_srgb = np.asarray(table_srgb, np.float64)
    knots = choose_stops(table_srgb, n)
    pos = knots / float(table_srgb.shape[0] - 1)
    rgb = fit_stop_colors(table_srgb, knots)
    if alpha == "ramp":
        a = pos.copy()
    elif alpha == "constant":
        a = np.ones_like(pos)
    else:
        raise ValueError(f"alpha must be 'ramp' or 'constant', not {alpha!r}")
    return pos, np.concatenate([rgb, a[:, None]], axis=1)


def ramp_error(name, n=MAX_STOPS):
    """Largest sRGB deviation (0..1) of the n-stop ramp from the colormap table."""
    tab = np.asarray(colormap(name), np.float64)
    pos, rgba = stops_from_table(tab, n)
    x = np.linspace(0.0, 1.0, tab.shape[0])
    lin = np.stack([np.interp(x, pos, rgba[:, k]) for k in range(3)], axis=1)
    return float(np.abs(linear_to_srgb(lin) - tab).max())
