"""The field error's lattice path (mixture.py): the set's most common classes of equal-sigma
Gaussians on one block lattice are summed per cell from a grid of nodes, not from pair lists.

A class is (sigma triple, edge e per axis): leaf-group Gaussians with that sigma whose centre
offset is an aligned e-block's centre, c2 = 2 x offset = e (2 j + 1) - 1, node j in [0, 8 / e)
(High: the 2^3 blocks and the single voxels; Medium adds the 4^3 blocks). e follows from the
centre alone (the lowest set bit of c2 + 1), so no size codes are needed. A class is taken only
when every member's k-sigma box stays within the 27 leaves around its own: a cell then sums its
class nodes from the 27 leaf groups around it (error_lattice_sums.py), with the same axis terms,
the same k-sigma ellipsoid cut and the same voxels as the pair lists would give. Everything else
(tiles, merged blocks, ellipsoids of rare shapes, off-lattice centres) stays on the pair lists.

Per chunk of cells, `gather_split` splits the Gaussians within reach into the pair path's
per-Gaussian arrays and, per class, dense node weights per leaf group (only for groups holding
members of the class), so the memory stays bounded by the chunk.
"""
from __future__ import annotations

import numpy as np

from ..jit import njit, parallel_for
from .error_pairs import _key

MAX_CLASSES = 4  # lattice classes at most (High has 2, Medium 3)
MIN_CLASS = 64  # Gaussians a class needs (fewer: cheaper on the pair lists)
_KEYS = 16  # distinct (sigma, edge) keys counted per block of groups
_BLOCKS = 64  # blocks of leaf groups counted on threads


@njit(cache=True, inline="always")
def _edge(off):
    """The block edge e whose aligned block has its centre at local offset ``off``, or 0 (not
    on the half-voxel lattice within a leaf)."""
    h = 2.0 * np.float64(off)
    if h != np.rint(h) or h < 0.0 or h > 14.0:
        return 0
    c = np.int64(h) + 1
    return c & -c


@njit(cache=True, inline="always")
def _class_of(j, offsets, sigmas, csig, ce):
    """The lattice class of leaf-group Gaussian j, or -1."""
    for q in range(csig.shape[0]):
        if (sigmas[j, 0] == csig[q, 0] and sigmas[j, 1] == csig[q, 1]
                and sigmas[j, 2] == csig[q, 2] and _edge(offsets[j, 0]) == ce[q, 0]
                and _edge(offsets[j, 1]) == ce[q, 1] and _edge(offsets[j, 2]) == ce[q, 2]):
            return q
    return -1


