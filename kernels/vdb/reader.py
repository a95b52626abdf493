"""Orchestration: header, grid descriptors, then each grid's metadata, transform, topology, leaves."""

import mmap
import os
import re
import struct
import warnings

import numpy as np

from . import codec
from .codec import ElementType, compression_text
from .errors import VDBFormatError
from .griddata import GridData, VDBFile
from .leaves import decode_leaves, njit, popcount_rows, scan_leaves
from .metadata import read_metamap
from .stream import Cursor
from .transform import read_transform
from .tree import read_tree_topology

MAGIC = 0x56444220
NATIVE_MIN_VERSION = 222   # node-mask compression era; older files go to the binding fallback
MAX_KNOWN_VERSION = 225
DEFAULT_MAX_BYTES = int(os.environ.get("GAUSSVDB_MAX_BYTES", 16 << 30))
_SEP = "\x1e"
_I64_MAX = int(np.iinfo(np.int64).max)
_CLASSES = {"fog volume": "fog_volume", "level set": "level_set", "staggered": "staggered"}
_TYPE_RE = re.compile(r"^Tree_(\w+?)_5_4_3$")
_SKIP_REASONS = {
    "int32": "integer grid: no continuous values to turn into Gaussians",
    "int64": "integer grid: no continuous values to turn into Gaussians",
    "bool": "bool grid: no continuous values to turn into Gaussians",
    "mask": "mask grid: topology only, no values",
    "vec3i": "integer vector grid: not supported",
    "ptdataidx32": "point data grid: holds points, not a volume",
    "ptdataidx64": "point data grid: holds points, not a volume",
    "string": "string grid: not supported",
}


class _Unsupported(Exception):
    """A grid the native reader will not read (reason in args[0]); skipped or sent to the fallback."""


class _OverBudget(Exception):
    """The memory limit (a VDBFormatError in args[0]): it refuses the whole read, never one grid."""


# Data errors a garbled grid can raise besides VDBFormatError (which is a ValueError).
_GRID_ERRORS = (ValueError, IndexError, OverflowError, struct.error)


def _load(path):
    p = os.fspath(path)
    if not os.path.exists(p):
        raise VDBFormatError("no such file", p)
    if os.path.isdir(p):
        raise VDBFormatError("is a directory, not a .vdb file", p)
    try:
        with open(p, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size == 0:
                raise VDBFormatError("empty file", p, offset=0)
            # copy-on-write, never written: its arrays are writable, so a kernel that also
            # reads scratch arrays compiles once (numba types read-only arrays apart)
            return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_COPY)
    except OSError as e:
        raise VDBFormatError(f"cannot open: {e.strerror}", p) from None


def _close(buf):
    try:
        buf.close()
    except BufferError:  # a view is still alive somewhere; the GC closes it later
        pass


def _header(cur):
    magic = cur.i64("magic number")
    if magic & 0xFFFFFFFF != MAGIC:
        raise cur.error("not a VDB file (bad magic number)", 0)
    version = cur.u32("file version")
    if version < 211 or version > 1000:
        raise cur.error(f"unsupported file format version {version}", 8)
    lib = (cur.u32("library major"), cur.u32("library minor"))
    has_offsets = cur.u8("grid offsets flag") != 0
    if 220 <= version < 222:
        cur.u8("file compression flag")
    cur.skip(36, "uuid")
    meta = read_metamap(cur, "file metadata")
    at = cur.pos
    count = cur.i32("grid count")
    if count < 0 or count * 12 > cur.remaining():
        raise cur.error(f"absurd grid count {count}", at)
    return version, lib, has_offsets, meta, count


def _descriptor(cur, version):
    at = cur.pos
    unique = cur.string("grid name", limit=1 << 16)
    cur.grid = unique.split(_SEP)[0]
    tname = cur.string("grid type", limit=1 << 10)
    parent = cur.string("instance parent", limit=1 << 16) if version >= 216 else ""
    pos = [cur.i64("grid offset") for _ in range(3)]
    return {"unique": unique, "name": unique.split(_SEP)[0], "type": tname, "parent": parent,
            "grid_pos": pos[0], "block_pos": pos[1], "end_pos": pos[2], "at": at}


def _tree_value_type(tname):
    """'Tree_float_5_4_3[_HalfFloat]' -> 'float'; None for other tree configurations."""
    base = tname[:-len("_HalfFloat")] if tname.endswith("_HalfFloat") else tname
    m = _TYPE_RE.match(base)
    return m.group(1) if m else None


