"""Inter-leaf clustering: the paper's second pass that merges homogeneous neighbouring blocks.

The paper assesses a block with its 26 neighbours and replaces the group by one Gaussian whose
bbox is the union. Done greedily that depends on the visiting order; we make it order-free (hence
thread-free) by fixing the groups on a lattice: full cubic blocks of edge e (e = 1, 2, 4 or 8:
single voxels, 2^3 / 4^3 blocks, dense Low leaves) with block coordinate q = lo / e belong to the
super-cell floor(q / 3); the block at q mod 3 = (1, 1, 1) is its centre and the other 26 are exactly
its 26-neighbourhood (faces, edges, corners), across leaf borders. A super-cell merges when all 27
blocks are present and homogeneous: population std of their values <= merge_tol x value range.
The merged Gaussian is a full (3e)^3 box (union bbox), its centre is the centroid (= the centre
block's centre, so it stays in that block's leaf group, on the half-voxel lattice), its value the
mean, V = 27 e^3. One pass, as in the paper; tiles are never merged.

With field weights a merged Gaussian (sigma = 0.6 x 3e among neighbours of sigma 0.6 x e) breaks the
mixture's partition of unity: alone in its neighbourhood its field peaks at 0.29 of the block's value
and its tails spill onto the neighbours. build_lod therefore keeps a field-weights merge only where
the exact field error of the leaf cells it touches stays within merge_tol (field_checked_merge).
"""
from __future__ import annotations

import numpy as np

from .mixture import cell_keys

DEFAULT_MERGE_TOL = 0.02


def merge_blocks(group, origins, n_leaf_groups, box, value_range, merge_tol=DEFAULT_MERGE_TOL,
                 exclude=None):
    """group: int64 (M,) group of each box; box: dict c2/ext/nvox/val/full_block; exclude: bool (M,),
    boxes that may not be the centre of a merge. Returns (group, box, n, centres): centres are the
    merged runs' centre boxes (indices into the input boxes)."""
    none = np.zeros(0, np.int64)
    c2, ext, nvox = box["c2"].astype(np.int64), box["ext"].astype(np.int64), box["nvox"]
    e = ext[:, 0]
    cand = (group < n_leaf_groups) & (ext[:, 1] == e) & (ext[:, 2] == e) & (nvox == e ** 3)
    idx = np.nonzero(cand)[0]
    if len(idx) < 27:
        return group, box, 0, none
    ei = e[idx]
    lo = origins[group[idx]].astype(np.int64) + (c2[idx] - ext[idx] + 1) // 2
    aligned = np.all(lo % ei[:, None] == 0, axis=1)
    idx, ei, lo = idx[aligned], ei[aligned], lo[aligned]
    q = lo // ei[:, None]
    sc = q // 3
    order = np.lexsort((sc[:, 2], sc[:, 1], sc[:, 0], ei))
    idx, ei, q, sc = idx[order], ei[order], q[order], sc[order]
    key_change = np.ones(len(idx), bool)
    key_change[1:] = (np.any(sc[1:] != sc[:-1], axis=1)) | (ei[1:] != ei[:-1])
    starts = np.nonzero(key_change)[0]
    lens = np.diff(np.append(starts, len(idx)))
    full = lens == 27
    if not np.any(full):
        return group, box, 0, none
    v = box["val"][idx].astype(np.float64)
    s1 = np.add.reduceat(v, starts)
    s2 = np.add.reduceat(v * v, starts)
    mean = s1 / np.maximum(lens, 1)
    std = np.sqrt(np.maximum(s2 / np.maximum(lens, 1) - mean ** 2, 0.0))
    ok = full & (std <= merge_tol * max(float(value_range), 0.0) + 1e-12 * np.abs(mean))
    member_run = np.repeat(np.arange(len(starts)), lens)
    is_centre = np.all(q % 3 == 1, axis=1)
    if exclude is not None:
        ok[member_run[is_centre & exclude[idx]]] = False
    runs = np.nonzero(ok)[0]
    if len(runs) == 0:
        return group, box, 0, none
    in_ok = ok[member_run]
    keep = np.ones(len(group), bool)
    keep[idx[in_ok & ~is_centre]] = False
    centres = idx[in_ok & is_centre]  # one per merged run, in run order
    run_of_centre = member_run[in_ok & is_centre]
    new = {k: a.copy() for k, a in box.items()}
    ec = e[centres]
    new["ext"][centres] = (3 * ec)[:, None].astype(new["ext"].dtype)
    new["nvox"][centres] = (27 * ec ** 3).astype(np.int32)
    new["val"][centres] = mean[run_of_centre].astype(np.float32)
    new["full_block"][centres] = 1
    new = {k: a[keep] for k, a in new.items()}
    return group[keep], new, len(runs), centres


def field_checked_merge(cells, err_before, err_after, scale, merge_tol, m):
    """The merges to undo: those whose Gaussian's support meets a leaf cell where the merges
    raised the field's RMS error by more than merge_tol x scale (the NRMSE's denominator).
    cells: merge_cells' (run, cell key) pairs; err_before / err_after: mixture.cell_errors of the
    Gaussians without / with the merges; m: the runs. Returns bool (m,): the runs to undo."""
    keys, sse0, sse1, npts = err_before[0], err_before[1], err_after[1], err_before[2]
    n = np.maximum(npts, 1.0)
    worse = np.sqrt(sse1 / n) - np.sqrt(sse0 / n) > merge_tol * float(scale)
    undo = np.zeros(m, bool)
    run, key = cells
    undo[run[np.isin(key, keys[worse])]] = True
    return undo


def merge_cells(group, origins, box, centres, sigma_scale, k):
    """(run, cell key) for every leaf cell that a merged Gaussian's k-sigma support meets (the
    merged box is 3 e around its centre block, sigma = sigma_scale x 3 e)."""
    c2, ext = box["c2"].astype(np.int64)[centres], box["ext"].astype(np.int64)[centres]
    centre2 = 2 * origins[group[centres]].astype(np.int64) + c2  # twice the centre
    reach = np.ceil(k * sigma_scale * 3 * ext[:, 0]).astype(np.int64)
    c0 = (centre2 // 2 - reach[:, None]) >> 3
    c1 = ((centre2 + 1) // 2 + reach[:, None]) >> 3
    span = int((c1 - c0).max()) + 1
    runs, keys = [], []
    for d in np.ndindex(span, span, span):
        cell = c0 + np.array(d)
        ok = np.all(cell <= c1, 1)
        runs.append(np.nonzero(ok)[0])
        keys.append(cell_keys(cell[ok]))
    return np.concatenate(runs), np.concatenate(keys)
