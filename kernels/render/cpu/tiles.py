"""Screen tiles for the particles and field modes: per frame, each visible Gaussian's support
ellipsoid is projected to the image (its exact bounding rectangle in pixels) and listed in the
TILE x TILE pixel tiles it covers, each list ordered by a lower bound of the ray distance at which
any ray can enter the support. Each entry carries the 64-bit mask of the tile's pixels inside the
rectangle, so a pixel scans its list sequentially and touches a Gaussian's data only when its
bit is set. A pixel then tests only its tile's Gaussians, front to back: once
the Gaussians with lower bound below t are tested, every chord entering before t is known, so the
event sweep can run up to there (the same completeness rule the leaf walk gives).

Why the rectangle is exact for perspective: the image-plane lines x = u (-z) that touch the support
are the planes through the eye tangent to the ellipsoid, (n . c)^2 = n^T S n with n = (1, 0, u): a
quadratic in u whose roots bound the footprint (S = the support's shape matrix in camera space).
"""
from __future__ import annotations

import math

import numpy as np

from ...jit import njit, parallel_for
from ..inputs.layout import (
    CAM_EX,
    CAM_EY,
    CAM_H,
    CAM_KIND,
    CAM_OX,
    CAM_OY,
    CAM_POS,
    CAM_ROT,
    CAM_W,
    LEAF,
    TILE,
)
from .vecmath import INF, _jit

MARGIN_PX = 1e-3  # widen the pixel rectangle for the rounding of the projection


@njit(**_jit, inline="always")
def _px_range(lo, hi, off, ext, n):
    """Pixels whose centre coordinate ((i + 1/2) / n - 1/2) ext + off lies in [lo, hi]."""
    a = (lo - off) / ext * n + 0.5 * n - 0.5 - MARGIN_PX
    b = (hi - off) / ext * n + 0.5 * n - 0.5 + MARGIN_PX
    a = min(max(a, -1.0), n + 1.0)
    b = min(max(b, -1.0), n + 1.0)
    i0 = max(int(math.ceil(a)), 0)
    i1 = min(int(math.floor(b)), n - 1)
    return i0, i1


@njit(**_jit, inline="always")
def _roots(c, cz, sxx, sxz, szz):
    """Tangent-plane roots u (see module doc) for one image axis; c, cz camera coordinates of the
    centre (cz < 0, in front)."""
    a = cz * cz - szz
    b = c * cz - sxz
    disc = b * b - a * (c * c - sxx)
    r = math.sqrt(disc) if disc > 0.0 else 0.0
    u0 = (-b - r) / a
    u1 = (-b + r) / a
    return min(u0, u1), max(u0, u1)


@njit(**_jit, inline="always")
def _straddle_range(c, cz, sxx, sxz, szz, off, ext):
    """Image coordinates u (one axis) of the eye planes x = u (-z) that meet a support straddling
    the eye's plane (cz^2 <= szz), clipped to the image's span [off - ext/2, off + ext/2]. With
    a = cz^2 - szz <= 0 the plane meets the support where a u^2 + 2 b u + c' <= 0: outside the
    roots, i.e. two unbounded pieces. One piece inside the span -> that piece; both -> the whole
    span (conservative); none -> an empty range. A camera inside a volume sees most of the
    supports around it far off to the side, so they now cover few tiles or none."""
    lo = off - 0.5 * ext
    hi = off + 0.5 * ext
    a = cz * cz - szz
    b = c * cz - sxz
    cc = c * c - sxx
    disc = b * b - a * cc
    if a >= 0.0 or disc <= 0.0:
        return lo, hi  # a degenerate (tangent) case, or every plane meets the support
    r = math.sqrt(disc)
    u0 = min((-b - r) / a, (-b + r) / a)
    u1 = max((-b - r) / a, (-b + r) / a)
    left = u0 >= lo  # the piece u <= u0 reaches into the span
    right = u1 <= hi  # the piece u >= u1 does
    if left and right:
        return lo, hi
    if left:
        return lo, min(u0, hi)
    if right:
        return max(u1, lo), hi
    return hi + 1.0, lo - 1.0  # neither: no pixel (_px_range: empty when lo > hi)


