"""The editable transfer function: a Blender ColorRamp (colour and alpha) filled by colormap presets.

A ColorRamp can only live inside a texture or a node, so the scene's transfer function is the
ramp of a Blend texture (``scene.gaussvdb.ramp_texture``), drawn in the render panel with
``template_color_ramp``. The texture is created lazily (at render time, or when a colormap is
picked): property update callbacks may run where datablocks cannot be created.

Filling from a colormap: a ColorRamp holds at most 32 elements and interpolates its (scene-linear)
colours linearly. The 32 stops are chosen greedily on the 256-entry sRGB table (insert a stop where
the ramp deviates most from the table, measured in sRGB after the ramp's linear interpolation), their colours fitted by
weighted least squares (``fit_stop_colors``), so
the ramp reproduces the table far better than 32 evenly spaced stops: under the Standard view
transform the rendered colours match the table within 1/255 for the smooth maps (viridis, plasma,
inferno, magma, cividis, coolwarm, grayscale: at most 0.84/255 before 8-bit rounding; turbo
1.2/255 and jet 2.3/255 have kinks; see ``ramp_error``). Alpha is a linear ramp 0 -> 1 over the
value range (``alpha='ramp'``, the default: low values thin, high values dense) or 1 everywhere
(``alpha='constant'``); edit the ramp's alpha freely afterwards.
"""

import numpy as np

MAX_STOPS = 32
TEXTURE_NAME = "GaussVDB Transfer Function"


# -- pure numpy (no bpy): stop selection --------------------------------------------------------
def _srgb_to_linear(c):
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(c):
    c = np.clip(np.asarray(c, np.float64), 0.0, None)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)


def _ramp_eval_srgb(table_lin, knots, x):
    """sRGB of a ramp with stops at table indices ``knots`` (sorted), linear interpolation in
    linear space, evaluated at table positions ``x`` (float indices)."""
    return _linear_to_srgb(np.stack([np.interp(x, knots, table_lin[knots, k]) for k in range(3)], 1))


def choose_stops(table_srgb, n=MAX_STOPS):
    """Greedy knot insertion: indices (sorted, n of them, first and last included) into the table."""
    table_srgb = np.asarray(table_srgb, np.float64)
    k = table_srgb.shape[0]
    n = max(2, min(int(n), k))
    lin = _srgb_to_linear(table_srgb)
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
    lin = _srgb_to_linear(tab)
    lo, hi = np.maximum(lin - 1e-4, 0.0), lin + 1e-4
    slope = (_linear_to_srgb(hi) - _linear_to_srgb(lo)) / (hi - lo)
    out = np.zeros((len(knots), 3))
    for c in range(3):
        u = np.ones(k)
        for _ in range(max(1, iters)):
            w = slope[:, c] * np.sqrt(u)
            sol = np.linalg.lstsq(basis * w[:, None], lin[:, c] * w, rcond=None)[0]
            err = np.abs(_linear_to_srgb(basis @ sol) - tab[:, c])
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
    from ..kernels.render.colormaps import colormap

    tab = np.asarray(colormap(name), np.float64)
    pos, rgba = stops_from_table(tab, n)
    x = np.linspace(0.0, 1.0, tab.shape[0])
    lin = np.stack([np.interp(x, pos, rgba[:, k]) for k in range(3)], axis=1)
    return float(np.abs(_linear_to_srgb(lin) - tab).max())


# -- Blender side --------------------------------------------------------------------------------
def ensure_texture(settings, colormap=None):
    """The scene's ramp texture, created (and filled from ``settings.colormap``) if missing.
    Raises where datablocks cannot be created (drawing); callers at render time may call it."""
    import bpy

    tex = settings.ramp_texture
    if tex is not None and getattr(tex, "color_ramp", None) is not None and tex.use_color_ramp:
        return tex
    if tex is None or tex.type != "BLEND":
        tex = bpy.data.textures.new(TEXTURE_NAME, "BLEND")
        settings.ramp_texture = tex
    tex.use_color_ramp = True
    _fill(tex.color_ramp, colormap or settings.colormap)
    return tex


def _fill(ramp, name, alpha="ramp"):
    from ..kernels.render.colormaps import colormap

    pos, rgba = stops_from_table(colormap(name), MAX_STOPS, alpha)
    ramp.color_mode = "RGB"
    ramp.interpolation = "LINEAR"
    els = ramp.elements
    while len(els) > 1:
        els.remove(els[-1])
    els[0].position = float(pos[0])
    for p in pos[1:]:
        els.new(float(p))  # kept sorted by Blender
    for el, c in zip(els, rgba):
        el.color = tuple(float(v) for v in c)
    # new() snaps nothing, but set positions again in case of rounding on insertion
    for el, p in zip(els, pos):
        el.position = float(p)


def fill_from_colormap(settings, name, alpha="ramp"):
    """Fill the scene's ramp from a colormap preset; creates the texture when allowed. Returns
    False when the texture could not be created here (the render creates it later)."""
    tex = settings.ramp_texture
    if tex is None or getattr(tex, "color_ramp", None) is None:
        try:
            ensure_texture(settings, name)
        except (AttributeError, RuntimeError):
            return False
        tex = settings.ramp_texture
    if alpha == "keep":
        old = [e.color[3] for e in tex.color_ramp.elements]
        old_pos = [e.position for e in tex.color_ramp.elements]
        _fill(tex.color_ramp, name)
        for el in tex.color_ramp.elements:
            c = list(el.color)
            c[3] = float(np.interp(el.position, old_pos, old))
            el.color = c
    else:
        _fill(tex.color_ramp, name, alpha)
    return True


def sample(settings, n=256, *, create=True):
    """(n, 4) float32 linear RGBA: the ramp evaluated at n evenly spaced points of [0, 1]. Without
    a ramp texture (and ``create`` False) the colormap preset is used directly."""
    tex = settings.ramp_texture
    if tex is None or getattr(tex, "color_ramp", None) is None:
        if create:
            tex = ensure_texture(settings)
        else:
            from ..kernels.render.colormaps import colormap

            pos, rgba = stops_from_table(colormap(settings.colormap))
            x = np.linspace(0.0, 1.0, n)
            return np.stack([np.interp(x, pos, rgba[:, k]) for k in range(4)], 1).astype(np.float32)
    ramp = tex.color_ramp
    return np.array([ramp.evaluate(i / (n - 1)) for i in range(n)], np.float32)
