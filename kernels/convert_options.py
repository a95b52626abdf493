"""How a .vdb file becomes Gaussians: every conversion option in one frozen value, with its
defaults in one place (``lod_names``). The import dialog, the command line, sequences, Reload and
scripts build one; ``kernels.pipeline`` reads it.

    opts = ConvertOptions(grids=("density",), lods=("low", "adaptive"), tolerance=0.01)
    opts.replace(compute_error=False)                # another value, the rest kept

Plain Python on purpose (no numpy, no numba), so registration and the command line import it
cheaply.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from . import lod_names


def split_names(text) -> list | None:
    """'density, temperature' -> ['density', 'temperature']; '' -> None (the default grids)."""
    if not text:
        return None
    if not isinstance(text, str):
        return list(text) or None
    names = [n.strip() for n in text.split(",") if n.strip()]
    return names or None


@dataclass(frozen=True)
class ConvertOptions:
    grids: tuple | None = None  # grid names ('a, b' is split); None: pipeline.default_grids
    lods: tuple = (lod_names.DEFAULT,)  # LOD presets, any order (the pipeline orders them); (): none
    # (the grid alone: an object the reference mode draws from its voxels)
    weights: str = lod_names.WEIGHTS[0]  # how sizes and amplitudes are set (lod_names.WEIGHTS)
    level_set_band: bool = True  # level sets: only Gaussians whose voxels straddle the surface
    vector_magnitude: bool = False  # vec3 grids (velocity) as their magnitude
    compute_error: bool = True  # measure each LOD's field error
    tolerance: float = lod_names.DEFAULT_TOLERANCE  # the adaptive preset's field NRMSE bound
    thresholds: tuple = ()  # kernels.lod.DEFAULTS overrides for every LOD, (name, value) pairs
    color_grid: str | None = None  # another grid of the file whose value each Gaussian carries
    max_bytes: int | None = None  # refuse a read larger than this
    index_limit: int | None = None  # refuse grids reaching index coordinates this far out
    value_figures: bool = True  # keep each grid's voxel_stats (the automatic value range)

    def __post_init__(self):
        # plain forms for what callers pass loosely, so equal options compare (and hash) equal
        grids = split_names(self.grids)
        lods = (self.lods,) if isinstance(self.lods, str) else tuple(self.lods or ())
        th = self.thresholds
        th = tuple(sorted(th.items())) if isinstance(th, dict) else tuple(th or ())
        object.__setattr__(self, "grids", None if grids is None else tuple(grids))
        object.__setattr__(self, "lods", lods)
        object.__setattr__(self, "thresholds", th)
        object.__setattr__(self, "color_grid", self.color_grid or None)

    def replace(self, **changes) -> ConvertOptions:
        return dataclasses.replace(self, **changes)

    def object_settings(self) -> dict:
        """What an imported object keeps of these options (its Reload and its sequence frames
        convert with them again): weights, level_set_band, vector_magnitude."""
        return dict(weights=self.weights, level_set_band=self.level_set_band,
                    vector_magnitude=self.vector_magnitude)


DEFAULTS = ConvertOptions()


def options_of(options=None, grids=None, lods=None, **changes) -> ConvertOptions:
    """``options`` (default: the defaults) with ``changes``; ``grids`` and ``lods`` replace theirs
    only when given (not None). The entry of every plain function that takes keywords."""
    options = DEFAULTS if options is None else options
    if grids is not None:
        changes["grids"] = grids
    if lods is not None:
        changes["lods"] = lods
    return options.replace(**changes) if changes else options
