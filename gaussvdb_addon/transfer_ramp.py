"""The editable transfer function: a Blender ColorRamp (colour and alpha) filled by colormap presets.

A ColorRamp can only live inside a texture or a node, so a transfer function's ramp is that of a
Blend texture (``ramp_texture`` of the scene's settings, or of an object's own), drawn with
``template_color_ramp``. ``ramp_signature`` remembers the ramp as a colormap or preset last wrote
it, so a hand edit is told apart (``is_edited``) and not replaced silently. The texture is created
lazily (at render time, or when a colormap is picked): property update callbacks may run where
datablocks cannot be created.

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

from functools import lru_cache

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
def texture_name(settings):
    """The scene's ramp texture, or one per object ("GaussVDB Transfer Function: Smoke")."""
    owner = settings.id_data
    return TEXTURE_NAME if owner is None or owner.id_type == "SCENE" else f"{TEXTURE_NAME}: {owner.name}"


def ensure_texture(settings, colormap=None):
    """The ramp texture of ``settings`` (scene or object), created (and filled from its
    colormap) if missing. Raises where datablocks cannot be created (drawing); callers at
    render time may call it."""
    import bpy

    tex = settings.ramp_texture
    if tex is not None and getattr(tex, "color_ramp", None) is not None and tex.use_color_ramp:
        return tex
    if tex is None or tex.type != "BLEND":
        tex = bpy.data.textures.new(texture_name(settings), "BLEND")
        settings.ramp_texture = tex
    tex.use_color_ramp = True
    _fill(tex.color_ramp, colormap or settings.colormap)
    settings.ramp_signature = signature(tex.color_ramp)
    return tex


@lru_cache(maxsize=64)
def _stops(name, alpha):
    from ..kernels.render.colormaps import colormap

    return stops_from_table(colormap(name), MAX_STOPS, alpha)


def _set_elements(ramp, pos, rgba):
    els = ramp.elements
    while len(els) > 1:
        els.remove(els[-1])
    els[0].position = float(pos[0])
    for p in pos[1:]:
        els.new(float(p))  # kept sorted by Blender
    order = np.argsort(np.asarray(pos, np.float64), kind="stable")
    for el, i in zip(els, order):
        el.position = float(pos[i])
        el.color = tuple(float(v) for v in rgba[i])


def _fill(ramp, name, alpha="ramp"):
    pos, rgba = _stops(name, alpha)
    ramp.color_mode = "RGB"
    ramp.interpolation = "LINEAR"
    _set_elements(ramp, pos, rgba)


def signature(ramp):
    """A short fingerprint of a ramp's interpolation and elements (as stored, float32)."""
    import hashlib

    parts = [ramp.interpolation, ramp.color_mode]
    parts += sorted(f"{e.position:.6f}:" + ",".join(f"{c:.6f}" for c in e.color) for e in ramp.elements)
    return hashlib.sha1(";".join(parts).encode()).hexdigest()[:16]


def is_edited(settings):
    """True when the ramp differs from what its colormap (or the preset last loaded) wrote: a
    hand edit that picking a colormap must not silently replace. Files from before the
    signature compare with a fresh fill of their colormap."""
    tex = settings.ramp_texture
    ramp = getattr(tex, "color_ramp", None) if tex is not None else None
    if ramp is None:
        return False
    sig = signature(ramp)
    if settings.ramp_signature:
        return sig != settings.ramp_signature
    if ramp.interpolation != "LINEAR" or len(ramp.elements) != MAX_STOPS:
        return True
    pos, rgba = _stops(settings.colormap, settings.colormap_alpha.lower()
                       if settings.colormap_alpha != "KEEP" else "ramp")
    got = np.array([list(e.color) for e in ramp.elements])
    at = np.array([e.position for e in ramp.elements])
    return not (np.allclose(at, pos, atol=1e-5) and np.allclose(got[:, :3], rgba[:, :3], atol=1e-5))


def fill_from_colormap(settings, name, alpha="ramp"):
    """Fill the ramp of ``settings`` from a colormap preset (replacing any edit); creates the
    texture when allowed. Returns False when the texture could not be created here (the render
    creates it later)."""
    tex = settings.ramp_texture
    if tex is None or getattr(tex, "color_ramp", None) is None:
        try:
            ensure_texture(settings, name)
        except (AttributeError, RuntimeError):
            return False
        tex = settings.ramp_texture
    ramp = tex.color_ramp
    if alpha == "keep":
        old = [e.color[3] for e in ramp.elements]
        old_pos = [e.position for e in ramp.elements]
        _fill(ramp, name)
        for el in ramp.elements:
            c = list(el.color)
            c[3] = float(np.interp(el.position, old_pos, old))
            el.color = c
    else:
        _fill(ramp, name, alpha)
    settings.ramp_signature = signature(ramp)
    return True


def stops_of(settings):
    """[(position, (r, g, b, a))] of the ramp, by position (what a saved preset stores; Python
    edits of a position leave the elements unsorted until the UI sorts them), or None."""
    tex = settings.ramp_texture
    ramp = getattr(tex, "color_ramp", None) if tex is not None else None
    if ramp is None:
        return None
    return sorted(((round(float(e.position), 6), tuple(round(float(c), 6) for c in e.color))
                   for e in ramp.elements), key=lambda s: s[0])


def load_stops(settings, stops, interpolation="LINEAR"):
    """Set the ramp to ``stops`` [(position, rgba)] (at most 32, clamped to [0, 1]) and remember
    it as loaded (not edited)."""
    stops = list(stops)[:MAX_STOPS]
    if not stops:
        raise ValueError("a ramp needs at least one stop")
    pos = np.clip([float(p) for p, _ in stops], 0.0, 1.0)
    rgba = np.array([[float(v) for v in c] for _, c in stops], np.float64).reshape(-1, 4)
    ramp = ensure_texture(settings).color_ramp
    ramp.color_mode = "RGB"
    ramp.interpolation = interpolation
    _set_elements(ramp, pos, rgba)
    settings.ramp_signature = signature(ramp)
    settings.id_data.update_tag()


def sample(settings, n=256, *, create=True):
    """(n, 4) float32 linear RGBA: the ramp evaluated at n evenly spaced points of [0, 1]. Without
    a ramp texture (and ``create`` False) the colormap preset is used directly."""
    tex = settings.ramp_texture
    if tex is None or getattr(tex, "color_ramp", None) is None:
        if create:
            tex = ensure_texture(settings)
        else:
            pos, rgba = _stops(settings.colormap, "constant" if settings.colormap_alpha == "CONSTANT"
                               else "ramp")
            x = np.linspace(0.0, 1.0, n)
            return np.stack([np.interp(x, pos, rgba[:, k]) for k in range(4)], 1).astype(np.float32)
    ramp = tex.color_ramp
    return np.array([ramp.evaluate(i / (n - 1)) for i in range(n)], np.float32)
