"""How the kernels get the openvdb binding (numba-free, so registration can set it up).

A plain ``import openvdb`` first; where that fails (Blender bundles the module out of the path),
the loader the Blender layer handed over. The kernels never import bpy themselves.
"""

_LOADER = {"fn": None}


def set_loader(loader):
    """``loader() -> module``: the fallback when a plain ``import openvdb`` fails."""
    _LOADER["fn"] = loader


def load():
    try:
        import openvdb
        return openvdb
    except ImportError as plain:
        loader = _LOADER["fn"]
        if loader is None:
            raise ImportError(f"the openvdb binding is not available: {plain}") from None
        try:
            return loader()
        except Exception as e:  # noqa: BLE001  (a Blender without the module)
            raise ImportError(f"the openvdb binding is not available: {e}") from None
