"""Compact encoding of a GaussianSet, and the paper's storage model for comparison.

Everything is a bit-packed stream of small unsigned integers whose width is fitted to the data:
- leaf origins once per leaf: a bitmap over the bbox of leaf coordinates (origin / 8), or packed
  coordinates, whichever is smaller (leaf groups are sorted by origin, so the order is implied);
- Gaussians per leaf (count - 1), or one number when all leaves hold the same count;
- centre offsets as c2 = 2 x offset (the half-voxel lattice of the leaf), minus their minimum;
- sizes as codes with sigma = sigma_scale x code (field: code = block edge; paper: code = 2 sigma):
  one code for a sphere, three for an ellipsoid, a 1-bit sphere flag when both kinds occur;
- voxels represented only where they differ from prod(code) (a 1-bit flag, then the exceptions);
- values (level sets: their uniform opacity is not stored, the stream holds their mean signed
  distances; none in older files): one number when constant, else float16 when every value
  survives the cast within VALUE_TOL x value range (a 256-entry transfer function resolves
  1/256 = 3.9e-3 of the range), else float32;
- amplitudes are never stored: they follow from sigma and V;
- tiles (one Gaussian each, all derived from the edge): leaf-lattice coordinates as int32 (few),
  the edge as a 2-bit level (or one number), the value in the value stream.
"""
from __future__ import annotations

import numpy as np

from .bitpack import leaf_ranges, leaf_streams, pack, unpack
from .gaussian_set import GaussianSet
from .weights import amplitudes64, factors_from_codes, field_amplitudes_match, quantize_factors, sigmas_from_codes

VERSION = 2  # 1: int64 "meta" + float arrays; 2: one varint "header" (both are decoded)
VALUE_TOL = 1e-3
_TILE_SIZES = np.array([8, 128, 4096], np.int64)
_CLASSES = ("fog_volume", "level_set", "staggered", "unknown")
_META = ("version", "n", "n_leaf", "n_tile", "paper", "level_set", "origin_mode", "lmin_x",
         "lmin_y", "lmin_z", "ldim_x", "ldim_y", "ldim_z", "w_lx", "w_ly", "w_lz", "count_const",
         "w_count", "cmin", "w_c", "sphere_mode", "smin", "w_s", "v_mode", "w_v", "value_mode",
         "class", "tile_const")  # version 1: int64 each, a fixed 224 B
_META2 = _META + ("amp_mode", "amp_cmin", "w_amp", "xform_mode")  # version 2: zigzag varints


def _zz(x: int) -> int:
    return (x << 1) if x >= 0 else ((-x << 1) - 1)


def _unzz(u: int) -> int:
    return (u >> 1) if not (u & 1) else -((u + 1) >> 1)


def varints(vals) -> bytes:
    out = bytearray()
    for v in vals:
        u = _zz(int(v))
        while True:
            b = u & 0x7F
            u >>= 7
            if u:
                out.append(b | 0x80)
            else:
                out.append(b)
                break
    return bytes(out)


def read_varints(buf, n, pos=0):
    vals = []
    for _ in range(n):
        u, sh = 0, 0
        while True:
            b = int(buf[pos])
            pos += 1
            u |= (b & 0x7F) << sh
            sh += 7
            if not b & 0x80:
                break
        vals.append(_unzz(u))
    return vals, pos


def _xform_encode(M):
    """index_to_world -> (mode, float64s): 0 full 4x4, 1 affine (12), 2 axis scales + translation
    (6), 3 uniform scale + translation (4). Exact: the decoder rebuilds the same float64s."""
    M = np.asarray(M, np.float64).reshape(4, 4)
    if not np.array_equal(M[3], [0.0, 0.0, 0.0, 1.0]):
        return 0, M.reshape(16)
    L = M[:3, :3]
    if np.array_equal(L, np.diag(np.diag(L))):
        d = np.diag(L)
        if d[0] == d[1] == d[2]:
            return 3, np.array([d[0], *M[:3, 3]])
        return 2, np.array([*d, *M[:3, 3]])
    return 1, M[:3].reshape(12)


