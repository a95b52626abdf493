"""Whether the kernels are compiled yet, and the message shown before the first compile.

numba compiles the kernels on first use (about a minute) and caches them on disk (see
kernels/cachedir.py). A cheap check, no numba import: the cache folder of a kernel subpackage,
for the identity this copy of the add-on imports its kernels under, holds index files.
"""

import os
import sys

MESSAGE = "Compiling GaussVDB kernels (first use, about a minute)..."


def compiled(subpackage: str) -> bool:
    """True when kernels/<subpackage> ('render', 'lod', 'vdb') has cached entries."""
    from ... import kernels
    from ...kernels import cachedir

    source = os.path.join(os.path.dirname(cachedir.__file__), subpackage, "__init__.py")
    folder = cachedir.folder_for(f"{kernels.__name__}.{subpackage}", source)
    if folder is None or not os.path.isdir(folder):
        return False
    return any(name.endswith(".nbi") for _, _, names in os.walk(folder) for name in names)


def announce(*subpackages, status=None) -> bool:
    """Print MESSAGE (and pass it to ``status``, a callable) when any of the subpackages is not
    compiled yet; returns whether it did."""
    if all(compiled(s) for s in subpackages):
        return False
    print(MESSAGE, file=sys.stderr, flush=True)
    if status is not None:
        status(MESSAGE)
    return True
