"""kernels/sequence.py: patterns, Blender's frame mapping (checked against a real Volume object),
the LRU cache within a memory budget, the on-disk cache file."""

import os

import numpy as np
import pytest

from kernels import sequence as seq
from kernels.convert_options import ConvertOptions


def test_parse_numbered_and_hash_patterns(tmp_path):
    a = seq.parse(str(tmp_path / "fluid_data_0007.vdb"))
    b = seq.parse(str(tmp_path / "fluid_data_####.vdb"))
    assert a == b
    assert (a.head, a.digits, a.tail) == ("fluid_data_", 4, ".vdb")
    assert a.path(12) == str(tmp_path / "fluid_data_0012.vdb")
    assert a.path(12345).endswith("fluid_data_12345.vdb")
    assert seq.parse(str(tmp_path / "smoke.vdb")) is None
    assert seq.frame_number(str(tmp_path / "x_v2_010.vdb")) == 10
    assert seq.frame_number(str(tmp_path / "x_####.vdb")) is None


def test_scan_keeps_one_padding_and_finds_gaps(tmp_path):
    for name in ("s_0001.vdb", "s_0002.vdb", "s_0004.vdb", "s_12345.vdb", "s_01.vdb", "s_0003.txt",
                 "t_0003.vdb"):
        (tmp_path / name).write_bytes(b"")
    assert seq.parse(str(tmp_path / "s_0001.vdb")).scan() == [1, 2, 4, 12345]


def test_group_selected_files():
    out = seq.group(["d/a_0003.vdb", "d/a_0001.vdb", "d/plain.vdb", "d/b_01.vdb", "d/a_0002.vdb"])
    assert [(p.text if p else None, v) for p, v in out] == [
        ("a_####.vdb", [1, 2, 3]), (None, ["d/plain.vdb"]), ("b_##.vdb", [1])]


def test_parse_frames():
    assert seq.parse_frames("35-38") == [35, 36, 37, 38]
    assert seq.parse_frames("1-2, 5,2") == [1, 2, 5]
    for bad in ("a-b", "5-3", ""):
        with pytest.raises(ValueError):
            seq.parse_frames(bad)


def test_modes_by_hand():
    m = seq.map_frame
    assert [m(f, 1, 0, 3, "CLIP") for f in range(0, 5)] == [None, 1, 2, 3, None]
    assert [m(f, 1, 0, 3, "EXTEND") for f in range(0, 5)] == [1, 1, 2, 3, 3]
    assert [m(f, 1, 0, 3, "REPEAT") for f in range(0, 8)] == [3, 1, 2, 3, 1, 2, 3, 1]
    assert [m(f, 1, 0, 3, "PING_PONG") for f in range(1, 8)] == [1, 2, 3, 2, 1, 2, 3]
    assert m(5, 10, 99, 4, "CLIP") is None and m(11, 10, 99, 4, "CLIP") == 101
    assert m(3, 1, 0, 1, "PING_PONG") == 1 and m(3, 1, 0, 0, "REPEAT") is None


def test_modes_match_blender_volume(bpy_module, tmp_path):
    """Blender's own Volume object (is_sequence) picks the same file number for every frame."""
    bpy = bpy_module
    from tests.vdb_fixtures import write_grid

    for n in (3, 4, 5, 7):
        write_grid(tmp_path / f"blob_{n:04d}.vdb", np.ones((2, 2, n), np.float32))
    bpy.ops.wm.read_homefile(use_empty=True)
    sc = bpy.context.scene
    vol = bpy.data.volumes.new("v")
    vol.filepath = str(tmp_path / "blob_0003.vdb")
    vol.is_sequence = True
    ob = bpy.data.objects.new("v", vol)
    sc.collection.objects.link(ob)
    checked = 0
    for start, offset, duration in ((1, 2, 5), (4, 0, 3), (-2, 5, 2)):
        vol.frame_start, vol.frame_offset, vol.frame_duration = start, offset, duration
        for mode in seq.MODES:
            vol.sequence_mode = mode
            for f in range(-4, 15):
                sc.frame_set(f)
                got = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.grids.frame
                ours = seq.map_frame(f, start, offset, duration, mode)
                assert (None if got == 2 ** 31 - 1 else got) == ours, (start, offset, duration, mode, f)
                checked += 1
    assert checked == 3 * 4 * 19


def test_held_frame():
    assert seq.held_frame(3, [1, 2, 4]) == 2
    assert seq.held_frame(4, [1, 2, 4]) == 4
    assert seq.held_frame(0, [1, 2, 4]) is None
    assert seq.held_frame(None, [1]) is None


def test_lru_budget_evicts_least_recent():
    c = seq.LRUCache(250)
    c.put("a", 1, 100)
    c.put("b", 2, 100)
    assert c.get("a") == 1  # a is now the most recent
    c.put("c", 3, 100)  # 300 > 250: b goes
    assert "b" not in c and "a" in c and "c" in c and c.evictions == 1 and c.nbytes == 200
    c.set_budget(50)  # only the newest stays
    assert list(c.items) == ["c"] and c.nbytes == 100
    assert c.get("zz") is None and c.misses == 1


def test_union_stats():
    a = {"min": 0.0, "max": 1.0, "positive_min": 0.1, "nonpositive": 2, "voxels": 10}
    b = {"min": -1.0, "max": 0.5, "positive_min": None, "nonpositive": 5, "voxels": 5}
    assert seq.union_stats([a, None, b]) == {"min": -1.0, "max": 1.0, "positive_min": 0.1,
                                              "nonpositive": 7, "voxels": 15}
    assert seq.union_stats([None, {"voxels": 0}]) is None


def test_disk_cache_roundtrip_and_stale(tmp_path):
    src = tmp_path / "f_0001.vdb"
    src.write_bytes(os.urandom(200_000))
    fp = seq.fingerprint(src)
    opts = ConvertOptions(weights="paper", level_set_band=False, vector_magnitude=True)
    name = seq.cache_name(src, "den sity", "low", opts)
    assert name == "f_0001.den_sity.low.paper.fullband.mag.npz"
    path = tmp_path / "cache" / name
    enc = {"x": np.arange(5, dtype=np.uint8)}
    seq.write_cache(str(path), enc, {"fingerprint": fp, "values": {"min": 0}})
    data, meta = seq.read_cache(str(path), fp)
    assert np.array_equal(data["x"], enc["x"]) and meta["values"] == {"min": 0}
    with open(src, "r+b") as f:  # the frame is re-baked: the cache no longer matches
        f.seek(199_000)
        f.write(b"changed")
    assert seq.fingerprint(src) != fp and seq.read_cache(str(path), seq.fingerprint(src)) is None
    (tmp_path / "cache" / "broken.npz").write_bytes(b"nonsense")
    assert seq.read_cache(str(tmp_path / "cache" / "broken.npz"), fp) is None
