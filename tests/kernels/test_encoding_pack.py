"""The compact encoding's word-level bit packer (kernels/lod/bitpack.py) against the bit-by-bit
packer it replaced (kept here as the reference): the same bytes for any width 1..64 and length,
the same values back, and the same leaf streams for real sets."""
import numpy as np
import pytest

from kernels.lod import bitpack, build_lod, decode_compact, encode_compact
from kernels.lod.synthetic import random_sparse_grid


def ref_pack(vals, width):
    """Each value expanded into its `width` bits, then np.packbits (the former encoder)."""
    vals = np.asarray(vals, np.uint64).ravel()
    if width == 0 or len(vals) == 0:
        return np.zeros(0, np.uint8)
    bits = ((vals[:, None] >> np.arange(width, dtype=np.uint64)) & np.uint64(1)).astype(np.uint8)
    return np.packbits(bits.ravel(), bitorder="little")


def ref_unpack(buf, width, n):
    if width == 0 or n == 0:
        return np.zeros(n, np.int64)
    bits = np.unpackbits(buf, bitorder="little", count=n * width).reshape(n, width)
    return (bits.astype(np.int64) << np.arange(width, dtype=np.int64)).sum(axis=1)


def ref_leaf_streams(g, ml):
    """The former encoder's leaf streams: per-Gaussian numpy arrays, then ref_pack."""
    off = g.offsets[:ml].astype(np.float64)
    c2 = np.rint(off * 2).astype(np.int64)
    codes = g.size_codes[:ml].astype(np.int64)
    sph = (codes[:, 0] == codes[:, 1]) & (codes[:, 1] == codes[:, 2])
    flat = codes[np.arange(3)[None, :] < np.where(sph, 1, 3)[:, None]]
    vox = g.voxels[:ml].astype(np.int64)
    explicit = vox != codes[:, 0] * codes[:, 1] * codes[:, 2]
    cmin, smin = int(c2.min()), int(flat.min())
    out = dict(centre=ref_pack(c2 - cmin, int(c2.max() - cmin).bit_length()),
               sizes=ref_pack(flat - smin, int(flat.max() - smin).bit_length()))
    if 0 < sph.sum() < ml:
        out["sphere_flags"] = np.packbits(sph.astype(np.uint8), bitorder="little")
    if explicit.any():
        out["v_flags"] = np.packbits(explicit.astype(np.uint8), bitorder="little")
        out["v_explicit"] = ref_pack(vox[explicit], int(vox[explicit].max()).bit_length())
    return out


@pytest.mark.parametrize("width", list(range(1, 65)))
def test_pack_equals_bit_by_bit(width):
    rng = np.random.default_rng(width)
    for n in (1, 2, 7, 8, 63, 64, 65, 1000):
        vals = rng.integers(0, 2 ** 63, n, dtype=np.uint64) * np.uint64(2) + np.uint64(1)
        vals &= np.uint64(2 ** width - 1) if width < 64 else np.uint64(2 ** 64 - 1)
        got = bitpack.pack(vals, width)
        assert got.dtype == np.uint8
        assert np.array_equal(got, ref_pack(vals, width)), (width, n)
        assert np.array_equal(bitpack.unpack(got, width, n), ref_unpack(got, width, n))
        if width < 64:
            assert np.array_equal(bitpack.unpack(got, width, n), vals.astype(np.int64))
    # wider values keep their low bits; signed ones wrap as uint64 did
    wide = np.array([-1, 2 ** 40 + 5, 3], np.int64)
    assert np.array_equal(bitpack.pack(wide, width), ref_pack(wide.astype(np.uint64), width))
    assert len(bitpack.pack([], width)) == 0 and len(bitpack.pack([1, 2], 0)) == 0


@pytest.mark.parametrize("preset,cls,weights", [
    ("high", "fog_volume", "field"), ("medium", "level_set", "field"),
    ("variance", "fog_volume", "paper"), ("merged", "fog_volume", "field"),
    ("low", "fog_volume", "paper"), ("adaptive", "fog_volume", "field")])
def test_leaf_streams_equal_the_former_encoder(preset, cls, weights):
    g = random_sparse_grid(9, n_leaves=80, span=5, grid_class=cls)
    gs = build_lod(g, preset, weights)
    enc = encode_compact(gs)
    ml = int(gs.group_start[gs.n_leaf_groups])
    ref = ref_leaf_streams(gs, ml)
    for k, v in ref.items():
        assert enc[k].dtype == np.uint8 and np.array_equal(enc[k], v), k
    assert not {"sphere_flags", "v_flags", "v_explicit"} - set(ref) & set(enc)
    back = decode_compact(enc)
    for name in ("offsets", "sigmas", "amplitudes", "voxels"):
        assert np.array_equal(getattr(back, name), getattr(gs, name)), name


def test_off_lattice_centres_refused():
    gs = build_lod(random_sparse_grid(2, n_leaves=10, span=2), "high")
    gs.offsets = gs.offsets + np.float32(0.25)
    with pytest.raises(ValueError, match="half-voxel lattice"):
        encode_compact(gs)
