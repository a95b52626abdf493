"""The table of render modes: per mode, what it draws and what a frame of it needs (screen tiles,
the leaf walk, pieces, lights, colour grids, surfaces, the GPU device's shader). The devices,
packing and the kernels ask it (``spec(mode).screen_tiles``, ``PIECE_MODES``) instead of comparing
modes by their order; ids, labels and descriptions stay in kernels/mode_names.py (numba-free, for
the render panel and the command line). Plain Python: no numba, no numpy.

Two rules are entries of the table, not code elsewhere:
- a derived mode (``drawn_as``) is another mode over data made from the scene: splat is the
  reference mode over lattices of the Gaussian field (splat_scene turns the scene before a device
  syncs it), so every other column of splat is the reference mode's;
- the surface rule (``with_surfaces``): a particles frame with a level-set surface
  (RenderObject.surface) is drawn as field, whose sampler finds the surface (frame_mode).

The kernels receive the mode as its int (int(Mode.FIELD) == 1); the id tuples below are what
they test it against (numba reads them as constants).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ...mode_names import Mode

GAUSSIANS, VOXELS = "gaussians", "voxels"  # what the kernels read (draws)
CENTRES, SAMPLES = "centres", "samples"  # how lit volumes are shaded (lights)
FIELD = "field"  # colour: the second mixture, sampled as the field is (color)


@dataclass(frozen=True)
class GpuShader:
    """A mode's compute shader on the GPU device (gaussvdb_addon/gpu/device.py)."""
    glsl: tuple  # its files in kernels/render/gpu/glsl/, after common.glsl and color.glsl, in order
    # WALK: common.glsl's leaf walk and its tables; ONE_PER_GROUP: one pixel per work group on llvmpipe
    defines: tuple = ()


@dataclass(frozen=True)
class ModeSpec:
    """What a mode draws and what its frames need."""
    mode: Mode
    draws: str  # what the kernels read: GAUSSIANS, or VOXELS (the source grids' bricks)
    # the summed Gaussian field is classified (weights value x amplitude, cells bounded by sums,
    # the second mixture), not each Gaussian by its own value
    field: bool
    # Gaussians listed per screen tile once per frame (cpu.tiles); the leaf walk only when the
    # lists are off or too long. False: every ray walks the leaves
    screen_tiles: bool
    # screen tiles no unskipped leaf projects into are the background, unwalked (leaf_tiles)
    leaf_tiles: bool
    # drawn piece by piece over the leaves a ray crosses (_cpu.trace_pieces), not by Gaussian
    # segments (cpu.gauss)
    pieces: bool
    lights: str | None  # lit volumes shaded at each Gaussian's CENTRES, at the SAMPLES; None: not lit
    surfaces: bool  # level-set surfaces (RenderObject.surface) drawn as surfaces; False: as shells
    # where a volume coloured by a second grid takes its colour: each Gaussian's second value
    # (GAUSSIANS), the second mixture (FIELD), the colour grid's bricks (VOXELS)
    color: str
    gpu: GpuShader | None  # the GPU device's shader; None: it hands such frames to the CPU device
    with_surfaces: Mode | None = None  # the surface rule: a frame with a level-set surface draws as this
    drawn_as: Mode | None = None  # a derived mode: drawn as this mode over data made from the scene


_GAUSS = dict(draws=GAUSSIANS, leaf_tiles=False)
_REFERENCE = ModeSpec(Mode.REFERENCE, draws=VOXELS, field=False, screen_tiles=False, leaf_tiles=True,
                      pieces=True, lights=SAMPLES, surfaces=True, color=VOXELS,
                      gpu=GpuShader(("reference.glsl",), ("WALK",)))
SPECS = {s.mode: s for s in (
    ModeSpec(Mode.PARTICLES, field=False, screen_tiles=True, pieces=False, lights=CENTRES, surfaces=True,
             color=GAUSSIANS, gpu=GpuShader(("gauss.glsl", "particles.glsl"), ("ONE_PER_GROUP",)),
             with_surfaces=Mode.FIELD, **_GAUSS),
    ModeSpec(Mode.FIELD, field=True, screen_tiles=True, pieces=False, lights=SAMPLES, surfaces=True,
             color=FIELD, gpu=GpuShader(("gauss.glsl", "field.glsl"), ("WALK", "ONE_PER_GROUP")), **_GAUSS),
    ModeSpec(Mode.PAPER, field=False, screen_tiles=False, pieces=True, lights=None, surfaces=False,
             color=GAUSSIANS, gpu=GpuShader(("gauss.glsl", "paper.glsl"), ("ONE_PER_GROUP",)), **_GAUSS),
    _REFERENCE,
    # the reference mode over the Gaussian field's lattices (splat_scene)
    dataclasses.replace(_REFERENCE, mode=Mode.SPLAT, drawn_as=Mode.REFERENCE),
)}


def spec(mode) -> ModeSpec:
    """The table's entry of a mode given as Mode, its int or its name."""
    return SPECS[Mode.of(mode) if isinstance(mode, str) else Mode(int(mode))]


def frame_mode(mode, surfaces: bool) -> Mode:
    """The mode a frame of ``mode`` is drawn in, ``surfaces``: whether it holds a level-set surface
    (the surface rule, with_surfaces)."""
    s = spec(mode)
    return s.with_surfaces if surfaces and s.with_surfaces is not None else s.mode


def drawn_modes() -> tuple:
    """The modes the kernels draw (every mode but the derived ones)."""
    return tuple(m for m, s in SPECS.items() if s.drawn_as is None)


def gpu_modes() -> tuple:
    """The names of the modes the GPU device draws (a derived mode: through the one it is drawn as)."""
    return tuple(m.name.lower() for m, s in SPECS.items() if spec(s.drawn_as or m).gpu is not None)


def _ids(column) -> tuple:
    return tuple(int(m) for m in drawn_modes() if getattr(SPECS[m], column))


# the kernels' tests of the mode int (_cpu.render_pixels)
SCREEN_TILE_MODES = _ids("screen_tiles")
LEAF_TILE_MODES = _ids("leaf_tiles")
PIECE_MODES = _ids("pieces")
