"""Cameras and primary rays.

Convention (Blender's): ``cam_to_world`` is the camera object's world matrix; the camera looks
down its local -Z axis, +Y is up and +X is right in the image. Scale in the matrix is ignored
(the rotation columns are normalised). ``sensor_fit`` is AUTO: ``fov_x`` (perspective) or
``ortho_scale`` (orthographic) spans the LARGER image dimension (the width when width >= height).
``shift_x``/``shift_y`` are in units of that larger dimension, as in Blender. ``pixel_aspect``
is a pixel's height over its width (Blender's pixel_aspect_y / pixel_aspect_x): the image spans
width x height * pixel_aspect in those units.

Pixel (col i, row j) is sampled at its centre; row 0 is the BOTTOM row, matching Blender's
render-pass buffers. Ray directions are unit WORLD vectors, so ray parameters t are world
distances. Perspective rays start at the camera position, orthographic rays on the camera plane.
Only the part of a ray between ``clip_start`` and ``clip_end`` is rendered; like Blender's, the
clip distances are measured along the view axis (a perspective ray at angle a to it runs from
clip_start / cos a).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..inputs.layout import (
    CAM_CLIP,
    CAM_EX,
    CAM_EY,
    CAM_H,
    CAM_KIND,
    CAM_OX,
    CAM_OY,
    CAM_POS,
    CAM_ROT,
    CAM_SIZE,
    CAM_W,
)

DEFAULT_FOV = 2.0 * math.atan(18.0 / 50.0)  # Blender default: 50 mm lens, 36 mm sensor


@dataclass
class Camera:
    cam_to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    width: int = 64
    height: int = 64
    kind: str = "persp"  # 'persp' | 'ortho'
    fov_x: float = DEFAULT_FOV
    ortho_scale: float = 1.0
    shift_x: float = 0.0
    shift_y: float = 0.0
    clip_start: float = 0.0
    clip_end: float = math.inf
    pixel_aspect: float = 1.0

    def __post_init__(self):
        self.cam_to_world = np.asarray(self.cam_to_world, dtype=np.float64).reshape(4, 4)
        self.width, self.height = int(self.width), int(self.height)
        if self.kind not in ("persp", "ortho"):
            raise ValueError(f"camera kind must be 'persp' or 'ortho', not {self.kind!r}")
        if self.width < 1 or self.height < 1:
            raise ValueError("image size must be positive")
        self.clip_start, self.clip_end = float(self.clip_start), float(self.clip_end)
        if not 0.0 <= self.clip_start <= self.clip_end:
            raise ValueError(f"camera clip range must satisfy 0 <= start <= end, not "
                             f"{self.clip_start}..{self.clip_end}")
        if not self.pixel_aspect > 0.0:
            raise ValueError(f"pixel aspect must be positive, not {self.pixel_aspect}")

    # -- packed form for the kernels ------------------------------------------------------
    def plane(self):
        """(extent_x, extent_y, offset_x, offset_y): the image rectangle on the plane z = -1
        (persp) or the camera plane (ortho), in camera units."""
        big = 2.0 * math.tan(0.5 * self.fov_x) if self.kind == "persp" else float(self.ortho_scale)
        h = self.height * self.pixel_aspect
        m = max(self.width, h)
        return (big * self.width / m, big * h / m, self.shift_x * big, self.shift_y * big)

    def basis(self):
        """Orthonormalised rotation (3x3, columns = camera x, y, z in world) and position."""
        m = self.cam_to_world
        r = m[:3, :3].copy()
        for k in range(3):
            n = np.linalg.norm(r[:, k])
            if n > 0:
                r[:, k] /= n
        return r, m[:3, 3].copy()

    def packed(self) -> np.ndarray:
        """float64 (CAM_SIZE,), layout.CAM: kind (1: ortho), W, H, ex, ey, ox, oy, R (9,
        row-major), pos (3), clip start, end."""
        r, p = self.basis()
        out = np.zeros(CAM_SIZE)
        out[CAM_KIND] = 1.0 if self.kind == "ortho" else 0.0
        out[CAM_W], out[CAM_H] = self.width, self.height
        out[CAM_EX], out[CAM_EY], out[CAM_OX], out[CAM_OY] = self.plane()
        out[CAM_ROT:CAM_ROT + 9] = r.ravel()
        out[CAM_POS:CAM_POS + 3] = p
        out[CAM_CLIP], out[CAM_CLIP + 1] = self.clip_start, self.clip_end
        return out

    # -- framing ---------------------------------------------------------------------------
    @classmethod
    def frame_box(cls, box_min, box_max, width, height, direction=(0.0, 1.0, 0.0), *,
                  kind="persp", fov_x=DEFAULT_FOV, up=(0.0, 0.0, 1.0), margin=1.05):
        """A camera that frames the world AABB [box_min, box_max].

        ``direction`` is the world viewing direction (camera -> box centre); the default looks
        along +Y like Blender's Front view. ``up`` is the world up (+Z), used unless parallel to
        the direction. The box's bounding sphere (radius r, times ``margin``) fits in the smaller
        field of view: perspective cameras sit at distance r / sin(fov_min / 2) from the centre,
        orthographic ones get ortho_scale = 2 r * max(W, H) / min(W, H) and sit 2 r in front."""
        lo = np.asarray(box_min, dtype=np.float64)
        hi = np.asarray(box_max, dtype=np.float64)
        c = 0.5 * (lo + hi)
        r = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-12) * margin
        fwd = np.asarray(direction, dtype=np.float64)
        fwd = fwd / np.linalg.norm(fwd)
        upv = np.asarray(up, dtype=np.float64)
        if abs(np.dot(upv, fwd)) > 0.999 * np.linalg.norm(upv):
            upv = np.array([0.0, 1.0, 0.0]) if abs(fwd[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        x = np.cross(fwd, upv)
        x /= np.linalg.norm(x)
        y = np.cross(x, fwd)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2] = x, y, -fwd
        aspect = max(width, height) / min(width, height)
        if kind == "persp":
            half_big = 0.5 * fov_x
            half_small = math.atan(math.tan(half_big) / aspect)
            dist = r / math.sin(half_small)
            m[:3, 3] = c - fwd * dist
            return cls(m, width, height, "persp", fov_x=fov_x)
        m[:3, 3] = c - fwd * 2.0 * r
        return cls(m, width, height, "ortho", ortho_scale=2.0 * r * aspect)


def generate_rays(camera: Camera, rows=None):
    """Origins and unit directions (float64, (n, 3)) for the pixel centres of rows
    ``rows = (row0, row1)`` (default all), row-major from the bottom row."""
    r0, r1 = (0, camera.height) if rows is None else rows
    ex, ey, ox, oy = camera.plane()
    rot, pos = camera.basis()
    jj, ii = np.meshgrid(np.arange(r0, r1), np.arange(camera.width), indexing="ij")
    px = ((ii + 0.5) / camera.width - 0.5) * ex + ox
    py = ((jj + 0.5) / camera.height - 0.5) * ey + oy
    px, py = px.ravel(), py.ravel()
    if camera.kind == "persp":
        dc = np.stack([px, py, -np.ones_like(px)], axis=1)
        d = dc @ rot.T
        o = np.broadcast_to(pos, d.shape).copy()
    else:
        d = np.broadcast_to(-rot[:, 2], (px.size, 3)).copy()
        o = pos + px[:, None] * rot[:, 0] + py[:, None] * rot[:, 1]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d
