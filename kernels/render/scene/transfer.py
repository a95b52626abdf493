"""Transfer functions: value -> (linear RGB, alpha), plus the extinction scale.

A value v maps to x = (v - vmin) / (vmax - vmin) (or the same in log10 when ``log_scale``),
clamped to [0, 1], then to the LUT by linear interpolation between its K entries. NaN values are
transparent. Extinction is ``density * alpha`` per WORLD unit (times the Gaussian's amplitude and
kernel in particles mode): scaling the world by s and the density by 1/s gives the same image.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..inputs.layout import LUT_SIZE, PAR_DENSITY, PAR_LOG, PAR_SIZE, PAR_VMAX, PAR_VMIN
from .colormaps import colormap, srgb_to_linear


@dataclass
class TransferFunction:
    lut: np.ndarray  # float32 (K, 4): LINEAR rgb, alpha in [0, 1]
    vmin: float = 0.0
    vmax: float = 1.0
    log_scale: bool = False
    density: float = 1.0  # extinction per world unit at alpha 1

    def __post_init__(self):
        lut = np.ascontiguousarray(self.lut, dtype=np.float32)
        if lut.ndim != 2 or lut.shape[1] != 4 or lut.shape[0] < 2:
            raise ValueError("lut must be (K >= 2, 4)")
        lut = lut.copy()
        lut[:, 3] = np.clip(lut[:, 3], 0.0, 1.0)
        self.lut = lut
        self.vmin, self.vmax = float(self.vmin), float(self.vmax)
        self.density = float(self.density)
        if not np.isfinite(self.density) or self.density < 0:
            raise ValueError("density must be finite and >= 0")
        if self.log_scale and not (self.vmin > 0 and self.vmax > 0):
            raise ValueError("log scale needs a positive value range")

    # -- builders ---------------------------------------------------------------------------
    @classmethod
    def from_colormap(cls, name="viridis", vmin=0.0, vmax=1.0, *, alpha="ramp", opacity=1.0,
                      log_scale=False, density=1.0):
        """A colormap preset: colours from the stored sRGB table converted to linear; alpha a
        linear ramp 0 -> opacity over the range (``alpha='ramp'``), constant ``opacity``
        (``'constant'``), or an explicit array of K alphas."""
        rgb = srgb_to_linear(colormap(name))
        k = rgb.shape[0]
        if isinstance(alpha, str):
            if alpha == "ramp":
                a = np.linspace(0.0, 1.0, k) * opacity
            elif alpha == "constant":
                a = np.full(k, float(opacity))
            else:
                raise ValueError(f"alpha must be 'ramp', 'constant' or an array, not {alpha!r}")
        else:
            a = np.interp(np.linspace(0, 1, k), np.linspace(0, 1, len(alpha)), np.asarray(alpha, float))
        return cls(np.concatenate([rgb, a[:, None]], axis=1), vmin, vmax, log_scale, density)

    @classmethod
    def from_samples(cls, rgba, vmin=0.0, vmax=1.0, *, log_scale=False, density=1.0):
        """From K evenly spaced samples of a Blender ColorRamp (``ramp.evaluate(i / (K - 1))``);
        ColorRamp colours are already scene-linear."""
        return cls(np.asarray(rgba, np.float32), vmin, vmax, log_scale, density)

    @classmethod
    def from_ramp(cls, positions, colors, vmin=0.0, vmax=1.0, *, interpolation="LINEAR",
                  size=LUT_SIZE, log_scale=False, density=1.0):
        """From ColorRamp elements (positions in [0, 1], linear RGBA), LINEAR or CONSTANT."""
        pos = np.asarray(positions, np.float64)
        col = np.asarray(colors, np.float64).reshape(-1, 4)
        order = np.argsort(pos, kind="stable")
        pos, col = pos[order], col[order]
        x = np.linspace(0.0, 1.0, size)
        if interpolation == "CONSTANT":
            idx = np.clip(np.searchsorted(pos, x, side="right") - 1, 0, len(pos) - 1)
            lut = col[idx]
        else:
            lut = np.stack([np.interp(x, pos, col[:, k]) for k in range(4)], axis=1)
        return cls(lut, vmin, vmax, log_scale, density)

    # -- evaluation (numpy; the kernels have the same code in numba) ------------------------
    def normalize(self, v):
        v = np.asarray(v, np.float64)
        if self.log_scale:
            lo, hi = np.log10(self.vmin), np.log10(self.vmax)
            with np.errstate(divide="ignore", invalid="ignore"):
                lv = np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), -np.inf)
            x = (lv - lo) / (hi - lo) if hi > lo else np.where(lv >= hi, 1.0, 0.0)
        else:
            x = (v - self.vmin) / (self.vmax - self.vmin) if self.vmax > self.vmin else \
                np.where(v >= self.vmax, 1.0, 0.0)
        return np.clip(x, 0.0, 1.0)

    def __call__(self, v):
        """(..., 4) float64 linear RGBA; NaN values -> all zeros."""
        v = np.asarray(v, np.float64)
        x = self.normalize(v)
        k = self.lut.shape[0]
        f = np.nan_to_num(x) * (k - 1)
        i0 = np.minimum(f.astype(np.int64), k - 2)
        w = (f - i0)[..., None]
        out = self.lut[i0] * (1.0 - w) + self.lut[i0 + 1] * w
        return np.where(np.isnan(v)[..., None], 0.0, out)

    def packed(self) -> np.ndarray:
        """float64 (PAR_SIZE,), layout.PAR: vmin, vmax, log_scale, density."""
        out = np.zeros(PAR_SIZE)
        out[PAR_VMIN], out[PAR_VMAX] = self.vmin, self.vmax
        out[PAR_LOG] = 1.0 if self.log_scale else 0.0
        out[PAR_DENSITY] = self.density
        return out


def value_range(values, log_scale=False):
    """Auto value range from data: min/max of the finite values (the positive ones for log).
    Returns (0, 1) (or (1e-3, 1) for log) when there is nothing usable. A flat range (a grid whose
    active voxels all hold one value v) is widened downwards so v maps to the top of the ramp: a
    constant medium shows as a uniform, visible one, not as the ramp's transparent end. The low
    end is 0 for v > 0 (the empty background stays transparent), v/10 for log scale."""
    v = np.asarray(values, np.float64).ravel()
    v = v[np.isfinite(v)]
    if log_scale:
        v = v[v > 0]
    if v.size == 0:
        return (1e-3, 1.0) if log_scale else (0.0, 1.0)
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        lo = hi / 10.0 if log_scale else (0.0 if hi > 0 else hi - max(-hi, 1.0))
    return lo, hi


def voxel_stats(grid, chunk=1 << 14):
    """What the transfer function needs to know of a grid's active values, whatever LOD is drawn:
    ``min``, ``max``, ``positive_min`` (None without positive values; the low end of a log
    scale), ``nonpositive`` (active voxels <= 0 or NaN: what a log scale cannot show) and
    ``voxels`` (active voxels, tiles counted by their size cubed). Duck-typed GridData: uint64
    (N, 8) leaf masks, (N, 512) leaf values, tiles."""
    lo, hi, pmin = np.inf, -np.inf, np.inf
    bad = total = 0

    def add(v, weight=None):  # one pass per test, in the grid's own dtype (no float64 copy)
        nonlocal lo, hi, pmin, bad, total
        if v.size == 0:
            return
        if v.dtype.kind != "f":
            v = v.astype(np.float64)
        fin = np.isfinite(v)
        f = v if fin.all() else v[fin]
        if f.size:
            lo, hi = min(lo, float(f.min())), max(hi, float(f.max()))
        pos = v > 0
        if pos.any():
            pmin = min(pmin, float(np.min(v, where=pos, initial=np.inf)))
        if weight is None:
            bad += v.size - int(np.count_nonzero(pos))
            total += v.size
        else:
            bad += int(weight[~pos].sum())
            total += int(weight.sum())

    masks = np.ascontiguousarray(grid.leaf_masks, np.uint64).reshape(-1, 8)
    values = grid.leaf_values
    for a in range(0, len(masks), chunk):
        m = np.unpackbits(masks[a:a + chunk].view(np.uint8), axis=1, bitorder="little").view(bool)
        add(np.asarray(values[a:a + chunk])[m])
    act = np.asarray(grid.tile_active, bool)
    if act.any():
        sizes = np.asarray(grid.tile_sizes, np.int64)[act]
        add(np.asarray(grid.tile_values, np.float64)[act], sizes ** 3)
    if lo > hi:
        lo = hi = 0.0
    return {"min": lo, "max": hi, "positive_min": pmin if np.isfinite(pmin) else None,
            "nonpositive": bad, "voxels": total}


# -- tables the devices read ------------------------------------------------------------------------
def alpha_max_table(lut):
    """t[i, j] = the largest alpha of the LUT's rows i..j."""
    a = np.asarray(lut[:, 3], np.float64)
    k = a.size
    t = np.zeros((k, k))
    for i in range(k):
        t[i, i:] = np.maximum.accumulate(a[i:])
    return t


def range_alpha(tf, lo, hi):
    """Max alpha of tf over value ranges [lo, hi] (arrays). NaN bounds -> 0."""
    k = tf.lut.shape[0]
    xlo = np.nan_to_num(tf.normalize(lo), nan=1.0)
    xhi = np.nan_to_num(tf.normalize(hi), nan=0.0)
    i0 = np.clip(np.floor(xlo * (k - 1)).astype(np.int64), 0, k - 1)
    i1 = np.clip(np.ceil(xhi * (k - 1)).astype(np.int64), 0, k - 1)
    tab = alpha_max_table(tf.lut)
    out = tab[i0, np.maximum(i0, i1)]
    return np.where(i1 >= i0, out, 0.0)


def resampled(t: TransferFunction) -> TransferFunction:
    """t with a LUT of LUT_SIZE rows (the devices' table size)."""
    if t.lut.shape[0] == LUT_SIZE:
        return t
    x = np.linspace(0, 1, LUT_SIZE)
    xp = np.linspace(0, 1, t.lut.shape[0])
    lut = np.stack([np.interp(x, xp, t.lut[:, c]) for c in range(4)], axis=1)
    return TransferFunction(lut, t.vmin, t.vmax, t.log_scale, t.density)