def _value_type(tname):
    vt = _tree_value_type(tname)
    if vt is None:
        raise _Unsupported(f"tree type {tname!r}: only standard 5-4-3 trees are read")
    if vt not in codec.VALUE_TYPES:
        raise _Unsupported(_SKIP_REASONS.get(vt, f"value type {vt!r} is not supported"))
    return vt


@njit(cache=True, nogil=True)
def _leaf_bbox(origins, words, lo, hi):
    """Fold the inclusive index bbox of every set mask bit into lo/hi (int64 (3,) each).

    words: (N, 8) uint64 masks; word x holds row y in byte y, bit z. Per leaf only the extreme
    set x, y and z matter: x from the nonzero words, y from the bytes of their OR, z from the
    OR of those bytes.
    """
    for i in range(words.shape[0]):
        xs = 0
        w = np.uint64(0)
        for x in range(8):
            if words[i, x]:
                xs |= 1 << x
                w |= words[i, x]
        if xs == 0:
            continue
        ys = 0
        zs = 0
        for y in range(8):
            b = np.int64((w >> np.uint64(8 * y)) & np.uint64(255))
            if b:
                ys |= 1 << y
                zs |= b
        for axis, m in ((0, xs), (1, ys), (2, zs)):
            a0 = 0
            while not (m >> a0) & 1:
                a0 += 1
            a1 = 7
            while not (m >> a1) & 1:
                a1 -= 1
            o = np.int64(origins[i, axis])
            lo[axis] = min(lo[axis], o + a0)
            hi[axis] = max(hi[axis], o + a1)


def _bbox(origins, masks_u8, tile_origins, tile_sizes, tile_active):
    lo = np.full(3, _I64_MAX, np.int64)
    hi = np.full(3, -_I64_MAX - 1, np.int64)
    if len(origins):
        _leaf_bbox(np.ascontiguousarray(origins), np.ascontiguousarray(masks_u8).view("<u8"), lo, hi)
    if len(tile_active) and tile_active.any():
        to = tile_origins[tile_active].astype(np.int64)
        ts = tile_sizes[tile_active].astype(np.int64)[:, None]
        lo = np.minimum(lo, to.min(axis=0))
        hi = np.maximum(hi, (to + ts - 1).max(axis=0))
    if lo[0] > hi[0]:
        return np.zeros(3, np.int64), np.full(3, -1, np.int64)
    return lo, hi


def estimate_grid_bytes(n_leaves, value_type, half=False):
    """Peak bytes a full read of one grid allocates, from its leaf count (topology only)."""
    comp, ncomp = codec.VALUE_TYPES.get(value_type, ("<f4", 1))
    stored = (2 if half else np.dtype(comp).itemsize) * ncomp
    per_leaf = 512 * (stored + 4 * ncomp + 4 * ncomp + (4 if ncomp > 1 else 0)) + 64 + 12 + 80
    return int(n_leaves) * per_leaf


