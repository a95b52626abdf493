"""The colour legend: a scalar bar (colormap, range, ticks, title) drawn with numpy, composited
over the Combined pass (premultiplied, "over") and drawn as the viewport overlay.

``legend_patch`` draws one bar per transfer function into a small premultiplied RGBA patch (row 0
at the top); ``corner_origin`` places it; ``composite`` lays it over an image whose row 0 is the
bottom row (Blender's passes). Text uses a built-in 5x7 bitmap font (digits, letters, a few signs),
scaled by whole pixels, so the legend looks the same everywhere and needs no font library.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CORNERS = ("top_left", "top_right", "bottom_left", "bottom_right")

# 5x7 glyphs, one hex byte per row (top to bottom, bit 4 = leftmost column); lowercase 'e' is
# the exponent of tick labels, titles are drawn in capitals.
_FONT = {
    "0": "0E11131519110E", "1": "040C040404040E", "2": "0E11010204081F", "3": "1F02040201110E",
    "4": "02060A121F0202", "5": "1F101E0101110E", "6": "0608101E11110E", "7": "1F010204080808",
    "8": "0E11110E11110E", "9": "0E11110F01020C", "A": "0E1111111F1111", "B": "1E11111E11111E",
    "C": "0E11101010110E", "D": "1C12111111121C", "E": "1F10101E10101F", "F": "1F10101E101010",
    "G": "0E11101711110F", "H": "1111111F111111", "I": "0E04040404040E", "J": "0702020202120C",
    "K": "11121418141211", "L": "1010101010101F", "M": "111B1515111111", "N": "11111915131111",
    "O": "0E11111111110E", "P": "1E11111E101010", "Q": "0E11111115120D", "R": "1E11111E141211",
    "S": "0F10100E01011E", "T": "1F040404040404", "U": "1111111111110E", "V": "11111111110A04",
    "W": "1111111515150A", "X": "11110A040A1111", "Y": "1111110A040404", "Z": "1F01020408101F",
    ".": "00000000000C0C", "-": "0000001F000000", "+": "0004041F040400", "_": "0000000000001F",
    " ": "00000000000000", "(": "02040808080402", ")": "08040202020408", "/": "00010204081000",
    ":": "000C0C000C0C00", "e": "00000E111F100E", "%": "18190204081303", "?": "0E110102040004",
}
GLYPH_W, GLYPH_H = 5, 7


def _glyph(ch):
    code = _FONT.get(ch) or _FONT.get(ch.upper()) or _FONT["?"]
    rows = [int(code[2 * i:2 * i + 2], 16) for i in range(GLYPH_H)]
    return np.array([[(r >> (4 - c)) & 1 for c in range(GLYPH_W)] for r in rows], bool)


_GLYPHS = {ch: _glyph(ch) for ch in _FONT}


def text_mask(text, scale=1):
    """(7 s, 6 s n - s) bool mask of ``text`` at integer scale s (one blank column between glyphs)."""
    s = max(1, int(scale))
    if not text:
        return np.zeros((GLYPH_H * s, 0), bool)
    cols = []
    for i, ch in enumerate(text):
        if i:
            cols.append(np.zeros((GLYPH_H, 1), bool))
        cols.append(_GLYPHS.get(ch) if ch in _GLYPHS else _glyph(ch))
    m = np.concatenate(cols, axis=1)
    return np.repeat(np.repeat(m, s, axis=0), s, axis=1)


# -- ticks ----------------------------------------------------------------------------------------
def _fmt(v, step=None):
    """Short label: fixed point where that stays short (as many decimals as ``step`` needs, else
    three significant digits), else mantissa 'e' exponent (1.5e+29)."""
    if v == 0:
        return "0"
    a = abs(v)
    if 1e-3 <= a < 1e5:
        dec = -math.floor(math.log10(step) + 1e-9) if step else 2 - math.floor(math.log10(a))
        text = f"{v:.{min(max(dec, 0), 6)}f}"
        return text.rstrip("0").rstrip(".") if "." in text else text
    m, e = f"{v:.1e}".split("e")
    return f"{m.rstrip('0').rstrip('.')}e{int(e):+d}"


def ticks(vmin, vmax, log_scale=False, target=5):
    """[(fraction along the bar 0..1, label)]: nice linear steps (1, 2, 5 x 10^k), or decades for
    a log scale; the range's ends are labelled when fewer than two ticks fall inside."""
    lo, hi = float(vmin), float(vmax)
    out = []
    if hi <= lo:
        return [(1.0, _fmt(hi))]
    if log_scale and lo > 0:
        a, b = math.log10(lo), math.log10(hi)
        k0, k1 = math.ceil(a - 1e-9), math.floor(b + 1e-9)
        every = max(1, math.ceil((k1 - k0 + 1) / target))
        for k in range(k0, k1 + 1, every):
            v = 10.0 ** k
            out.append(((k - a) / (b - a), _fmt(v) if -3 <= k <= 4 else f"1e{k:+d}"))
    else:
        raw = (hi - lo) / max(1, target - 1)
        mag = 10.0 ** math.floor(math.log10(raw))
        step = next(m * mag for m in (1, 2, 5, 10) if m * mag >= raw * 0.999)
        k0, k1 = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
        for k in range(k0, k1 + 1):
            v = k * step
            out.append(((v - lo) / (hi - lo), _fmt(0.0 if abs(v) < step * 1e-9 else v, step)))
    if len(out) < 2:
        out = [(0.0, _fmt(lo))] + [t for t in out if 0.05 < t[0] < 0.95] + [(1.0, _fmt(hi))]
    return out


