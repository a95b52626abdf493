"""The lattice path's per-cell sums (error_lattice.py): a cell gathers each class's nodes from
the 27 leaf groups around it into a window, then adds them at its 8^3 voxels either node by node
(few nodes: the pair path's own products and cut) or by separable passes: along z, per window
column, the running sums of w e_z over the nodes in order of distance (one sum per z level),
then per voxel column (x, y) e_x e_y times the sum down to the deepest z level that the k-sigma
ellipsoid keeps for that (node x, node y). Either way each (voxel, node) term is the same as on
the pair lists; only the order of the additions differs."""
from __future__ import annotations

from ..jit import njit
from .error_pairs import _key

DIRECT_FACTOR = 6.0  # a direct multiply-add costs about this many separable ones (measured)


@njit(cache=True, inline="always")
def _find(keys, n, key):
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) >> 1
        if keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo if lo < n and keys[lo] == key else -1


@njit(cache=True)
def neighbours(c, corg, keys, nlg, nb):
    """nb[27]: the index in the chunk's groups of each leaf around cell c (-1: none)."""
    cx, cy, cz = corg[c, 0] >> 3, corg[c, 1] >> 3, corg[c, 2] >> 3
    for dx in range(3):
        for dy in range(3):
            for dz in range(3):
                nb[dx * 9 + dy * 3 + dz] = _find(keys, nlg, _key(cx + dx - 1, cy + dy - 1, cz + dz - 1))


@njit(cache=True)
def _window(q, nb, slot, nodes, nper, nw, wr, wnode, nwm, W, colnz):
    """The class-q nodes of the window into W (nwm^3, x-major; 0 where no node), colnz[(tx, ty)]
    whether the column holds any that is not 0; returns the nodes and the columns that are not
    0. Leaf by leaf: a leaf's part of the window is a box, contiguous along z."""
    nx, ny, nz = nw[q, 0], nw[q, 1], nw[q, 2]
    py, pz = nper[q, 1], nper[q, 2]
    for tx in range(nx):
        for ty in range(ny):
            col = tx * nwm + ty
            colnz[col] = False
            for tz in range(nz):
                W[col * nwm + tz] = 0.0
    nnz = 0
    for i in range(27):
        g = nb[i]
        if g < 0 or slot[q, g] < 0:
            continue
        s = slot[q, g]
        lx, ly, lz = i // 9, (i // 3) % 3, i % 3
        z0, z1 = wr[q, 2, lz, 0], wr[q, 2, lz, 1]
        for tx in range(wr[q, 0, lx, 0], wr[q, 0, lx, 1]):
            for ty in range(wr[q, 1, ly, 0], wr[q, 1, ly, 1]):
                col = tx * nwm + ty
                src = s + (wnode[q, 0, tx] * py + wnode[q, 1, ty]) * pz + wnode[q, 2, z0] - z0
                n = 0
                for tz in range(z0, z1):
                    v = nodes[src + tz]
                    W[col * nwm + tz] = v
                    n += v != 0.0
                if n:
                    colnz[col] = True
                    nnz += n
    ncol = 0
    for tx in range(nx):
        for ty in range(ny):
            ncol += colnz[tx * nwm + ty]
    return nnz, ncol


@njit(cache=True)
def _direct(q, k2, nw, qa, ea, nwm, W, acc):
    """Node by node, as mixture._add_gaussian sums a Gaussian: (w e_x e_y) e_z within the cut."""
    for tx in range(nw[q, 0]):
        for ty in range(nw[q, 1]):
            base = (tx * nwm + ty) * nwm
            for tz in range(nw[q, 2]):
                wg = W[base + tz]
                if wg == 0.0:
                    continue
                for x in range(8):
                    q0 = qa[q, 0, x, tx]
                    if q0 > k2:
                        continue
                    for y in range(8):
                        qxy = q0 + qa[q, 1, y, ty]
                        if qxy > k2:
                            continue
                        wxy = wg * ea[q, 0, x, tx] * ea[q, 1, y, ty]
                        o = x * 64 + y * 8
                        for z in range(8):
                            if qxy + qa[q, 2, z, tz] <= k2:
                                acc[o + z] += wxy * ea[q, 2, z, tz]


