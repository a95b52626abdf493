"""Fixture writer (through the openvdb binding) and a small transcoder for .vdb test files.

Other tests reuse ``write_grid``:

    from tests.vdb_fixtures import write_grid
    write_grid(tmp_path / "cube.vdb", np.ones((16, 16, 16), np.float32), voxel_size=0.1)

``transcode`` rewrites a file with other compression / active-mask / half settings, or as a stream
without grid offsets; tests check that the binding reads every variant back identically.
"""

import struct
import zlib

import numpy as np

from kernels.vdb import codec
from kernels.vdb.metadata import read_metamap
from kernels.vdb.stream import Cursor
from kernels.vdb.transform import read_transform


def openvdb():
    import bpy

    bpy.utils.expose_bundled_modules()
    import openvdb as ov
    return ov


def write_nan_inf(path, name="density"):
    """An 8^3 block of 0.5 with one NaN, one +Inf and one -Inf voxel, all active. Returns the path."""
    ov = openvdb()
    g = ov.FloatGrid()
    g.name = name
    acc = g.getAccessor()
    for ijk in np.ndindex(8, 8, 8):
        acc.setValueOn(ijk, 0.5)
    for ijk, v in (((1, 1, 1), np.nan), ((2, 2, 2), np.inf), ((5, 5, 5), -np.inf)):
        acc.setValueOn(ijk, float(v))
    ov.write(str(path), grids=[g])
    return path


def write_grid(path, values_dense=None, *, name="density", origin=(0, 0, 0), background=0.0,
               voxel_size=1.0, grid_class="fog volume", half=False, matrix=None, tolerance=0.0):
    """Write one float grid: ``values_dense`` (x, y, z) placed at index ``origin``; voxels equal to
    the background (within ``tolerance``) stay inactive. Returns the path."""
    ov = openvdb()
    g = ov.FloatGrid()
    g.background = float(background)
    if values_dense is not None:
        g.copyFromArray(np.ascontiguousarray(values_dense, np.float32), ijk=tuple(int(c) for c in origin),
                        tolerance=tolerance)
    g.name = name
    g.gridClass = {"fog volume": ov.GridClass.FOG_VOLUME, "level set": ov.GridClass.LEVEL_SET}.get(
        grid_class, ov.GridClass.UNKNOWN)
    g.transform = ov.createLinearTransform(np.asarray(matrix, float).T.tolist()) if matrix is not None \
        else ov.createLinearTransform(voxelSize=float(voxel_size))
    g.saveFloatAsHalf = bool(half)
    ov.write(str(path), grids=[g])
    return path


# ---- transcoder -------------------------------------------------------------------------------

def _pack_string(s):
    b = s.encode() if isinstance(s, str) else s
    return struct.pack("<I", len(b)) + b


def _metamap_bytes(meta_raw):
    out = [struct.pack("<I", len(meta_raw))]
    for name, tname, raw in meta_raw:
        out += [_pack_string(name), _pack_string(tname), struct.pack("<I", len(raw)), raw]
    return b"".join(out)


def _raw_metamap(cur):
    count = cur.u32()
    entries = []
    for _ in range(count):
        name = cur.string()
        tname = cur.string()
        size = cur.u32()
        entries.append((name, tname, bytes(cur.bytes(size))))
    return entries


