"""The Gaussian mixture evaluated at the voxels, and its field error against them, exactly, at every
active voxel centre.

s(x) = sum_i value_i amplitude_i exp(-1/2 sum_k ((x_k - c_ik)/sigma_ik)^2), each Gaussian truncated
to its k-sigma ellipsoid (k = 4 by default: the cut-off is exp(-8) = 3.4e-4 of the peak; the renderer
uses the same support). Evaluation uses the leaf structure: every Gaussian is listed (count-then-fill)
in the cells (leaves, tiles) its support box meets, then each cell sums its list over its 8^3 voxels
with separable exponentials, on threads over cells. The set's common classes of equal-sigma
Gaussians on a block lattice (High's 2^3 blocks and voxels) skip the lists: each cell sums them from
the nodes of the 27 leaves around it (error_lattice.py), the same terms in another order (1e-11).
Per-cell partial sums are reduced in cell order, so the numbers depend neither on the thread count
nor on the chunk size.

Reference: fog volumes (and any non-level-set grid) the voxel value; NRMSE divides the RMSE by the
value range of the active voxels (or by max |value| when the range is 0, as for a constant grid).
Level sets carry no values: the mixture is an occupancy. The reference occupancy is 1 on the voxels
the Gaussians stand for (the zero-crossing shell when the band option is on, else the whole band)
and 0 on the other active voxels; RMSE/NRMSE/max_abs are of that occupancy (denominator 1), and the
surface error is the IoU of {s >= 1/2} with the reference shell over the active voxels
(`surface_iou`, 1 is perfect) plus the fraction of active voxels classified differently
(`surface_mismatch`).
Tiles: an 8^3 tile is evaluated at all its voxels; a larger tile at the 8^3 voxels around its centre,
weighted by (edge/8)^3 (its interior is far from any edge effect).
The per-cell pieces (axis terms, mixture, residual, per-pair sums) are shared with refine.py and
fit.py, so the three measure the same field at the same voxels.
"""
from __future__ import annotations

import time

import numpy as np

from ..jit import njit, parallel_for
from .error_lattice import class_tables, classify, gather_split, lattice_classes, node_slots
from .error_lattice_sums import lattice_cell
from .error_pairs import _OFF, _count_pairs, _fill_pairs, chunk_pairs, distinct_sigmas, group_boxes
from .gridprep import effective_masks, finite_grid, value_range
from .levelset import band_threshold

DEFAULT_K = 4.0
@njit(cache=True, inline="always")
def axis_terms(c, g, corg, cent, sig, power, cut, q, e):
    """Along each axis a, at the 8 voxel centres l of cell c: q[a, l] = d^2 and
    e[a, l] = exp(-power d^2 / 2), d the distance to Gaussian g's centre in its sigmas. Beyond
    the truncation (q > cut) e is 0 and never read (every caller skips those voxels): the
    exponentials are most of the evaluation's cost, about half of them out there."""
    for a in range(3):
        for li in range(8):
            d = (corg[c, a] + li - cent[g, a]) / sig[g, a]
            q[a, li] = d * d
            e[a, li] = np.exp(-0.5 * power * d * d) if d * d <= cut else 0.0


@njit(cache=True, inline="always")
def _add_gaussian(acc, wg, k2, q, e):
    """acc += wg x the separable exponentials e where the k-sigma ellipsoid holds (q: d^2)."""
    for x in range(8):
        if q[0, x] > k2:
            continue
        for y in range(8):
            qxy = q[0, x] + q[1, y]
            if qxy > k2:
                continue
            wxy = wg * e[0, x] * e[1, y]
            base = x * 64 + y * 8
            # q[2] is unimodal in z (|d| is monotonic in the distance, and so is its rounding):
            # the voxels within the ellipsoid are one run, summed without a test per voxel
            z0 = 0
            while z0 < 8 and not qxy + q[2, z0] <= k2:
                z0 += 1
            z1 = 7
            while z1 > z0 and not qxy + q[2, z1] <= k2:
                z1 -= 1
            for z in range(z0, z1 + 1):
                acc[base + z] += wxy * e[2, z]


@njit(cache=True, inline="always")
def cell_mixture(c, corg, cstart, pg, cent, sig, w, k2, acc, q, e):
    """Add to acc (512) the mixture at the voxel centres of cell c: every Gaussian listed for the
    cell, truncated at k sigma (k2 = k^2), with separable exponentials per axis."""
    for p in range(cstart[c], cstart[c + 1]):
        g = pg[p]
        axis_terms(c, g, corg, cent, sig, 1.0, k2, q, e)
        _add_gaussian(acc, w[g], k2, q, e)


