"""The colormaps by name: the tables in kernels/render/scene/colormaps.npz (tools/gen_colormaps.py writes
them from these matplotlib names), the transfer-function menu, the command line and the shipped
presets all use this list. Plain Python on purpose, outside kernels/render (whose __init__ loads
numba), so the extension registers its enums without loading the kernels."""

# our name -> matplotlib's, in menu order
MATPLOTLIB = {
    "viridis": "viridis",
    "plasma": "plasma",
    "inferno": "inferno",
    "magma": "magma",
    "cividis": "cividis",
    "turbo": "turbo",
    "jet": "jet",
    "coolwarm": "coolwarm",
    "grayscale": "gray",
}
NAMES = tuple(MATPLOTLIB)
DEFAULT = "viridis"
RAMP_STOPS = 32  # the stops a colormap becomes: the most elements a Blender ColorRamp holds
ALIASES = {"gray": "grayscale", "grey": "grayscale", "greyscale": "grayscale"}


def canonical(name: str) -> str:
    """'Grey' -> 'grayscale', 'Viridis' -> 'viridis' (unknown names pass through, lower-cased)."""
    key = name.lower()
    return ALIASES.get(key, key)


def label(name: str) -> str:
    return name.title()


def enum_items() -> tuple:
    """(identifier, label, description) of every colormap, for a Blender EnumProperty."""
    return tuple((n, label(n), f"{n} colormap") for n in NAMES)
