"""Acceleration data built once per scene sync (numpy): the VDB leaf hierarchy as a two-level
sparse grid per object.

The Gaussians (build_gaussians) and their per-leaf lists (add_halo_lists) are built apart: the
screen-tile path needs no lists, so a device adds them only for the frames that walk the leaves.

Index space is OpenVDB's (voxel centres at integers). Work coordinates are q = index + 0.5, so
leaf cell c = floor(q / 8) spans index [8c - 0.5, 8c + 7.5] (exactly the VDB leaf with origin 8c)
and node n = floor(q / 128) holds 16^3 leaf cells. Per object: a dense table over the bounding
box of occupied nodes (-> node id or -1); per node a 16^3 table (-> global cell id or -1); per
cell a list of Gaussians whose k-sigma support box meets it (its own and its halo), in
ascending Gaussian id. All objects are packed into flat arrays with global ids.
"""
from __future__ import annotations

import os

import numpy as np

from ...jit import njit
from .bricks import leaf_bricks, sub_max
from .gauss_pack import drawn, spheres
from .layout import BRICK, LEAF, NODE_LEAVES

MAX_NODE_TABLE = 1 << 26  # dense node table entries per object (sparse-enough for any VDB we read)
# Peak bytes per halo-list entry (Gaussian x cell) while add_halo_lists builds them, a cell per
# entry at worst (measured with tracemalloc: ids, cell coordinates, sort keys and order, the face
# lists, per cell its coordinates and list starts), and per node its cell table; the lists are
# checked against the available memory before they are built, never against a fixed count.
HALO_BYTES = 320
NODE_BYTES = 3 * 4 * NODE_LEAVES ** 3  # a node's cell table, its copy when packed, a mask
TABLE_BYTES = 16  # per entry of a dense node table and its temporaries
# Levels of the Gaussians' lists: a Gaussian is listed in the cells of the first level (cells of
# LEVEL_CELLS^level leaves per axis) where its support box spans at most LEVEL_SPAN cells per axis,
# so it has at most LEVEL_SPAN^3 entries whatever its size (a per-leaf halo grows with
# support^3: a Low Gaussian met 125 leaves, an active tile's thousands). Each level is a grid of
# its own that rays walk; the cells' coordinates and the Gaussians' boxes are in their level's
# cells.
LEVEL_CELLS = 4
LEVEL_SPAN = 3
MAX_LEVEL = 12  # cells of 8 * 4^12 voxels: past any index range a VDB holds


def _cells_to_nodes(cell_xyz):
    """cell coords (C,3) int64 -> (node_min (3,), node_dims (3,), node_table (prod,), node_cells
    (n_nodes, 4096) local cell ids)."""
    nodes = np.floor_divide(cell_xyz, NODE_LEAVES)
    nmin = nodes.min(axis=0)
    ndims = nodes.max(axis=0) - nmin + 1
    if int(np.prod(ndims)) > MAX_NODE_TABLE:
        raise MemoryError(f"object spans {ndims} nodes: too sparse for a dense node table")
    rel = nodes - nmin
    nkey = (rel[:, 0] * ndims[1] + rel[:, 1]) * ndims[2] + rel[:, 2]
    ukeys, ninv = np.unique(nkey, return_inverse=True)
    table = np.full(int(np.prod(ndims)), -1, np.int32)
    table[ukeys] = np.arange(ukeys.size, dtype=np.int32)
    loc = cell_xyz - nodes * NODE_LEAVES
    lkey = (loc[:, 0] * NODE_LEAVES + loc[:, 1]) * NODE_LEAVES + loc[:, 2]
    ncells = np.full((ukeys.size, NODE_LEAVES ** 3), -1, np.int32)
    ncells[ninv.ravel(), lkey] = np.arange(cell_xyz.shape[0], dtype=np.int32)
    return nmin, ndims, table, ncells


