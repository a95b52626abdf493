"""Front-to-back walk of an object's leaf hierarchy (nodes of 128^3, leaves of 8^3) with integer
cell indices, or of one of its grids of coarser cells (accel.py's levels)."""
from __future__ import annotations

import math

from ...jit import njit
from ..inputs.layout import LEAF, NODE, NODE_LEAVES
from .vecmath import INF, _hot


@njit(**_hot)
def slab(ox, oy, oz, dx, dy, dz, lx, ly, lz, hx, hy, hz, t0, t1):
    """NaN-free slab test: zero direction components are handled explicitly."""
    o = (ox, oy, oz)
    d = (dx, dy, dz)
    lo = (lx, ly, lz)
    hi = (hx, hy, hz)
    for k in range(3):
        if d[k] == 0.0:
            if o[k] < lo[k] or o[k] > hi[k]:
                return 1.0, 0.0
        else:
            inv = 1.0 / d[k]
            ta = (lo[k] - o[k]) * inv
            tb = (hi[k] - o[k]) * inv
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
    return t0, t1


@njit(**_hot)
def dda_axis(o, d, t, size, lo, hi):
    """Integer cell, step, t of the next boundary, t per cell along one axis."""
    c = int(math.floor((o + t * d) / size))
    if c < lo:
        c = lo
    if c > hi - 1:
        c = hi - 1
    if d > 0.0:
        return c, 1, ((c + 1) * size - o) / d, size / d
    if d < 0.0:
        return c, -1, (c * size - o) / d, -size / d
    return c, 0, INF, INF


@njit(**_hot)
def walk_object(ox, oy, oz, dx, dy, dz, t_near, t_far, nmin, ndims, noff, node_table, node_cells,
                node_box, cell_skip, obj, iv_ta, iv_tb, iv_obj, iv_cell, n, cap, scale):
    """Hierarchical DDA (nodes of 128^3, then leaves of 8^3, integer cell indices; both ``scale``
    times larger for a grid of coarse cells) in q-space (q = index + 0.5) over the ray's [t_near, t_far];
    appends the non-empty, non-transparent cell intervals front to back, tagged ``obj``. Inside a
    node the leaf DDA runs only over the box of its drawn cells (node_box, packing.node_boxes):
    most of a sparse node is empty, and stepping through it cost more than the samples."""
    if ndims[0] == 0:
        return n
    node = float(NODE) * scale
    leaf = float(LEAF) * scale
    qx, qy, qz = ox + 0.5, oy + 0.5, oz + 0.5
    t0, t1 = slab(qx, qy, qz, dx, dy, dz, nmin[0] * node, nmin[1] * node, nmin[2] * node,
                  (nmin[0] + ndims[0]) * node, (nmin[1] + ndims[1]) * node,
                  (nmin[2] + ndims[2]) * node, t_near, t_far)
    if not t0 < t1:
        return n
    t = t0
    cx, sx, mx, ex = dda_axis(qx, dx, t, node, nmin[0], nmin[0] + ndims[0])
    cy, sy, my, ey = dda_axis(qy, dy, t, node, nmin[1], nmin[1] + ndims[1])
    cz, sz, mz, ez = dda_axis(qz, dz, t, node, nmin[2], nmin[2] + ndims[2])
    while True:
        t_near = min(mx, my, mz, t1)
        if t_near > t:
            nid = node_table[noff + ((cx - nmin[0]) * ndims[1] + (cy - nmin[1])) * ndims[2] + (cz - nmin[2])]
            if nid >= 0 and node_box[nid, 0] < node_box[nid, 3]:
                # leaf-level DDA over the node's drawn cells [lo, hi) within [t, t_near]
                bx, by, bz = cx * NODE_LEAVES, cy * NODE_LEAVES, cz * NODE_LEAVES
                x0, y0, z0 = bx + node_box[nid, 0], by + node_box[nid, 1], bz + node_box[nid, 2]
                x1, y1, z1 = bx + node_box[nid, 3], by + node_box[nid, 4], bz + node_box[nid, 5]
                u, ue = slab(qx, qy, qz, dx, dy, dz, x0 * leaf, y0 * leaf, z0 * leaf, x1 * leaf,
                             y1 * leaf, z1 * leaf, t, t_near)
                if u < ue:
                    lx, lsx, lmx, lex = dda_axis(qx, dx, u, leaf, x0, x1)
                    ly, lsy, lmy, ley = dda_axis(qy, dy, u, leaf, y0, y1)
                    lz, lsz, lmz, lez = dda_axis(qz, dz, u, leaf, z0, z1)
                    while True:
                        un = min(lmx, lmy, lmz, ue)
                        if un > u:
                            cid = node_cells[nid, ((lx - bx) * NODE_LEAVES + (ly - by)) * NODE_LEAVES + (lz - bz)]
                            if cid >= 0 and cell_skip[cid] == 0 and n < cap:
                                iv_ta[n] = u
                                iv_tb[n] = un
                                iv_obj[n] = obj
                                iv_cell[n] = cid
                                n += 1
                        if un >= ue:
                            break
                        if lmx <= lmy and lmx <= lmz:
                            lx += lsx
                            lmx += lex
                            if lx < x0 or lx >= x1:
                                break
                        elif lmy <= lmz:
                            ly += lsy
                            lmy += ley
                            if ly < y0 or ly >= y1:
                                break
                        else:
                            lz += lsz
                            lmz += lez
                            if lz < z0 or lz >= z1:
                                break
                        if un > u:
                            u = un
        if t_near >= t1:
            break
        if mx <= my and mx <= mz:
            cx += sx
            mx += ex
            if cx < nmin[0] or cx >= nmin[0] + ndims[0]:
                break
        elif my <= mz:
            cy += sy
            my += ey
            if cy < nmin[1] or cy >= nmin[1] + ndims[1]:
                break
        else:
            cz += sz
            mz += ez
            if cz < nmin[2] or cz >= nmin[2] + ndims[2]:
                break
        if t_near > t:
            t = t_near
    return n


@njit(**_hot)
def clip_interval(hs, ox, oy, oz, dx, dy, dz):
    """The t interval of the world ray o + t d inside all half-spaces hs[:, 4] (-inf, inf when
    none cut it; lo >= hi when it misses)."""
    lo = -INF
    hi = INF
    for k in range(hs.shape[0]):
        num = hs[k, 0] * ox + hs[k, 1] * oy + hs[k, 2] * oz + hs[k, 3]
        den = hs[k, 0] * dx + hs[k, 1] * dy + hs[k, 2] * dz
        if den > 0.0:
            lo = max(lo, -num / den)
        elif den < 0.0:
            hi = min(hi, -num / den)
        elif num < 0.0:
            return INF, -INF
    return lo, hi
