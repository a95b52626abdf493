"""Start the kernel warm-up (warmup.py) under a given importing identity.

numba's cache entries are only loadable by a process that imports the kernels under the same
module names (cachedir.py), so a warm-up for the extension (`bl_ext.user_default.gaussvdb.kernels`)
must import them under that name. ``import_as`` does so without executing the extension's
``__init__.py`` (which imports bpy): its parent packages become empty namespace modules whose
search path is the extension's folder.

As a script (the extension's background process, ``sys.executable`` of Blender's Python):

    python kernels/warmup_boot.py --package bl_ext.user_default.gaussvdb [warmup.main's arguments]

Plain Python, no bpy; imports nothing of the kernels until ``import_as`` is called.
"""
from __future__ import annotations

import importlib
import os
import sys
import types

# the folder holding kernels/ (the extension's or the repository's root)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def import_as(package: str, root: str = ROOT):
    """The warmup module of the kernels in ``root``, imported as ``<package>.kernels.warmup``
    (``package`` '' : as ``kernels.warmup``, from ``root`` on sys.path)."""
    if not package:
        if root not in sys.path:
            sys.path.insert(0, root)
        return importlib.import_module("kernels.warmup")
    parts = package.split(".")
    for i in range(1, len(parts) + 1):
        name = ".".join(parts[:i])
        if name in sys.modules:
            continue
        mod = types.ModuleType(name)
        # the last one is the extension's folder; the ones above it hold nothing we import
        mod.__path__ = [root] if i == len(parts) else []
        mod.__package__ = name
        sys.modules[name] = mod
        if i > 1:
            setattr(sys.modules[".".join(parts[:i - 1])], parts[i - 1], mod)
    return importlib.import_module(f"{package}.kernels.warmup")


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    package = ""
    if "--package" in argv:
        i = argv.index("--package")
        package = argv[i + 1]
        del argv[i:i + 2]
    return import_as(package).main(argv)


if __name__ == "__main__":
    # run as a script: its own folder (kernels/) must not shadow top-level modules
    here = os.path.dirname(os.path.abspath(__file__))
    sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != here]
    sys.exit(main())