def _xform_decode(mode, f):
    if mode == 0:
        return f[:16].reshape(4, 4).copy()
    M = np.eye(4)
    if mode == 1:
        M[:3] = f[:12].reshape(3, 4)
    elif mode == 2:
        M[:3, :3] = np.diag(f[:3])
        M[:3, 3] = f[3:6]
    else:
        M[:3, :3] = np.eye(3) * f[0]
        M[:3, 3] = f[1:4]
    return M


_XFORM_N = {0: 16, 1: 12, 2: 6, 3: 4}


def _bitlen(x: int) -> int:
    return int(x).bit_length()


def _enc_coords(L, name):
    """Sorted distinct int coordinates -> bitmap over their bbox or packed, whichever is smaller."""
    lmin = L.min(0)
    dims = L.max(0) - lmin + 1
    w = max(_bitlen(d - 1) for d in dims)
    rel = L - lmin
    use_bitmap = int(np.prod(dims)) <= len(L) * 3 * w
    hdr = np.frombuffer(varints([0 if use_bitmap else 1, *lmin, *dims, w]), np.uint8).copy()
    if use_bitmap:
        bm = np.zeros(int(np.prod(dims)), np.uint8)
        bm[np.ravel_multi_index(rel.T, dims)] = 1
        return {name + "_hdr": hdr, name + "_bitmap": np.packbits(bm, bitorder="little")}
    return {name + "_hdr": hdr, name + "_coords": pack(rel.ravel(), w)}


def _dec_coords(enc, name, n):
    hdr = enc[name + "_hdr"]
    if hdr.dtype == np.uint8:  # version 2: varints
        hdr = np.array(read_varints(hdr, 8)[0], np.int64)
    lmin, dims, w = hdr[1:4], tuple(int(d) for d in hdr[4:7]), int(hdr[7])
    if hdr[0] == 0:
        bm = np.unpackbits(enc[name + "_bitmap"], bitorder="little", count=int(np.prod(dims)))
        return np.stack(np.unravel_index(np.nonzero(bm)[0], dims), 1) + lmin
    return unpack(enc[name + "_coords"], w, 3 * n).reshape(n, 3) + lmin


def paper_model_bytes(gset: GaussianSet) -> int:
    """Position 12 B + covariance 4 B (sphere) or 12 B (ellipsoid) + opacity 4 B (not for level sets)."""
    n, ns = gset.count, gset.n_spheres
    return int(12 * n + 4 * ns + 12 * (n - ns) + (0 if gset.grid_class == "level_set" else 4 * n))


def encoded_nbytes(enc: dict) -> int:
    return int(sum(np.asarray(a).nbytes for a in enc.values()))


CHUNK = 1 << 21  # Gaussians per pass of the value and amplitude checks


def _chunks(n, step=CHUNK):
    return [(i, min(n, i + step)) for i in range(0, n, step)]


def _leaf_streams(g, ml, meta):
    """Centres, size codes, sphere flags and explicit voxel counts of the ml leaf-group Gaussians
    (bitpack.py: the ranges and modes in one pass, every stream in a second, with no per-Gaussian
    copies). Fills meta; returns the streams."""
    cmin, cmax, exact, smin, smax, nsph, nexp, vmax = (
        int(x) for x in leaf_ranges(g.offsets, g.size_codes, g.voxels, ml))
    if not exact:
        raise ValueError("centres must lie on the half-voxel lattice")
    meta.update(cmin=cmin, w_c=_bitlen(cmax - cmin), smin=smin, w_s=_bitlen(smax - smin),
                sphere_mode=0 if nsph == ml else 1 if nsph == 0 else 2)
    if vmax >= 0:
        meta.update(v_mode=1, w_v=_bitlen(vmax))
    centre, sizes, sflags, vflags, vexp = leaf_streams(
        g.offsets, g.size_codes, g.voxels, ml, cmin, meta["w_c"], smin, meta["w_s"], nsph,
        meta["sphere_mode"] == 2, nexp, meta["w_v"], vmax >= 0)
    enc = dict(centre=centre)  # the keys in the order the encoding always had
    if meta["sphere_mode"] == 2:
        enc["sphere_flags"] = sflags
    enc["sizes"] = sizes
    if vmax >= 0:
        enc.update(v_flags=vflags, v_explicit=vexp)
    return enc


