"""The LOD presets and weight rules by name: what `build_lod`, the command line, the import dialog
and the object panel all list. Plain Python on purpose, outside kernels/lod (whose __init__ loads
numba), so the extension registers its enums without loading the kernels."""

# ordered: the paper's three spatial schemes, the two clustering schemes, then the error-bounded one
PRESETS = ("low", "medium", "high", "variance", "merged", "adaptive")
DEFAULT = "medium"
LABELS = {"low": "Low", "medium": "Medium", "high": "High", "variance": "Variance",
          "merged": "Merged", "adaptive": "Adaptive"}
DESCRIPTIONS = {
    "low": "One Gaussian per leaf (the paper's Low LOD)",
    "medium": "4^3 blocks in dense leaves, 2^3 blocks or voxels in sparse ones",
    "high": "2^3 blocks in dense leaves, one Gaussian per voxel in sparse ones",
    "variance": "Variance-based clustering inside each leaf (recursive bisection)",
    "merged": "High plus merging similar neighbouring blocks across leaves",
    "adaptive": "The fewest Gaussians whose field meets the tolerance (fitted amplitudes)",
}
# the presets built to meet an error tolerance (the dialog shows Tolerance only for them)
TOLERANCE_PRESETS = ("adaptive",)
DEFAULT_TOLERANCE = 0.02  # largest field NRMSE over the active voxels

WEIGHTS = ("field", "paper")
WEIGHT_LABELS = {"field": "Field", "paper": "Paper"}
WEIGHT_DESCRIPTIONS = {
    "field": "Normalized kernels times the volume they stand for (exact fields)",
    "paper": "The paper's weights: sigma = half extent, value as peak",
}


def label(name: str) -> str:
    """The label of a preset; a name this version does not know (a newer file) is title-cased."""
    return LABELS.get(name, name.title())


def enum_items() -> tuple:
    """(identifier, label, description) of every preset, for a Blender EnumProperty."""
    return tuple((n, LABELS[n], DESCRIPTIONS[n]) for n in PRESETS)


def weight_items() -> tuple:
    return tuple((w, WEIGHT_LABELS[w], WEIGHT_DESCRIPTIONS[w]) for w in WEIGHTS)