def gauss_footprints(cam, cmat, onorm, g_mu, g_inv, g_obj, g_w, k, box, lb):
    """Per Gaussian: box = pixel rectangle (i0, i1, j0, j1; empty when i0 > i1 or j0 > j1) and lb =
    a lower bound of the ray parameter where rays enter its k-sigma support.
    cmat[ob] (3x4): index space -> camera coordinates (the camera basis inverse times the object's
    index-to-world matrix, translation relative to the camera position); onorm[ob]: the spectral
    norm of the object's index-to-world linear part."""
    parallel_for(_footprints, g_mu.shape[0], cam, cmat, onorm, g_mu, g_inv, g_obj, g_w, float(k), box, lb)


@njit(**_jit)
def _footprints(g0, g1, cam, cmat, onorm, g_mu, g_inv, g_obj, g_w, k, box, lb):
    W = int(cam[CAM_W])
    H = int(cam[CAM_H])
    ex, ey, offx, offy = cam[CAM_EX], cam[CAM_EY], cam[CAM_OX], cam[CAM_OY]
    ortho = cam[CAM_KIND] > 0.5
    for g in range(g0, g1):
        box[g, 0] = 1
        box[g, 1] = 0
        box[g, 2] = 1
        box[g, 3] = 0
        lb[g] = INF
        if g_w[g] == 0.0:
            continue
        ob = g_obj[g]
        B = cmat[ob]
        m0, m1, m2 = g_mu[g, 0], g_mu[g, 1], g_mu[g, 2]
        cx = B[0, 0] * m0 + B[0, 1] * m1 + B[0, 2] * m2 + B[0, 3]
        cy = B[1, 0] * m0 + B[1, 1] * m1 + B[1, 2] * m2 + B[1, 3]
        cz = B[2, 0] * m0 + B[2, 1] * m1 + B[2, 2] * m2 + B[2, 3]
        s0 = k / g_inv[g, 0]
        s1 = k / g_inv[g, 1]
        s2 = k / g_inv[g, 2]
        s0, s1, s2 = s0 * s0, s1 * s1, s2 * s2
        sxx = B[0, 0] * B[0, 0] * s0 + B[0, 1] * B[0, 1] * s1 + B[0, 2] * B[0, 2] * s2
        syy = B[1, 0] * B[1, 0] * s0 + B[1, 1] * B[1, 1] * s1 + B[1, 2] * B[1, 2] * s2
        szz = B[2, 0] * B[2, 0] * s0 + B[2, 1] * B[2, 1] * s1 + B[2, 2] * B[2, 2] * s2
        sxz = B[0, 0] * B[2, 0] * s0 + B[0, 1] * B[2, 1] * s1 + B[0, 2] * B[2, 2] * s2
        syz = B[1, 0] * B[2, 0] * s0 + B[1, 1] * B[2, 1] * s1 + B[1, 2] * B[2, 2] * s2
        if ortho:
            rz = math.sqrt(szz)
            rx = math.sqrt(sxx)
            ry = math.sqrt(syy)
            i0, i1 = _px_range(cx - rx, cx + rx, offx, ex, W)
            j0, j1 = _px_range(cy - ry, cy + ry, offy, ey, H)
            lbg = -cz - rz
        elif cz * cz > szz:
            if cz > 0.0:
                continue  # wholly behind the eye
            u0, u1 = _roots(cx, cz, sxx, sxz, szz)
            v0, v1 = _roots(cy, cz, syy, syz, szz)
            i0, i1 = _px_range(u0, u1, offx, ex, W)
            j0, j1 = _px_range(v0, v1, offy, ey, H)
            rmax = onorm[ob] * k / min(g_inv[g, 0], g_inv[g, 1], g_inv[g, 2])
            lbg = math.sqrt(cx * cx + cy * cy + cz * cz) - rmax
        else:  # the support straddles the eye's plane (or holds the eye): see _straddle_range
            ua, ub = _straddle_range(cx, cz, sxx, sxz, szz, offx, ex)
            va, vb = _straddle_range(cy, cz, syy, syz, szz, offy, ey)
            i0, i1 = _px_range(ua, ub, offx, ex, W)
            j0, j1 = _px_range(va, vb, offy, ey, H)
            lbg = -INF  # its chords may enter behind the eye: tested first
        box[g, 0], box[g, 1], box[g, 2], box[g, 3] = i0, i1, j0, j1
        # a hair below, so a chord rounded in index space is never found after its time
        lb[g] = lbg - 1e-9 * (abs(lbg) + 1.0)