def encode_compact(g: GaussianSet) -> dict:
    meta = dict.fromkeys(_META, 0)
    nl, ng = g.n_leaf_groups, len(g.group_origins)
    ml = int(g.group_start[nl])  # Gaussians in leaf groups
    meta.update(version=VERSION, n=g.count, n_leaf=nl, n_tile=ng - nl, paper=int(g.weights == "paper"),
                level_set=int(g.grid_class == "level_set"),
                **{"class": _CLASSES.index(g.grid_class) if g.grid_class in _CLASSES else 3})
    enc = {}
    # -- leaf origins
    lo = g.group_origins[:nl].astype(np.int64)
    if nl:
        if np.any(lo % 8):
            raise ValueError("leaf group origins must be multiples of 8")
        L = lo >> 3
        lmin = L.min(0)
        dims = L.max(0) - lmin + 1
        rel = L - lmin
        w = [_bitlen(d - 1) for d in dims]
        bitmap_bits = int(np.prod(dims))
        packed_bits = nl * sum(w)
        meta.update(lmin_x=lmin[0], lmin_y=lmin[1], lmin_z=lmin[2], ldim_x=dims[0], ldim_y=dims[1],
                    ldim_z=dims[2], w_lx=w[0], w_ly=w[1], w_lz=w[2])
        if bitmap_bits <= packed_bits:
            bm = np.zeros(bitmap_bits, np.uint8)
            bm[np.ravel_multi_index(rel.T, dims)] = 1
            enc["leaf_bitmap"] = np.packbits(bm, bitorder="little")
            meta["origin_mode"] = 0
        else:
            enc["leaf_coords"] = pack(np.stack([rel[:, 0], rel[:, 1], rel[:, 2]], 1).ravel(), max(w))
            meta.update(origin_mode=1, w_lx=max(w))
        counts = np.diff(g.group_start[:nl + 1])
        if np.all(counts == counts[0]):
            meta["count_const"] = int(counts[0])
        else:
            meta["w_count"] = _bitlen(int(counts.max()) - 1)
            enc["counts"] = pack(counts - 1, meta["w_count"])
    # -- per-Gaussian streams (leaf groups)
    if ml:
        enc.update(_leaf_streams(g, ml, meta))
    # -- tiles: one Gaussian each, fully determined by origin, edge and value
    nt = ng - nl
    if nt:
        if not np.all(np.diff(g.group_start[nl:]) == 1):
            raise ValueError("tile groups hold exactly one Gaussian")
        to = g.group_origins[nl:].astype(np.int64)
        ts = np.rint(g.offsets[ml:, 0].astype(np.float64) * 2).astype(np.int64) + 1
        lv = np.searchsorted(_TILE_SIZES, ts)
        if np.any(to % 8) or np.any(_TILE_SIZES[np.minimum(lv, 2)] != ts):
            raise ValueError("tiles must have edges 8, 128 or 4096 and origins on the leaf lattice")
        enc.update(_enc_coords(to >> 3, "tile"))
        if np.all(lv == lv[0]):
            meta["tile_const"] = int(lv[0]) + 1
        else:
            enc["tile_levels"] = pack(lv, 2)
    # -- values (leaves, then tiles)
    v = g.distances if g.grid_class == "level_set" else g.values
    if v is None or g.count == 0:
        meta["value_mode"] = 0
    else:
        v = np.asarray(v, np.float32)
        if np.all(v == v[0]):
            meta["value_mode"] = 1
            enc["value_const"] = v[:1].astype(np.float32)
        else:
            vmin, vmax = g.params.get("value_min"), g.params.get("value_max")
            rng = (vmax - vmin) if vmin is not None else 0.0
            rng = max(rng, float(v.max() - v.min()))
            v16 = v.astype(np.float16)
            ok = all(bool(np.all(np.isfinite(v16[i:j]))) and float(np.max(np.abs(
                v16[i:j].astype(np.float64) - v[i:j]))) <= VALUE_TOL * rng for i, j in _chunks(len(v)))
            meta["value_mode"] = 2 if ok else 3
            enc["values"] = v16 if ok else v.astype(np.float32)
    # -- amplitudes: derived from sigma and V; a refined set stores its quantized factors
    meta.update(amp_mode=0, amp_cmin=0, w_amp=0)
    if g.count and g.weights == "field":
        ml = int(g.group_start[g.n_leaf_groups])
        if not field_amplitudes_match(g.sigmas, g.voxels, g.amplitudes, ml, g.true_voxels(ml)):
            a0 = amplitudes64(g.sigmas, g.true_voxels(), "field")
            c = quantize_factors(g.amplitudes.astype(np.float64) / a0)
            if np.array_equal((a0 * factors_from_codes(c)).astype(np.float32), g.amplitudes):
                cmin = int(c.min())
                meta.update(amp_mode=1, amp_cmin=cmin, w_amp=_bitlen(int(c.max()) - cmin))
                enc["amp_codes"] = pack(c - cmin, meta["w_amp"])
            else:  # amplitudes edited by hand: stored as they are
                meta["amp_mode"] = 2
                enc["amp_raw"] = g.amplitudes.astype(np.float32)
    elif g.count and not np.all(g.amplitudes == 1):
        meta["amp_mode"] = 2
        enc["amp_raw"] = g.amplitudes.astype(np.float32)
    # -- header: varints, then the transform and scalars as float64/float32 bytes, then the LOD
    xm, xf = _xform_encode(g.index_to_world)
    meta["xform_mode"] = xm
    lod = g.lod.encode()
    head = varints([int(meta[k]) for k in _META2] + [len(lod)]) + lod
    floats = np.concatenate([[np.float64(g.sigma_scale)], xf]).astype("<f8").tobytes()
    head += floats + np.array([g.background], "<f4").tobytes()
    enc["header"] = np.frombuffer(head, np.uint8).copy()
    return enc


