"""The compiled decompression paths (kernels/vdb/frames.py, the compiled tree walk) against the
Python modules they stand in for: same bytes, or a clean hand-over, never a different answer."""

import os

import numpy as np
import pytest

from kernels.vdb import frames, leaves, read_topology, read_vdb, tree
from tests.vdb_fixtures import build_oracle_file, transcode

blosc = pytest.importorskip("blosc")
DATA = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "data")


def _frame(src, n, vsize, slack=64):
    """Our decode of one blosc frame, unshuffled, or None when declined."""
    arr = np.frombuffer(src, np.uint8)
    dst = np.full(n + slack, 0xAB, np.uint8)  # slack: the decoder may write past n, never past the end
    tmp = np.full(n + slack, 0xCD, np.uint8)
    r = frames.blosc_frame(arr, 0, len(src), n, vsize, dst, tmp)
    if r == 1:
        return bytes(src[16:16 + n])
    if r == 2:
        return tmp[:n].reshape(vsize, n // vsize).T.tobytes()
    return dst[:n].tobytes() if r == 0 else None


def test_blosc_frames_decode_like_blosc():
    rng = np.random.default_rng(0)
    decoded = 0
    for it in range(1500):
        ts = int(rng.choice([1, 2, 4, 6, 12]))
        n = int(rng.integers(0, 700)) * ts
        kind = it % 3
        if kind == 0:
            data = rng.random(n // 4 + 1).astype(np.float32).tobytes()[:n]
        elif kind == 1:
            data = np.round(rng.random(n // 2 + 1) * 4).astype(np.float16).tobytes()[:n]
        else:
            data = rng.integers(0, 3, n).astype(np.uint8).tobytes()
        cname = str(rng.choice(["lz4", "lz4hc", "blosclz", "zstd"]))
        shuffle = int(rng.choice([0, 1, 2]))
        blosc.set_blocksize(int(rng.choice([0, 0, 64, 256, 1000])))
        try:
            c = blosc.compress(data, typesize=ts, cname=cname, shuffle=shuffle)
        finally:
            blosc.set_blocksize(0)
        got = _frame(c, n, ts)
        if got is None:  # only codecs and shuffles we leave to blosc, or an odd layout
            assert cname in ("blosclz", "zstd") or shuffle == 2, (cname, shuffle, ts, n)
        else:
            assert got == data, (cname, shuffle, ts, n)
            decoded += 1
    assert decoded > 400


def test_corrupt_frames_are_declined_or_decoded_as_blosc_does():
    rng = np.random.default_rng(1)
    for it in range(4000):
        ts = int(rng.choice([2, 4, 12]))
        n = int(rng.integers(1, 400)) * ts
        data = np.round(rng.random(n // 4 + 1) * 8).astype(np.float32).tobytes()[:n]
        c = bytearray(blosc.compress(data, typesize=ts, cname="lz4", shuffle=int(rng.integers(0, 2))))
        for _ in range(int(rng.integers(1, 4))):
            c[int(rng.integers(0, len(c)))] = int(rng.integers(0, 256))
        got = _frame(bytes(c), n, ts)
        if got is not None:
            assert got == blosc.decompress(bytes(c)), it


def _lz4(block, oend):
    dst = np.zeros(64, np.uint8)
    return frames.lz4_block(np.frombuffer(block, np.uint8), 0, len(block), dst, 0, oend), dst


def test_lz4_blocks_breaking_the_end_rules_are_declined():
    # 4 literals, a 4-byte match at offset 4, 8 closing literals
    r, d = _lz4(b"\x40abcd\x04\x00\x80stuvwxyz", 16)
    assert r == 0 and d[:16].tobytes() == b"abcdabcdstuvwxyz"
    # 1 literal, an overlapping 7-byte match at offset 1 (repeats it), 5 closing literals
    r, d = _lz4(b"\x13a\x01\x00\x50vwxyz", 13)
    assert r == 0 and d[:13].tobytes() == b"aaaaaaaavwxyz"
    declined = [
        (b"\x40abcd\x04\x00\x80stuvwxyz", 17),  # output not filled exactly
        (b"\x40abcd\x04\x00\x80stuvwxy", 16),  # input ends inside the last literals
        (b"\x40abcd\x00\x00\x80stuvwxyz", 16),  # offset 0
        (b"\x40abcd\x05\x00\x80stuvwxyz", 16),  # offset before the block start
        (b"\x40abcd\x04\x00\x40wxyz", 12),  # match starts under 12 bytes from the end
        (b"\x13a\x01\x00\x40wxyz", 12),  # match covers part of the last 5 bytes
        (b"\x40abcd\x04\x00", 8),  # ends on a match, not on literals
        (b"", 1),
    ]
    for block, oend in declined:
        assert _lz4(block, oend)[0] == frames.DECLINED, (block, oend)


def test_zlib_through_ctypes_matches_python_zlib():
    import zlib
    fn = frames.zlib_uncompress()
    if fn is None:
        pytest.skip("no C zlib found here: zip chunks take the Python path")
    rng = np.random.default_rng(2)
    chunks = [np.round(rng.random(int(rng.integers(1, 900))) * 7).astype(np.float16).tobytes()
              for _ in range(40)]
    packed = [zlib.compress(c) for c in chunks]
    packed[7] = packed[7][:-3]  # truncated: must be left to Python, not half-decoded
    buf = np.frombuffer(b"".join(packed), np.uint8)
    lens = np.array([len(p) for p in packed], np.int64)
    offs = np.cumsum(lens) - lens
    nbytes = np.array([len(c) for c in chunks], np.int64)
    start = np.cumsum(nbytes) - nbytes
    pool = np.zeros(int(nbytes.sum()), np.uint8)
    for threads in (1, 2):
        st = frames.inflate_all(buf, np.arange(40), offs, lens, nbytes, pool, start, threads)
        assert st[7] == 1 and st.sum() == 1
        for i in range(40):
            if i != 7:
                assert pool[start[i]:start[i] + nbytes[i]].tobytes() == chunks[i]


@pytest.fixture(scope="module")
def variants(tmp_path_factory):
    d = tmp_path_factory.mktemp("frames")
    src = str(build_oracle_file(d / "oracle.vdb"))
    out = [src]
    for comp, mask, half in [("zip", True, None), ("zip", False, True), ("blosc", False, True),
                             ("blosc", True, True), ("none", True, None)]:
        out.append(transcode(src, str(d / f"{comp}{int(mask)}{half}.vdb"), compression=comp,
                             active_mask=mask, half=half))
    small = os.path.join(DATA, "mantaflow_fire_r96_f035.vdb")
    if os.path.exists(small):
        out += [small, transcode(small, str(d / "fire_blosc.vdb"), compression="blosc")]
    teapot = os.path.join(DATA, "teapot_ls_256.vdb")
    if os.path.exists(teapot):
        out.append(teapot)
    # blosclz frames: the compiled decoder declines them all, the blosc module takes over
    real = blosc.compress
    blosc.compress = lambda b, typesize=8, cname="lz4", **k: real(b, typesize, cname="blosclz", **k)
    try:
        out.append(transcode(src, str(d / "blosclz.vdb"), compression="blosc"))
    finally:
        blosc.compress = real
    return out


def _arrays(f):
    keys = ("leaf_origins", "leaf_masks", "leaf_values", "leaf_vectors", "tile_origins", "tile_sizes",
            "tile_values", "tile_active", "bbox_min", "bbox_max")
    return [(g.name, g.active_voxels, k, None if getattr(g, k) is None else
             np.ascontiguousarray(getattr(g, k)).tobytes()) for g in f.grids for k in keys]


def test_compiled_paths_equal_the_python_paths(variants, monkeypatch):
    fast = [(_arrays(read_vdb(p)), _arrays(read_topology(p))) for p in variants]
    monkeypatch.setattr(leaves, "HAVE_NUMBA", False)  # blosc frames through the blosc module
    monkeypatch.setattr(leaves, "inflate_all", lambda *a: None)  # zip chunks through zlib
    monkeypatch.setattr(tree, "_compiled_walk", lambda *a: False)  # the node-by-node walk
    slow = [(_arrays(read_vdb(p)), _arrays(read_topology(p))) for p in variants]
    for p, a, b in zip(variants, fast, slow):
        assert a == b, p


def test_compiled_walk_grows_its_leaf_arrays(variants, monkeypatch):
    want = [_arrays(read_topology(p)) for p in variants]
    monkeypatch.setattr(tree, "_LEAF_CAP", 3)  # room for 3 leaves: every grid makes it grow
    assert [_arrays(read_topology(p)) for p in variants] == want


def test_declined_frames_take_the_blosc_module(variants, monkeypatch):
    seen = []
    real = leaves._decompress_all
    monkeypatch.setattr(leaves, "_decompress_all",
                        lambda cur, t, idx, *a: (seen.append(len(idx)), real(cur, t, idx, *a)))
    lz, lzb = variants[0], variants[-1]
    assert _arrays(read_vdb(lzb)) == _arrays(read_vdb(lz))
    assert sum(seen) > 0


def test_serial_and_parallel_decode_agree(variants, monkeypatch):
    big = [p for p in variants if "teapot" in p or "fire" in p] or variants[:1]
    serial = [_arrays(read_vdb(p)) for p in big]
    monkeypatch.setattr(leaves, "PARALLEL_LEAVES", 1)
    assert [_arrays(read_vdb(p)) for p in big] == serial


def _overloads():
    from numba.core.registry import CPUDispatcher

    return {(m.__name__, name): len(d.overloads) for m in (leaves, frames, tree)
            for name, d in vars(m).items() if isinstance(d, CPUDispatcher)}


@pytest.mark.skipif(not os.path.exists(os.path.join(DATA, "teapot_ls_256.vdb")),
                    reason="needs the shared data")
def test_a_large_file_decodes_with_the_kernels_the_warm_up_s_small_file_loads(tmp_path):
    """A large grid (over PARALLEL_LEAVES leaves: threads) runs the compiled kernels a small one
    (the warm-up's file, on the calling thread) does: no kernel of its own to compile after a
    warm-up."""
    from kernels import warmup

    teapot = os.path.join(DATA, "teapot_ls_256.vdb")
    big = [transcode(teapot, str(tmp_path / f"{c}.vdb"), compression=c) for c in ("zip", "blosc")]
    warmup.JOBS["reader"]()
    before = _overloads()
    for p in big:
        g = read_vdb(p).grids[0]
        assert len(g.leaf_origins) >= leaves.PARALLEL_LEAVES and g.active_voxels > 0
    assert _overloads() == before