class _Reader:
    def __init__(self, path, topology_only, max_bytes):
        self.path = os.fspath(path)
        self.topology_only = topology_only
        self.max_bytes = DEFAULT_MAX_BYTES if max_bytes is None else int(max_bytes)
        self.used_bytes = 0
        self.trees = {}  # unique name -> decoded tree (shared by instances)

    def grid(self, cur, d, version, wanted_tree=True):
        """Parse one grid body at cur.pos (bounded by cur.end). Returns GridData or None (instance
        parent only) and leaves cur at the end of the grid."""
        name = d["display"]
        start = cur.pos
        flags = cur.u32("compression flags")
        if flags & ~7:
            raise cur.error(f"unknown compression flags {flags:#x}", start)
        meta = read_metamap(cur, "grid metadata")
        half = bool(meta.get("is_saved_as_half_float", False))
        xform, map_kind = read_transform(cur)
        vt = d["value_type"]
        et = ElementType(vt, half)
        if d["parent"]:
            tree = self.trees.get(d["parent"])
            if tree is None:
                raise cur.error(f"instance of grid {d['parent']!r}, which was not read before it", start)
            if self.has_offsets and cur.pos != cur.end:  # an instance stores no tree
                raise cur.error(f"instance ends at byte {cur.pos}, its descriptor says {cur.end}")
        else:
            tree = self.tree(cur, flags, et, name, d)
        topo, values, vectors = tree
        lo, hi = _bbox(topo.leaf_origins, topo.leaf_masks, topo.tile_origins, topo.tile_sizes,
                       topo.tile_active)
        leaf_count = int((topo.popc if topo.popc is not None else popcount_rows(topo.leaf_masks)).sum())
        tile_count = 0
        if len(topo.tile_active) and topo.tile_active.any():
            tile_count = int(np.sum(topo.tile_sizes[topo.tile_active].astype(np.int64) ** 3))
        active = leaf_count + tile_count
        expected = meta.get("file_voxel_count")
        if isinstance(expected, int) and expected != active:
            raise cur.error(f"active voxel count {active} differs from the file's "
                            f"file_voxel_count {expected}", start)
        bgv = topo.background.astype(np.float64)

        def mag(a):
            return np.sqrt((a.astype(np.float64) ** 2).sum(axis=-1)) if a.shape[-1] > 1 else a[..., 0]

        self.info[name] = {"map": map_kind, "metadata": meta, "byte_range": (start, cur.end),
                           "unique_name": d["unique"], "instance_of": d["parent"] or None,
                           "leaf_count": len(topo.leaf_origins)}
        return GridData(
            name=name,
            grid_class=_CLASSES.get(str(meta.get("class", "")).lower(), "unknown"),
            value_type=vt, background=float(mag(bgv[None])[0]), file_version=version,
            compression=compression_text(flags), half=half, index_to_world=xform,
            leaf_origins=topo.leaf_origins, leaf_masks=topo.leaf_masks.view("<u8").reshape(-1, 8),
            leaf_values=values, tile_origins=topo.tile_origins,
            tile_sizes=topo.tile_sizes, tile_values=mag(topo.tile_values).astype(np.float32),
            tile_active=topo.tile_active, active_voxels=active, bbox_min=lo, bbox_max=hi,
            leaf_vectors=vectors)

    def tree(self, cur, flags, et, name, d):
        topo = read_tree_topology(cur, flags, et)
        # The descriptor's offsets pin both ends: a grid that parses to other boundaries was
        # misread (e.g. values of the wrong size), however plausible its counts look.
        if self.has_offsets and cur.pos != d["block_pos"]:
            raise cur.error(f"topology ends at byte {cur.pos}, the descriptor's block offset is "
                            f"{d['block_pos']}")
        table = scan_leaves(cur, topo.leaf_masks, flags, et)  # cheap (~2 ms a big file): always
        topo.popc = table["popc"]
        if self.has_offsets and cur.pos != cur.end:
            raise cur.error(f"leaf data ends at byte {cur.pos}, the descriptor's end offset is {cur.end}")
        values = vectors = None
        if not self.topology_only:
            need = estimate_grid_bytes(len(topo.leaf_origins), d["value_type"], et.half)
            if self.used_bytes + need > self.max_bytes:
                raise _OverBudget(VDBFormatError(
                    f"reading needs about {(self.used_bytes + need) / 2**20:.1f} MiB, above the "
                    f"limit of {self.max_bytes / 2**20:.1f} MiB (raise max_bytes to read it)",
                    self.path, name, topo.start))
            self.used_bytes += need
            mags = np.empty((len(topo.leaf_masks), 512), np.float32) if et.ncomp == 3 else None
            out = decode_leaves(cur, topo.leaf_masks, table, flags, et, topo.background, mags)
            if et.ncomp == 1:
                values = out.reshape(-1, 512)
            else:
                vectors = out
                values = mags  # float32 sqrt(x*x + y*y + z*z), computed in the decode pass
        tree = (topo, values, vectors)
        self.trees[d["unique"]] = tree
        return tree

    def read(self, grids, allow_fallback):
        buf = _load(self.path)
        try:
            return self._read(buf, grids, allow_fallback)
        finally:
            _close(buf)

    def _read(self, buf, grids, allow_fallback):
        cur = Cursor(buf, self.path)
        version, lib, self.has_offsets, fmeta, count = _header(cur)
        result = VDBFile(self.path, version, lib, metadata=fmeta)
        self.info = result.grid_info
        if version < NATIVE_MIN_VERSION:
            return self._fallback(result, grids, allow_fallback,
                                  f"file format version {version} predates 222")
        wanted = None if grids is None else ([grids] if isinstance(grids, str) else list(grids))
        descs = []
        seen = {}
        for i in range(count):
            d = _descriptor(cur, version)
            k = seen.get(d["name"], 0)
            seen[d["name"]] = k + 1
            d["display"] = cur.grid = d["name"] if k == 0 else f"{d['name']}[{k}]"
            d["last"] = i == count - 1
            if self.has_offsets:
                if not (cur.pos <= d["grid_pos"] <= d["end_pos"] <= len(buf)):
                    raise cur.error(f"grid offsets {d['grid_pos']}..{d['end_pos']} lie outside the "
                                    f"file of {len(buf)} bytes", d["at"])
                cur.pos = d["end_pos"]  # the next descriptor follows this grid
            else:
                # Nothing pins a stream grid's end but the next descriptor and the end of the file:
                # a grid misread to a wrong length shows up there, so blame it.
                if not d["type"].startswith("Tree_"):
                    raise VDBFormatError(
                        f"garbled grid descriptor (type {d['type'][:40]!r})"
                        + (f": grid {descs[-1]['display']!r} before it was misread" if descs else ""),
                        self.path, descs[-1]["display"] if descs else None, d["at"])
                self._one(cur, d, version, result, wanted)  # parse it to find the next one
            descs.append(d)
        if self.has_offsets:
            self._offset_grids(buf, descs, version, result, wanted)
        elif descs and not descs[-1].get("unparsed") and cur.pos != len(buf):
            raise VDBFormatError(f"{len(buf) - cur.pos} bytes follow the last grid: a grid was "
                                 "misread", self.path, descs[-1]["display"], cur.pos)
        self._check_wanted(wanted, descs, result)
        return result

    def _selected(self, d, wanted):
        # A plain name picks its first grid only; duplicates are asked for as name[1], name[2].
        return wanted is None or d["display"] in wanted or d["unique"] in wanted

    def _offset_grids(self, buf, descs, version, result, wanted):
        by_unique = {d["unique"]: d for d in descs}
        needed = set()
        for d in descs:
            if self._selected(d, wanted):
                needed.add(d["unique"])
                p = d["parent"]
                while p and p in by_unique and p not in needed:  # instances need their parent's tree
                    needed.add(p)
                    p = by_unique[p]["parent"]
        for d in descs:
            if d["unique"] not in needed:
                continue
            cur = Cursor(buf, self.path, d["grid_pos"], d["end_pos"], d["display"], arr=None)
            self._one(cur, d, version, result, wanted)

    def _one(self, cur, d, version, result, wanted):
        """Read one grid into result.grids, or list it in result.skipped with the reason.

        With grid offsets a grid that does not parse consistently is skipped with a warning and
        the others are still read; without them the grids after it cannot be located, so the file
        is refused. A grid asked for by name is never skipped: it reads or raises.
        """
        selected = self._selected(d, wanted)
        requested = wanted is not None and selected
        name = d["display"]
        try:
            d["value_type"] = _value_type(d["type"])
            if d["parent"] and d["parent"] not in self.trees:
                raise _Unsupported(f"instance of {d['parent']!r}, which could not be read")
            if codec.blosc is None:
                raise _Unsupported("the blosc module is not installed")
            g = self.grid(cur, d, version)
        except _Unsupported as e:
            reason = str(e.args[0])
            if requested:
                raise VDBFormatError(f"grid cannot be read: {reason}", self.path, name, cur.pos) from None
            if not self.has_offsets and not self._skim(cur, d, reason):  # find where it ends
                if not d["last"]:
                    raise VDBFormatError(f"grid cannot be read ({reason}) and the file has no grid "
                                         "offsets, so the grids after it cannot be located",
                                         self.path, name, cur.pos) from None
                d["unparsed"] = True  # the last grid: nothing after it to find
            if selected:
                result.skipped.append((name, reason))
            return
        except _OverBudget as e:
            raise e.args[0] from None
        except _GRID_ERRORS as e:
            err = e if isinstance(e, VDBFormatError) else \
                VDBFormatError(f"malformed grid: {type(e).__name__}: {e}", self.path, name, cur.pos)
            if not self.has_offsets or requested:
                raise VDBFormatError(err.reason, self.path, name, err.offset) from e
            if "NonlinearFrustumMap" in err.reason:  # unsupported, not broken
                result.skipped.append((name, err.reason))
                return
            reason = f"malformed, not read: {err.reason} (byte offset {err.offset})"
            warnings.warn(f"{self.path}: grid {name!r} {reason}; the other grids were read",
                          stacklevel=6)  # the caller of read_vdb
            if selected:
                result.skipped.append((name, reason))
            return
        if selected:
            result.grids.append(g)

    def _skim(self, cur, d, reason):
        """Parse a grid we do not read just far enough to find its end (stream files only).

        False when its layout is unknown; raises when it does not parse."""
        at = cur.pos
        vt = _tree_value_type(d["type"])
        if vt not in codec.VALUE_TYPES and vt not in codec.LAYOUT_TYPES and not d["parent"]:
            return False
        try:
            flags = cur.u32("compression flags")
            meta = read_metamap(cur, "grid metadata")
            read_transform(cur)
            if d["parent"]:
                return True  # an instance stores no tree
            et = ElementType(vt, bool(meta.get("is_saved_as_half_float", False)) and vt in codec.VALUE_TYPES)
            topo = read_tree_topology(cur, flags, et)
            if vt == "bool":  # each leaf: value mask, origin, value bit mask
                n = len(topo.leaf_masks)
                leaves = cur.array(np.uint8, n * 140, "bool leaf buffers").reshape(n, 140)
                if not np.array_equal(leaves[:, :64], topo.leaf_masks):
                    raise cur.error("a bool leaf's buffer mask differs from its topology mask", at)
            else:
                scan_leaves(cur, topo.leaf_masks, flags, et)
            return True
        except _GRID_ERRORS as e:
            why = e.reason if isinstance(e, VDBFormatError) else f"{type(e).__name__}: {e}"
            raise VDBFormatError(f"grid cannot be read ({reason}) nor stepped over ({why}); the "
                                 "file has no grid offsets, so the grids after it cannot be located",
                                 self.path, d["display"], at) from None

    def _check_wanted(self, wanted, descs, result):
        if wanted is None:
            return
        names = {n for d in descs for n in (d["display"], d["unique"])}
        for w in wanted:
            if w not in names:
                listed = ", ".join(repr(d["display"]) for d in descs) or "none"
                raise VDBFormatError(f"no grid named {w!r} (grids: {listed})", self.path, w, None)

    def _fallback(self, result, grids, allow_fallback, why):
        if not allow_fallback:
            raise VDBFormatError(f"{why}; the native reader cannot read it (fallback disabled)",
                                 self.path, None, 8)
        from .fallback import read_with_binding
        warnings.warn(f"{self.path}: {why}; reading through the openvdb binding (slow)",
                      stacklevel=3)
        return read_with_binding(self.path, result, grids, self.topology_only, self.max_bytes)