class Hierarchy:
    """Packed two-level grid for all objects (see module doc), and what the builders add to it
    (the Gaussians, their lists, or the voxel bricks); packing.pack_accel turns it into the
    kernels' Accel group. ``cell_items`` is empty for the voxel (reference) structure, which
    uses ``bricks`` instead."""

    def __init__(self, n_obj):
        self.n_obj = n_obj
        self.clear()

    def clear(self, walk_obj=None, walk_scale=None):
        """No cells: the hierarchy before add(), over one walk grid per object (its leaves) or the
        grids given: walk_obj[w] the object of grid w, walk_scale[w] its cell size in leaves."""
        self.walk_obj = np.arange(self.n_obj, dtype=np.int32) if walk_obj is None else \
            np.asarray(walk_obj, np.int32)
        self.walk_scale = np.ones(self.n_obj, np.int64) if walk_scale is None else \
            np.asarray(walk_scale, np.int64)
        n_obj = self.walk_obj.shape[0]
        self.node_min = np.zeros((n_obj, 3), np.int64)
        self.node_dims = np.zeros((n_obj, 3), np.int64)   # 0 dims = empty object
        self.node_off = np.zeros(n_obj, np.int64)
        self.node_off_id = np.zeros(n_obj, np.int64)
        self.tables, self.ncells_list, self.cell_xyz_list = [], [], []
        self.n_cells = 0
        self.n_nodes = 0
        self.table_size = 0

    def add(self, k, cell_xyz):
        """Register walk grid k's cells (C,3) int64; returns the global id of its first cell."""
        first = self.n_cells
        if cell_xyz.shape[0] == 0:
            return first
        nmin, ndims, table, ncells = _cells_to_nodes(cell_xyz)
        self.node_min[k], self.node_dims[k] = nmin, ndims
        self.node_off[k] = self.table_size
        table[table >= 0] += self.n_nodes  # in place: node tables are the sparse lists' bulk
        ncells[ncells >= 0] += first
        self.tables.append(table)
        self.ncells_list.append(ncells)
        self.cell_xyz_list.append(cell_xyz)
        self.table_size += table.size
        self.n_nodes += ncells.shape[0]
        self.n_cells += cell_xyz.shape[0]
        return first

    def finish(self):
        self.node_table = np.concatenate(self.tables) if self.tables else np.full(1, -1, np.int32)
        self.node_cells = np.concatenate(self.ncells_list) if self.ncells_list else \
            np.full((1, NODE_LEAVES ** 3), -1, np.int32)
        self.cell_xyz = np.concatenate(self.cell_xyz_list) if self.cell_xyz_list else \
            np.zeros((0, 3), np.int64)
        self.max_walk = int(sum(int(NODE_LEAVES * d.sum()) + 3 * NODE_LEAVES + 8
                                for d in self.node_dims if d.sum() > 0)) + 8
        del self.tables, self.ncells_list, self.cell_xyz_list
        return self


def drawn_gaussians(gs, support_k=3.0, max_level=MAX_LEVEL, sigmas=False):
    """The Gaussians of set gs the renderer draws (gauss_pack.drawn with this module's levels)."""
    return drawn(gs, support_k, max_level, LEVEL_CELLS, LEVEL_SPAN, LEAF, sigmas)


def gaussian_bounds(gs, support_k):
    """((lo, hi) of the drawn Gaussians' centres, (lo, hi) of their support_k-sigma supports), in
    index coords, or None when none is drawn."""
    return drawn(gs, support_k, 0, LEVEL_CELLS, LEVEL_SPAN, LEAF, arrays=False)["bounds"]


