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
"""
from __future__ import annotations

import numpy as np

DEFAULT_MERGE_TOL = 0.02


def merge_blocks(group, origins, n_leaf_groups, box, value_range, merge_tol=DEFAULT_MERGE_TOL):
    """group: int64 (M,) group of each box; box: dict c2/ext/nvox/val/kind. Returns (group, box, n)."""
    c2, ext, nvox = box["c2"].astype(np.int64), box["ext"].astype(np.int64), box["nvox"]
    e = ext[:, 0]
    cand = (group < n_leaf_groups) & (ext[:, 1] == e) & (ext[:, 2] == e) & (nvox == e ** 3)
    idx = np.nonzero(cand)[0]
    if len(idx) < 27:
        return group, box, 0
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
        return group, box, 0
    v = box["val"][idx].astype(np.float64)
    s1 = np.add.reduceat(v, starts)
    s2 = np.add.reduceat(v * v, starts)
    mean = s1 / np.maximum(lens, 1)
    std = np.sqrt(np.maximum(s2 / np.maximum(lens, 1) - mean ** 2, 0.0))
    ok = full & (std <= merge_tol * max(float(value_range), 0.0) + 1e-12 * np.abs(mean))
    runs = np.nonzero(ok)[0]
    if len(runs) == 0:
        return group, box, 0
    member_run = np.repeat(np.arange(len(starts)), lens)
    in_ok = ok[member_run]
    is_centre = np.all(q % 3 == 1, axis=1)
    keep = np.ones(len(group), bool)
    keep[idx[in_ok & ~is_centre]] = False
    centres = idx[in_ok & is_centre]  # one per merged run, in run order
    run_of_centre = member_run[in_ok & is_centre]
    new = {k: a.copy() for k, a in box.items()}
    ec = e[centres]
    new["ext"][centres] = (3 * ec)[:, None].astype(new["ext"].dtype)
    new["nvox"][centres] = (27 * ec ** 3).astype(np.int32)
    new["val"][centres] = mean[run_of_centre].astype(np.float32)
    new["kind"][centres] = 1
    new = {k: a[keep] for k, a in new.items()}
    return group[keep], new, len(runs)
