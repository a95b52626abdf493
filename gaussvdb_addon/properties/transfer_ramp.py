"""The editable transfer function: a Blender ColorRamp (colour and alpha) filled by colormap presets.

A ColorRamp can only live inside a texture or a node, so a transfer function's ramp is that of a
Blend texture (``ramp_texture`` of the scene's settings, or of an object's own), drawn with
``template_color_ramp``. ``ramp_signature`` remembers the ramp as a colormap or preset last wrote
it, so a hand edit is told apart (``is_edited``) and not replaced silently. The texture is created
lazily (at render time, or when a colormap is picked): property update callbacks may run where
datablocks cannot be created.

Filling from a colormap: the 32 stops of kernels/render/scene/colormaps.py's ``stops_from_table``
(the table within 1/255 for the smooth maps); edit the ramp's alpha freely afterwards.
"""

from functools import lru_cache

import numpy as np

from ...kernels.colormap_names import RAMP_STOPS as MAX_STOPS

TEXTURE_NAME = "GaussVDB Transfer Function"


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
    from ...kernels.render.scene.colormaps import colormap, stops_from_table

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
