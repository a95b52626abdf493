"""MetaMap parsing: known types decoded, others skipped by their declared size."""

import struct

_SCALAR = {"bool": "<?", "int32": "<i", "int64": "<q", "float": "<f", "double": "<d",
           "vec3i": "<3i", "vec3s": "<3f", "vec3d": "<3d", "vec2i": "<2i", "vec2s": "<2f",
           "vec2d": "<2d"}


_U32 = struct.Struct("<I")
_UNPACK = {k: (struct.Struct(v), struct.calcsize(v)) for k, v in _SCALAR.items()}


def read_metamap(cur, what="metadata"):
    at = cur.pos
    count = cur.u32(what + " count")
    if count * 12 > cur.remaining():  # every entry needs three u32 lengths at least
        raise cur.error(f"absurd {what} entry count {count}", at)
    meta = {}
    buf, pos, end = cur.buf, cur.pos, cur.end
    u32 = _U32.unpack_from
    try:
        for _ in range(count):
            strings = []
            for label, limit in (("name", 1 << 16), ("type", 1 << 10)):
                if end - pos < 4:
                    raise cur.error(f"truncated {what} {label} length: need 4 bytes, "
                                    f"{end - pos} left", pos)
                n = u32(buf, pos)[0]
                pos += 4
                if n > limit:
                    raise cur.error(f"absurd {what} {label} length {n}", pos - 4)
                if n > end - pos:
                    raise cur.error(f"truncated {what} {label}: need {n} bytes, {end - pos} left", pos)
                strings.append(bytes(buf[pos:pos + n]).decode("utf-8", "replace"))
                pos += n
            name, tname = strings
            if end - pos < 4:
                raise cur.error(f"truncated {what} size: need 4 bytes, {end - pos} left", pos)
            size = u32(buf, pos)[0]
            pos += 4
            if size > end - pos:
                raise cur.error(f"truncated {what} value {name!r}: need {size} bytes, "
                                f"{end - pos} left", pos)
            if tname == "string":
                meta[name] = bytes(buf[pos:pos + size]).decode("utf-8", "replace")
            else:
                fmt = _UNPACK.get(tname)
                if fmt is not None and fmt[1] == size:
                    v = fmt[0].unpack_from(buf, pos)
                    meta[name] = v[0] if len(v) == 1 else tuple(v)
                else:
                    meta[name] = None  # unknown type: kept as present, value skipped
            pos += size
    finally:
        cur.pos = pos
    return meta