def decode_compact(enc: dict) -> GaussianSet:
    if "header" in enc:
        head = bytes(np.asarray(enc["header"], np.uint8))
        vals, pos = read_varints(head, len(_META2) + 1)
        meta = dict(zip(_META2, vals[:-1]))
        lod = head[pos:pos + vals[-1]].decode()
        pos += vals[-1]
        nf = 1 + _XFORM_N[meta["xform_mode"]]
        fl = np.frombuffer(head[pos:pos + 8 * nf], "<f8").astype(np.float64)
        pos += 8 * nf
        scale = float(fl[0])
        i2w = _xform_decode(meta["xform_mode"], fl[1:])
        background = float(np.frombuffer(head[pos:pos + 4], "<f4")[0])
    else:  # version 1
        meta = dict(zip(_META, (int(x) for x in enc["meta"])))
        meta.update(amp_mode=0)
        lod = bytes(enc["lod"]).decode()
        scale = float(enc["sigma_scale"][0])
        i2w = enc["index_to_world"].reshape(4, 4).copy()
        background = float(enc["background"][0])
    n, nl, nt = meta["n"], meta["n_leaf"], meta["n_tile"]
    lmin = np.array([meta["lmin_x"], meta["lmin_y"], meta["lmin_z"]], np.int64)
    dims = (meta["ldim_x"], meta["ldim_y"], meta["ldim_z"])
    if nl == 0:
        L = np.zeros((0, 3), np.int64)
    elif meta["origin_mode"] == 0:
        bm = np.unpackbits(enc["leaf_bitmap"], bitorder="little", count=int(np.prod(dims)))
        L = np.stack(np.unravel_index(np.nonzero(bm)[0], dims), 1) + lmin
    else:
        L = unpack(enc["leaf_coords"], meta["w_lx"], 3 * nl).reshape(nl, 3) + lmin
    origins = (L << 3).astype(np.int32)
    if nl:
        counts = (np.full(nl, meta["count_const"], np.int64) if meta["count_const"]
                  else unpack(enc["counts"], meta["w_count"], nl) + 1)
    else:
        counts = np.zeros(0, np.int64)
    ml = int(counts.sum())
    c2 = unpack(enc.get("centre", np.zeros(0, np.uint8)), meta["w_c"], 3 * ml).reshape(ml, 3) + meta["cmin"]
    if meta["sphere_mode"] == 2:
        sph = np.unpackbits(enc["sphere_flags"], bitorder="little", count=ml).astype(bool)
    else:
        sph = np.full(ml, meta["sphere_mode"] == 0)
    per = np.where(sph, 1, 3)
    flat = unpack(enc.get("sizes", np.zeros(0, np.uint8)), meta["w_s"], int(per.sum())) + meta["smin"]
    codes = np.empty((ml, 3), np.int64)
    sel = np.arange(3)[None, :] < per[:, None]
    codes[sel] = flat
    codes[sph, 1] = codes[sph, 0]
    codes[sph, 2] = codes[sph, 0]
    vox = codes[:, 0] * codes[:, 1] * codes[:, 2]
    if meta["v_mode"] == 1:
        ex = np.unpackbits(enc["v_flags"], bitorder="little", count=ml).astype(bool)
        vox[ex] = unpack(enc["v_explicit"], meta["w_v"], int(ex.sum()))
    weights = "paper" if meta["paper"] else "field"
    sig = sigmas_from_codes(codes, scale)
    amp = amplitudes64(sig, vox, weights)
    # tiles: sigma, amplitude and voxels follow from the edge, like a Low leaf (bbox rule)
    if nt:
        lv = (np.full(nt, meta["tile_const"] - 1, np.int64) if meta["tile_const"]
              else unpack(enc["tile_levels"], 2, nt))
        ts = _TILE_SIZES[lv]
        tcodes = np.repeat((np.maximum(ts - 1, 1) if weights == "paper" else ts)[:, None], 3, 1)
        tsig = sigmas_from_codes(tcodes, scale)
        tvox_true = ts.astype(np.float64) ** 3
        c2 = np.concatenate([c2, np.repeat((ts - 1)[:, None], 3, 1)])
        codes = np.concatenate([codes, tcodes])
        sig = np.concatenate([sig, tsig])
        amp = np.concatenate([amp, amplitudes64(tsig, tvox_true, weights)])
        vox = np.concatenate([vox, np.minimum(ts ** 3, np.iinfo(np.int32).max)])
        origins = np.concatenate([origins, (_dec_coords(enc, "tile", nt) << 3).astype(np.int32)])
    m_all = ml + nt
    if meta["amp_mode"] == 1:
        amp = amp * factors_from_codes(unpack(enc["amp_codes"], meta["w_amp"], m_all) + meta["amp_cmin"])
    amp = amp.astype(np.float32)
    if meta["amp_mode"] == 2:
        amp = np.asarray(enc["amp_raw"], np.float32).copy()
    vm = meta["value_mode"]
    if vm == 0:
        vals = np.ones(m_all, np.float32)
    elif vm == 1:
        vals = np.full(m_all, enc["value_const"][0], np.float32)
    else:
        vals = enc["values"].astype(np.float32)
    dist = None
    if _CLASSES[meta["class"]] == "level_set":
        dist, vals = (vals if vm else None), np.ones(m_all, np.float32)
    offsets = (c2.astype(np.float32) * np.float32(0.5))
    gstart = np.zeros(nl + nt + 1, np.int64)
    np.cumsum(np.concatenate([counts, np.ones(nt, np.int64)]), out=gstart[1:])
    assert len(offsets) == n
    return GaussianSet(
        group_origins=origins.reshape(-1, 3), group_start=gstart, offsets=offsets.astype(np.float32),
        sigmas=sig.astype(np.float32), values=vals.astype(np.float32), amplitudes=amp.astype(np.float32),
        voxels=vox.astype(np.int32), grid_class=_CLASSES[meta["class"]],
        lod=lod, weights=weights, index_to_world=i2w, background=background, n_leaf_groups=nl,
        size_codes=codes.astype(np.int32),
        sigma_scale=scale, params={}, distances=dist)