class _Enc:
    def __init__(self, flags, half, et_in, et_out):
        self.flags, self.half, self.et_in, self.et_out = flags, half, et_in, et_out

    def chunk(self, arr_bytes, count, itemsize):
        """readData's framing for ``count`` values already converted to bytes."""
        if self.half and count < 1:
            return b""
        if self.flags & codec.COMPRESS_BLOSC:
            import blosc
            c = blosc.compress(arr_bytes, typesize=itemsize, cname="lz4")
            return struct.pack("<q", len(c)) + c
        if self.flags & codec.COMPRESS_ZIP:
            if not arr_bytes:
                return struct.pack("<q", 0)
            c = zlib.compress(arr_bytes)
            if len(c) >= len(arr_bytes):  # store raw with a negative size, as OpenVDB may
                return struct.pack("<q", -len(arr_bytes)) + arr_bytes
            return struct.pack("<q", len(c)) + c
        return arr_bytes

    def values(self, values, active, bg):
        """Inverse of read_node_values (writeCompressedValues)."""
        et = self.et_out
        full = et.full
        vals = np.ascontiguousarray(values, full).reshape(len(active), et.ncomp)
        bgv = np.asarray(bg, full).reshape(1, et.ncomp)
        u = np.dtype(f"<u{full.itemsize}")
        uv = vals.view(u)
        ub, unb = bgv.view(u)[0], (-bgv).view(u)[0]
        code, v0, v1, sel = 6, None, None, None
        if self.flags & codec.COMPRESS_ACTIVE_MASK:
            d = np.unique(uv[~active], axis=0)  # distinct inactive values, bitwise
            def same(row):
                return np.all(uv == row, axis=1) & ~active

            def isb(row):
                return np.array_equal(row, ub)

            def isnb(row):
                return np.array_equal(row, unb)

            if len(d) == 0 or (len(d) == 1 and isb(d[0])):
                code = 0
            elif len(d) == 1 and isnb(d[0]):
                code = 1
            elif len(d) == 1:
                code, v0 = 2, d[0].view(full)
            elif len(d) == 2:
                if {d[0].tobytes(), d[1].tobytes()} == {ub.tobytes(), unb.tobytes()}:
                    code, sel = 3, same(ub)
                elif isb(d[0]) or isb(d[1]):
                    other = d[1] if isb(d[0]) else d[0]
                    code, v0, sel = 4, other.view(full), same(ub)
                else:
                    code, v0, v1, sel = 5, d[0].view(full), d[1].view(full), same(d[1])
        out = [bytes([code])]
        if v0 is not None:
            out.append(np.asarray(v0, full).tobytes())
        if v1 is not None:
            out.append(np.asarray(v1, full).tobytes())
        if sel is not None:
            out.append(np.packbits(sel, bitorder="little").tobytes())
        stored = vals[active] if (self.flags & codec.COMPRESS_ACTIVE_MASK and code != 6) else vals
        sdt = np.dtype("<f2") if self.half else full
        raw = stored.astype(sdt).tobytes()
        out.append(self.chunk(raw, len(stored), sdt.itemsize))
        return b"".join(out)