def axis_tables(u, k, limit=1 << 23):
    """Centres on the half-voxel lattice (every set build_lod or the decoder makes) with few
    distinct sigmas u: d = (voxel - centre) / sigma takes few values, so q = d^2 and
    e = exp(-d^2/2) come from a table over (sigma, h = 2 x (voxel - centre)), made with the very
    operations axis_terms does (the same bits). Returns (tq, te, H), tables over h in [-H, H]
    (beyond it q > k^2), or None above ``limit`` entries."""
    hh = int(np.ceil(2.0 * k * u.max())) + 2
    if len(u) * (2 * hh + 1) > limit:
        return None
    return (*_tables(u, float(k), hh), hh)


@njit(cache=True)
def _tables(u, k, hh):
    tq = np.empty((u.shape[0], 2 * hh + 1))
    te = np.empty((u.shape[0], 2 * hh + 1))
    k2 = k * k
    power = 1.0
    for s in range(u.shape[0]):
        for h in range(-hh, hh + 1):
            d = (h * 0.5) / u[s]  # = (voxel - centre) / sigma: the difference is exact
            tq[s, h + hh] = d * d
            te[s, h + hh] = np.exp(-0.5 * power * d * d) if d * d <= k2 else 0.0
    return tq, te


@njit(cache=True, inline="always")
def _table_terms(c, g, corg, c2, sid, tq, te, hh, q, e):
    """axis_terms (power 1) from axis_tables' tables."""
    for a in range(3):
        h0 = 2 * corg[c, a] - c2[g, a] + hh
        s = sid[g, a]
        for li in range(8):
            i = h0 + 2 * li
            if 0 <= i <= 2 * hh:
                q[a, li] = tq[s, i]
                e[a, li] = te[s, i]
            else:
                q[a, li] = np.inf
                e[a, li] = 0.0


@njit(cache=True, inline="always")
def gaussian_terms(c, g, corg, cent, sig, k2, c2, sid, tq, te, hh, q, e):
    """axis_terms (power 1) of Gaussian g at cell c; from axis_tables' (c2, sid, tq, te, hh)
    when hh >= 0 (the same bits)."""
    if hh >= 0:
        _table_terms(c, g, corg, c2, sid, tq, te, hh, q, e)
    else:
        axis_terms(c, g, corg, cent, sig, 1.0, k2, q, e)


@njit(cache=True, inline="always")
def cell_residual(c, cmask, cref, acc, res, act):
    """The residual reference - mixture at the active voxels i of cell c into res[i], act[i] = True
    there (both left as they are elsewhere). Returns (sum of squares, max |residual|, voxels)."""
    s2 = 0.0
    m = 0.0
    n = 0.0
    for wd in range(8):
        mk = cmask[c, wd]
        if mk == 0:
            continue
        for b in range(64):
            if (mk >> np.uint64(b)) & np.uint64(1):
                i = wd * 64 + b
                r = np.float64(cref[c, i]) - acc[i]
                res[i] = r
                act[i] = True
                s2 += r * r
                m = max(m, abs(r))
                n += 1.0
    return s2, m, n


@njit(cache=True, inline="always")
def pair_voxels(q, e, k2, gather, both, u, wu, v, wv):
    """A pair's Gaussian g over its cell's voxels inside its k-sigma ellipsoid (q, e: its axis
    terms). gather False: u += wu[0] g, v += wv[0] g (u, v 512 each; the weights come in
    one-element arrays, so both uses pass arrays in the same places). gather True: u[z] += g a, v[z] += g b
    summed over the (x, y) rows for a = wu, b = wv (512 each, 0 off the active voxels), u, v
    scratch (8), then returns (sum g a, sum g b) across z: eight independent chains in SIMD lanes
    (a running sum voxel by voxel was bound by the latency of its additions). both False: u only
    (the second sum 0). Inlined with gather and both constants: each use is its own loop."""
    if gather:
        u[:8] = 0.0
        v[:8] = 0.0
    for x in range(8):
        if q[0, x] > k2:
            continue
        for y in range(8):
            qxy = q[0, x] + q[1, y]
            if qxy > k2:
                continue
            exy = e[0, x] * e[1, y]
            b = x * 64 + y * 8
            for z in range(8):
                if gather:
                    ps = exy * e[2, z] if qxy + q[2, z] <= k2 else 0.0
                    u[z] += ps * wu[b + z]
                    if both:
                        v[z] += ps * wv[b + z]
                elif qxy + q[2, z] <= k2:
                    u[b + z] += (wu[0] * exy) * e[2, z]
                    if both:
                        v[b + z] += (wv[0] * exy) * e[2, z]
    if not gather:
        return 0.0, 0.0
    return (((u[0] + u[1]) + (u[2] + u[3])) + ((u[4] + u[5]) + (u[6] + u[7])),
            ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7])))


