"""Files shaped like the real ones that broke readers: duplicate names, constant grids, a vec3s
grid before a scalar one (valid, and as a non-OpenVDB writer wrote it), empty and int32 grids.
Every value is compared bit for bit with what was written and with openvdb's own reading."""

import numpy as np
import pytest

from kernels.vdb import VDBFormatError, read_topology, read_vdb
from kernels.vdb.info import describe
from tests.vdb_fixtures import (
    openvdb,
    transcode,
    vec3_then_scalar_values,
    write_constant_fog,
    write_empty_beside_full,
    write_float_sized_vec3_root,
    write_int_beside_float,
    write_same_name_grids,
    write_vec3_then_scalar,
)


def ours_active(g):
    """{(i, j, k): value bits} of the active leaf voxels of one of our grids (vectors for vec3)."""
    vals = g.leaf_vectors if g.leaf_vectors is not None else g.leaf_values[..., None]
    bits = np.unpackbits(g.leaf_masks.view(np.uint8), axis=1, bitorder="little").astype(bool)
    li, slot = np.nonzero(bits)
    ijk = g.leaf_origins[li].astype(np.int64) + np.stack([slot // 64, (slot // 8) % 8, slot % 8], 1)
    out = {tuple(p): vals[a, s].astype(np.float32).tobytes() for p, a, s in zip(ijk.tolist(), li, slot)}
    return out


def binding_active(b):
    """The same map from openvdb's on-iterator (tiles expanded to their voxels)."""
    out = {}
    for it in b.citerOnValues():
        v = np.asarray(it.value, np.float32).reshape(-1).tobytes()
        lo, hi = np.array(it.min), np.array(it.max)
        for p in np.ndindex(*(hi - lo + 1)):
            out[tuple((lo + p).tolist())] = v
    return out


def expand(g):
    """ours_active plus each active tile expanded (scalar grids; fixtures keep tiles small)."""
    out = ours_active(g)
    for o, s, v, a in zip(g.tile_origins, g.tile_sizes, g.tile_values, g.tile_active):
        if a:
            assert s <= 128
            for p in np.ndindex(int(s), int(s), int(s)):
                out[tuple((o.astype(np.int64) + p).tolist())] = np.float32(v).tobytes()
    return out


def dense_active(values, origin=(0, 0, 0)):
    """{(i, j, k): bits} for a dense array written with copyFromArray (every voxel active)."""
    a = np.asarray(values, np.float32)
    shape = a.shape[:3]
    flat = a.reshape(*shape, -1)
    return {tuple((np.array(p) + origin).tolist()): flat[p].tobytes() for p in np.ndindex(*shape)}


def binding_grids(path):
    ov = openvdb()
    grids, _ = ov.readAll(str(path))
    return grids


# ---- duplicate names ---------------------------------------------------------------------------

def test_three_grids_named_density(tmp_path):
    p = write_same_name_grids(tmp_path / "dup.vdb")
    f = read_vdb(p)
    assert [g.name for g in f.grids] == ["density", "density[1]", "density[2]"]
    theirs = [binding_active(b) for b in binding_grids(p)]
    for k, g in enumerate(f.grids):
        n = 8 + 4 * k
        ramp = np.arange(n ** 3, dtype=np.float32).reshape(n, n, n) / n ** 3
        want = dense_active(k + 1 + ramp, (16 * k, 0, 0))
        assert expand(g) == want, g.name
        assert sum(t == want for t in theirs) == 1, g.name  # openvdb reads the same grid once


def test_a_name_selects_one_grid(tmp_path):
    p = write_same_name_grids(tmp_path / "dup.vdb")
    every = {g.name: g for g in read_vdb(p).grids}
    for read in (read_vdb, read_topology):
        for name in ("density", "density[1]", "density[2]"):
            f = read(p, name)
            assert [g.name for g in f.grids] == [name]
            assert f.grids[0].active_voxels == every[name].active_voxels
            assert np.array_equal(f.grids[0].leaf_origins, every[name].leaf_origins)
        assert [g.name for g in read(p, ["density[2]", "density"]).grids] == ["density", "density[2]"]
        with pytest.raises(VDBFormatError, match=r"no grid named 'density\[3\]'.*'density\[1\]'"):
            read(p, "density[3]")


# ---- constant grids ----------------------------------------------------------------------------

@pytest.mark.parametrize("value", [0.5, 1.0])
def test_constant_fog(tmp_path, value):
    p = write_constant_fog(tmp_path / "c.vdb", value)
    (g,) = read_vdb(p).grids
    assert g.tile_active.any() and len(g.leaf_origins)  # both kinds of storage are exercised
    ours = expand(g)
    assert len(ours) == g.active_voxels == 20 * 16 * 16
    assert set(ours.values()) == {np.float32(value).tobytes()}
    (b,) = binding_grids(p)
    assert ours == binding_active(b)


# ---- a vec3s grid before a scalar grid ---------------------------------------------------------

def test_vec3_then_scalar(tmp_path):
    p = write_vec3_then_scalar(tmp_path / "vs.vdb")
    vel, dens = vec3_then_scalar_values()
    f = read_vdb(p)
    g = {x.name: x for x in f.grids}
    assert list(g) == ["velocity", "density"] and not f.skipped
    assert g["density"].active_voxels == 6400
    assert expand(g["density"]) == dense_active(dens)
    assert ours_active(g["velocity"]) == dense_active(vel)
    b = {x.name: x for x in binding_grids(p)}
    assert ours_active(g["velocity"]) == binding_active(b["velocity"])
    assert expand(g["density"]) == binding_active(b["density"])


def test_float_sized_vec3_root_keeps_the_density_grid(tmp_path):
    good = write_vec3_then_scalar(tmp_path / "vs.vdb")
    bad = write_float_sized_vec3_root(good, tmp_path / "bad.vdb")
    # The shape is right: openvdb itself misreads the velocity grid (silently, as empty) ...
    b = {x.name: x for x in binding_grids(bad)}
    assert b["velocity"].activeVoxelCount() != 6400
    # ... while ours names it and still reads the density grid exactly.
    for read in (read_vdb, read_topology):
        with pytest.warns(UserWarning, match=r"grid 'velocity' malformed.*block offset"):
            f = read(bad)
        assert [g.name for g in f.grids] == ["density"]
        assert [n for n, _ in f.skipped] == ["velocity"] and "byte offset" in f.skipped[0][1]
    with pytest.warns(UserWarning):
        f = read_vdb(bad)
    want = read_vdb(good, "density").grids[0]
    got = f.grids[0]
    for field in ("leaf_origins", "leaf_masks", "leaf_values", "tile_origins", "tile_values",
                  "tile_active"):
        assert np.array_equal(getattr(got, field).view(np.uint8), getattr(want, field).view(np.uint8)), field
    assert expand(got) == dense_active(vec3_then_scalar_values()[1])
    with pytest.warns(UserWarning):
        assert [s["name"] for s in describe(bad)["skipped"]] == ["velocity"]  # what `info` prints
    with pytest.raises(VDBFormatError, match=r"grid 'velocity'.*byte offset"):
        read_vdb(bad, "velocity")  # asked for by name: never skipped


def test_float_sized_vec3_root_in_a_stream_is_refused(tmp_path):
    good = write_vec3_then_scalar(tmp_path / "vs.vdb")
    bad = write_float_sized_vec3_root(good, tmp_path / "bad.vdb", offsets=False)
    with pytest.raises(Exception):  # openvdb refuses it too
        binding_grids(bad)
    for read in (read_vdb, read_topology):
        with pytest.raises(VDBFormatError, match=r"'velocity'"):
            read(bad)
    # the valid stream reads in full
    stream = transcode(good, tmp_path / "s.vdb", offsets=False)
    assert [g.name for g in read_vdb(stream).grids] == ["velocity", "density"]


# ---- empty and int32 grids beside float ones ---------------------------------------------------

def test_empty_grid_beside_a_full_one(tmp_path):
    p = write_empty_beside_full(tmp_path / "e.vdb")
    f = read_vdb(p)
    g = {x.name: x for x in f.grids}
    assert list(g) == ["flame", "density"] and not f.skipped
    assert g["flame"].active_voxels == 0 and len(g["flame"].leaf_origins) == 0
    assert g["flame"].bbox_min[0] > g["flame"].bbox_max[0]  # empty box
    b = {x.name: x for x in binding_grids(p)}
    assert b["flame"].activeVoxelCount() == 0
    dens = np.linspace(0.1, 1.0, 1000, dtype=np.float32).reshape(10, 10, 10)
    assert expand(g["density"]) == dense_active(dens, (-3, 2, 5)) == binding_active(b["density"])


@pytest.mark.parametrize("offsets", [True, False])
def test_int32_grid_beside_a_float_grid(tmp_path, offsets):
    p = write_int_beside_float(tmp_path / "i.vdb")
    if not offsets:  # a stream: the int32 grid must be stepped over to find the float one
        p = transcode(p, tmp_path / "is.vdb", offsets=False)
    f = read_vdb(p)
    assert [g.name for g in f.grids] == ["density"]
    assert [n for n, _ in f.skipped] == ["ids"] and "integer" in f.skipped[0][1]
    dens = np.linspace(0.5, 2.0, 216, dtype=np.float32).reshape(6, 6, 6)
    b = {x.name: x for x in binding_grids(p)}
    assert b["ids"].activeVoxelCount() == 216
    assert expand(f.grids[0]) == dense_active(dens) == binding_active(b["density"])
    with pytest.raises(VDBFormatError, match=r"integer grid.*grid 'ids'"):
        read_vdb(p, "ids")
