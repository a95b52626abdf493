"""The adaptive preset: the fewest Gaussians whose field meets an error tolerance.

A hierarchy mirroring the VDB tree: every leaf starts as one node (its 8^3 cell); a node is an
aligned cubic cell of edge e = 8, 4, 2 or 1 inside its leaf and stands for its kept voxels with one
Gaussian on their bounding box (centre = box centre on the half-voxel lattice, sigma = 0.6 x box
edge per axis, V = the voxels, value = their mean), so supports overlap exactly as in the field
weights; active tiles are one Gaussian each, as in every preset. Each round
  1. fits all weights to the voxels (fit.py: least squares, warm-started from the previous round;
     the first round from the partition-of-unity amplitudes),
  2. measures the residual at every active voxel (the `field_error` metric: NRMSE over the active
     voxels, level sets against the kept-shell occupancy),
  3. stops when the SSE is within the budget N (tolerance x range)^2 (and every |residual| within
     max_error when that is set), else splits the nodes with the largest SSE per added Gaussian into
     their non-empty octants, just enough of them to close the gap if a split removed SPLIT_GAIN of
     a node's SSE (nodes over max_error always split). A node's SSE is half the SSE over its cell
     and half its share of every voxel's error (its part of the field there): a coarse Gaussian
     whose tail spills over an edge is split, not only the fine ones where the error shows.
Smooth regions keep coarse Gaussians; edges and detail end at single voxels. The result is then
measured with `field_error` itself on the quantized amplitudes, and params say what was met:
`tolerance_met` is never true unless that measurement is within the tolerance.
Everything is per node or per cell in parallel, reduced in a fixed order, with stable sorts: the
output does not depend on the thread count.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ..jit import njit, parallel_for
from . import weights as W
from .fit import fit_weights
from .gaussian_set import GaussianSet
from .mixture import DEFAULT_K, cell_table, field_error, nrmse_denominator, pair_lists

MAX_ROUNDS = 12  # fit + split rounds (a leaf reaches single voxels in 3 splits)
CG_STEPS = 6  # per round: conjugate-gradient steps, then
MM_STEPS = 2  # monotone projected steps (and the measuring pass)
SPLIT_GAIN = 1.0  # assumed share of a node's SSE that splitting it removes: split the fewest
MARGIN = 0.98  # fit to 0.98 x the tolerance: the amplitude quantization (0.27 %) must not tip it


def node_boxes(kept, values, order, nleaf, nxyz, ne, c2, ext, nvox, val, nchild):
    """Per node: bounding box of its kept voxels (c2 = lo + hi, ext = hi - lo + 1, local to the
    leaf), their count and mean value, and how many of its octants hold any (0 for e = 1)."""
    parallel_for(_box_rows, nleaf.shape[0], kept, values, order, nleaf, nxyz, ne, c2, ext, nvox,
                 val, nchild)


@njit(cache=True, nogil=True)
def _box_rows(lo, hi, kept, values, order, nleaf, nxyz, ne, c2, ext, nvox, val, nchild):
    for j in range(lo, hi):
        i = nleaf[j]
        x0, y0, z0, e = nxyz[j, 0], nxyz[j, 1], nxyz[j, 2], ne[j]
        h = e // 2
        lx = ly = lz = 8
        hx = hy = hz = -1
        n = 0
        s = 0.0
        octs = 0
        vals = values[order[i]]
        for x in range(x0, x0 + e):
            for y in range(y0, y0 + e):
                word = kept[i, x]
                for z in range(z0, z0 + e):
                    b = y * 8 + z
                    if (word >> np.uint64(b)) & np.uint64(1):
                        n += 1
                        s += vals[x * 64 + b]
                        lx, ly, lz = min(lx, x), min(ly, y), min(lz, z)
                        hx, hy, hz = max(hx, x), max(hy, y), max(hz, z)
                        if h:
                            octs |= 1 << (4 * ((x - x0) // h) + 2 * ((y - y0) // h) + (z - z0) // h)
        c2[j, 0], c2[j, 1], c2[j, 2] = lx + hx, ly + hy, lz + hz
        ext[j, 0], ext[j, 1], ext[j, 2] = hx - lx + 1, hy - ly + 1, hz - lz + 1
        nvox[j] = n
        val[j] = s / n if n else 0.0
        k = 0
        for o in range(8):
            k += (octs >> o) & 1
        nchild[j] = k


def node_errors(nleaf, nxyz, ne, leaf_cell, cres):
    """Per node: SSE and max |residual| over its cell (cres is 0 at inactive voxels)."""
    m = nleaf.shape[0]
    sse = np.zeros(m)
    mx = np.zeros(m)
    parallel_for(_error_rows, m, nleaf, nxyz, ne, leaf_cell, cres, sse, mx)
    return sse, mx


@njit(cache=True, nogil=True)
def _error_rows(lo, hi, nleaf, nxyz, ne, leaf_cell, cres, sse, mx):
    for j in range(lo, hi):
        c = leaf_cell[nleaf[j]]
        x0, y0, z0, e = nxyz[j, 0], nxyz[j, 1], nxyz[j, 2], ne[j]
        s = 0.0
        a = 0.0
        for x in range(x0, x0 + e):
            for y in range(y0, y0 + e):
                for z in range(z0, z0 + e):
                    r = cres[c, x * 64 + y * 8 + z]
                    s += r * r
                    a = max(a, abs(r))
        sse[j], mx[j] = s, a


def _boxes(kept, values, order, nodes):
    nleaf, nxyz, ne = nodes
    m = len(nleaf)
    box = dict(c2=np.empty((m, 3), np.int16), ext=np.empty((m, 3), np.int16),
               nvox=np.empty(m, np.int32), val=np.empty(m, np.float32))
    nchild = np.empty(m, np.int64)
    node_boxes(kept, values, order, nleaf, nxyz, ne, box["c2"], box["ext"], box["nvox"],
               box["val"], nchild)
    box["full_block"] = (box["nvox"] == np.prod(box["ext"].astype(np.int64), 1)).astype(np.uint8)
    return box, nchild


def _canonical(nodes, f):
    """Nodes sorted by (leaf, x, y, z): nodes of a leaf never overlap, so the key is unique."""
    nleaf, nxyz, ne = nodes
    o = np.argsort(nleaf * 512 + nxyz[:, 0] * 64 + nxyz[:, 1] * 8 + nxyz[:, 2], kind="stable")
    return (nleaf[o], nxyz[o], ne[o]), f[o]


def _split(nodes, f, chosen):
    """Replace the chosen nodes by their 8 octants (empty ones are dropped by the caller)."""
    nleaf, nxyz, ne = nodes
    keep = np.ones(len(nleaf), bool)
    keep[chosen] = False
    h = ne[chosen] // 2
    octs = np.array([[(o >> 2) & 1, (o >> 1) & 1, o & 1] for o in range(8)], np.int64)
    cxyz = (nxyz[chosen][:, None, :] + octs[None, :, :] * h[:, None, None]).reshape(-1, 3)
    nodes = (np.concatenate([nleaf[keep], np.repeat(nleaf[chosen], 8)]),
             np.concatenate([nxyz[keep], cxyz]), np.concatenate([ne[keep], np.repeat(h, 8)]))
    return nodes, np.concatenate([f[keep], np.repeat(f[chosen], 8)])


def _choose(node_sse, node_max, nchild, splittable, need, max_error):
    """Nodes to split: the largest SSE per added Gaussian first, until SPLIT_GAIN x their SSE
    covers `need` (all of them if it never does); plus every node over max_error."""
    cand = np.flatnonzero(splittable)
    chosen = np.zeros(0, np.int64)
    if need > 0 and len(cand):
        prio = node_sse[cand] / np.maximum(nchild[cand] - 1, 0.5)
        o = cand[np.argsort(-prio, kind="stable")]
        gain = SPLIT_GAIN * np.cumsum(node_sse[o])
        chosen = o[:int(np.searchsorted(gain, need)) + 1]
    if max_error > 0:
        chosen = np.union1d(chosen, cand[node_max[cand] > max_error])
    return chosen


def _gaussians(box, tbox, nt, is_ls, scale):
    """Boxes (leaf nodes, then tiles) -> the output arrays of weights.new_gaussians, and a level
    set's signed distances (else None)."""
    if nt:
        box = {k: np.concatenate([box[k], tbox[k]]) for k in box}
    out = W.new_gaussians(len(box["nvox"]))
    W.boxes_to_gaussians(box["c2"], box["ext"], box["nvox"], box["val"], box["full_block"],
                         len(box["nvox"]) - nt, False, scale, out, 0)
    return out, W.level_set_distances(out) if is_ls else None