CELLS_PER_TASK = 16  # cells per task (parallel_for's index): one set of scratch arrays per task


@njit(cache=True, inline="always")
def _store(c, acc, vals, masks):
    """vals[c] = acc as float32, masks[c] = where acc is nonzero."""
    for wd in range(8):
        m = np.uint64(0)
        for b in range(64):
            v = acc[wd * 64 + b]
            vals[c, wd * 64 + b] = np.float32(v)
            if v != 0.0:
                m |= np.uint64(1) << np.uint64(b)
        masks[c, wd] = m


@njit(cache=True, nogil=True)
def _eval_rows(lo, hi, corg, cmask, cref, cstart, pg, cent, sig, w, k, c2, sid, tq, te, hh, keys, nlg, slot,
               nodes, nper, nw, wr, wnode, qa, ea, tz, ez, nlev, xys, xyt, xyl, xye, cost, nwm, nlm, vals,
               masks, sse, mx, npts, inter, union):
    """_eval_cells' tasks lo..hi-1: CELLS_PER_TASK cells each, one set of scratch arrays."""
    nc, k2 = corg.shape[0], k * k
    for t in range(lo, hi):
        acc = np.empty(512)
        res = np.empty(512)
        act = np.empty(512, np.bool_)
        q = np.empty((3, 8))
        e = np.empty((3, 8))
        nb = np.empty(27, np.int64)
        W = np.empty(nwm * nwm * nwm)
        colnz = np.zeros(nwm * nwm, np.bool_)
        Z = np.empty(nwm * nwm * nlm * 8)
        for c in range(t * CELLS_PER_TASK, min(nc, (t + 1) * CELLS_PER_TASK)):
            acc[:] = 0.0
            act[:] = False
            lattice_cell(c, corg, k2, keys, nlg, slot, nodes, nper, nw, wr, wnode, qa, ea, tz, ez,
                         nlev, xys, xyt, xyl, xye, cost, nwm, nlm, nb, W, colnz, Z, acc)
            for p in range(cstart[c], cstart[c + 1]):
                gaussian_terms(c, pg[p], corg, cent, sig, k2, c2, sid, tq, te, hh, q, e)
                _add_gaussian(acc, w[pg[p]], k2, q, e)
            if vals.shape[0]:
                _store(c, acc, vals, masks)
            sse[c], mx[c], npts[c] = cell_residual(c, cmask, cref, acc, res, act)
            it = 0.0
            un = 0.0
            for i in range(512):
                if act[i]:
                    occ = acc[i] >= 0.5
                    ref = cref[c, i] >= 0.5
                    if occ and ref:
                        it += 1.0
                    if occ or ref:
                        un += 1.0
            inter[c], union[c] = it, un


