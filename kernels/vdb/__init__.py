"""Exact, fast OpenVDB (.vdb) ingest: leaves, masks, tiles and transforms of every grid.

    from kernels.vdb import read_vdb
    f = read_vdb("smoke.vdb")          # VDBFile: .version, .grids (GridData), .skipped
    f = read_vdb("smoke.vdb", "density[1]")  # one grid: the second of those named density
"""

from .errors import VDBFormatError
from .griddata import GridData, VDBFile
from .reader import DEFAULT_MAX_BYTES, check_header, estimate_bytes, read_topology, read_vdb
from .sanitize import count_nonfinite, sanitize_nonfinite

__all__ = ["read_vdb", "read_topology", "check_header", "estimate_bytes", "VDBFormatError", "GridData", "VDBFile",
           "DEFAULT_MAX_BYTES", "count_nonfinite", "sanitize_nonfinite"]
