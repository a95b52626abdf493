"""Lights for lit level-set surfaces (Blinn-Phong): suns, and point-like lights (point, spot and
area lights count as a point at their centre). With none, a headlight (a strength-1 white sun
shining along each ray) lights the scene.

Units as Blender's: a sun's ``strength`` is its irradiance (W/m^2), so a white surface facing a
strength-1 sun shades to its albedo (diffuse 1, no ambient); a point light's ``strength`` is its
power (W), giving the irradiance P / (4 pi r^2) at distance r.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..inputs.layout import LIGHT_KIND, LIGHT_RGB, LIGHT_SIZE, LIGHT_VEC, LightKind

KINDS = ("sun", "point")


@dataclass
class Light:
    kind: str = "sun"
    vector: tuple = (0.0, 0.0, -1.0)  # sun: the direction its light travels; point: its position
    color: tuple = (1.0, 1.0, 1.0)
    strength: float = 1.0

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"light kind must be one of {KINDS}, not {self.kind!r}")
        v = np.asarray(self.vector, np.float64).reshape(3)
        if self.kind == "sun" and not np.linalg.norm(v) > 0.0:
            raise ValueError("a sun's direction must not be zero")
        if not (np.all(np.isfinite(v)) and math.isfinite(self.strength)):
            raise ValueError("light vector and strength must be finite")


def pack(lights) -> np.ndarray:
    """(n, LIGHT_SIZE) float64 rows, layout.LIGHT_ROW [kind, x, y, z, r, g, b, 0]: suns with their
    unit travel direction and colour x irradiance, points with their position and colour x
    power / 4 pi; the headlight (white) alone when there are none."""
    if not lights:
        out = np.zeros((1, LIGHT_SIZE))
        out[0, LIGHT_KIND] = LightKind.HEADLIGHT
        out[0, LIGHT_RGB:LIGHT_RGB + 3] = 1.0
        return out
    out = np.zeros((len(lights), LIGHT_SIZE))
    for i, lt in enumerate(lights):
        v = np.asarray(lt.vector, np.float64)
        c = np.asarray(lt.color, np.float64)[:3] * float(lt.strength)
        if lt.kind == "sun":
            out[i, LIGHT_KIND], vec, rgb = LightKind.SUN, v / np.linalg.norm(v), c
        else:
            out[i, LIGHT_KIND], vec, rgb = LightKind.POINT, v, c / (4.0 * math.pi)
        out[i, LIGHT_VEC:LIGHT_VEC + 3], out[i, LIGHT_RGB:LIGHT_RGB + 3] = vec, rgb
    return out
