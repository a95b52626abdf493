"""The render modes by name: their ids (what the kernels receive), labels and descriptions, for
the kernels, the render panel and the command line. Plain Python, outside kernels/render (whose
__init__ loads numba), so the extension registers its enums without loading the kernels."""
from enum import IntEnum


class Mode(IntEnum):
    """The render modes; the kernels receive them as ints (int(Mode.FIELD) == 1)."""
    PARTICLES = 0  # closed-form Gaussian segments (render/cpu/gauss)
    FIELD = 1      # the summed Gaussian field, sampled (render/cpu/gauss)
    PAPER = 2      # the seed paper's closest hits (render/cpu/pieces)
    REFERENCE = 3  # trilinear voxel samples of the source grid (render/cpu/pieces)
    SPLAT = 4      # the Gaussian field on a lattice at its own scale, drawn as REFERENCE (render/splat_scene)

    @classmethod
    def of(cls, name: str) -> "Mode":
        return cls[name.upper()]


NAMES = tuple(m.name.lower() for m in Mode)  # RenderScene.mode and --mode, in Mode's order
DEFAULT = "particles"
LABELS = {"particles": "Particles", "field": "Field", "splat": "Splat", "reference": "Reference",
          "paper": "Paper"}
DESCRIPTIONS = {
    "particles": "Each Gaussian classified by its value; closed-form optical depth",
    "field": "Transfer function on the summed Gaussian field (post-classification DVR)",
    "splat": "The summed Gaussian field evaluated once on a lattice at the Gaussians' scale, then "
             "rendered as voxels: the fastest Gaussian mode, with the lattice's interpolation error",
    "reference": "Direct volume render of the source voxels: the ground truth",
    "paper": "The seed paper's closest-hit renderer, for comparison only",
}
MENU_ORDER = ("particles", "field", "splat", "reference", "paper")  # the Gaussian modes, then the others
# the enum's value a .blend file stores per mode (the menu position each had when it came): a new
# mode takes the next number, none is ever renumbered, so saved scenes keep their mode
SAVED_VALUES = {"particles": 0, "field": 1, "reference": 2, "paper": 3, "splat": 4}


def enum_items() -> tuple:
    """(IDENTIFIER, label, description, saved value) of every mode, for a Blender EnumProperty."""
    return tuple((n.upper(), LABELS[n], DESCRIPTIONS[n], SAVED_VALUES[n]) for n in MENU_ORDER)
