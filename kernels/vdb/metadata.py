"""MetaMap parsing: known types decoded, others skipped by their declared size."""

import struct

import numpy as np

_SCALAR = {"bool": "<?", "int32": "<i", "int64": "<q", "float": "<f", "double": "<d",
           "vec3i": "<3i", "vec3s": "<3f", "vec3d": "<3d", "vec2i": "<2i", "vec2s": "<2f",
           "vec2d": "<2d"}


def read_metamap(cur, what="metadata"):
    at = cur.pos
    count = cur.u32(what + " count")
    if count * 12 > cur.remaining():  # every entry needs three u32 lengths at least
        raise cur.error(f"absurd {what} entry count {count}", at)
    meta = {}
    for _ in range(count):
        name = cur.string(what + " name", limit=1 << 16)
        tname = cur.string(what + " type", limit=1 << 10)
        size = cur.u32(what + " size")
        start = cur.pos
        raw = bytes(cur.bytes(size, f"{what} value {name!r}"))
        if tname == "string":
            meta[name] = raw.decode("utf-8", "replace")
        elif tname in _SCALAR and struct.calcsize(_SCALAR[tname]) == size:
            v = struct.unpack(_SCALAR[tname], raw)
            meta[name] = v[0] if len(v) == 1 else tuple(v)
        else:
            meta[name] = None  # unknown type: kept as present, value skipped
        cur.pos = start + size
    return meta


def as_bbox(meta):
    lo, hi = meta.get("file_bbox_min"), meta.get("file_bbox_max")
    if isinstance(lo, tuple) and isinstance(hi, tuple):
        return np.array(lo, np.int64), np.array(hi, np.int64)
    return None