def read_vdb(path, grids=None, *, topology_only=False, max_bytes=None, allow_fallback=True):
    """Read the grids of a .vdb file (all, or those named in ``grids``) into GridData.

    ``grids``: a name or a list of names. A name selects exactly one grid: ``"density"`` the first
    grid called density, ``"density[1]"`` the second, ``"density[2]"`` the third (the names the
    result reports). An unknown name raises VDBFormatError listing the grids there are.
    Grids that cannot be read are listed in ``.skipped`` as (name, reason): int, bool and point
    grids, and, in files with grid offsets, a malformed grid (also warned about) whose
    neighbours are still read. A requested grid that cannot be read, a malformed grid in a file
    without grid offsets, or anything else wrong raises VDBFormatError (file, grid and byte offset
    in the message).
    """
    try:
        return _Reader(path, topology_only, max_bytes).read(grids, allow_fallback)
    except VDBFormatError:
        raise
    except (MemoryError, OverflowError, ValueError, IndexError, KeyError, TypeError,
            UnicodeError, struct_error()) as e:  # last line of defence: never a raw traceback
        raise VDBFormatError(f"malformed file: {type(e).__name__}: {e}", path) from e


def struct_error():
    import struct
    return struct.error


def check_header(path):
    """Raise VDBFormatError unless ``path`` is a readable file that starts as a .vdb file does
    (magic number, a supported version, a sane grid count). Plain Python, nothing compiled: what
    a command can refuse before it starts Blender."""
    buf = _load(path)
    try:
        _header(Cursor(buf, os.fspath(path)))
    except VDBFormatError:
        raise
    except (ValueError, IndexError, struct_error()) as e:
        raise VDBFormatError(f"malformed file: {type(e).__name__}: {e}", os.fspath(path)) from e
    finally:
        _close(buf)


def read_topology(path, grids=None, **kw):
    """Origins, masks, tiles, transforms and counts without decompressing leaf values."""
    return read_vdb(path, grids, topology_only=True, **kw)


def estimate_bytes(path_or_file, grids=None):
    """Bytes a full read would allocate, from the topology alone."""
    f = path_or_file if isinstance(path_or_file, VDBFile) else read_topology(path_or_file, grids)
    return sum(estimate_grid_bytes(len(g.leaf_origins), g.value_type, g.half) for g in f.grids)
