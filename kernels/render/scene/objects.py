"""What the engine hands to a Device: objects (Gaussian sets in index space + their world
matrices), the background, and the render settings."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from ...mode_names import NAMES as MODES  # noqa: F401  (RenderScene.mode's names)
from ...mode_names import Mode  # noqa: F401  (the kernels' mode ids: kernels.render.scene.objects.Mode)
from .transfer import TransferFunction

SHADINGS = ("emission", "lit")  # RenderObject.shading


@dataclass
class RenderObject:
    """One grid placed in the world.

    ``gaussians``: a GaussianSet (kernels.lod; duck-typed: group_origins, group_start, offsets,
    sigmas, values, amplitudes, optional voxels/grid_class), in INDEX space.
    ``matrix_world``: float64 4x4 index -> world (rotation, non-uniform scale, translation).
    ``grid``: the source GridData, needed only by the 'reference' mode.
    ``is_level_set``: default from the set's / grid's grid_class.
    ``tf``: optional per-object TransferFunction overriding the scene's.
    ``level_set_color``: 'x' | 'y' | 'z' (colormap over that WORLD coordinate across the object's
    world bounds; default 'z', the height) or an RGB triple (scene-linear constant colour).
    ``surface``: a level set drawn as a lit opaque surface (its zero level) instead of a
    translucent shell; the Blender layer and the CLI default to it.
    ``clip``: optional (k, 4) world half-spaces a x + b y + c z + d >= 0 the object is cut to
    (kernels.render.scene.clip builds them from planes and boxes).
    ``shading``: 'emission' (emission-absorption) or 'lit' (a volume: the scene's lights shade
    each sample by Blinn-Phong on the field's gradient, RenderScene.shading and
    lit_threshold; particles mode shades each chord once, at its closest approach to the
    Gaussian's centre; paper mode stays emission). ``shadows``: lit samples see each light
    through the medium (single scattering).
    ``color_tf``: a volume coloured by a second grid of its file: the colour comes from this
    transfer function's colours at the second grid's value, the opacity from ``tf`` (or the
    scene's) at the object's own value. The second grid's values are ``gaussians.color_values``
    (kernels.lod.second_grid, one per Gaussian) and, for the reference mode, ``color_grid`` (its
    GridData).
    """
    gaussians: Any = None
    matrix_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    grid: Any = None
    is_level_set: Optional[bool] = None
    tf: Optional[TransferFunction] = None
    level_set_color: Any = "z"
    name: str = ""
    clip: Any = None
    surface: bool = False
    shading: str = "emission"
    shadows: bool = False
    color_tf: Optional[TransferFunction] = None
    color_grid: Any = None

    def __post_init__(self):
        if self.shading not in SHADINGS:
            raise ValueError(f"shading must be one of {SHADINGS}, not {self.shading!r}")
        self.matrix_world = np.asarray(self.matrix_world, np.float64).reshape(4, 4)
        if self.is_level_set is None:
            gc = getattr(self.gaussians, "grid_class", None) or getattr(self.grid, "grid_class", None)
            self.is_level_set = gc == "level_set"
        if self.color_tf is not None and self.gaussians is not None and \
                getattr(self.gaussians, "color_values", None) is None:
            raise ValueError(f"{self.name or 'object'}: a colour map over a second grid needs its "
                             "values on the Gaussians (gaussians.color_values)")


@dataclass
class RenderScene:
    objects: list = field(default_factory=list)
    background: tuple = (0.0, 0.0, 0.0, 0.0)  # straight RGBA (linear); alpha 0 = transparent film
    mode: str = "particles"
    transmittance_min: float = 1e-3  # early termination; 0 disables
    step: float = 0.5                # field/reference sample spacing, in voxels along the ray
    tau_max: float = 0.1             # particles: max (optical depth x colour spread) per mixed segment
    support_k: float = 3.0           # Gaussian support radius in sigmas (truncation)
    paper_steps: int = 8             # paper mode: fixed samples per Gaussian
    paper_max_depth: int = 10        # paper mode: closest-hit continuations
    threads: Optional[int] = None
    passes: tuple = ("Depth", "Value")
    lights: tuple = ()               # kernels.render.scene.lights.Light; none: a headlight
    shading: tuple = (0.1, 0.8, 0.2, 32.0)  # surfaces, lit volumes: Blinn-Phong ambient, diffuse, specular, shininess
    # lit volumes: samples whose gradient (per voxel) is below this fraction of the transfer
    # function's value range keep their emission colour (homogeneous regions stay unlit)
    lit_threshold: float = 0.01

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, not {self.mode!r}")

    def features(self) -> tuple:
        """What of the scene decides which kernels its frames run besides the mode (lights,
        shadows, level sets and surfaces, colour grids, clipping): one frame of each compiles them."""
        return tuple(sorted({(o.shading, bool(o.shadows), bool(o.is_level_set), bool(o.surface),
                              o.color_tf is not None, o.clip is not None) for o in self.objects}))

    def geometry_key(self):
        """What sync() depends on (objects' data by identity, placement, support radius). The key
        holds the data objects themselves (so their ids cannot be reused while it lives); compare
        keys with ``same_geometry``. The engine skips a re-sync when only the TF, camera or
        settings changed (replace the GaussianSet object when its arrays change)."""
        return (float(self.support_k),) + tuple(
            (o.gaussians, o.grid, o.matrix_world.tobytes(), bool(o.is_level_set), o.color_grid)
            for o in self.objects)


def same_geometry(a, b) -> bool:
    if a is None or b is None or len(a) != len(b) or a[0] != b[0]:
        return False
    return all(x[0] is y[0] and x[1] is y[1] and x[2] == y[2] and x[3] == y[3] and x[4] is y[4]
               for x, y in zip(a[1:], b[1:]))
