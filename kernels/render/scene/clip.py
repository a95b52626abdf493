"""Per-object clipping: an object keeps only the part of its medium inside all of its clip
half-spaces, rows (a, b, c, d) of world points with a x + b y + c z + d >= 0. Their intersection is
convex, so each ray meets it in one interval (cpu.walk.clip_interval), which narrows that object's chords
(particles, field, paper) and leaf intervals (reference): the medium ends exactly at the cut, so
the cut face shows the volume's colour there.

A clip plane is an object's local XY plane keeping the side its local +Z axis points to; a clip
box is its local [-1, 1]^3 cube (Blender Empties: an Empty's matrix_world).
"""
from __future__ import annotations

import numpy as np


def _inverse_rows(matrix):
    m = np.asarray(matrix, np.float64).reshape(4, 4)
    try:
        inv = np.linalg.inv(m)
    except np.linalg.LinAlgError:
        inv = None
    if inv is None or not np.all(np.isfinite(inv)):
        raise ValueError("clip object's matrix is singular (zero scale)")
    return inv


def plane_from_matrix(matrix) -> np.ndarray:
    """(1, 4): the half-space local z >= 0 of the object with this world matrix."""
    return _inverse_rows(matrix)[2:3].copy()


def box_from_matrix(matrix) -> np.ndarray:
    """(6, 4): the local cube -1 <= x, y, z <= 1 of the object with this world matrix."""
    inv = _inverse_rows(matrix)
    rows = []
    for k in range(3):
        r = inv[k].copy()
        r[3] += 1.0            # u_k + 1 >= 0
        rows.append(r)
        r = -inv[k].copy()
        r[3] += 1.0            # 1 - u_k >= 0
        rows.append(r)
    return np.array(rows)


def plane_from_point_normal(point, normal) -> np.ndarray:
    """(1, 4): the world half-space n . (x - p) >= 0 (the side the normal points to)."""
    p = np.asarray(point, np.float64).reshape(3)
    n = np.asarray(normal, np.float64).reshape(3)
    if not np.linalg.norm(n) > 0.0:
        raise ValueError("clip plane normal must not be zero")
    return np.array([[n[0], n[1], n[2], -float(n @ p)]])


def box_from_corners(lo, hi) -> np.ndarray:
    """(6, 4): the world axis-aligned box lo <= x <= hi."""
    lo = np.asarray(lo, np.float64).reshape(3)
    hi = np.asarray(hi, np.float64).reshape(3)
    if not np.all(hi > lo):
        raise ValueError(f"clip box needs min < max on every axis, not {lo.tolist()}..{hi.tolist()}")
    rows = []
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        rows.append([*e, -lo[k]])
        rows.append([*(-e), hi[k]])
    return np.array(rows)


def halfspaces(clip) -> np.ndarray:
    """A RenderObject's ``clip`` as a (k, 4) float64 array (None: no rows)."""
    if clip is None:
        return np.zeros((0, 4))
    c = np.asarray(clip, np.float64)
    if c.size == 0:
        return np.zeros((0, 4))
    if c.ndim != 2 or c.shape[1] != 4 or not np.all(np.isfinite(c)):
        raise ValueError("clip must be rows (a, b, c, d) of finite numbers: a x + b y + c z + d >= 0")
    return c


def pack(objects) -> np.ndarray:
    """(n, k, 4) for the kernels, k >= 1; short lists are padded with 0 x + 1 >= 0 (always kept)."""
    rows = []
    for o in objects:
        try:
            rows.append(halfspaces(getattr(o, "clip", None)))
        except ValueError as err:
            raise ValueError(f"object {getattr(o, 'name', '') or '?'}: {err}") from None
    k = max([1] + [r.shape[0] for r in rows])
    out = np.zeros((max(1, len(rows)), k, 4))
    out[:, :, 3] = 1.0
    for i, r in enumerate(rows):
        out[i, :r.shape[0]] = r
    return out
