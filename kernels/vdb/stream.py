"""A bounded little-endian cursor over the file bytes: every read is checked before it happens."""

import struct

import numpy as np

from .errors import VDBFormatError

_U32 = struct.Struct("<I")
_I32 = struct.Struct("<i")
_I64 = struct.Struct("<q")


class Cursor:
    """Reads from ``buf[pos:end]``; ``end`` can be narrowed to one grid's byte range."""

    __slots__ = ("buf", "arr", "pos", "end", "path", "grid")

    def __init__(self, buf, path, pos=0, end=None, grid=None, arr=None):
        self.buf = buf
        self.arr = np.frombuffer(buf, np.uint8) if arr is None else arr
        self.pos = pos
        self.end = len(buf) if end is None else end
        self.path = path
        self.grid = grid

    def error(self, message, offset=None):
        return VDBFormatError(message, self.path, self.grid, self.pos if offset is None else offset)

    def remaining(self):
        return self.end - self.pos

    def need(self, n, what="data"):
        if n < 0 or n > self.end - self.pos:
            raise self.error(f"truncated {what}: need {n} bytes, {self.end - self.pos} left")

    def skip(self, n, what="data"):
        self.need(n, what)
        self.pos += n

    def bytes(self, n, what="data"):
        self.need(n, what)
        p = self.pos
        self.pos = p + n
        return self.buf[p:p + n]

    def u8(self, what="byte"):
        self.need(1, what)
        v = self.buf[self.pos]
        self.pos += 1
        return v

    def u32(self, what="u32"):
        self.need(4, what)
        v = _U32.unpack_from(self.buf, self.pos)[0]
        self.pos += 4
        return v

    def i32(self, what="i32"):
        self.need(4, what)
        v = _I32.unpack_from(self.buf, self.pos)[0]
        self.pos += 4
        return v

    def i64(self, what="i64"):
        self.need(8, what)
        v = _I64.unpack_from(self.buf, self.pos)[0]
        self.pos += 8
        return v

    def array(self, dtype, count, what="array"):
        """A read-only numpy view of ``count`` items (no copy)."""
        dt = np.dtype(dtype)
        self.need(count * dt.itemsize, what)
        a = np.frombuffer(self.buf, dt, count, self.pos)
        self.pos += count * dt.itemsize
        return a

    def string(self, what="string", limit=1 << 20):
        n = self.u32(what + " length")
        if n > limit:
            raise self.error(f"absurd {what} length {n}", self.pos - 4)
        raw = self.bytes(n, what)
        return bytes(raw).decode("utf-8", "replace")
