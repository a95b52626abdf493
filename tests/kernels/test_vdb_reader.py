"""Oracle tests of kernels.vdb against the bundled openvdb binding, bit for bit."""

import glob
import os
import warnings

import numpy as np
import pytest

from kernels import warmup
from kernels.vdb import VDBFormatError, estimate_bytes, read_topology, read_vdb
from tests.vdb_fixtures import build_oracle_file, openvdb, transcode, write_grid

DATA = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "data")
DATA_FILES = sorted(glob.glob(os.path.join(DATA, "*.vdb")))
_DEPTH = {4096: 0, 128: 1, 8: 2}


@pytest.fixture(scope="module")
def oracle(tmp_path_factory):
    return str(build_oracle_file(tmp_path_factory.mktemp("vdb") / "oracle.vdb"))


def _bits(a):
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def compare_with_binding(path, ours, full=True, only=None):
    """Everything the binding can tell about each grid equals what we read."""
    ov = openvdb()
    binding = {}
    for x in ov.readAll(path)[0]:
        binding.setdefault(x.name, []).append(x)
    for g in ours.grids:
        if only is not None and g.name not in only:
            continue
        base, _, k = g.name.partition("[")
        b = binding[base][int(k[:-1]) if k else 0]  # duplicates keep file order
        assert g.active_voxels == b.activeVoxelCount(), g.name
        assert len(g.leaf_origins) == b.leafCount(), g.name
        if g.active_voxels:
            lo, hi = b.evalActiveVoxelBoundingBox()
            assert tuple(g.bbox_min) == tuple(lo) and tuple(g.bbox_max) == tuple(hi), g.name
        bg = np.linalg.norm(b.background) if np.ndim(b.background) else b.background
        assert _bits(g.background) == _bits(bg), g.name
        acc = b.getConstAccessor()
        # leaves exist where we say; active voxels equal the binding's on-iterator
        for o in g.leaf_origins[:: max(1, len(g.leaf_origins) // 300)]:
            assert acc.getValueDepth(tuple(int(c) for c in o)) == 3, (g.name, o)
        on_vox, on_tiles = [], []
        for it in b.citerOnValues():
            (on_vox if it.depth == 3 else on_tiles).append(it)
        bits = np.unpackbits(g.leaf_masks.view(np.uint8), axis=1, bitorder="little").astype(bool)
        li, slot = np.nonzero(bits)
        ours_vox = g.leaf_origins[li].astype(np.int64) + np.stack(
            [slot // 64, (slot // 8) % 8, slot % 8], 1)
        theirs = np.array([it.min for it in on_vox], np.int64).reshape(-1, 3)
        assert np.array_equal(np.unique(ours_vox, axis=0), np.unique(theirs, axis=0)), g.name
        act = g.tile_active
        ours_t = sorted((tuple(o), int(s)) for o, s in zip(g.tile_origins[act], g.tile_sizes[act]))
        theirs_t = sorted((tuple(it.min), int(it.max[0] - it.min[0] + 1)) for it in on_tiles)
        assert ours_t == theirs_t, g.name
        # every tile we report: depth, value and state as the binding sees it
        step = max(1, len(g.tile_sizes) // 400)  # half files without mask compression hold
        # tens of thousands of inactive ~background tiles (half-rounded): sample them
        for o, s, v, a in list(zip(g.tile_origins, g.tile_sizes, g.tile_values, g.tile_active))[::step]:
            ijk = tuple(int(c) for c in o)
            assert acc.getValueDepth(ijk) == _DEPTH[int(s)], (g.name, ijk, s)
            val, on = acc.probeValue(ijk)
            assert bool(on) == bool(a)
            want = np.linalg.norm(val) if np.ndim(val) else val
            assert _bits(want) == _bits(v), (g.name, ijk)
        if not full:
            assert g.leaf_values is None
            continue
        # all 512 values of every leaf, inactive slots included, bit for bit
        vec = g.leaf_vectors is not None
        block = np.empty((8, 8, 8, 3) if vec else (8, 8, 8), np.float32)
        for i, o in enumerate(g.leaf_origins):
            b.copyToArray(block, ijk=tuple(int(c) for c in o))
            want = block.reshape(512, -1)
            got = g.leaf_vectors[i] if vec else g.leaf_values[i][:, None]
            assert np.array_equal(_bits(got), _bits(want)), (g.name, tuple(o))


def test_oracle_fixture_matches_binding(oracle):
    f = read_vdb(oracle)
    names = [g.name for g in f.grids]
    assert names == ["codes", "codes_inst", "sphere", "dbl", "vel", "sphere[1]", "sphere_half"]
    assert dict(f.skipped).keys() == {"ids", "flags"}
    assert all("grid" in r for r in dict(f.skipped).values())
    compare_with_binding(oracle, f)
    g = {x.name: x for x in f.grids}
    assert g["sphere"].grid_class == "level_set" and g["codes"].grid_class == "fog_volume"
    assert g["sphere_half"].half and not g["sphere"].half
    # level sets keep their inactive -background interior tiles
    s = g["sphere"]
    assert np.any(~s.tile_active & (s.tile_values == -s.background))
    # tiles at every level, including the root
    assert set(g["codes"].tile_sizes.tolist()) == {8, 128, 4096}
    assert g["codes_inst"].leaf_values is g["codes"].leaf_values  # instance shares the tree
    vel = g["vel"]
    assert vel.leaf_vectors.shape == (len(vel.leaf_origins), 512, 3)
    assert np.allclose(vel.leaf_values, np.linalg.norm(vel.leaf_vectors, axis=2))


def test_transforms(oracle):
    ov = openvdb()
    f = read_vdb(oracle, ["codes", "dbl", "vel", "sphere", "sphere[1]"])
    for g in f.grids:
        if "[" in g.name:
            continue
        t = ov.read(oracle, g.name).transform
        for ijk in [(0, 0, 0), (1, 2, 3), (-5, 7, 11)]:
            w = g.index_to_world @ np.array([*ijk, 1.0])
            assert np.allclose(w[:3], t.indexToWorld(ijk), atol=1e-12), (g.name, ijk)
    kinds = {g.name: f.grid_info[g.name]["map"] for g in f.grids}
    assert kinds == {"codes": "AffineMap", "dbl": "ScaleTranslateMap",
                     "vel": "UniformScaleTranslateMap", "sphere": "UniformScaleMap",
                     "sphere[1]": "UniformScaleMap"}


def test_every_metadata_code_is_exercised(oracle):
    from kernels.vdb import codec
    from kernels.vdb.leaves import scan_leaves
    from kernels.vdb.metadata import read_metamap
    from kernels.vdb.stream import Cursor
    from kernels.vdb.transform import read_transform
    from kernels.vdb.tree import read_tree_topology
    f = read_topology(oracle, "codes")
    a, b = f.grid_info["codes"]["byte_range"]
    data = open(oracle, "rb").read()
    cur = Cursor(data, oracle, a, b)
    flags = cur.u32()
    read_metamap(cur)
    read_transform(cur)
    et = codec.ElementType("float", False)
    topo = read_tree_topology(cur, flags, et)
    t = scan_leaves(cur, topo.leaf_masks, flags, et)
    assert set(t["codes"].tolist()) >= {0, 1, 2, 3, 4, 5, 6}


@pytest.mark.parametrize("compression,active_mask,half", [
    ("zip", True, None), ("none", False, None), ("blosc", False, True), ("zip", False, True),
    ("none", True, True)])
def test_transcoded_variants(oracle, tmp_path, compression, active_mask, half):
    dst = str(tmp_path / "v.vdb")
    transcode(oracle, dst, compression=compression, active_mask=active_mask, half=half)
    ov = openvdb()
    # the binding reads the variant back identically (halves: to half precision)
    for name in ["codes", "sphere"]:
        a, b = ov.read(oracle, name), ov.read(dst, name)
        assert a.activeVoxelCount() == b.activeVoxelCount() and a.leafCount() == b.leafCount()
        if half is None:
            for ijk in [(0, 0, 1), (3, 5, 6), (9, 1, 1), (26, 0, 1), (-10, 1, 1)]:
                assert _bits(a.getConstAccessor().getValue(ijk)) == _bits(b.getConstAccessor().getValue(ijk))
    f = read_vdb(dst)
    assert f.grids[0].compression == {"zip": "zip", "none": "none", "blosc": "blosc"}[compression] + (
        " + active mask" if active_mask else "") if compression != "none" else (
        "active mask" if active_mask else "none")
    compare_with_binding(dst, f, only={"codes", "sphere", "vel", "dbl"})


@pytest.mark.parametrize("compression", ["zip", "blosc", "none"])
def test_leaves_in_blocks_decode_as_one(oracle, tmp_path, monkeypatch, compression):
    """Blocks of two leaves (each block's zip pool, its file pages handed back) read the same bits
    as one block, and as the binding."""
    from kernels.vdb import leaves

    dst = str(tmp_path / "b.vdb")
    transcode(oracle, dst, compression=compression)
    whole = read_vdb(dst)
    monkeypatch.setattr(leaves, "BLOCK_LEAVES", 2)
    blocks = read_vdb(dst)
    assert max(len(g.leaf_values) for g in blocks.grids) > 4  # several blocks
    for a, b in zip(whole.grids, blocks.grids):
        assert np.array_equal(a.leaf_values.view(np.uint32), b.leaf_values.view(np.uint32))
    compare_with_binding(dst, blocks, only={"codes", "sphere", "vel", "dbl"})


def test_stream_file_without_offsets(oracle, tmp_path):
    dst = str(tmp_path / "s.vdb")
    transcode(oracle, dst, offsets=False, compression="zip")
    f = read_vdb(dst)
    # the int and bool grids are stepped over, so the grid after them is still found
    assert [g.name for g in f.grids] == ["codes", "codes_inst", "sphere", "dbl", "vel", "sphere[1]",
                                         "sphere_half"]
    assert dict(f.skipped).keys() == {"ids", "flags"}
    compare_with_binding(dst, f)
    t = read_topology(dst)
    assert [g.active_voxels for g in t.grids] == [g.active_voxels for g in f.grids]


def test_topology_only_and_estimate(oracle):
    t = read_topology(oracle)
    f = read_vdb(oracle)
    for a, b in zip(t.grids, f.grids):
        assert a.leaf_values is None and a.active_voxels == b.active_voxels
        assert np.array_equal(a.leaf_masks, b.leaf_masks) and np.array_equal(a.leaf_origins, b.leaf_origins)
        assert np.array_equal(a.tile_values, b.tile_values)
    need = estimate_bytes(t)
    assert need > sum(g.leaf_values.nbytes for g in f.grids if g.name != "codes_inst")
    with pytest.raises(VDBFormatError, match=r"needs about .* MiB.*limit"):
        read_vdb(oracle, max_bytes=need // 10)


def test_write_grid_helper(tmp_path):
    vals = np.zeros((20, 12, 9), np.float32)
    vals[3:15, 2:10, 1:8] = np.arange(12 * 8 * 7).reshape(12, 8, 7) + 1
    p = write_grid(tmp_path / "w.vdb", vals, origin=(-10, 4, 7), voxel_size=0.25)
    f = read_vdb(p)
    g = f.grids[0]
    assert g.active_voxels == 12 * 8 * 7
    assert tuple(g.bbox_min) == (-7, 6, 8) and tuple(g.bbox_max) == (4, 13, 14)
    assert np.allclose(np.diag(g.index_to_world), [0.25, 0.25, 0.25, 1])
    compare_with_binding(str(p), f)


@pytest.mark.parametrize("path", DATA_FILES, ids=os.path.basename)
def test_shared_data_files(path):
    f = read_vdb(path)
    assert f.grids and not f.skipped
    ov = openvdb()
    counts = {b.name: b.activeVoxelCount() for b in ov.readAll(path)[0]}
    assert {g.name: g.active_voxels for g in f.grids} == counts
    if os.path.getsize(path) < 1_000_000:
        compare_with_binding(path, f)


@pytest.mark.parametrize("path", [warmup.FIXTURE, warmup.CACHE_FIXTURE], ids=os.path.basename)
def test_warm_up_fixtures(path):
    """The warm-up's two files (blosc; a Mantaflow frame with fog grids raw and the velocity
    zip), read as the binding reads them."""
    f = read_vdb(path)
    compressions = {g.compression for g in f.grids}
    blosc = path == warmup.FIXTURE
    assert compressions == ({"blosc + active mask"} if blosc else {"active mask", "zip + active mask"})
    compare_with_binding(path, f)


@pytest.mark.parametrize("content", [None, b"", b"hello world, not a vdb file" * 3])
def test_bad_files(tmp_path, content):
    p = tmp_path / "bad.vdb"
    if content is not None:
        p.write_bytes(content)
    with pytest.raises(VDBFormatError, match="bad.vdb"):
        read_vdb(p)


def test_unknown_grid_name(oracle):
    with pytest.raises(VDBFormatError, match=r"no grid named 'nope'.*grid 'nope'"):
        read_vdb(oracle, "nope")
    with pytest.raises(VDBFormatError, match="integer grid"):
        read_vdb(oracle, "ids")


def test_truncation_names_offset(oracle, tmp_path):
    data = open(oracle, "rb").read()
    p = tmp_path / "t.vdb"
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(VDBFormatError, match=r"t\.vdb.*byte offset \d+"):
        read_vdb(p)


def test_frustum_is_refused_clearly(tmp_path):
    ov = openvdb()
    g = ov.FloatGrid()
    g.name = "fr"
    g.copyFromArray(np.ones((4, 4, 4), np.float32))
    g.transform = ov.createFrustumTransform(xyzMin=(0, 0, 0), xyzMax=(10, 10, 10), taper=0.5, depth=5.0)
    p = str(tmp_path / "fr.vdb")
    ov.write(p, grids=[g])
    f = read_vdb(p)
    assert not f.grids and "frustum" in f.skipped[0][1].lower()
    with pytest.raises(VDBFormatError, match="frustum"):
        read_vdb(p, "fr")


def test_fallback_route_is_exact_for_active_data(oracle):
    from vdb_fixtures import openvdb

    from kernels.openvdb_binding import set_loader
    from kernels.vdb.fallback import read_with_binding
    from kernels.vdb.griddata import VDBFile
    set_loader(openvdb)  # as the extension does: kernels never import bpy
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fb = read_with_binding(oracle, VDBFile(oracle, 224, (12, 0)), ["sphere_half", "vel"], False, None)
    ours = {g.name: g for g in read_vdb(oracle, ["sphere_half", "vel"]).grids}
    for g in fb.grids:
        o = ours[g.name]
        assert g.active_voxels == o.active_voxels
        keep = o.leaf_masks.any(axis=1)  # the binding cannot see leaves without active voxels
        assert np.array_equal(g.leaf_origins, np.unique(o.leaf_origins[keep], axis=0))
        order = np.lexsort(o.leaf_origins[keep].T[::-1])
        assert np.array_equal(g.leaf_masks, o.leaf_masks[keep][order])
        assert np.array_equal(_bits(g.leaf_values), _bits(o.leaf_values[keep][order]))
        assert len(g.leaf_origins) > 10