@njit(cache=True)
def _separable(q, nw, tz, ez, nlev, xys, xyt, xyl, xye, nwm, nlm, W, colnz, Z, acc):
    """Z[(column, level, z)]: sum of w e_z over the column's nodes up to that z level; then
    acc[x, y, :] += e_x e_y Z[column, deepest level, :] over the (x, y) terms. Eight scalar
    sums, one per z: kept in registers (acc and Z could alias, as far as the compiler knows)."""
    nl = nlev[q]
    ns = tz.shape[2]
    for tx in range(nw[q, 0]):
        for ty in range(nw[q, 1]):
            col = tx * nwm + ty
            if not colnz[col]:
                continue
            wb = col * nwm
            s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
            for lv in range(nl):
                for sl in range(ns):
                    s0 += W[wb + tz[q, lv, sl, 0]] * ez[q, lv, sl, 0]
                    s1 += W[wb + tz[q, lv, sl, 1]] * ez[q, lv, sl, 1]
                    s2 += W[wb + tz[q, lv, sl, 2]] * ez[q, lv, sl, 2]
                    s3 += W[wb + tz[q, lv, sl, 3]] * ez[q, lv, sl, 3]
                    s4 += W[wb + tz[q, lv, sl, 4]] * ez[q, lv, sl, 4]
                    s5 += W[wb + tz[q, lv, sl, 5]] * ez[q, lv, sl, 5]
                    s6 += W[wb + tz[q, lv, sl, 6]] * ez[q, lv, sl, 6]
                    s7 += W[wb + tz[q, lv, sl, 7]] * ez[q, lv, sl, 7]
                b = (col * nlm + lv) * 8
                Z[b], Z[b + 1], Z[b + 2], Z[b + 3] = s0, s1, s2, s3
                Z[b + 4], Z[b + 5], Z[b + 6], Z[b + 7] = s4, s5, s6, s7
    for xy in range(64):
        a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = 0.0
        for t in range(xys[q * 64 + xy], xys[q * 64 + xy + 1]):
            col = xyt[t]
            if not colnz[col]:
                continue
            b = (col * nlm + xyl[t]) * 8
            f = xye[t]
            a0 += f * Z[b]
            a1 += f * Z[b + 1]
            a2 += f * Z[b + 2]
            a3 += f * Z[b + 3]
            a4 += f * Z[b + 4]
            a5 += f * Z[b + 5]
            a6 += f * Z[b + 6]
            a7 += f * Z[b + 7]
        o = xy * 8
        acc[o] += a0
        acc[o + 1] += a1
        acc[o + 2] += a2
        acc[o + 3] += a3
        acc[o + 4] += a4
        acc[o + 5] += a5
        acc[o + 6] += a6
        acc[o + 7] += a7


@njit(cache=True)
def lattice_cell(c, corg, k2, keys, nlg, slot, nodes, nper, nw, wr, wnode, qa, ea, tz, ez, nlev,
                 xys, xyt, xyl, xye, cost, nwm, nlm, nb, W, colnz, Z, acc):
    """Add to acc (512) every lattice class's field at the voxels of cell c."""
    nk = nper.shape[0]
    if nk == 0:
        return
    neighbours(c, corg, keys, nlg, nb)
    for q in range(nk):
        seen = False
        for i in range(27):
            if nb[i] >= 0 and slot[q, nb[i]] >= 0:
                seen = True
                break
        if not seen:
            continue
        nnz, ncol = _window(q, nb, slot, nodes, nper, nw, wr, wnode, nwm, W, colnz)
        if nnz == 0:
            continue
        sep = cost[q, 0] * ncol / (nw[q, 0] * nw[q, 1])
        if DIRECT_FACTOR * nnz * cost[q, 1] < sep:
            _direct(q, k2, nw, qa, ea, nwm, W, acc)
        else:
            _separable(q, nw, tz, ez, nlev, xys, xyt, xyl, xye, nwm, nlm, W, colnz, Z, acc)