def _tree(cur, enc, flags_in):
    """Re-encode Tree topology + buffers; returns the bytes."""
    out = []
    et = enc.et_in
    out.append(struct.pack("<i", cur.i32()))
    bg = cur.array(et.full, et.ncomp).copy()
    out.append(bg.tobytes())
    nt, nc = cur.u32(), cur.u32()
    out.append(struct.pack("<II", nt, nc))
    tile_size = 12 + et.full_size + 1
    out.append(bytes(cur.bytes(nt * tile_size)))
    leaf_masks = []

    def internal(log2):
        n = 1 << (3 * log2)
        cm = cur.array(np.uint8, n // 8).copy()
        vm = cur.array(np.uint8, n // 8).copy()
        active = np.unpackbits(vm, bitorder="little").astype(bool)
        vals = read_node_values(cur, n, active, flags_in, et, bg)
        out.extend([cm.tobytes(), vm.tobytes(), enc.values(vals, active, bg)])
        kids = int(np.unpackbits(cm).sum())
        if log2 == 4:
            for _ in range(kids):
                m = cur.array(np.uint8, 64).copy()
                leaf_masks.append(m)
                out.append(m.tobytes())
        else:
            for _ in range(kids):
                internal(4)

    for _ in range(nc):
        out.append(bytes(cur.bytes(12)))
        internal(5)
    topo = b"".join(out)
    out = []
    for m in leaf_masks:
        assert bytes(cur.bytes(64)) == m.tobytes()
        active = np.unpackbits(m, bitorder="little").astype(bool)
        vals = read_node_values(cur, 512, active, flags_in, et, bg)
        out.extend([m.tobytes(), enc.values(vals, active, bg)])
    return topo, b"".join(out)


def transcode(src, dst, *, compression="blosc", active_mask=True, half=None, offsets=True):
    """Rewrite ``src`` (any v>=222 file) with ``compression`` in {"blosc", "zip", "none"}, the
    active-mask flag, half floats (None keeps each grid's setting) and with or without grid offsets."""
    data = open(src, "rb").read()
    cur = Cursor(data, str(src))
    head_start = cur.pos
    cur.i64()
    version = cur.u32()
    assert version >= 222
    cur.skip(8)
    off_flag_pos = cur.pos
    cur.u8()
    cur.skip(36)
    read_metamap(cur)
    count = cur.i32()
    header = bytearray(data[head_start:cur.pos])
    header[off_flag_pos] = 1 if offsets else 0
    flags = {"blosc": codec.COMPRESS_BLOSC, "zip": codec.COMPRESS_ZIP, "none": 0}[compression]
    flags |= codec.COMPRESS_ACTIVE_MASK if active_mask else 0
    out = bytearray(header)
    for _ in range(count):
        unique, tname, parent = cur.string(), cur.string(), cur.string()
        gpos, _bpos, epos = cur.i64(), cur.i64(), cur.i64()
        g = Cursor(data, str(src), gpos, epos)
        flags_in = g.u32()
        meta = _raw_metamap(g)
        was_half = any(n == "is_saved_as_half_float" and r == b"\x01" for n, _, r in meta)
        h = was_half if half is None else half
        vt = tname.replace("_HalfFloat", "").split("_")[1]
        meta = [e for e in meta if e[0] != "is_saved_as_half_float"]
        if vt in codec.VALUE_TYPES:
            meta.append(("is_saved_as_half_float", "bool", b"\x01" if h else b"\x00"))
        xs = g.pos
        read_transform(g)
        xform = data[xs:g.pos]
        body = struct.pack("<I", flags if vt in codec.VALUE_TYPES else flags_in)
        body += _metamap_bytes(meta) + xform
        block = len(body)
        if not parent:
            if vt in codec.VALUE_TYPES:
                enc = _Enc(flags, h, codec.ElementType(vt, was_half), codec.ElementType(vt, h))
                g.grid = unique
                topo, bufs = _tree(g, enc, flags_in)
                block = len(body) + len(topo)
                body += topo + bufs
                assert g.pos == epos, (g.pos, epos)
            else:
                body = data[gpos:epos]  # other value types: copied untouched
                block = _bpos - gpos
        base = tname.replace("_HalfFloat", "")
        tname_out = base + ("_HalfFloat" if h and vt in codec.VALUE_TYPES else "")
        desc = _pack_string(unique) + _pack_string(tname_out) + _pack_string(parent)
        gstart = len(out) + len(desc) + 24
        if offsets:
            desc += struct.pack("<qqq", gstart, gstart + block, gstart + len(body))
        else:
            desc += struct.pack("<qqq", 0, 0, 0)
        out += desc + body
        cur.pos = epos  # source files have grid offsets: the next descriptor follows this grid
    open(dst, "wb").write(bytes(out))
    return dst


# ---- oracle fixture --------------------------------------------------------------------------

def build_oracle_file(path):
    """Many grids exercising every feature the reader claims; written by the binding."""
    ov = openvdb()
    g = ov.FloatGrid()
    g.background = 2.0
    g.name = "codes"
    g.gridClass = ov.GridClass.FOG_VOLUME
    a = g.getAccessor()
    rng = np.random.default_rng(7)

    def leaf(org, inactive_vals, nan=False):
        for n in range(512):
            ijk = (org[0] + n // 64, org[1] + (n // 8) % 8, org[2] + n % 8)
            if n % 3 == 0:
                a.setValueOn(ijk, float(rng.normal()))
            else:
                a.setValueOff(ijk, float(inactive_vals[n % len(inactive_vals)]))
        if nan:
            a.setValueOn(org, float("nan"))
            a.setValueOn((org[0], org[1], org[2] + 1), float("inf"))
            a.setValueOn((org[0], org[1], org[2] + 2), float("-inf"))

    leaf((0, 0, 0), [2.0], nan=True)             # code 0
    leaf((8, 0, 0), [-2.0])                      # code 1
    leaf((16, 0, 0), [5.0])                      # code 2
    leaf((24, 0, 0), [2.0, -2.0])                # code 3
    leaf((32, 0, 0), [2.0, 7.0])                 # code 4
    leaf((40, 0, 0), [7.0, 9.0])                 # code 5
    leaf((48, 0, 0), [7.0, 9.0, 11.0, 13.0])     # code 6
    leaf((-8, -16, -24), [2.0])                  # negative coordinates
    leaf((-4096 - 8, 5000 - 5000 % 8, -130 - 6), [-2.0])  # far corner, another root child
    for k in range(8):                            # a fully active leaf
        for j in range(8):
            for i in range(8):
                a.setValueOn((200 + i, 200 + j, 200 + k), float(i + j + k))
    g.fill((64, 64, 64), (71, 71, 71), 3.0, True)          # level-1 tile, 8^3, active
    g.fill((72, 64, 64), (79, 71, 71), -2.0, False)        # level-1 tile, inactive, -bg
    g.fill((256, 0, 0), (383, 127, 127), 4.0, True)        # level-2 tile, 128^3
    g.fill((384, 0, 0), (511, 127, 127), 6.5, False)       # inactive level-2 tile, other value
    g.fill((8192, 0, 0), (12287, 4095, 4095), 1.5, True)   # root tile, 4096^3, active
    g.fill((-8192, 0, 0), (-4097, 4095, 4095), 9.0, False)  # root tile, inactive
    m = np.array([[0.0, -0.5, 0.0, 1.0], [0.5, 0.0, 0.0, -2.0], [0.0, 0.0, 0.25, 3.5],
                  [0.0, 0.0, 0.0, 1.0]])  # column-vector: rotation + anisotropic scale + shift
    g.transform = ov.createLinearTransform(m.T.tolist())

    s = ov.createLevelSetSphere(radius=3.0, center=(-1.0, 0.5, 2.0), voxelSize=0.1,
                                          halfWidth=3.0)
    s.name = "sphere"
    d = ov.DoubleGrid()
    d.background = -1.0
    d.name = "dbl"
    d.copyFromArray(rng.normal(size=(20, 9, 5)), ijk=(-3, 4, 100))
    d.transform = ov.createLinearTransform(np.diag([1.0, 2.0, 3.0, 1.0]).tolist())
    d.transform.postTranslate((1.0, 2.0, 3.0))
    v = ov.Vec3SGrid()
    v.name = "vel"
    v.copyFromArray(rng.normal(size=(12, 10, 9, 3)).astype(np.float32), ijk=(5, -7, 3))
    v.transform = ov.createLinearTransform(voxelSize=1.0)
    v.transform.postTranslate((0.5, -1.0, 2.0))
    inst = g.copy()
    inst.name = "codes_inst"
    dup = ov.FloatGrid()
    dup.name = "sphere"
    dup.copyFromArray(np.ones((9, 9, 9), np.float32))
    ids = ov.Int32Grid()
    ids.name = "ids"
    ids.copyFromArray(np.arange(27, dtype=np.int32).reshape(3, 3, 3) + 1)
    flags = ov.BoolGrid()
    flags.name = "flags"
    flags.copyFromArray(np.ones((4, 4, 4), bool))
    half = s.deepCopy()
    half.name = "sphere_half"
    half.saveFloatAsHalf = True
    ov.write(str(path), grids=[g, inst, s, d, v, dup, ids, flags, half])
    return path


# ---- files shaped like real ones -------------------------------------------------------------
# Each writer takes the path to write and returns it; the tests compare our reader with openvdb's.

def _float_grid(ov, name, values, origin=(0, 0, 0)):
    g = ov.FloatGrid()
    g.name = name
    g.gridClass = ov.GridClass.FOG_VOLUME
    g.copyFromArray(np.ascontiguousarray(values, np.float32), ijk=tuple(origin))
    return g


def write_same_name_grids(path, count=3, name="density"):
    """``count`` fog grids all named ``name`` (as simulation caches write them): grid k is a
    (8 + 4k)^3 block of values k + 1 + a ramp, so each one's values and extent differ."""
    ov = openvdb()
    grids = []
    for k in range(count):
        n = 8 + 4 * k
        ramp = np.arange(n ** 3, dtype=np.float32).reshape(n, n, n) / n ** 3
        grids.append(_float_grid(ov, name, k + 1 + ramp, origin=(16 * k, 0, 0)))
    ov.write(str(path), grids=grids)
    return path


def write_constant_fog(path, value, *, shape=(20, 16, 16), name="density", voxel_size=1.0):
    """One fog grid whose active voxels all hold ``value``: the constant 8^3 blocks become active
    tiles (as OpenVDB prunes them), the ragged x edge stays in leaves. Returns the path."""
    ov = openvdb()
    g = _float_grid(ov, name, np.full(shape, value, np.float32))
    g.transform = ov.createLinearTransform(voxelSize=float(voxel_size))
    ov.write(str(path), grids=[g])
    return path


def vec3_then_scalar_values(seed=3):
    """The arrays write_vec3_then_scalar stores: velocity (20, 20, 16, 3), density (20, 20, 16)."""
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(20, 20, 16, 3)).astype(np.float32),
            (0.05 + rng.random((20, 20, 16))).astype(np.float32))


def write_vec3_then_scalar(path):
    """A vec3s 'velocity' grid followed by a float 'density' grid of 6,400 active voxels (the
    order Mantaflow caches use). Returns the path."""
    ov = openvdb()
    vel, dens = vec3_then_scalar_values()
    v = ov.Vec3SGrid()
    v.name = "velocity"
    v.copyFromArray(vel)
    ov.write(str(path), grids=[v, _float_grid(ov, "density", dens)])
    return path


def write_empty_beside_full(path):
    """An empty float grid 'flame' (0 active voxels, as Mantaflow writes for smoke without fire)
    before a 10^3 fog grid 'density'. Returns the path."""
    ov = openvdb()
    empty = ov.FloatGrid()
    empty.name = "flame"
    empty.gridClass = ov.GridClass.FOG_VOLUME
    dens = np.linspace(0.1, 1.0, 1000, dtype=np.float32).reshape(10, 10, 10)
    ov.write(str(path), grids=[empty, _float_grid(ov, "density", dens, origin=(-3, 2, 5))])
    return path


def write_int_beside_float(path):
    """An int32 grid 'ids' before a float grid 'density' (both 6^3). Returns the path."""
    ov = openvdb()
    ids = ov.Int32Grid()
    ids.name = "ids"
    ids.copyFromArray(np.arange(216, dtype=np.int32).reshape(6, 6, 6) + 1)
    dens = np.linspace(0.5, 2.0, 216, dtype=np.float32).reshape(6, 6, 6)
    ov.write(str(path), grids=[ids, _float_grid(ov, "density", dens)])
    return path


def _rewrite(src, dst, edit, *, offsets=True):
    """Copy ``src`` (a file with grid offsets) grid by grid through ``edit(type_name, head, topology,
    buffers) -> (head, topology, buffers)`` (byte strings; head = compression flags, metadata and
    transform), writing fresh descriptor offsets, or none with ``offsets=False`` (a stream)."""
    data = open(src, "rb").read()
    cur = Cursor(data, str(src))
    cur.skip(20)  # magic, file version, library version
    flag_at = cur.pos
    cur.skip(1 + 36)
    read_metamap(cur)
    count = cur.i32()
    out = bytearray(data[:cur.pos])
    out[flag_at] = 1 if offsets else 0
    for _ in range(count):
        unique, tname, parent = cur.string(), cur.string(), cur.string()
        gpos, bpos, epos = cur.i64(), cur.i64(), cur.i64()
        g = Cursor(data, str(src), gpos, epos)
        g.u32()
        _raw_metamap(g)
        read_transform(g)
        head, topo, bufs = edit(tname, data[gpos:g.pos], data[g.pos:bpos], data[bpos:epos])
        desc = _pack_string(unique) + _pack_string(tname) + _pack_string(parent)
        start = len(out) + len(desc) + 24
        pos = (start, start + len(head) + len(topo), start + len(head) + len(topo) + len(bufs))
        out += desc + struct.pack("<qqq", *(pos if offsets else (0, 0, 0))) + head + topo + bufs
        cur.pos = epos
    open(dst, "wb").write(bytes(out))
    return dst


def _strip_file_metadata(head):
    """Drop the file_* grid metadata (bbox, voxel count) that only OpenVDB itself writes."""
    c = Cursor(head, "head")
    flags = c.u32()
    meta = [e for e in _raw_metamap(c) if not e[0].startswith("file_")]
    return struct.pack("<I", flags) + _metamap_bytes(meta) + head[c.pos:]


def write_float_sized_vec3_root(src, dst, *, offsets=True):
    """What a non-OpenVDB writer produced: ``src``'s vec3s grids with the root background and
    root tile values stored as one float (4 bytes) instead of three, and no file_* metadata, with
    the descriptor offsets fixed up to match (or none: a stream). Returns ``dst``."""
    def edit(tname, head, topo, bufs):
        head = _strip_file_metadata(head)
        if "vec3s" not in tname:
            return head, topo, bufs
        c = Cursor(topo, "topology")
        nbuf = c.i32()
        bg = c.array("<f4", 3)
        ntiles, nchild = c.u32(), c.u32()
        root = [struct.pack("<i", nbuf), bg[:1].tobytes(), struct.pack("<II", ntiles, nchild)]
        for _ in range(ntiles):
            origin, value, active = bytes(c.bytes(12)), c.array("<f4", 3), c.u8()
            root += [origin, value[:1].tobytes(), bytes([active])]
        return head, b"".join(root) + topo[c.pos:], bufs
    return _rewrite(src, dst, edit, offsets=offsets)


def write_mantaflow_like(path, shape=(24, 20, 16)):
    """Grids named as a Mantaflow cache's, ``shadow`` first (a domain-wide constant -1, as
    Blender leaves it unbaked), then heat, density and an empty flame grid."""
    ov = openvdb()
    rng = np.random.default_rng(7)
    density = rng.random(shape, dtype=np.float32) * (np.arange(shape[0])[:, None, None] < 12)
    grids = [_float_grid(ov, "shadow", np.full(shape, -1.0, np.float32)),
             _float_grid(ov, "heat", 0.5 * density), _float_grid(ov, "density", density),
             _float_grid(ov, "flame", np.zeros(shape, np.float32))]
    ov.write(str(path), grids=grids)
    return path


def fire_like_values(shape=(32, 24, 24), seed=11, background=0.25):
    """The arrays write_fire_like stores: density (sparse random voxels, a nearly constant
    dense 16^3 corner that the merged LOD merges, a constant 8^3 block that becomes a tile) and
    temperature (a ramp over a region shifted from the density's, so some density voxels have
    no temperature voxel: those hold the background)."""
    rng = np.random.default_rng(seed)
    density = rng.random(shape, dtype=np.float32) * (rng.random(shape) < 0.35)
    density[:16, :16, :16] = 0.5 + 0.002 * rng.random((16, 16, 16), dtype=np.float32)  # merges
    density[16:24, 0:8, 0:8] = 0.6  # one constant leaf: an active tile
    x = np.arange(shape[0], dtype=np.float32)[:, None, None]
    temperature = np.full(shape, background, np.float32)
    temperature[4:, :, 2:] = (1.0 + x / shape[0] + 0.1 * rng.random(shape, dtype=np.float32))[4:, :, 2:]
    return density, temperature


def write_fire_like(path, background=0.25):
    """Two fog grids of one fire: ``density`` and ``temperature`` (fire_like_values), the
    temperature with background ``background`` and a constant block of 3.0 at (32, 0, 0) + 16^3
    beside the density's leaves (a tile). Returns the path."""
    ov = openvdb()
    density, temperature = fire_like_values(background=background)
    d = _float_grid(ov, "density", density)
    t = ov.FloatGrid(float(background))
    t.name = "temperature"
    t.gridClass = ov.GridClass.FOG_VOLUME
    t.copyFromArray(np.ascontiguousarray(temperature), ijk=(0, 0, 0))
    t.fill((16, 0, 8), (31, 15, 23), 3.0, True)
    t.prune()
    ov.write(str(path), grids=[d, t])
    return path


def read_node_values(cur, nslots, active, flags, et, background):
    """Decode all ``nslots`` values of one node (the reader decodes leaves in bulk; the
    transcoder here one node at a time); ``active`` is its value mask as a bool array.

    Returns (values (nslots, ncomp) full dtype). Inactive slots are rebuilt from the metadata code.
    """
    code, val0, val1, sel, data = codec.read_node_parts(cur, nslots, int(np.count_nonzero(active)),
                                                        flags, et)
    count = len(data)
    if count == nslots:
        return data
    val0, val1 = codec.inactive_values(code, val0, val1, background, et)
    if sel is None:
        out = np.empty((nslots, et.ncomp), et.full)
        out[:] = val0
    else:
        sel = np.unpackbits(sel, bitorder="little")
        out = np.where(sel[:, None].astype(bool), val1, val0).astype(et.full)
    if count:
        out[active] = data
    return out


def bits_from_masks(masks):
    """uint64 (N, 8) leaf masks -> bool (N, 512): voxel n at bit n & 63 of word n >> 6."""
    m = np.asarray(masks, dtype=np.uint64)
    b = (m[:, :, None] >> np.arange(64, dtype=np.uint64)) & np.uint64(1)
    return b.reshape(len(m), 512).astype(bool)
