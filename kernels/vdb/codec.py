"""The per-node values codec (readCompressedValues in OpenVDB io/Compression.h) and chunk decompression."""

import zlib

import numpy as np

try:  # Blender ships no blosc for Python; without it blosc grids go to the fallback.
    import blosc
except ImportError:  # pragma: no cover - depends on the environment
    blosc = None

COMPRESS_ZIP = 1
COMPRESS_ACTIVE_MASK = 2
COMPRESS_BLOSC = 4

# Metadata codes written before each node's values (v >= 222).
NO_MASK_OR_INACTIVE_VALS = 0
NO_MASK_AND_MINUS_BG = 1
NO_MASK_AND_ONE_INACTIVE_VAL = 2
MASK_AND_NO_INACTIVE_VALS = 3
MASK_AND_ONE_INACTIVE_VAL = 4
MASK_AND_TWO_INACTIVE_VALS = 5
NO_MASK_AND_ALL_VALS = 6

# value type name -> (component dtype, components); half storage uses <f2 with the same components.
VALUE_TYPES = {
    "float": ("<f4", 1),
    "double": ("<f8", 1),
    "vec3s": ("<f4", 3),
    "vec3d": ("<f8", 3),
}

# Value types parsed only to step over their grids (a stream file has no offsets to jump by): the
# tree layout and codec are the same, only the value size differs. Bool leaves hold bit masks.
LAYOUT_TYPES = {"int32": ("<i4", 1), "int64": ("<i8", 1), "bool": ("u1", 1)}

HALF_LUT = np.arange(65536, dtype=np.uint16).view(np.float16).astype(np.float32)


def compression_text(flags):
    parts = []
    if flags & COMPRESS_BLOSC:
        parts.append("blosc")
    elif flags & COMPRESS_ZIP:
        parts.append("zip")
    if flags & COMPRESS_ACTIVE_MASK:
        parts.append("active mask")
    return " + ".join(parts) if parts else "none"


class ElementType:
    """How one value of a grid is stored: full-precision dtype, stored dtype (half or not), components."""

    def __init__(self, value_type, half):
        comp, self.ncomp = VALUE_TYPES.get(value_type) or LAYOUT_TYPES[value_type]
        self.full = np.dtype(comp)
        self.stored = np.dtype("<f2") if half else self.full
        self.half = half
        self.full_size = self.full.itemsize * self.ncomp
        self.stored_size = self.stored.itemsize * self.ncomp


def check_blosc_header(cur, start, size, nbytes):
    """Validate a blosc1 frame header before handing it to C (guards the destination size)."""
    if size < 16:
        raise cur.error(f"blosc chunk of {size} bytes is shorter than its header", start)
    h = np.frombuffer(cur.buf, "<u4", 3, start + 4)
    if int(h[0]) != nbytes or int(h[2]) != size:
        raise cur.error(f"blosc chunk header says {int(h[0])} bytes from {int(h[2])}, "
                        f"expected {nbytes} from {size}", start)


def decompress(cur, start, size, nbytes, flags):
    """Decompress the chunk buf[start:start+size] into exactly ``nbytes`` bytes."""
    chunk = cur.buf[start:start + size]
    if flags & COMPRESS_BLOSC:
        if blosc is None:
            raise cur.error("grid is blosc-compressed and the blosc module is not installed", start)
        check_blosc_header(cur, start, size, nbytes)
        try:
            out = blosc.decompress(chunk)
        except Exception as e:  # blosc raises assorted types on corrupt frames
            raise cur.error(f"corrupt blosc chunk: {e}", start) from None
    else:
        d = zlib.decompressobj()
        try:
            out = d.decompress(chunk, nbytes + 1)  # bounded: never more than expected + 1
        except zlib.error as e:
            raise cur.error(f"corrupt zip chunk: {e}", start) from None
    if len(out) != nbytes:
        raise cur.error(f"chunk decompressed to {len(out)} bytes, expected {nbytes}", start)
    return out


def read_data(cur, count, et, flags):
    """Read ``count`` stored values (readData / HalfReader) -> float array (count, ncomp) full dtype."""
    nbytes = count * et.stored_size
    if et.half and count < 1:
        return np.zeros((0, et.ncomp), et.full)  # half writers emit nothing for no values
    if flags & (COMPRESS_BLOSC | COMPRESS_ZIP):
        size = cur.i64("chunk size")
        if size <= 0:
            if -size != nbytes:
                raise cur.error(f"raw chunk of {-size} bytes, expected {nbytes}", cur.pos - 8)
            raw = cur.bytes(nbytes, "raw chunk")
        else:
            start = cur.pos
            cur.skip(size, "compressed chunk")
            raw = decompress(cur, start, size, nbytes, flags)
    else:
        raw = cur.bytes(nbytes, "values")
    a = np.frombuffer(raw, et.stored, count * et.ncomp)
    return a.astype(et.full).reshape(count, et.ncomp)


_POPC8 = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).sum(axis=1).astype(np.int64)


def popcount_bytes(mask_u8):
    """Set bits in a uint8 mask array."""
    return int(_POPC8[mask_u8].sum())


def read_node_parts(cur, nslots, nactive, flags, et):
    """Read one node's values codec without expanding it.

    ``nactive`` is the popcount of the node's value mask. Returns (code, val0, val1, sel, data):
    val0/val1 the stored inactive values (full dtype, or None when the code implies them), sel the
    selection mask bytes (or None) and data the (count, ncomp) stored values in full dtype.
    """
    at = cur.pos
    code = cur.u8("node metadata code")
    if code > 6:
        raise cur.error(f"unknown node metadata code {code}", at)
    val0 = val1 = None
    if code in (NO_MASK_AND_ONE_INACTIVE_VAL, MASK_AND_ONE_INACTIVE_VAL, MASK_AND_TWO_INACTIVE_VALS):
        val0 = cur.array(et.full, et.ncomp, "inactive value").copy()
        if code == MASK_AND_TWO_INACTIVE_VALS:
            val1 = cur.array(et.full, et.ncomp, "inactive value").copy()
    sel = None
    if code in (MASK_AND_NO_INACTIVE_VALS, MASK_AND_ONE_INACTIVE_VAL, MASK_AND_TWO_INACTIVE_VALS):
        sel = cur.array(np.uint8, nslots // 8, "selection mask")
    mask_comp = bool(flags & COMPRESS_ACTIVE_MASK)
    count = nactive if (mask_comp and code != NO_MASK_AND_ALL_VALS) else nslots
    data = read_data(cur, count, et, flags)
    return code, val0, val1, sel, data


def inactive_values(code, val0, val1, background, et):
    """The two inactive values a node's code selects between (full dtype, (ncomp,) each)."""
    bg = np.asarray(background, et.full).reshape(et.ncomp)
    if val0 is None:
        val0 = bg if code == NO_MASK_OR_INACTIVE_VALS else -bg
    if val1 is None:
        val1 = bg
    return val0, val1