def build_gaussians(objects, support_k):
    """The Gaussians of all objects, packed (ids object by object), each with the leaf-cell box of
    its k-sigma support and a bounding sphere; the leaf hierarchy and its lists stay empty until
    add_halo_lists (only the leaf walk, paper mode and surface normals read them)."""
    n = len(objects)
    acc = Hierarchy(n)
    acc.finish()
    parts = []
    acc.g_first = np.zeros(n + 1, np.int64)
    acc.g_bounds = []  # per object: gaussian_bounds (None: nothing drawn)
    for k, ob in enumerate(objects):
        d = drawn_gaussians(ob.gaussians, support_k, 0 if ob.is_level_set and ob.surface else MAX_LEVEL)
        d["obj"] = np.full(d["amp"].shape[0], k, np.int32)
        acc.g_first[k + 1] = acc.g_first[k] + d["amp"].shape[0]
        acc.g_bounds.append(d.pop("bounds"))
        parts.append(d)

    def joined(name, empty):
        if len(parts) == 1:
            return parts[0][name]  # no copy
        return np.concatenate([d[name] for d in parts]) if parts else empty

    acc.cell_start = np.zeros(1, np.int64)
    acc.cell_items = np.zeros(0, np.int32)
    acc.face_start = np.zeros(1, np.int64)
    acc.face_items = np.zeros(0, np.int32)
    acc.has_lists = False
    acc.g_mu = joined("mu", np.zeros((0, 3)))
    acc.g_inv = joined("inv", np.zeros((0, 3)))
    acc.g_val = joined("val", np.zeros(0))
    acc.g_cval = joined("cval", np.zeros(0))  # second grids' values (NaN: none)
    acc.g_amp = joined("amp", np.zeros(0))
    acc.g_obj = joined("obj", np.zeros(0, np.int32))
    # each Gaussian's level and range of that level's cells (inclusive): the kernels test it once
    # per ray
    acc.g_lev = joined("lev", np.zeros(0, np.int64))
    acc.g_clo = joined("clo", np.zeros((0, 3), np.int64))
    acc.g_chi = joined("chi", np.zeros((0, 3), np.int64))
    parts.clear()
    # bounding spheres for the kernels' cheap rejection: float32 centres relative to a reference
    # point per object (exact enough near the data at any translation), radius^2 widened by a
    # margin that covers the float32 rounding (~1e-4 voxel at 1000 voxels from the reference)
    acc.obj_ref = np.zeros((max(n, 1), 3))
    acc.g_sph = np.zeros((acc.g_mu.shape[0], 4), np.float32)
    for k in range(n):
        a0, a1 = acc.g_first[k], acc.g_first[k + 1]
        if a1 > a0:
            acc.obj_ref[k] = np.floor(acc.g_mu[a0:a1].mean(axis=0))
    # with each, paper mode's volume factor 1/det(Sigma) (index units)
    acc.g_volfac = np.zeros(acc.g_mu.shape[0])
    spheres(acc.g_mu, acc.g_inv, acc.obj_ref, acc.g_obj, float(support_k), acc.g_sph, acc.g_volfac)
    return acc


def halo_entries(acc):
    """The (Gaussian, cell) pairs the halo lists would hold: each support's box volume in the cells
    of its level."""
    ext = acc.g_chi - acc.g_clo + 1
    return int(np.prod(ext, axis=1, dtype=np.int64).sum()) if ext.shape[0] else 0


def halo_nodes(acc):
    """(nodes, dense node-table entries) the lists will use: the distinct nodes (NODE_LEAVES^3 cells
    of a level) the supports' boxes meet, and per walk grid the box of its nodes. A node's cell
    table costs 16 kB, so sparse supports need them counted."""
    m = acc.g_clo.shape[0]
    if m == 0:
        return 0, 0
    grid = np.repeat(np.arange(acc.n_obj), np.diff(acc.g_first)) * (MAX_LEVEL + 1) + acc.g_lev
    boxes = _unique_rows(np.column_stack([grid, np.floor_divide(acc.g_clo, NODE_LEAVES),
                                          np.floor_divide(acc.g_chi, NODE_LEAVES)]))
    grid, nlo, nhi = boxes[:, 0], boxes[:, 1:4], boxes[:, 4:7]
    # a box spans at most LEVEL_SPAN < NODE_LEAVES cells, so at most two nodes per axis: the
    # corners' nodes are all of them (boxes left wider at MAX_LEVEL are counted whole)
    corners = np.stack([np.stack([(nlo, nhi)[(c >> a) & 1][:, a] for a in range(3)], 1)
                        for c in range(8)]).reshape(-1, 3)
    keys = _unique_rows(np.column_stack([np.tile(grid, 8), corners]))
    wide = np.prod(nhi - nlo + 1, axis=1) > 8
    nodes = keys.shape[0] + int(np.prod(nhi[wide] - nlo[wide] + 1, axis=1).sum())
    table = 0
    for gk in np.unique(keys[:, 0]):
        k = keys[keys[:, 0] == gk, 1:]
        table += int(np.prod(k.max(0) - k.min(0) + 1))
    return nodes, table


