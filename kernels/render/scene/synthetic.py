"""Small synthetic inputs (GaussianSet- and GridData-shaped namespaces) for tests, the
benchmark's fallback and demos. Same fields as kernels.lod.GaussianSet / kernels.vdb.GridData."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np


def gaussian_set(centers, sigmas, values=None, amplitudes=None, *, grid_class="fog_volume",
                 index_to_world=None):
    """Gaussians grouped by the 8^3 leaf holding their centre (index space)."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    n = c.shape[0]
    s = np.broadcast_to(np.asarray(sigmas, np.float64), (n, 3)) if np.ndim(sigmas) <= 1 and \
        np.size(sigmas) in (1, 3) else np.asarray(sigmas, np.float64).reshape(n, 3)
    v = np.ones(n) if values is None else np.broadcast_to(np.asarray(values, np.float64), (n,))
    a = np.ones(n) if amplitudes is None else np.broadcast_to(np.asarray(amplitudes, np.float64), (n,))
    leaf = np.floor_divide(np.floor(c + 0.5).astype(np.int64), 8) * 8
    key = [tuple(x) for x in leaf]
    order = sorted(range(n), key=lambda i: (key[i], i))
    origins, start = [], [0]
    cnt = 0
    for i in order:
        if not origins or tuple(origins[-1]) != key[i]:
            if origins:
                start.append(start[-1] + cnt)
            origins.append(leaf[i])
            cnt = 0
        cnt += 1
    start.append(start[-1] + cnt if n else 0)
    if n == 0:
        start = [0]
    order = np.array(order, np.int64)
    origins = np.array(origins, np.int32).reshape(-1, 3)
    grp = np.repeat(origins, np.diff(start), axis=0) if n else np.zeros((0, 3), np.int32)
    return SimpleNamespace(
        group_origins=origins, group_start=np.array(start, np.int64),
        offsets=(c[order] - grp).astype(np.float32), sigmas=s[order].astype(np.float32),
        values=v[order].astype(np.float32), amplitudes=a[order].astype(np.float32),
        voxels=np.ones(n, np.int32), grid_class=grid_class, lod="synthetic", weights="field",
        index_to_world=np.eye(4) if index_to_world is None else index_to_world, background=0.0)


def grid_from_dense(values, origin=(0, 0, 0), *, grid_class="fog_volume", background=0.0,
                    active=None):
    """A GridData-shaped namespace from a dense array (voxel (i,j,k) at index origin + (i,j,k));
    leaves that are entirely background (or inactive) are dropped."""
    v = np.asarray(values, np.float32)
    o = np.asarray(origin, np.int64)
    act = np.ones(v.shape, bool) if active is None else np.asarray(active, bool)
    lo = np.floor_divide(o, 8) * 8
    hi = o + np.array(v.shape)
    origins, vals, masks = [], [], []
    for x in range(lo[0], hi[0], 8):
        for y in range(lo[1], hi[1], 8):
            for z in range(lo[2], hi[2], 8):
                blk = np.full((8, 8, 8), background, np.float32)
                ab = np.zeros((8, 8, 8), bool)
                sx = slice(max(x, o[0]), min(x + 8, hi[0]))
                sy = slice(max(y, o[1]), min(y + 8, hi[1]))
                sz = slice(max(z, o[2]), min(z + 8, hi[2]))
                if sx.start >= sx.stop or sy.start >= sy.stop or sz.start >= sz.stop:
                    continue
                src = (slice(sx.start - o[0], sx.stop - o[0]), slice(sy.start - o[1], sy.stop - o[1]),
                       slice(sz.start - o[2], sz.stop - o[2]))
                dst = (slice(sx.start - x, sx.stop - x), slice(sy.start - y, sy.stop - y),
                       slice(sz.start - z, sz.stop - z))
                blk[dst] = v[src]
                ab[dst] = act[src]
                if not ab.any():
                    continue
                origins.append((x, y, z))
                vals.append(blk.ravel())
                bits = np.packbits(ab.ravel().reshape(8, 64), axis=1, bitorder="little")
                masks.append(np.frombuffer(bits.tobytes(), "<u8").astype(np.uint64))
    n = len(origins)
    return SimpleNamespace(
        name="synthetic", grid_class=grid_class, value_type="float", background=float(background),
        index_to_world=np.eye(4), leaf_origins=np.array(origins, np.int32).reshape(n, 3),
        leaf_masks=np.array(masks, np.uint64).reshape(n, 8),
        leaf_values=np.array(vals, np.float32).reshape(n, 512),
        tile_origins=np.zeros((0, 3), np.int32), tile_sizes=np.zeros(0, np.int32),
        tile_values=np.zeros(0, np.float32), tile_active=np.zeros(0, bool),
        active_voxels=int(act.sum()), bbox_min=o.copy(), bbox_max=hi - 1)


def warm_objects():
    """(Gaussian objects, voxel objects, a camera on them) for a device's load_kernels: the Low
    and the High set of a small block, GaussianSets equal to build_lod's (splat: a coarse lattice
    and one of single voxels, with the dtypes imports make) but made without the LOD kernels (a
    render's warm-up runs beside an import that compiles those), and the block's grid alone (the
    reference mode, which needs no Gaussians)."""
    from ...lod.synthetic import full_block_set, grid_from_dense
    from .camera import Camera
    from .objects import RenderObject

    shape = (16, 8, 8)
    g = grid_from_dense(np.ones(shape, np.float32))
    objs = [RenderObject(full_block_set(shape, edge, lod), np.eye(4))
            for lod, edge in (("low", 8), ("high", 2))]
    return objs, [RenderObject(None, np.eye(4), grid=g)], Camera.frame_box([-3.0] * 3, [19.0] * 3, 8, 8)
