"""Describe a .vdb file for `gaussvdb info`: one dict per grid, and a text table."""

import os

import numpy as np

from .codec import COMPRESS_BLOSC
from .errors import VDBFormatError
from .reader import _close, _descriptor, _header, _load, read_topology
from .stream import Cursor


def uses_blosc(path):
    """Whether a grid of ``path`` is blosc-compressed (the reader compiles its decoders per
    compression), from the header and each grid's first word: plain Python, nothing compiled.
    True where it cannot tell (no grid offsets, a malformed file)."""
    try:
        buf = _load(path)
    except VDBFormatError:
        return True
    try:
        cur = Cursor(buf, os.fspath(path))
        version, _lib, has_offsets, _meta, count = _header(cur)
        flags = 0 if has_offsets else COMPRESS_BLOSC
        for _ in range(count if has_offsets else 0):  # each descriptor, then its grid
            d = _descriptor(cur, version)
            flags |= int(np.frombuffer(buf, "<u4", 1, d["grid_pos"])[0])
            cur.pos = d["end_pos"]
        return bool(flags & COMPRESS_BLOSC)
    except (VDBFormatError, ValueError, IndexError):
        return True
    finally:
        _close(buf)


def describe(path):
    f = read_topology(path)
    grids = []
    for g in f.grids:
        m = g.index_to_world
        empty = g.active_voxels == 0
        corners = np.array([[g.bbox_min[0], g.bbox_min[1], g.bbox_min[2], 1.0],
                            [g.bbox_max[0], g.bbox_max[1], g.bbox_max[2], 1.0]])
        world = (m @ corners.T).T[:, :3]
        info = f.grid_info[g.name]
        grids.append({
            "name": g.name, "class": g.grid_class, "value_type": g.value_type,
            "active_voxels": int(g.active_voxels), "leaves": int(len(g.leaf_origins)),
            "tiles": int(len(g.tile_sizes)), "active_tiles": int(g.tile_active.sum()),
            "voxel_size": [float(x) for x in np.linalg.norm(m[:3, :3], axis=0)],
            "index_to_world": m.tolist(), "map": info["map"],
            "bbox_index": None if empty else [g.bbox_min.tolist(), g.bbox_max.tolist()],
            "bbox_world": None if empty else [world.min(0).tolist(), world.max(0).tolist()],
            "compression": g.compression, "half": bool(g.half), "file_version": int(g.file_version),
            "background": float(g.background), "instance_of": info["instance_of"],
        })
    return {"file": str(path), "file_version": int(f.version),
            "library_version": list(f.library_version), "grids": grids,
            "skipped": [{"name": n, "reason": r} for n, r in f.skipped]}


def format_text(d):
    lines = [f"{d['file']}: VDB file version {d['file_version']}, library "
             f"{'.'.join(map(str, d['library_version']))}, {len(d['grids'])} grid(s)"]
    for g in d["grids"]:
        vs = ", ".join(f"{v:.6g}" for v in g["voxel_size"])
        rows = [("class", g["class"]), ("value type", g["value_type"] + (" (half)" if g["half"] else "")),
                ("active voxels", f"{g['active_voxels']:,}"), ("leaves", f"{g['leaves']:,}"),
                ("tiles", f"{g['tiles']:,} ({g['active_tiles']:,} active)"),
                ("bbox index", g["bbox_index"] or "empty"),
                ("bbox world", "empty" if not g["bbox_world"] else
                 " .. ".join("(" + ", ".join(f"{v:.6g}" for v in c) + ")" for c in g["bbox_world"])),
                ("voxel size", f"{vs} ({g['map']})"), ("compression", g["compression"]),
                ("file version", g["file_version"])]
        if g["instance_of"]:
            rows.append(("instance of", g["instance_of"]))
        lines.append(f"\n  grid {g['name']!r}")
        lines += [f"    {k:<14} {v}" for k, v in rows]
    for s in d["skipped"]:
        lines.append(f"\n  skipped {s['name']!r}: {s['reason']}")
    return "\n".join(lines)
