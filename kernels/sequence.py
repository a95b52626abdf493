"""Numbered .vdb sequences (one file per frame): the pure parts, no Blender.

    pat = parse("cache/fluid_data_0001.vdb")      # or "cache/fluid_data_####.vdb"
    pat.path(12)                                   # 'cache/fluid_data_0012.vdb'
    pat.scan()                                     # frame numbers on disk, sorted
    map_frame(scene_frame, start, offset, duration, "PING_PONG")  # -> file number or None

Frame numbers follow Blender's Volume sequences (``BKE_volume_frame_number``): scene frame
``start`` shows the sequence's first frame, ``offset`` is added to the number after the mode
(Clip, Extend, Repeat, Ping-Pong) maps it into 1..duration. ``LRUCache`` holds converted frames
within a memory budget; ``write_cache``/``read_cache`` keep a frame's compact encoding on disk,
keyed by a fingerprint of the source file so a changed file is converted again.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import socket
import uuid
import zlib
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from .convert_options import DEFAULTS

MODES = ("CLIP", "EXTEND", "REPEAT", "PING_PONG")
CACHE_VERSION = 1
_HASHES = re.compile(r"^(.*?)(#+)(.*)$")
_DIGITS = re.compile(r"^(.*?)(\d+)(\D*)$")  # the last run of digits of the stem (Blender's rule)


@dataclass(frozen=True)
class Pattern:
    directory: str
    head: str  # file name before the number
    digits: int  # zero padding (numbers with more digits are written in full)
    tail: str  # after the number: the rest of the stem and the extension

    def name(self, number: int) -> str:
        return f"{self.head}{int(number):0{self.digits}d}{self.tail}"

    def path(self, number: int) -> str:
        return os.path.join(self.directory, self.name(number))

    @property
    def text(self) -> str:
        """The pattern with '#' for the digits: 'fluid_data_####.vdb'."""
        return self.head + "#" * self.digits + self.tail

    def number(self, filename: str):
        """The frame number of ``filename`` when it belongs to this sequence, else None."""
        if not (filename.startswith(self.head) and filename.endswith(self.tail)):
            return None
        mid = filename[len(self.head):len(filename) - len(self.tail)]
        # 'x_12.vdb' and 'x_0012.vdb' are not frames of one padding; wider numbers are
        if not mid.isdigit() or len(mid) < self.digits or (len(mid) > self.digits and mid[0] == "0"):
            return None
        return int(mid)

    def scan(self) -> list:
        """The frame numbers present on disk, ascending."""
        try:
            names = os.listdir(self.directory or ".")
        except OSError:
            return []
        found = (self.number(n) for n in names)
        return sorted(n for n in found if n is not None)


def parse(path):
    """The Pattern of a numbered file ('smoke_0007.vdb') or a '#' pattern ('smoke_####.vdb');
    None when the name holds no number."""
    path = os.fspath(path)
    directory, name = os.path.split(path)
    m = _HASHES.match(name)
    if m:
        return Pattern(directory, m.group(1), len(m.group(2)), m.group(3))
    stem, ext = os.path.splitext(name)
    m = _DIGITS.match(stem)
    if not m:
        return None
    return Pattern(directory, m.group(1), len(m.group(2)), m.group(3) + ext)


def frame_number(path):
    pat = parse(path)
    return None if pat is None or "#" in os.path.basename(path) else pat.number(os.path.basename(path))


def group(paths) -> list:
    """Selected files -> [(Pattern or None, [frame numbers] or [path])]: files of one numbered
    sequence together (in the order first seen), a file without a number alone."""
    out, index = [], {}
    for p in paths:
        pat, num = parse(p), frame_number(p)
        if pat is None or num is None:
            out.append((None, [p]))
            continue
        key = (os.path.normcase(os.path.abspath(pat.directory)), pat.head, pat.tail)
        if key not in index:
            index[key] = len(out)
            out.append((pat, []))
        out[index[key]][1].append(num)
    return [(pat, sorted(set(v)) if pat is not None else v) for pat, v in out]


def parse_frames(text: str) -> list:
    """'35-50' / '7' / '1-3,8' -> sorted distinct frame numbers; ValueError naming the bad part."""
    frames = set()
    for part in (p.strip() for p in str(text).split(",")):
        m = re.fullmatch(r"(-?\d+)(?:\s*-\s*(-?\d+))?", part)
        if not m:
            raise ValueError(f"{part!r} is not a frame or range like 35-50")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) is not None else a
        if b < a:
            raise ValueError(f"range {part!r} ends before it starts")
        frames.update(range(a, b + 1))
    return sorted(frames)


# -- timeline -> file number (Blender's Volume sequence rules) -----------------------------------
def map_frame(frame: int, start: int, offset: int, duration: int, mode: str = "REPEAT"):
    """The file number scene ``frame`` shows, or None (Clip outside the range, no duration)."""
    if duration <= 0:
        return None
    n = int(frame) - int(start) + 1  # time starts at 1
    if mode == "CLIP":
        if n < 1 or n > duration:
            return None
    elif mode == "EXTEND":
        n = min(max(n, 1), duration)
    elif mode == "REPEAT":
        n %= duration
        if n == 0:
            n = duration
    elif mode == "PING_PONG":
        period = 2 * duration - 2
        if period <= 0:  # one frame: nothing to bounce between
            n = 1
        else:
            n %= period
            if n == 0:
                n = period
            if n > duration:
                n = 2 * duration - n
    else:
        raise ValueError(f"unknown sequence mode {mode!r}; choose from {', '.join(MODES)}")
    return n + int(offset)  # after the mode, so a loop over files 100-110 works


def held_frame(number, present):
    """The frame shown for file ``number``: itself when present, else the last present one
    before it (a missing frame holds the previous), else None."""
    if number is None or not present:
        return None
    i = int(np.searchsorted(present, number, side="right"))
    return present[i - 1] if i > 0 else None


def union_stats(items):
    """One voxel_stats dict over several frames' (min of mins, max of maxes, counts summed);
    None when none is known."""
    items = [s for s in items if s and s.get("voxels")]
    if not items:
        return None
    pmins = [s["positive_min"] for s in items if s.get("positive_min") is not None]
    return {"min": min(s["min"] for s in items), "max": max(s["max"] for s in items),
            "positive_min": min(pmins) if pmins else None,
            "nonpositive": sum(int(s.get("nonpositive", 0)) for s in items),
            "voxels": sum(int(s["voxels"]) for s in items)}


def frame_figures(path, wanted=None) -> dict:
    """One frame's part of a sequence import, read once: {"names": its grids in file order,
    "grids": {name: {"values": voxel_stats or None (level sets), "box": leaf box (lo, hi)}}}
    for the scalar grids of ``wanted`` (None: all) holding voxels, or {"error": reason} when the
    file cannot be read. Plain values: a cluster task returns them to the driver."""
    from . import pipeline, vdb
    from .render.scene.transfer import voxel_stats

    try:
        names = [g.name for g in vdb.read_topology(path).grids]
        keep = [g for g in names if wanted is None or g in wanted]
        f = vdb.read_vdb(path, keep) if keep else None
    except (vdb.VDBFormatError, OSError, MemoryError) as err:
        return {"error": getattr(err, "reason", None) or str(err)}
    grids = {}
    for g in f.grids if f is not None else ():
        if g.value_type.startswith("vec3") or not g.active_voxels:
            continue
        grids[g.name] = {"values": None if g.grid_class == "level_set" else voxel_stats(g),
                         "box": pipeline.leaf_box(g)}
    return {"names": names, "grids": grids}


# -- converted frames in memory -------------------------------------------------------------------
class LRUCache:
    """Values with a size in bytes, the least recently used evicted once the total passes the
    budget (the newest entry always stays, even when it alone is larger)."""

    def __init__(self, budget_bytes: int):
        self.budget = int(budget_bytes)
        self.items = OrderedDict()  # key -> (value, nbytes)
        self.nbytes = 0
        self.hits = self.misses = self.evictions = 0

    def __len__(self):
        return len(self.items)

    def __contains__(self, key):
        return key in self.items

    def get(self, key, default=None):
        item = self.items.get(key)
        if item is None:
            self.misses += 1
            return default
        self.items.move_to_end(key)
        self.hits += 1
        return item[0]

    def put(self, key, value, nbytes: int):
        old = self.items.pop(key, None)
        if old is not None:
            self.nbytes -= old[1]
        self.items[key] = (value, int(nbytes))
        self.nbytes += int(nbytes)
        self._trim()

    def set_budget(self, budget_bytes: int):
        self.budget = int(budget_bytes)
        self._trim()

    def clear(self):
        self.items.clear()
        self.nbytes = 0

    def _trim(self):
        while self.nbytes > self.budget and len(self.items) > 1:
            _, (_, n) = self.items.popitem(last=False)
            self.nbytes -= n
            self.evictions += 1


# -- converted frames on disk (the compact encoding) ----------------------------------------------
def fingerprint(path, block=1 << 16) -> str:
    """Size and CRC32 of the first and last 64 KiB: changes when a frame is re-baked, survives
    copying to another machine (unlike a modification time)."""
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        crc = zlib.crc32(f.read(block))
        if size > block:
            f.seek(max(block, size - block))
            crc = zlib.crc32(f.read(block), crc)
    return f"{size}-{crc:08x}"


def cache_name(frame_path, grid, lod, options=DEFAULTS) -> str:
    """The cache file of one frame's grid at one LOD converted with the ConvertOptions
    ``options`` (the object settings they hold): '<frame stem>.<grid>.<lod>[.opts].npz'."""
    stem = os.path.splitext(os.path.basename(frame_path))[0]
    opts = "".join(("" if options.weights == DEFAULTS.weights else f".{options.weights}",
                    "" if options.level_set_band else ".fullband",
                    ".mag" if options.vector_magnitude else ""))
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", grid)
    return f"{stem}.{safe}.{lod}{opts}.npz"


def temporary_name(path) -> str:
    """A name beside ``path`` no other process uses (host, process, random part), to write to
    and then rename over ``path``; the umask's permissions, unlike mkstemp's 0600."""
    host = re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname())[:32]
    return f"{path}.{host}-{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp"


def write_cache(path, enc: dict, meta: dict):
    """Write the encoding and its metadata (JSON) atomically (render-farm nodes may share the
    folder: a reader never sees half a file)."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    meta = {**meta, "cache_version": CACHE_VERSION}
    # a name of its own, created exclusively: two nodes writing one frame (same pid on two
    # hosts) never share a temporary file; the last rename wins, whole
    tmp = temporary_name(path)
    try:
        with open(tmp, "xb") as f:
            np.savez(f, **enc, cache_meta=np.frombuffer(json.dumps(meta).encode(), np.uint8))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def read_cache(path, source_fingerprint: str):
    """(encoding dict, metadata) of a cache file made from the same source file, else None."""
    try:
        with np.load(path) as z:
            data = {k: z[k] for k in z.files}
        meta = json.loads(bytes(data.pop("cache_meta")).decode())
    except (OSError, ValueError, KeyError, EOFError, zlib.error):
        return None
    if meta.get("cache_version") != CACHE_VERSION or meta.get("fingerprint") != source_fingerprint:
        return None
    return data, meta


def write_frame(cache_file, gset, values, source_path, grid, lod):
    """One frame's cache file: the compact encoding of its Gaussians (None: the grid has no
    voxels in this frame, kept as a marker) and its voxel figures. The add-on and
    `./gaussvdb convert --cache-dir` both write it; returns the bytes written."""
    from .lod import encode_compact

    meta = {"fingerprint": fingerprint(source_path), "source": os.path.basename(source_path),
            "grid": grid, "lod": lod, "values": values, "empty": gset is None}
    write_cache(cache_file, {} if gset is None else encode_compact(gset), meta)
    return os.path.getsize(cache_file)


def read_frame(cache_file, source_path):
    """(GaussianSet or None for an empty frame, voxel figures) from a cache file made from this
    very source file; None when there is none (or it is stale or broken)."""
    from .lod import decode_compact

    if not os.path.isfile(cache_file):
        return None
    found = read_cache(cache_file, fingerprint(source_path))
    if found is None:
        return None
    enc, meta = found
    return (None if meta.get("empty") else decode_compact(enc)), meta.get("values")
