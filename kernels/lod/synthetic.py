"""Synthetic grids with the GridData contract (duck-typed), for tests and benchmarks."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np


def grid_from_dense(values, mask=None, origin=(0, 0, 0), *, grid_class="fog_volume",
                    index_to_world=None, tiles=(), background=0.0, name="density"):
    """Build a GridData-like object from a dense array.

    values: (X, Y, Z) float array placed with voxel (0, 0, 0) at index `origin`; mask: bool array of
    the same shape (default: values != background). Leaves are created for every 8^3 cell with at
    least one active voxel. tiles: iterable of (origin(3), size, value, active).
    """
    values = np.asarray(values, dtype=np.float32)
    if mask is None:
        mask = values != background
    mask = np.asarray(mask, dtype=bool)
    origin = np.asarray(origin, dtype=np.int64)
    idx = np.argwhere(mask) + origin
    leaf_keys = np.unique(idx >> 3, axis=0) if len(idx) else np.zeros((0, 3), np.int64)
    n = len(leaf_keys)
    leaf_origins = (leaf_keys << 3).astype(np.int32)
    leaf_values = np.full((n, 512), background, np.float32)
    bits = np.zeros((n, 512), bool)
    lut = {tuple(k): i for i, k in enumerate(leaf_keys)}
    if len(idx):
        li = np.array([lut[tuple(k)] for k in (idx >> 3)], dtype=np.int64)
        loc = idx & 7
        n_loc = loc[:, 0] * 64 + loc[:, 1] * 8 + loc[:, 2]
        rel = idx - origin
        leaf_values[li, n_loc] = values[rel[:, 0], rel[:, 1], rel[:, 2]]
        bits[li, n_loc] = True
    # also copy inactive values that fall inside the leaves (realistic: leaves store them)
    for i, lo in enumerate(leaf_origins.astype(np.int64)):
        for n_loc in range(512):
            if bits[i, n_loc]:
                continue
            p = lo + np.array([n_loc >> 6, (n_loc >> 3) & 7, n_loc & 7]) - origin
            if np.all(p >= 0) and np.all(p < values.shape):
                leaf_values[i, n_loc] = values[tuple(p)]
    return make_grid(leaf_origins, bits, leaf_values, grid_class=grid_class,
                     index_to_world=index_to_world, tiles=tiles, background=background, name=name)


def full_block_set(shape, edge, lod):
    """The GaussianSet build_lod makes (field weights) of a grid of ones of ``shape`` (multiples
    of 8, origin 0) at a LOD that keeps each full ``edge``^3 block as one Gaussian (Low: 8, High:
    2), made here with numpy: a device's load_kernels draws it without compiling a LOD kernel.
    tests/kernels/test_lod_synthetic.py checks it equals build_lod's."""
    from . import weights
    from .gaussian_set import GaussianSet

    # C order, as build_lod's: numba compiles an F-ordered array's kernels again
    leaves = np.ascontiguousarray(np.argwhere(np.ones(np.asarray(shape) // 8, bool)), np.int32) * 8
    per = 8 // edge
    blocks = np.argwhere(np.ones((per, per, per), bool)) * edge + (edge - 1) / 2.0
    n = len(leaves) * len(blocks)
    codes = np.full((n, 3), edge, np.int32)
    scale = weights.sigma_scale("field")
    sigmas = weights.sigmas_from_codes(codes, scale)
    voxels = np.full(n, edge ** 3, np.int32)
    return GaussianSet(
        group_origins=leaves, group_start=np.arange(len(leaves) + 1, dtype=np.int64) * len(blocks),
        offsets=np.tile(blocks, (len(leaves), 1)).astype(np.float32), sigmas=sigmas,
        values=np.ones(n, np.float32), amplitudes=weights.amplitudes(sigmas, voxels, "field"),
        voxels=voxels, lod=lod, n_leaf_groups=len(leaves), size_codes=codes, sigma_scale=scale)


def masks_from_bits(bits):
    """bool (N, 512) -> uint64 (N, 8) with voxel n at bit n & 63 of word n >> 6."""
    bits = np.asarray(bits, dtype=bool).reshape(-1, 8, 64)
    w = (bits.astype(np.uint64) << np.arange(64, dtype=np.uint64)).sum(axis=2, dtype=np.uint64)
    return w.astype(np.uint64)


def make_grid(leaf_origins, leaf_bits, leaf_values, *, grid_class="fog_volume", index_to_world=None,
              tiles=(), background=0.0, name="density"):
    leaf_origins = np.asarray(leaf_origins, np.int32).reshape(-1, 3)
    masks = masks_from_bits(leaf_bits)
    leaf_values = np.asarray(leaf_values, np.float32).reshape(-1, 512)
    tiles = list(tiles)
    t_or = np.array([t[0] for t in tiles], np.int32).reshape(-1, 3)
    t_sz = np.array([t[1] for t in tiles], np.int32)
    t_val = np.array([t[2] for t in tiles], np.float32)
    t_act = np.array([t[3] if len(t) > 3 else True for t in tiles], bool)
    m = np.eye(4) if index_to_world is None else np.asarray(index_to_world, np.float64)
    nact = int(np.asarray(leaf_bits, bool).sum()) + int((t_sz.astype(np.int64) ** 3)[t_act].sum())
    lo = [leaf_origins.min(0)] if len(leaf_origins) else []
    hi = [leaf_origins.max(0) + 7] if len(leaf_origins) else []
    return SimpleNamespace(
        name=name, grid_class=grid_class, value_type="float", background=float(background),
        file_version=224, compression="none", half=False, index_to_world=m,
        leaf_origins=leaf_origins, leaf_masks=masks, leaf_values=leaf_values,
        tile_origins=t_or, tile_sizes=t_sz, tile_values=t_val, tile_active=t_act,
        active_voxels=nact,
        bbox_min=np.min(lo, 0).astype(np.int64) if lo else np.zeros(3, np.int64),
        bbox_max=np.max(hi, 0).astype(np.int64) if hi else np.zeros(3, np.int64),
    )


def random_sparse_grid(seed, n_leaves=6, density=0.5, span=3, grid_class="fog_volume", dense_frac=0.3):
    """Random leaves on a small lattice of leaf positions: some dense, some sparse (clumpy)."""
    rng = np.random.default_rng(seed)
    keys = set()
    while len(keys) < n_leaves:
        keys.add(tuple(rng.integers(-span, span + 1, size=3)))
    keys = np.array(sorted(keys), np.int64)
    n = len(keys)
    bits = np.zeros((n, 512), bool)
    for i in range(n):
        if rng.random() < dense_frac:
            bits[i] = True
        else:
            # clumpy: random 2^3-aligned cells full, plus scattered voxels
            cells = rng.random(64) < density * 0.5
            b = np.zeros((8, 8, 8), bool)
            for c in np.nonzero(cells)[0]:
                x, y, z = (c >> 4) * 2, ((c >> 2) & 3) * 2, (c & 3) * 2
                b[x:x + 2, y:y + 2, z:z + 2] = True
            b |= rng.random((8, 8, 8)) < density * 0.3
            if not b.any():
                b[rng.integers(8), rng.integers(8), rng.integers(8)] = True
            bits[i] = b.reshape(512)
    if grid_class == "level_set":
        vals = rng.uniform(-3, 3, size=(n, 512)).astype(np.float32)
    else:
        vals = rng.uniform(0.1, 1.0, size=(n, 512)).astype(np.float32)
    return make_grid((keys << 3).astype(np.int32), bits, vals, grid_class=grid_class)