def _unique_rows(rows):
    """np.unique(rows, axis=0) for int64 rows, through one int64 key per row where the rows'
    ranges allow it (sorting void rows is ~10x slower)."""
    lo = rows.min(0)
    span = rows.max(0) - lo + 1
    if float(np.prod(span.astype(np.float64))) >= 2.0 ** 62:
        return np.unique(rows, axis=0)
    key = np.zeros(rows.shape[0], np.int64)
    for a in range(rows.shape[1]):
        key = key * span[a] + (rows[:, a] - lo[a])
    key = np.unique(key)
    out = np.empty((key.size, rows.shape[1]), np.int64)
    for a in range(rows.shape[1] - 1, -1, -1):
        out[:, a] = key % span[a] + lo[a]
        key //= span[a]
    return out


def halo_bytes(entries, nodes=0, table=0):
    """Peak bytes add_halo_lists takes at most for that many entries, nodes and node-table entries
    (see HALO_BYTES)."""
    return int(entries) * HALO_BYTES + int(nodes) * NODE_BYTES + int(table) * TABLE_BYTES


def available_bytes():
    """Memory the system can give now (Linux MemAvailable, else free pages), or None if unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


# Screen-tile lists: a frame keeps them up to this many entries per Gaussian (a High set of
# 40 M small supports needs 1-2; a camera inside a dense volume puts every support near the eye
# plane in every tile, and then the leaf walk is cheaper), and while the memory holds them.
TILE_FANOUT = 8
TILE_ENTRY_BYTES = 32  # an id, a pixel mask, and the counting and filling passes' temporaries


def tile_budget(m, floor):
    """Most screen-tile entries a frame of m Gaussians builds (at least ``floor``, the fixed
    budget that predates scale; past it the lists must also fit the available memory)."""
    avail = available_bytes()
    room = avail // TILE_ENTRY_BYTES if avail is not None else floor
    return max(floor, min(TILE_FANOUT * int(m), room))


def check_halo_memory(acc, available=None):
    """Raise MemoryError (one line, with advice that helps) when the halo lists cannot fit in the
    memory available (``available`` bytes; default: the system's now)."""
    entries = halo_entries(acc)
    need = halo_bytes(entries, *halo_nodes(acc))
    avail = available_bytes() if available is None else available
    if avail is None or need <= avail:
        return
    raise MemoryError(
        f"the per-leaf Gaussian lists of this scene need about {need / 2**30:.1f} GiB "
        f"({entries:,} Gaussian-leaf pairs; {avail / 2**30:.1f} GiB available): draw it in particles "
        f"or field mode with screen tiles (no per-leaf lists), or with a coarser LOD (fewer pairs).")


def add_halo_lists(acc, support_k):
    """The leaf hierarchy and, per leaf cell, the Gaussians whose support box meets it (its own
    and its halo) and those first met per entry face; checks the memory first."""
    check_halo_memory(acc)
    n = acc.n_obj
    # walk grids: each object's leaves first (grid k = object k), then its coarser levels
    g_ob = np.repeat(np.arange(n), np.diff(acc.g_first))
    coarse = sorted(set(zip(g_ob[acc.g_lev > 0].tolist(), acc.g_lev[acc.g_lev > 0].tolist())))
    grids = [(k, 0) for k in range(n)] + coarse
    acc.clear([k for k, _ in grids], [LEVEL_CELLS ** lv for _, lv in grids])
    starts, items, faces = [np.zeros(1, np.int64)], [], []
    for w, (k, lv) in enumerate(grids):
        sel = np.arange(acc.g_first[k], acc.g_first[k + 1])
        sel = sel[acc.g_lev[sel] == lv]  # this grid's Gaussians, ascending ids
        m = sel.size
        if m == 0:
            continue
        clo, chi = acc.g_clo[sel], acc.g_chi[sel]
        ext = chi - clo + 1
        cnt = ext[:, 0] * ext[:, 1] * ext[:, 2]
        gid = np.repeat(np.arange(m, dtype=np.int64), cnt)
        first = np.repeat(np.cumsum(cnt) - cnt, cnt)
        rr = np.arange(gid.size, dtype=np.int64) - first
        del first
        eyz = ext[gid, 1] * ext[gid, 2]
        cx = clo[gid, 0] + rr // eyz
        cy = clo[gid, 1] + (rr % eyz) // ext[gid, 2]
        cz = clo[gid, 2] + rr % ext[gid, 2]
        del rr, eyz
        cmin = np.array([cx.min(), cy.min(), cz.min()])
        cdim = np.array([cx.max(), cy.max(), cz.max()]) - cmin + 1
        key = ((cx - cmin[0]) * cdim[1] + (cy - cmin[1])) * cdim[2] + (cz - cmin[2])
        order = np.argsort(key, kind="stable")  # keeps ascending gid within a cell
        key, gid = key[order], gid[order]
        ukey, ucount = np.unique(key, return_counts=True)
        del key
        cxyz = np.stack([ukey // (cdim[1] * cdim[2]) + cmin[0],
                         (ukey // cdim[2]) % cdim[1] + cmin[1],
                         ukey % cdim[2] + cmin[2]], axis=1).astype(np.int64)
        acc.add(w, cxyz)
        starts.append(starts[-1][-1] + np.cumsum(ucount))
        items.append(sel[gid].astype(np.int32))
        counts, fitems = _face_lists(np.repeat(np.arange(ukey.size), ucount), cx[order], cy[order],
                                     cz[order], gid, clo, chi, ukey.size, 0)
        faces.append((counts, sel[fitems].astype(np.int32)))
    acc.finish()
    acc.cell_start = np.concatenate(starts).astype(np.int64)
    acc.cell_items = np.concatenate(items) if items else np.zeros(0, np.int32)
    acc.face_items = np.concatenate([f[1] for f in faces]) if faces else np.zeros(0, np.int32)
    acc.face_start = np.zeros(6 * acc.n_cells + 1, np.int64)
    if faces:  # cells are numbered grid by grid, so the per-grid counts line up
        np.cumsum(np.concatenate([f[0] for f in faces]), out=acc.face_start[1:])
    acc.has_lists = True
    return acc


@njit(cache=True, nogil=True)
def _face_lists(cell, cx, cy, cz, gid, clo, chi, n_cells, g_off):
    """Per (cell, entry face) the Gaussians first met there by a ray coming from the face
    neighbour: face 2a when moving +a (the support box starts at this cell on axis a), 2a+1 when
    moving -a (it ends here). Pairs come in cell order, ids ascending within a cell, so a counting
    sort keeps the ids ascending per list. Returns (entries per key cell * 6 + face, ids)."""
    counts = np.zeros(6 * n_cells, np.int64)
    for p in range(cell.size):
        g = gid[p]
        c = (cx[p], cy[p], cz[p])
        for a in range(3):
            if c[a] == clo[g, a]:
                counts[6 * cell[p] + 2 * a] += 1
            if c[a] == chi[g, a]:
                counts[6 * cell[p] + 2 * a + 1] += 1
    cur = np.cumsum(counts) - counts
    out = np.empty(counts.sum(), np.int32)
    for p in range(cell.size):
        g = gid[p]
        c = (cx[p], cy[p], cz[p])
        for a in range(3):
            for f, edge in ((2 * a, clo[g, a]), (2 * a + 1, chi[g, a])):
                if c[a] == edge:
                    k = 6 * cell[p] + f
                    out[cur[k]] = g + g_off
                    cur[k] += 1
    return counts, out


def _grid_leaves(grid):
    """(origins int64 (N,3), values float32 (N,8,8,8)) of a GridData, with active tiles expanded
    into constant leaves (tiles of 4096 voxels are skipped: too large to expand)."""
    org = np.asarray(grid.leaf_origins, np.int64).reshape(-1, 3)
    val = np.asarray(grid.leaf_values, np.float32).reshape(-1, LEAF, LEAF, LEAF)
    to = getattr(grid, "tile_origins", None)
    if to is not None and len(to):
        to = np.asarray(to, np.int64).reshape(-1, 3)
        ts = np.asarray(grid.tile_sizes, np.int64)
        tv = np.asarray(grid.tile_values, np.float32)
        ta = np.asarray(grid.tile_active, bool)
        extra_o, extra_v = [], []
        for o, s, v, a in zip(to, ts, tv, ta):
            if not a or s > 128:
                continue
            r = np.arange(0, s, LEAF)
            g = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3) + o
            extra_o.append(g)
            extra_v.append(np.full((g.shape[0], LEAF, LEAF, LEAF), v, np.float32))
        if extra_o:
            org = np.concatenate([org] + extra_o)
            val = np.concatenate([val] + extra_v)
    return org, val


def build_voxel_accel(objects):
    """Reference-mode structure: one cell per VDB leaf with a 10^3 brick (apron of the
    neighbours' voxels; voxels of missing leaves take the grid background), and the colour
    grids' bricks on the same cells (second_grid.object_bricks)."""
    from ...lod.second_grid import object_bricks

    n = len(objects)
    acc = Hierarchy(n)
    bricks, ranges = [], []
    for k, ob in enumerate(objects):
        if ob.grid is None:
            continue
        org, val = _grid_leaves(ob.grid)
        if org.shape[0] == 0:
            continue
        b, blo, bhi = leaf_bricks(org, val, float(getattr(ob.grid, "background", 0.0) or 0.0))
        cells = np.floor_divide(org, LEAF)
        acc.add(k, cells)
        bricks.append(b)
        ranges.append((blo, bhi))
    acc.finish()
    acc.bricks = np.concatenate(bricks) if len(bricks) > 1 else bricks[0] if bricks else \
        np.zeros((1, BRICK, BRICK, BRICK), np.float32)
    acc.sub_max = sub_max(acc.bricks)  # the transparent-sample skip's bound (packing.clear_bits)
    acc.brick_lo = np.concatenate([r[0] for r in ranges]) if ranges else np.zeros(1)
    acc.brick_hi = np.concatenate([r[1] for r in ranges]) if ranges else np.zeros(1)
    acc.cell_obj = np.concatenate([np.full(int(c), k, np.int32) for k, c in enumerate(_cell_counts(acc))]) \
        if acc.n_cells else np.zeros(0, np.int32)
    acc.cbricks = object_bricks(objects, acc.cell_obj, acc.cell_xyz)
    return acc


def _cell_counts(acc):
    # cells were added in object order; recover per-object counts from node tables
    counts = np.zeros(acc.n_obj, np.int64)
    for k in range(acc.n_obj):
        if acc.node_dims[k].sum() == 0:
            continue
        t = acc.node_table[acc.node_off[k]: acc.node_off[k] + int(np.prod(acc.node_dims[k]))]
        ids = t[t >= 0]
        counts[k] = int((acc.node_cells[ids] >= 0).sum())
    return counts
