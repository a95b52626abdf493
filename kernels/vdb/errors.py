"""The one exception type of the VDB reader."""


class VDBFormatError(ValueError):
    """A .vdb file could not be read. The message names the file, the grid and the byte offset."""

    def __init__(self, message, path=None, grid=None, offset=None):
        self.path = None if path is None else str(path)
        self.grid = grid
        self.offset = offset
        where = [f"file {self.path!r}"]
        if grid is not None:
            where.append(f"grid {grid!r}")
        if offset is not None:
            where.append(f"byte offset {offset}")
        super().__init__(f"{message} ({', '.join(where)})")
        self.reason = message