# -- the raster -----------------------------------------------------------------------------------
@dataclass
class LegendEntry:
    """One scalar bar: a (K, 4) linear RGBA LUT over [vmin, vmax] (log10 when log_scale)."""
    title: str
    lut: np.ndarray
    vmin: float
    vmax: float
    log_scale: bool = False


FG = np.array([1.0, 1.0, 1.0])  # text and frame: linear white
BG_ALPHA = 0.55  # the dark panel behind (premultiplied black, so only alpha)


def _paint(img, mask, y, x, rgb, alpha=1.0):
    h, w = mask.shape
    y1, x1 = min(img.shape[0], y + h), min(img.shape[1], x + w)
    if y1 <= y or x1 <= x:
        return
    m = mask[:y1 - y, :x1 - x, None] * alpha
    reg = img[y:y1, x:x1]
    src = np.concatenate([np.broadcast_to(rgb, m.shape[:2] + (3,)) * m, m], axis=2)
    reg[:] = src + reg * (1.0 - m)


def legend_patch(entries, height):
    """(h, w, 4) float32 premultiplied linear RGBA (row 0 at the top), about ``height`` pixels
    tall: for each entry its title, a vertical bar with a frame and tick labels on the right."""
    entries = list(entries)
    height = max(40, int(height))
    s = max(1, round(height / 90))  # font scale
    pad, gap = 3 * s, 2 * s
    title_h = GLYPH_H * s
    half_label = GLYPH_H * s // 2  # the end labels reach half a glyph past the bar's ends
    bar_h = height - 2 * pad - title_h - gap - 2 * half_label
    bar_w = max(6, height // 12)
    blocks = []
    for e in entries:
        tk = ticks(e.vmin, e.vmax, e.log_scale)
        labels = [(f, text_mask(t, s)) for f, t in tk]
        title = text_mask(e.title.upper(), s)
        lab_w = max((m.shape[1] for _, m in labels), default=0)
        w = max(title.shape[1], bar_w + 2 * s + 2 * s + lab_w)
        blocks.append((e, labels, title, w))
    total_w = pad + sum(b[3] for b in blocks) + pad * max(0, len(blocks) - 1) + pad
    img = np.zeros((height, total_w, 4), np.float32)
    img[..., 3] = BG_ALPHA
    x = pad
    y_bar = pad + title_h + gap + half_label
    for e, labels, title, w in blocks:
        _paint(img, title, pad, x, FG)
        # the bar: top = vmax; LUT colour, opaque, inside a 1-s frame
        k = e.lut.shape[0]
        f = np.linspace(1.0, 0.0, bar_h)
        col = np.stack([np.interp(f, np.linspace(0, 1, k), e.lut[:, c]) for c in range(3)], 1)
        img[y_bar:y_bar + bar_h, x + s:x + s + bar_w, :3] = col[:, None, :]
        img[y_bar:y_bar + bar_h, x + s:x + s + bar_w, 3] = 1.0
        frame = np.zeros((bar_h + 2 * s, bar_w + 2 * s), bool)
        frame[:s], frame[-s:], frame[:, :s], frame[:, -s:] = True, True, True, True
        _paint(img, frame, y_bar - s, x, FG)
        for frac, m in labels:
            yc = y_bar + int(round((1.0 - frac) * (bar_h - 1)))
            _paint(img, np.ones((s, 2 * s), bool), yc, x + 2 * s + bar_w, FG)  # tick mark
            _paint(img, m, yc - m.shape[0] // 2, x + 4 * s + bar_w + s, FG)
        x += w + pad
    return img


def corner_origin(width, height, patch_shape, corner="bottom_right", margin=None):
    """(x0, y0) of the patch's bottom-left pixel in an image whose row 0 is the bottom row."""
    ph, pw = patch_shape[:2]
    m = max(4, min(width, height) // 40) if margin is None else int(margin)
    if corner not in CORNERS:
        raise ValueError(f"legend corner must be one of {', '.join(CORNERS)}, not {corner!r}")
    x0 = m if corner.endswith("left") else width - pw - m
    y0 = m if corner.startswith("bottom") else height - ph - m
    return max(0, x0), max(0, y0)


def composite(image, patch, corner="bottom_right"):
    """Lay ``patch`` (premultiplied, row 0 at the top) over ``image`` ((H, W, 4) premultiplied,
    row 0 = bottom) at ``corner``, in place; the part that does not fit is cut off. Returns image."""
    hh, ww = image.shape[:2]
    x0, y0 = corner_origin(ww, hh, patch.shape, corner)
    up = patch[::-1]  # to bottom-up rows
    h, w = min(up.shape[0], hh - y0), min(up.shape[1], ww - x0)
    if h <= 0 or w <= 0:
        return image
    src = up[:h, :w]
    dst = image[y0:y0 + h, x0:x0 + w]
    dst[:] = src + dst * (1.0 - src[..., 3:4])
    return image