NCHUNK = 8  # Gaussian chunks counted and scattered in parallel; chunk by chunk keeps id order


@njit(**_jit, inline="always")
def tile_span(box, g):
    """Tiles covered by Gaussian g's rectangle: tx0, tx1, ty0, ty1 (an empty range when none)."""
    if box[g, 0] > box[g, 1] or box[g, 2] > box[g, 3]:
        return 0, -1, 0, -1
    return box[g, 0] // TILE, box[g, 1] // TILE, box[g, 2] // TILE, box[g, 3] // TILE


def tile_counts(box, ntx, nty):
    """Entries per Gaussian chunk and tile: cnt[c, t]."""
    cnt = np.zeros((NCHUNK, ntx * nty), np.int64)
    parallel_for(_tile_counts, NCHUNK, box, np.int64(ntx), cnt)
    return cnt


@njit(**_jit)
def _tile_counts(c0, c1, box, ntx, cnt):
    m = box.shape[0]
    for c in range(c0, c1):
        for g in range(c * m // NCHUNK, (c + 1) * m // NCHUNK):
            tx0, tx1, ty0, ty1 = tile_span(box, g)
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    cnt[c, ty * ntx + tx] += 1


def tile_fill(box, lb, cnt, start, ntx):
    """Tile lists (tile t: items[start[t]:start[t + 1]], start from cnt's column sums), each sorted
    by (lb, id): Gaussian ids (int32) and per entry the mask of the tile's pixels in its rectangle
    (int64, bit TILE * (j % TILE) + i % TILE for pixel column i, row j)."""
    items = np.empty(start[-1], np.int32)
    masks = np.empty(start[-1], np.int64)
    fill = np.empty_like(cnt)
    parallel_for(_chunk_starts, cnt.shape[1], cnt, start, fill)
    parallel_for(_scatter, NCHUNK, box, np.int64(ntx), fill, items)
    parallel_for(_sort_masks, start.shape[0] - 1, box, lb, start, np.int64(ntx), items, masks)
    return items, masks


@njit(**_jit)
def _chunk_starts(t0, t1, cnt, start, fill):
    """Where each Gaussian chunk's entries of tile t begin: chunk by chunk keeps id order."""
    for t in range(t0, t1):
        acc = start[t]
        for c in range(NCHUNK):
            fill[c, t] = acc
            acc += cnt[c, t]


@njit(**_jit)
def _scatter(c0, c1, box, ntx, fill, items):
    m = box.shape[0]
    for c in range(c0, c1):
        for g in range(c * m // NCHUNK, (c + 1) * m // NCHUNK):
            tx0, tx1, ty0, ty1 = tile_span(box, g)
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    t = ty * ntx + tx
                    items[fill[c, t]] = g
                    fill[c, t] += 1


@njit(**_jit)
def _sort_by_lb(items, a, b, lb):
    """items[a:b] (ids in increasing order) sorted stably by lb[id], NaN last: what
    np.argsort(kind="mergesort") gives, as a bottom-up merge sort of its own (numba's stable
    argsort compiled 1.5 s of a cold frame)."""
    n = b - a
    src = items[a:b].copy()
    dst = np.empty_like(src)
    w = 1
    while w < n:
        for lo in range(0, n, 2 * w):
            mid = min(lo + w, n)
            hi = min(lo + 2 * w, n)
            i, j, k = lo, mid, lo
            while i < mid and j < hi:
                x, y = lb[src[j]], lb[src[i]]
                if x < y or (x == x and y != y):  # the right one strictly first: ties keep order
                    dst[k] = src[j]
                    j += 1
                else:
                    dst[k] = src[i]
                    i += 1
                k += 1
            while i < mid:
                dst[k] = src[i]
                i += 1
                k += 1
            while j < hi:
                dst[k] = src[j]
                j += 1
                k += 1
        src, dst = dst, src
        w *= 2
    for q in range(n):
        items[a + q] = src[q]


@njit(**_jit)
def _sort_masks(t0, t1, box, lb, start, ntx, items, masks):
    """Each tile's list sorted by (lb, id), and its pixel masks."""
    for t in range(t0, t1):
        a = start[t]
        b = start[t + 1]
        if b - a > 1:
            _sort_by_lb(items, a, b, lb)
        x0 = (t % ntx) * TILE
        y0 = (t // ntx) * TILE
        for q in range(a, b):
            g = items[q]
            i0 = max(box[g, 0] - x0, 0)
            i1 = min(box[g, 1] - x0, TILE - 1)
            row = (np.int64(1) << (i1 + 1)) - (np.int64(1) << i0)  # bits i0..i1
            bits = np.int64(0)
            for y in range(max(box[g, 2] - y0, 0), min(box[g, 3] - y0, TILE - 1) + 1):
                bits |= row << (TILE * y)
            masks[q] = bits


def tile_camera(cam, i2w):
    """Per object: cmat (3x4, index space -> camera coordinates relative to the camera position)
    and onorm (the spectral norm of its index-to-world linear part), as gauss_footprints takes."""
    rot = np.asarray(cam[CAM_ROT:CAM_ROT + 9], np.float64).reshape(3, 3)
    pos = np.asarray(cam[CAM_POS:CAM_POS + 3], np.float64)
    rinv = np.linalg.inv(rot)
    n = len(i2w)
    cmat = np.zeros((n, 3, 4))
    onorm = np.zeros(n)
    for j, mw in enumerate(i2w):
        cmat[j, :, :3] = rinv @ mw[:3, :3]
        cmat[j, :, 3] = rinv @ (mw[:3, 3] - pos)
        onorm[j] = np.linalg.norm(mw[:3, :3], 2)
    return cmat, onorm


def screen_tiles(cam, i2w, g_mu, g_inv, g_obj, g_w, k, limit):
    """The screen-tile lists (above) of Gaussians with weights g_w for the packed camera cam
    and the objects' index -> world matrices i2w: starts, ids, pixel masks and each Gaussian's
    entry bound; None when they would hold more than limit entries."""
    cmat, onorm = tile_camera(cam, i2w)
    m = g_mu.shape[0]
    box = np.empty((m, 4), np.int32)
    lb = np.empty(m)
    gauss_footprints(cam, cmat, onorm, g_mu, g_inv, g_obj, g_w, float(k), box, lb)
    ntx = (int(cam[CAM_W]) + TILE - 1) // TILE
    nty = (int(cam[CAM_H]) + TILE - 1) // TILE
    cnt = tile_counts(box, ntx, nty)
    start = np.zeros(ntx * nty + 1, np.int64)
    np.cumsum(cnt.sum(0), out=start[1:])
    if start[-1] > limit:
        return None
    items, masks = tile_fill(box, lb, cnt, start, ntx)
    return start, items, masks, lb


def leaf_tiles(cam, w2i, cell_xyz, cell_obj, cell_skip):
    """Reference mode's empty-space test per screen tile: tile t's leaf count is start[t + 1] -
    start[t] (the leaves, skipped ones left out, whose bounding sphere's footprint meets it); a
    pixel of a tile with none walks nothing. w2i: the objects' world -> index matrices. With
    NO_TILES' layout (ids and masks unused)."""
    n = cell_xyz.shape[0]
    centre = cell_xyz * float(LEAF) + 0.5 * (LEAF - 1)  # a leaf's voxels span 8 c - 0.5 .. 8 c + 7.5
    inv = np.full((n, 3), 1.0 / (0.5 * LEAF * math.sqrt(3.0)))
    cmat, onorm = tile_camera(cam, [np.linalg.inv(m) for m in w2i])
    box = np.empty((n, 4), np.int32)
    gauss_footprints(cam, cmat, onorm, centre, inv, cell_obj.astype(np.int32),
                     (cell_skip == 0).astype(np.float64), 1.0, box, np.empty(n))
    ntx = (int(cam[CAM_W]) + TILE - 1) // TILE
    nty = (int(cam[CAM_H]) + TILE - 1) // TILE
    start = np.zeros(ntx * nty + 1, np.int64)
    np.cumsum(tile_counts(box, ntx, nty).sum(0), out=start[1:])
    return start, np.zeros(1, np.int32), np.zeros(1, np.int64)