@njit(cache=True, nogil=True)
def _class_count_rows(lo, hi, gstart, nl, offsets, sigmas, ks, ke, cnt):
    """Per block b of leaf groups in lo..hi-1: its first _KEYS distinct (sigma, edge) keys and
    their counts."""
    for b in range(lo, hi):
        n = 0
        last = -1
        for j in range(gstart[b * nl // _BLOCKS], gstart[(b + 1) * nl // _BLOCKS]):
            e0, e1, e2 = _edge(offsets[j, 0]), _edge(offsets[j, 1]), _edge(offsets[j, 2])
            if e0 == 0 or e1 == 0 or e2 == 0:
                continue
            s0, s1, s2 = sigmas[j, 0], sigmas[j, 1], sigmas[j, 2]
            hit = -1
            for t in range(n):  # the last key first: runs of one class are the rule
                q = (last + t) % n
                if (ks[b, q, 0] == s0 and ks[b, q, 1] == s1 and ks[b, q, 2] == s2
                        and ke[b, q, 0] == e0 and ke[b, q, 1] == e1 and ke[b, q, 2] == e2):
                    hit = q
                    break
            if hit < 0:
                if n == _KEYS:
                    continue
                hit = n
                ks[b, n, 0], ks[b, n, 1], ks[b, n, 2] = s0, s1, s2
                ke[b, n, 0], ke[b, n, 1], ke[b, n, 2] = e0, e1, e2
                n += 1
            cnt[b, hit] += 1
            last = hit


def _class_counts(gstart, nl, offsets, sigmas):
    """Per block of leaf groups: its first _KEYS distinct (sigma, edge) keys and their counts."""
    ks = np.zeros((_BLOCKS, _KEYS, 3), np.float32)
    ke = np.zeros((_BLOCKS, _KEYS, 3), np.int64)
    cnt = np.zeros((_BLOCKS, _KEYS), np.int64)
    parallel_for(_class_count_rows, _BLOCKS, gstart, np.int64(nl), offsets, sigmas, ks, ke, cnt)
    return ks, ke, cnt


def _fits(s, e, k):
    """Whether the k-sigma boxes (as error_pairs._box makes them) of every node of an e-block
    lattice in a leaf stay within the 27 leaves around it, with a margin for the rounding of
    centres far from the origin."""
    r = k * np.float64(s)
    lo = (e - 1) / 2.0 - r
    hi = 8.0 - (e + 1) / 2.0 + r
    return lo > -9.0 + 1e-6 and hi < 16.0 - 1e-6


def lattice_classes(gset, k):
    """(csig float32 (K, 3), ce int64 (K, 3)): the lattice classes of the set, most common
    first; K = 0 when none qualifies."""
    nl = int(gset.n_leaf_groups)
    none = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64)
    if nl == 0:
        return none
    ks, ke, cnt = _class_counts(gset.group_start, nl, gset.offsets, gset.sigmas)
    total = {}
    for key_s, key_e, c in zip(ks.reshape(-1, 3), ke.reshape(-1, 3), cnt.ravel()):
        if c:
            key = (tuple(key_s.tolist()), tuple(key_e.tolist()))
            total[key] = total.get(key, 0) + int(c)
    ranked = sorted(total.items(), key=lambda kv: (-kv[1], kv[0]))
    keep = [key for key, c in ranked if c >= MIN_CLASS
            and all(_fits(np.float32(s), e, k) for s, e in zip(*key))][:MAX_CLASSES]
    if not keep:
        return none
    return (np.array([key[0] for key in keep], np.float32),
            np.array([key[1] for key in keep], np.int64))


@njit(cache=True)
def _axis_qe(diff, s, k2, q, e):
    """q = d^2 and e = exp(-d^2 / 2) of d = diff / s, as mixture.axis_terms computes them (e = 0
    beyond the cut)."""
    power = 1.0
    for i in range(diff.shape[0]):
        d = diff[i] / s
        q[i] = d * d
        e[i] = np.exp(-0.5 * power * d * d) if d * d <= k2 else 0.0


def _axis_table(s, e, k2):
    """One axis of a class: the window of node indices J (in the leaf's own node units, -8 / e
    <= J < 16 / e) that reach the cell's voxels 0..7, and q, e over (voxel, window node)."""
    nper = 8 // e
    J = np.arange(-nper, 2 * nper)
    pos = e * J + (e - 1) / 2.0
    diff = (np.arange(8)[:, None] - pos[None, :]).astype(np.float64).ravel()
    q, ex = np.empty(len(diff)), np.empty(len(diff))
    _axis_qe(diff, np.float64(s), k2, q, ex)
    q, ex = q.reshape(8, -1), ex.reshape(8, -1)
    near = np.flatnonzero((q <= k2).any(0))
    w = slice(near[0], near[-1] + 1)
    return J[w], q[:, w], ex[:, w]


def _z_levels(qz, ez, k2):
    """The z pass of one class: the distinct q values within the cut along z (its levels), and
    per (level, z) the window indices at that level, padded with e = 0 (adds nothing)."""
    v = np.unique(qz[qz <= k2])
    per = [[np.flatnonzero(qz[z] == lv) for z in range(8)] for lv in v]
    slots = max([1] + [len(t) for row in per for t in row])
    tz = np.zeros((len(v), slots, 8), np.int64)
    ez_ = np.zeros((len(v), slots, 8))
    for li, row in enumerate(per):
        for z, t in enumerate(row):
            tz[li, :len(t), z] = t
            ez_[li, :len(t), z] = ez[z, t]
    return v, tz, ez_


def class_tables(csig, ce, k):
    """The per-class tables of error_lattice_sums.lattice_cell (a tuple, in its argument order):
    nper, window sizes, each leaf's range of window indices, the node of each window index, q and
    e per axis over (voxel, window index), the z pass (levels: the distinct q values along z;
    per (level, slot, z) a window index and its e_z), the (x, y) terms of the separable sum
    (window column, deepest z level within the cut, e_x e_y), the cost estimates of the two
    sums, and the largest window and level count."""
    nk = len(csig)
    k2 = float(k) * float(k)
    axes = [[_axis_table(csig[q, a], int(ce[q, a]), k2) for a in range(3)] for q in range(nk)]
    nwm = max([1] + [len(ax[0]) for cls in axes for ax in cls])
    nper = np.asarray(8 // np.maximum(ce, 1), np.int64).reshape(nk, 3)
    nw = np.zeros((nk, 3), np.int64)
    wr = np.zeros((nk, 3, 3, 2), np.int64)
    wnode = np.zeros((nk, 3, nwm), np.int64)
    qa = np.full((nk, 3, 8, nwm), np.inf)
    ea = np.zeros((nk, 3, 8, nwm))
    zs = []
    for q, cls in enumerate(axes):
        for a, (J, qq, ee) in enumerate(cls):
            n = len(J)
            nw[q, a] = n
            leaf = np.floor_divide(J, nper[q, a])  # -1, 0, 1: the leaf around the cell's
            wnode[q, a, :n] = J - leaf * nper[q, a]
            for d in range(3):
                t = np.flatnonzero(leaf == d - 1)
                wr[q, a, d] = (t[0], t[-1] + 1) if len(t) else (0, 0)
            qa[q, a, :, :n], ea[q, a, :, :n] = qq, ee
        zs.append(_z_levels(qa[q, 2, :, :nw[q, 2]], ea[q, 2, :, :nw[q, 2]], k2))
    nlm = max([1] + [len(v) for v, _, _ in zs])
    slots = max([1] + [t.shape[1] for _, t, _ in zs])
    nlev = np.array([len(v) for v, _, _ in zs], np.int64)
    tz = np.zeros((nk, nlm, slots, 8), np.int64)
    ez = np.zeros((nk, nlm, slots, 8))
    xys = np.zeros(nk * 64 + 1, np.int64)
    xyt, xyl, xye = [], [], []
    cost = np.zeros((nk, 2))
    for q, (v, tq, eq) in enumerate(zs):
        tz[q, :len(v), :tq.shape[1]], ez[q, :len(v), :tq.shape[1]] = tq, eq
        direct = 0
        for x in range(8):
            for y in range(8):
                for tx in range(nw[q, 0]):
                    q0 = qa[q, 0, x, tx]
                    if q0 > k2:
                        continue
                    for ty in range(nw[q, 1]):
                        qxy = q0 + qa[q, 1, y, ty]
                        if qxy > k2:
                            continue
                        # the cut keeps z levels while qxy + level <= k2: a prefix of them
                        deep = int(np.count_nonzero(qxy + v <= k2)) - 1
                        if deep < 0:
                            continue
                        xyt.append(tx * nwm + ty)
                        xyl.append(deep)
                        xye.append(ea[q, 0, x, tx] * ea[q, 1, y, ty])
                        direct += int(np.count_nonzero(qxy + qa[q, 2, :, :nw[q, 2]] <= k2))
                xys[q * 64 + x * 8 + y + 1] = len(xyt)
        cols = nw[q, 0] * nw[q, 1]
        # multiply-adds: the separable sum over every window column, and a direct node on average
        cost[q] = (cols * 8 * len(v) * tq.shape[1] + 8 * (xys[q * 64 + 64] - xys[q * 64]),
                   direct / max(1, cols * nw[q, 2]))
    return (nper, nw, wr, wnode, qa, ea, tz, ez, nlev, xys, np.array(xyt, np.int64),
            np.array(xyl, np.int64), np.array(xye, np.float64), cost, nwm, nlm)


@njit(cache=True, nogil=True)
def _classify_rows(lo, hi, gstart, nl, offsets, sigmas, csig, ce, cls, rest, held):
    for gi in range(lo, hi):
        for j in range(gstart[gi], gstart[gi + 1]):
            q = _class_of(j, offsets, sigmas, csig, ce) if gi < nl else -1
            cls[j] = q
            if q < 0:
                rest[gi] += 1
            else:
                held[gi] |= 1 << q


def classify(gstart, nl, offsets, sigmas, csig, ce):
    """Per Gaussian its lattice class (int8, -1: none; tiles none); per group the Gaussians of
    no class and the classes it holds (bit q for class q: see node_slots)."""
    ng = gstart.shape[0] - 1
    cls = np.full(gstart[ng], -1, np.int8)
    rest = np.zeros(ng, np.int64)
    held = np.zeros(ng, np.int64)
    parallel_for(_classify_rows, ng, gstart, np.int64(nl), offsets, sigmas, csig, ce, cls, rest,
                 held)
    return cls, rest, held


def node_slots(grp, held, nper):
    """slot (K, groups): where each group of grp keeps its class-q nodes in the chunk's node
    array (-1: it holds none), and that array's size."""
    nk = len(nper)
    slot = np.full((nk, len(grp)), -1, np.int64)
    size = 0
    h = held[grp]
    for q in range(nk):
        on = np.flatnonzero((h >> q) & 1)
        per = int(np.prod(nper[q]))
        slot[q, on] = size + per * np.arange(len(on))
        size += per * len(on)
    return slot, size


@njit(cache=True, nogil=True)
def _gather_rows(lo, hi, grp, gstart, origins, offsets, sigmas, values, amps, u, cls, ce, nper,
                 slot, nodes, first, shift, keys, cent, sig, w, c2, sid, off):
    for i in range(lo, hi):
        gi = grp[i]
        keys[i] = _key(np.int64(origins[gi, 0]) >> 3, np.int64(origins[gi, 1]) >> 3,
                       np.int64(origins[gi, 2]) >> 3)
        o = first[i]
        for j in range(gstart[gi], gstart[gi + 1]):
            wj = np.float64(values[j]) * np.float64(amps[j])
            q = cls[j]
            if q >= 0:
                node = 0
                for a in range(3):
                    h = np.int64(2.0 * np.float64(offsets[j, a]))
                    node = node * nper[q, a] + ((h + 1 - ce[q, a]) >> shift[q, a])
                nodes[slot[q, i] + node] += wj
                continue
            w[o] = wj
            for a in range(3):
                c = np.float64(origins[gi, a]) + np.float64(offsets[j, a])
                s = np.float64(sigmas[j, a])
                cent[o, a] = c
                sig[o, a] = s
                h = np.rint(2.0 * c)
                if h != 2.0 * c or abs(h) >= 2.0 ** 52:
                    off[i] = True
                else:
                    c2[o, a] = np.int64(h)
                t = 0
                while t < u.shape[0] - 1 and u[t] != s:
                    t += 1
                sid[o, a] = t
            o += 1


def gather_split(grp, gstart, origins, offsets, sigmas, values, amps, u, cls, rest, ce, nper,
                 slot, nodes):
    """Centres and sigmas (float64, as GaussianSet.centers() and mixture.setup make them) and
    weights of the Gaussians of groups grp of no lattice class (classify's cls, rest), in order;
    with u (the set's distinct sigmas) also their doubled centres (int64) and sigma ids for the
    axis tables, and whether every such centre is on the half-voxel lattice. The class nodes of
    grp's groups go to nodes (node_slots' slot: float64 weights value x amplitude, 0 where a
    node holds no Gaussian); returns also keys, each group's cell key (grp's leaf groups come
    first, sorted)."""
    ng = grp.shape[0]
    keys = np.zeros(ng, np.int64)
    first = np.zeros(ng + 1, np.int64)  # where each group's Gaussians of no class start
    np.cumsum(rest[grp], out=first[1:])
    nodes[:] = 0.0
    shift = np.zeros(ce.shape, np.int64)  # node j = (c2 + 1 - e) / 2e, e a power of 2
    for q in range(ce.shape[0]):
        for a in range(3):
            while (1 << int(shift[q, a])) < ce[q, a]:
                shift[q, a] += 1
            shift[q, a] += 1
    m = first[ng]
    cent = np.empty((m, 3))
    sig = np.empty((m, 3))
    w = np.empty(m)
    c2 = np.zeros((m, 3), np.int64)
    sid = np.zeros((m, 3), np.int32)
    off = np.zeros(ng, np.bool_)
    parallel_for(_gather_rows, ng, grp, gstart, origins, offsets, sigmas, values, amps, u, cls, ce,
                 nper, slot, nodes, first, shift, keys, cent, sig, w, c2, sid, off)
    return cent, sig, w, c2, sid, not off.any(), keys