def _eval_cells(corg, cmask, cref, cstart, pg, cent, sig, w, k, c2, sid, tq, te, hh, keys, nlg, slot, nodes,
                nper, nw, wr, wnode, qa, ea, tz, ez, nlev, xys, xyt, xyl, xye, cost, nwm, nlm, vals, masks):
    """Per cell: squared residual, max |residual|, active voxels, and the occupancy's
    intersection and union. hh >= 0: the axis terms from axis_tables' (c2, sid, tq, te, hh).
    With vals (float32 (cells, 512); else empty) the mixture itself too, and in masks (uint64
    (cells, 8)) where it is nonzero (a splat lattice: kernels.lod.splat).
    The lattice classes (keys ... nlm: error_lattice_sums.lattice_cell's) first, then the
    cell's pair list."""
    out = tuple(np.zeros(len(corg)) for _ in range(5))  # sse, mx, npts, inter, union
    parallel_for(_eval_rows, -(-len(corg) // CELLS_PER_TASK), corg, cmask, cref, cstart, pg, cent, sig, w,
                 np.float64(k), c2, sid, tq, te, np.int64(hh), keys, np.int64(nlg), slot, nodes, nper, nw, wr,
                 wnode, qa, ea, tz, ez, nlev, xys, xyt, xyl, xye, cost, np.int64(nwm), np.int64(nlm), vals,
                 masks, *out)
    return out


def _cells(grid, gset):
    """Evaluation cells: leaves, then active tiles as 8^3 pseudo-leaves; origins, masks, weights,
    and where each cell's reference per voxel comes from (made per chunk by _cref: a copy of
    every reference at once would be as large as the voxel values)."""
    is_ls = grid.grid_class == "level_set"
    band = bool(gset.params.get("level_set_band", False)) if gset.params else False
    if is_ls and not gset.params:  # decoded set: no params; assume the default (band on)
        band = True
    corg = [np.asarray(grid.leaf_origins, np.int64).reshape(-1, 3)]
    cmask = [np.asarray(grid.leaf_masks, np.uint64).reshape(-1, 8)]
    if is_ls:  # the reference occupancy: the kept bits
        leaf = np.asarray(effective_masks(grid, band)[0], np.uint64).reshape(-1, 8)
    else:
        leaf = np.asarray(grid.leaf_values, np.float32).reshape(-1, 512)
    cw = [np.ones(len(corg[0]))]
    tref = np.zeros(0, np.float32)
    act = np.nonzero(np.asarray(grid.tile_active, bool))[0]
    if len(act):
        to = np.asarray(grid.tile_origins, np.int64).reshape(-1, 3)[act]
        ts = np.asarray(grid.tile_sizes, np.int64)[act]
        tv = np.asarray(grid.tile_values, np.float32)[act]
        off = np.where(ts > 8, ts // 2, 0)
        corg.append(to + off[:, None])
        cmask.append(np.full((len(act), 8), np.iinfo(np.uint64).max, np.uint64))
        if is_ls:
            thr = band_threshold(grid) if band else np.inf
            tref = (np.abs(tv) <= thr).astype(np.float32)
        else:
            tref = tv
        cw.append((ts / 8.0) ** 3)
    return (np.concatenate(corg), np.concatenate(cmask), np.concatenate(cw), is_ls,
            dict(leaf=leaf, tile=tref))


def _cref(ref, rows, is_ls):
    """float32 (len(rows), 512): the reference per voxel of the cells ``rows`` (_cells' order)."""
    out = np.empty((len(rows), 512), np.float32)
    nleaf = len(ref["leaf"])
    leaf = rows < nleaf
    li = rows[leaf]
    if is_ls:
        bits = (ref["leaf"][li][:, :, None] >> np.arange(64, dtype=np.uint64)) & np.uint64(1)
        out[leaf] = bits.reshape(len(li), 512)
    else:
        out[leaf] = ref["leaf"][li]
    out[~leaf] = ref["tile"][rows[~leaf] - nleaf][:, None]
    return out


def cell_keys(cells):
    """The sort keys of leaf cells given as index >> 3 (int64 (n, 3)), as error_pairs._key computes them."""
    return ((cells[:, 0] + _OFF) << 42) | ((cells[:, 1] + _OFF) << 21) | (cells[:, 2] + _OFF)


def cell_index(grid, gset):
    """The evaluation cells, sorted by key: origins, masks, weights (big tiles count (edge/8)^3),
    keys, whether the grid is a level set, and rows / ref (where the reference of each comes from,
    for _cref)."""
    grid, _ = finite_grid(grid)  # the voxels build_lod kept: NaN/Inf ones are inactive there too
    corg, cmask, cw, is_ls, ref = _cells(grid, gset)
    keys = cell_keys(corg >> 3)
    srt = np.argsort(keys, kind="stable")
    return dict(corg=corg[srt], cmask=cmask[srt], cw=cw[srt], keys=keys[srt], is_ls=is_ls,
                rows=srt, ref=ref)


def cell_table(grid, gset):
    """cell_index plus cref, the reference per voxel of every cell. Depends on the grid and on the
    set's level-set band option only, so an adaptive build computes it once."""
    t = cell_index(grid, gset)
    return dict(t, cref=_cref(t["ref"], t["rows"], t["is_ls"]))


def pair_lists(table, cent, sig, k=DEFAULT_K):
    """The (cell, Gaussian) pairs of Gaussians at cent with sigmas sig (float64), truncated at k
    sigma, grouped by cell: table plus cstart, pg (Gaussian of each pair), cent, sig, k."""
    keys, corg = table["keys"], table["corg"]
    kk = float(k)
    cnt = _count_pairs(cent, sig, kk, keys, corg)
    start = np.zeros(len(cnt) + 1, np.int64)
    np.cumsum(cnt, out=start[1:])
    pc = np.empty(int(start[-1]), np.int64)
    _fill_pairs(cent, sig, kk, keys, corg, start, pc)
    pg = np.repeat(np.arange(len(cnt), dtype=np.int64), cnt)
    o = np.argsort(pc, kind="stable")
    pg = pg[o]
    cstart = np.zeros(len(corg) + 1, np.int64)
    np.cumsum(np.bincount(pc, minlength=len(corg)), out=cstart[1:])
    return dict(table, cstart=cstart, pg=pg, cent=cent, sig=sig, k=kk)


def setup(grid, gset, k=DEFAULT_K):
    """Cells (sorted by key), the (cell, Gaussian) pair lists and the Gaussians' geometry: all that
    the evaluation needs except the weights (so an amplitude refinement can reuse it)."""
    return pair_lists(cell_table(grid, gset), gset.centers(), gset.sigmas.astype(np.float64), k)


def nrmse_denominator(is_ls, vmin, vmax):
    """What the RMSE is divided by: 1 for level sets (an occupancy), else the value range, or
    max |value| when the range is 0 (a constant grid)."""
    if is_ls:
        return 1.0
    return (vmax - vmin) or max(abs(vmin), abs(vmax)) or 1.0


class _Reach:
    """Which Gaussians a run of cells (contiguous in key order, so in cell x) can meet. Leaf
    groups are sorted by origin: the running maximum of their reach's high end and the running
    minimum from the back of its low end are monotonic, so two binary searches bound the leaf
    Gaussians; tile groups (few, any size) are tested one by one."""

    def __init__(self, gset, k, lattice=True, values=None):
        self.gs, gstart, nl = gset, gset.group_start, gset.n_leaf_groups
        self.values = gset.values if values is None else values
        self.origins = np.asarray(gset.group_origins).reshape(-1, 3)
        lo, hi = (b[:, 0] for b in group_boxes(self.origins, gstart, np.asarray(gset.offsets),
                                                 np.asarray(gset.sigmas), 0.0, 1.0, float(k)))
        self.pmax = np.maximum.accumulate(hi[:nl])
        self.smin = np.minimum.accumulate(lo[:nl][::-1])[::-1]
        self.tlo, self.thi, self.nl = lo[nl:], hi[nl:], nl
        self.u, few = distinct_sigmas(gset.sigmas)
        self.tables = axis_tables(self.u, k) if few and len(self.u) else None
        csig, ce = lattice_classes(gset, k) if lattice else _NO_CLASSES
        self.ce, self.lattice = ce, class_tables(csig, ce, k)
        self.cls = classify(gstart, nl, gset.offsets, gset.sigmas, csig, ce)
        self.buf = np.zeros(0)

    def geometry(self, xa, xb):
        """The Gaussians whose boxes reach cell x in [xa, xb]: those of no lattice class in
        increasing index order (so each cell sums them in the set's order) as (centres, sigmas,
        weights, axis-table arguments of _eval_cells), and the lattice arguments of _eval_cells
        (the classes' nodes of the leaf groups within reach)."""
        g = self.gs
        g0 = int(np.searchsorted(self.pmax, xa, "left"))
        g1 = max(g0, int(np.searchsorted(self.smin, xb, "right")))
        tsel = np.flatnonzero((self.thi >= xa) & (self.tlo <= xb)) + self.nl
        grp = np.concatenate([np.arange(g0, g1, dtype=np.int64), tsel])
        u = self.u if len(self.u) else np.zeros(1)
        cls, rest, held = self.cls
        slot, size = node_slots(grp, held, self.lattice[0])
        if size > len(self.buf):  # kept from chunk to chunk: its pages are touched once
            self.buf = np.empty(int(size * 1.25))
        nodes = self.buf[:size]
        cent, sig, w, c2, sid, lattice, keys = gather_split(
            grp, g.group_start, self.origins, g.offsets, g.sigmas, self.values, g.amplitudes, u, cls,
            rest, self.ce, self.lattice[0], slot, nodes)
        lat = (keys, g1 - g0, slot, nodes, *self.lattice)
        if lattice and self.tables is not None:
            return cent, sig, w, (c2, sid, *self.tables), lat
        return cent, sig, w, _NO_TABLES, lat


_NO_TABLES = (np.zeros((0, 3), np.int64), np.zeros((0, 3), np.int32), np.zeros((0, 0)),
              np.zeros((0, 0)), -1)
_NO_CLASSES = (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64))
# _eval_cells' lattice arguments without any class (every Gaussian on the pair lists)
_NO_LATTICE = (np.zeros(0, np.int64), 0, np.zeros((0, 0), np.int64), np.zeros(0),
               *class_tables(*_NO_CLASSES, DEFAULT_K))


NO_VALUES = (np.zeros((0, 512), np.float32), np.zeros((0, 8), np.uint64))  # _eval_cells: no mixture out
DEFAULT_CHUNK = 8192  # cells per evaluation chunk: bounds its pair lists (~500 a cell) and class nodes


def mixture_chunks(keys, corg, gset, k, chunk=DEFAULT_CHUNK, lattice=True, values=None):
    """Per chunk of cells (sorted by key): (a, b, the arguments of _eval_cells after corg, cmask,
    cref: the chunk's pair lists, Gaussians, tables and lattice classes). Each chunk lists only
    its own pairs, with its Gaussians in the set's order, so every cell sums the same terms in
    the same order as one list over all cells would. The lattice classes (error_lattice.py;
    ``lattice=False``: none) are summed from their nodes instead, the same terms in another
    order, again the same for any chunk. ``values``: the weights' values (default the set's)."""
    nc, kk = len(keys), float(k)
    # the lattice sums take cells on the leaf lattice (tiles are aligned to their size)
    reach = _Reach(gset, kk, lattice and not np.any(corg & 7), values)
    for a in range(0, nc, max(1, int(chunk))):
        b = min(nc, a + max(1, int(chunk)))
        ck, co = keys[a:b], corg[a:b]
        cent, sig, w, tab, lat = reach.geometry(co[0, 0] >> 3, co[-1, 0] >> 3)
        if len(cent) == 0:  # every Gaussian within reach is on the lattice
            cstart, pg = np.zeros(b - a + 1, np.int64), np.zeros(0, np.int32)
        else:
            cstart, pg = chunk_pairs(cent, sig, kk, co, ck)
        yield a, b, (cstart, pg, cent, sig, w, kk, *tab, *lat)


def _evaluate(grid, gset, k, chunk=DEFAULT_CHUNK, lattice=True):
    """The per-cell figures of _eval_cells over every cell (sorted by key), a chunk of cells at a
    time (mixture_chunks)."""
    t = cell_index(grid, gset)
    nc = len(t["keys"])
    out = [np.zeros(nc) for _ in range(5)]
    pairs = 0
    for a, b, args in mixture_chunks(t["keys"], t["corg"], gset, k, chunk, lattice):
        pairs += len(args[1])
        cref = _cref(t["ref"], t["rows"][a:b], t["is_ls"])
        res = _eval_cells(t["corg"][a:b], t["cmask"][a:b], cref, *args, *NO_VALUES)
        for o, r in zip(out, res):
            o[a:b] = r
    return dict(t, pairs=pairs, k=float(k)), out


def cell_errors(grid, gset, k=DEFAULT_K, chunk=DEFAULT_CHUNK):
    """Per evaluation cell, sorted by key: (keys, summed squared residual, active voxels)."""
    st, (sse, _, npts, _, _) = _evaluate(grid, gset, k, chunk)
    return st["keys"], sse, npts


def field_error(grid, gset, k=DEFAULT_K, chunk=DEFAULT_CHUNK) -> dict:
    """The error figures; ``chunk``: cells evaluated at a time (bounds the memory; any value
    gives the same figures)."""
    t0 = time.perf_counter()
    st, (sse, mx, npts, inter, union) = _evaluate(grid, gset, k, chunk)
    cw, is_ls, kk = st["cw"], st["is_ls"], st["k"]
    n = float(np.sum(npts * cw))
    rmse = float(np.sqrt(np.sum(sse * cw) / n)) if n else 0.0
    vmin, vmax = gset.params.get("value_min"), gset.params.get("value_max")
    if vmin is None and not is_ls:
        vmin, vmax = value_range(grid)
    den = nrmse_denominator(is_ls, vmin, vmax)
    out = dict(rmse=rmse, nrmse=rmse / den, max_abs=float(mx.max()) if len(mx) else 0.0,
               nrmse_denominator=float(den), points=int(n), k_sigma=kk,
               pairs=int(st["pairs"]), seconds=time.perf_counter() - t0)
    if is_ls:
        it, un = float(np.sum(inter * cw)), float(np.sum(union * cw))
        out.update(surface_iou=it / un if un else 1.0, surface_mismatch=(un - it) / n if n else 0.0,
                   reference="occupancy of the kept shell")
    else:
        out["reference"] = "voxel value"
    return out