def adaptive_rounds(grid, kept, order, leaf_origins, t_or, tbox, *, tolerance, max_error,
                    scale, band, params, k=DEFAULT_K):
    """kept/order: the scan's kept masks in canonical leaf order; leaf_origins (file order); t_or,
    tbox: the active tiles (build._tile_boxes). A generator: yields (round, its figures:
    gaussians, nrmse, max_abs) after each round's fit, so a caller can report progress or stop;
    returns the GaussianSet, params filled in."""
    is_ls = grid.grid_class == "level_set"
    values = grid.leaf_values
    occupied = np.flatnonzero(kept.any(axis=1))
    nodes = (occupied.astype(np.int64), np.zeros((len(occupied), 3), np.int64),
             np.full(len(occupied), 8, np.int64))
    nt = len(t_or)
    f = np.ones(len(occupied))
    table = cell_table(grid, SimpleNamespace(params=dict(level_set_band=band)))
    active = np.unpackbits(np.ascontiguousarray(table["cmask"]).view(np.uint8), axis=1).sum(1)
    npts = float(np.sum(active * table["cw"]))
    den = nrmse_denominator(is_ls, params["value_min"], params["value_max"])
    budget = npts * (MARGIN * tolerance * den) ** 2
    lo = np.asarray(leaf_origins, np.int64).reshape(-1, 3)[order]  # canonical leaf order
    lkey = ((lo[:, 0] >> 3) + (1 << 20) << 42) | ((lo[:, 1] >> 3) + (1 << 20) << 21) \
        | ((lo[:, 2] >> 3) + (1 << 20))
    leaf_cell = np.searchsorted(table["keys"], lkey)
    f_tile = np.ones(nt)
    rounds, hist = 0, []
    while True:
        rounds += 1
        box, nchild = _boxes(kept, values, order, nodes)
        m = len(box["nvox"])
        out, dist = _gaussians(box, tbox, nt, is_ls, scale)
        offsets, sig, vals = out[0], out[2], out[5]
        cent = np.concatenate([lo[nodes[0]], t_or.astype(np.int64)]) + offsets.astype(np.float64)
        vox = np.concatenate([box["nvox"].astype(np.float64),
                              np.prod(tbox["ext"].astype(np.float64), 1) if nt else np.zeros(0)])
        va0 = vals.astype(np.float64) * W.amplitudes64(sig, vox, "field")
        w0 = va0 * np.concatenate([f, f_tile])
        st = pair_lists(table, cent, sig.astype(np.float64), k)
        w, cres, sse, mx, share = fit_weights(st, w0, np.sign(va0), CG_STEPS, MM_STEPS)
        fac = np.divide(w, va0, out=np.ones_like(w), where=va0 != 0)
        f, f_tile = fac[:m], fac[m:]
        total, worst = float(np.sum(sse * table["cw"])), float(mx.max(initial=0.0))
        hist.append(dict(gaussians=m + nt, nrmse=float(np.sqrt(total / npts)) / den if npts else 0.0,
                         max_abs=worst))
        yield rounds, hist[-1]
        if (total <= budget and (max_error <= 0 or worst <= max_error)) or rounds >= MAX_ROUNDS:
            break
        node_sse, node_max = node_errors(nodes[0], nodes[1], nodes[2], leaf_cell, cres)
        node_sse = 0.5 * (node_sse + share[:m])  # where the error is, and whose field makes it
        chosen = _choose(node_sse, node_max, nchild, nodes[2] > 1, total - budget,
                         max_error / MARGIN if max_error > 0 else 0.0)
        if not len(chosen):
            break  # only single voxels (and tiles) left where the error is
        nodes, f = _split(nodes, f, chosen)
        nb, _ = _boxes(kept, values, order, nodes)
        nonempty = nb["nvox"] > 0
        nodes, f = _canonical(tuple(a[nonempty] for a in nodes), f[nonempty])

    # the set, with the fitted factors quantized as the encoding stores them
    nleaf = nodes[0]
    groups, gcount = np.unique(nleaf, return_counts=True)
    origins = np.concatenate([lo[groups], t_or.astype(np.int64)]).astype(np.int32)
    gcount = np.concatenate([gcount, np.ones(nt, np.int64)])
    gstart = np.zeros(len(gcount) + 1, np.int64)
    np.cumsum(gcount, out=gstart[1:])
    offsets, codes, sig, amp, vox, vals = out
    gs = GaussianSet(
        group_origins=origins.reshape(-1, 3), group_start=gstart, offsets=offsets, sigmas=sig,
        values=vals, amplitudes=amp, voxels=vox, grid_class=grid.grid_class, lod="adaptive",
        weights="field", index_to_world=np.asarray(grid.index_to_world, np.float64),
        background=float(grid.background), n_leaf_groups=len(groups), size_codes=codes,
        sigma_scale=scale, params=params, distances=dist)
    a0 = W.amplitudes64(gs.sigmas, gs.true_voxels(), "field")
    gs.amplitudes = (a0 * W.factors_from_codes(W.quantize_factors(np.concatenate([f, f_tile]))))\
        .astype(np.float32)
    err = field_error(grid, gs, k)
    met = err["nrmse"] <= tolerance and (max_error <= 0 or err["max_abs"] <= max_error)
    params.update(tolerance=float(tolerance), max_error=float(max_error), tolerance_met=bool(met),
                  achieved_nrmse=err["nrmse"], achieved_max_abs=err["max_abs"], rounds=rounds,
                  round_history=hist, field_error=err)
    return gs
