"""The one conversion: file -> grids -> LODs -> errors, for every caller (the Blender import and
its sequences, `gaussvdb convert` and `render`, the benchmarks).

    cgs = convert_file("smoke.vdb", lods=("low", "medium"), progress=print, cancel=None)
    cgs[0].lods[1].gset                       # the Medium GaussianSet of the first grid
    convert_file("smoke.vdb", lods=())        # the grids' figures alone: no Gaussians
    convert_file("fire.vdb", ["density"], color_grid="temperature")  # + gset.color_values
    convert_file("smoke.vdb", options=ConvertOptions(lods=("adaptive",), tolerance=0.01))

The options are one ``ConvertOptions`` (convert_options.py: every option and its default);
``convert_file``'s keywords are a script's shorthand for one. ``convert_steps`` is the same as a
generator that yields (fraction, text) before each step, so
a modal operator can run one step per timer event; ``run`` drives one with a progress callback
and a cancel test. Nothing here knows Blender: errors are ``ConversionError`` with a one-line
message, and the kernels (numba) load on first use, not when this module is imported.

The default grids are decided here once (``default_grids``), per known cache layout: a Mantaflow
cache gives density (its ``shadow`` grid is a domain-wide constant Blender does not bake).
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import lod_names
from .convert_options import DEFAULTS, ConvertOptions, options_of, split_names  # noqa: F401


class ConversionError(Exception):
    """A conversion failed; the message says why in one line. Nothing was created."""


class ConversionCancelled(ConversionError):
    """The cancel callback said so. Nothing was created."""

    def __init__(self, message="import cancelled: nothing was created"):
        super().__init__(message)


# -- which grids -----------------------------------------------------------------------------------
# Grids of a Blender Mantaflow (smoke/fire) cache. `shadow` is a domain-wide constant -1 that
# Blender does not bake: taking it by default would cover the whole domain.
MANTAFLOW_GRIDS = {"density", "heat", "temperature", "flame", "fuel", "react", "shadow", "velocity",
                   "color_r", "color_g", "color_b", "density_noise", "flame_noise", "fuel_noise",
                   "react_noise", "color_r_noise", "color_g_noise", "color_b_noise"}
MANTAFLOW_DEFAULT = ("density",)
MANTAFLOW_LEFT_OUT = "Mantaflow cache: only density by default (name it under Grids to import it)"


def cache_layout(names) -> str:
    """'mantaflow' when the grid names are a Mantaflow cache's (density beside two or more of
    its other grids), else '' (an ordinary file)."""
    names = set(names)
    if "density" in names and len(names & (MANTAFLOW_GRIDS - {"density"})) >= 2:
        return "mantaflow"
    return ""


def default_grids(names):
    """The grids taken when the caller names none: (wanted, or None for every scalar grid;
    [(name, reason) left out])."""
    if cache_layout(names) == "mantaflow":
        wanted = [n for n in MANTAFLOW_DEFAULT if n in names]
        return wanted, [(n, MANTAFLOW_LEFT_OUT) for n in names if n not in wanted]
    return None, []


def order_lods(lods) -> list:
    """LOD names in the kernels' preset order (coarse first), validated, duplicates dropped. None
    (``()``): the grids alone, no Gaussians (what the reference mode draws: their voxels)."""
    if isinstance(lods, str):
        lods = [lods]
    lods = list(lods or ())
    bad = [name for name in lods if name not in lod_names.PRESETS]
    if bad:
        raise ConversionError(f"unknown LOD preset {bad[0]!r}; choose from {', '.join(lod_names.PRESETS)}")
    return [p for p in lod_names.PRESETS if p in lods]


def lod_label(name: str) -> str:
    return lod_names.label(name)


# -- results ---------------------------------------------------------------------------------------
@dataclass
class ConvertedLOD:
    name: str
    gset: object
    seconds: float  # building the LOD
    error: dict = field(default_factory=dict)  # field_error's scalar figures ({} when not measured)
    seconds_error: float = 0.0  # measuring the field error (within seconds for the adaptive preset)
    seconds_color: float = 0.0  # the colour grid's values at the Gaussians (gset.color_values)


@dataclass
class ConvertedGrid:
    filepath: str
    name: str
    grid_class: str
    value_type: str
    index_to_world: np.ndarray
    leaf_box: tuple  # (min, max) index-space box of the leaves and active tiles (voxel corners)
    lods: list = field(default_factory=list)  # [ConvertedLOD]
    nonfinite_voxels: int = 0  # NaN/Inf voxels made inactive before conversion
    values: dict = field(default_factory=dict)  # kernels.render.voxel_stats: the auto range of any LOD
    seconds_compile: float = 0.0  # kernels compiled (or loaded from the cache) before converting
    sequence: dict = None  # a sequence's settings and per-frame figures (the Blender layer's)
    seconds_read: float = 0.0  # reading the file's chosen grids
    active_voxels: int = 0
    leaves: int = 0
    tiles: int = 0  # active tiles
    color_grid: str = ""  # the grid of the same file the Gaussians also carry (gset.color_values)
    color_stats: dict = field(default_factory=dict)  # voxel_stats of that grid: its auto range

    @property
    def is_level_set(self) -> bool:
        return self.grid_class == "level_set"


def leaf_box(grid):
    """Index box covered by the leaf nodes and active tiles (what Blender's Volume bounds show)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    if len(grid.leaf_origins):
        o = np.asarray(grid.leaf_origins, np.float64)
        lo = np.minimum(lo, o.min(0) - 0.5)
        hi = np.maximum(hi, o.max(0) + 7.5)
    act = np.asarray(grid.tile_active, bool)
    if act.any():
        o = np.asarray(grid.tile_origins, np.float64)[act]
        s = np.asarray(grid.tile_sizes, np.float64)[act][:, None]
        lo = np.minimum(lo, (o - 0.5).min(0))
        hi = np.maximum(hi, (o + s - 0.5).max(0))
    return lo, hi


_WARM = set()  # (grid class, LOD, weights, band, error) converted once in this process


def _warm_up(grid, options, ready=None) -> float:
    """Convert a few leaves of ``grid`` first, so that compiling (or loading) the kernels on
    first use is timed apart from the LODs' own conversion times; seconds it took. ``ready``:
    convert_steps'."""
    from . import lod

    o = options
    keys = {n: (grid.grid_class, n, o.weights, o.level_set_band, o.compute_error) for n in o.lods}
    todo = [n for n in o.lods if keys[n] not in _WARM]
    if not todo or grid.leaf_values is None or not len(grid.leaf_origins):
        return 0.0
    k = min(8, len(grid.leaf_origins))
    masks = np.ascontiguousarray(grid.leaf_masks[:k])
    small = dataclasses.replace(
        grid, leaf_origins=np.ascontiguousarray(grid.leaf_origins[:k]), leaf_masks=masks,
        leaf_values=np.ascontiguousarray(grid.leaf_values[:k]), tile_origins=grid.tile_origins[:0],
        tile_sizes=grid.tile_sizes[:0], tile_values=grid.tile_values[:0],
        tile_active=grid.tile_active[:0],
        active_voxels=int(np.unpackbits(masks.view(np.uint8)).sum()))
    t0 = time.perf_counter()
    for name in todo:
        if ready is not None:
            ready([f"lod:{name}"])
        gset = lod.build_lod(small, name, o.weights, level_set_band=o.level_set_band)
        if o.compute_error:
            if ready is not None:
                ready(["error"])
            lod.field_error(small, gset)
        _WARM.add(keys[name])
    return time.perf_counter() - t0


# -- the steps -------------------------------------------------------------------------------------
def lod_thresholds(options, name) -> dict:
    """The kernels.lod.DEFAULTS overrides LOD ``name`` is built with: the adaptive preset's
    tolerance, then ``options.thresholds`` (they win)."""
    th = dict(tolerance=options.tolerance) if name == "adaptive" else {}
    th.update(options.thresholds)
    return th


def convert_lod(grid, name, options=None, **changes) -> ConvertedLOD:
    """One LOD of one grid, timed, with its field error (scalar figures) when asked.
    ``changes``: ConvertOptions fields over ``options``."""
    from .lod.build import finish

    return finish(convert_lod_steps(grid, name, options_of(options, **changes)))


def convert_lod_steps(grid, name, options=DEFAULTS):
    """convert_lod as a generator: yields the adaptive preset's (round, figures) after each
    round (kernels.lod.build.build_steps); its seconds leave out the time spent suspended."""
    from .lod.build import build_steps

    steps = build_steps(grid, name, options.weights, level_set_band=options.level_set_band,
                        **lod_thresholds(options, name))
    seconds = 0.0
    while True:
        t0 = time.perf_counter()
        try:
            item = next(steps)
        except StopIteration as stop:
            gset = stop.value
            break
        except MemoryError as err:
            raise ConversionError(f"{grid.name}: out of memory building the {name} LOD") from err
        finally:
            seconds += time.perf_counter() - t0
        yield item
    error, seconds_error = {}, 0.0
    if options.compute_error:
        t0 = time.perf_counter()
        try:
            error = measure_error(grid, gset)
        except MemoryError:
            error = {}
        seconds_error = time.perf_counter() - t0
    return ConvertedLOD(name, gset, seconds, error, seconds_error)


def add_color_values(cl, grid, cgrid):
    """The colour grid's value at each Gaussian of the ConvertedLOD ``cl`` (built from ``grid``)."""
    from .lod.second_grid import attach

    t0 = time.perf_counter()
    attach(cl.gset, grid, cgrid)
    cl.seconds_color = time.perf_counter() - t0


def measure_error(grid, gset) -> dict:
    """kernels.lod.field_error's scalar figures (the adaptive preset measured them while building)."""
    from . import lod

    measured = gset.params.get("field_error") or lod.field_error(grid, gset)
    return {k: v for k, v in measured.items() if isinstance(v, (int, float, str))}


def read_grids(filepath, wanted=None, vector_magnitude=False, max_bytes=None, skipped=None,
               index_limit=None):
    """The grids of ``filepath`` to convert (``wanted`` names, or the default grids) and the
    seconds reading them took; ``skipped`` collects (grid, reason) for grids left out.
    ``index_limit``: refuse grids reaching index coordinates this far from the origin."""
    from . import vdb

    base = os.path.basename(filepath)
    skipped = [] if skipped is None else skipped
    try:
        if wanted is None:
            wanted, left_out = default_grids([g.name for g in vdb.read_topology(filepath).grids])
            skipped.extend(left_out)
        t0 = time.perf_counter()
        vfile = vdb.read_vdb(filepath, wanted, max_bytes=max_bytes)
        seconds = time.perf_counter() - t0
    except vdb.VDBFormatError as err:
        raise ConversionError(f"cannot import {base}: {err.reason}"
                              + (f" (grid {err.grid!r})" if err.grid else "")) from err
    except MemoryError as err:
        raise ConversionError(f"cannot import {base}: out of memory while reading") from err
    skipped.extend(vfile.skipped)
    chosen = []
    for g in vfile.grids:
        if g.value_type.startswith("vec3") and not vector_magnitude:
            skipped.append((g.name, "vector grid (enable 'Vector Grids as Magnitude' to import it)"))
        elif g.active_voxels == 0:
            skipped.append((g.name, "empty grid (no active voxels)"))
        else:
            chosen.append(g)
    if not chosen:
        why = "; ".join(f"{n}: {r}" for n, r in skipped) or "the file holds no grids"
        raise ConversionError(f"no scalar grid to import in {base} ({why})")
    for g in chosen if index_limit else ():
        if max(np.abs(g.bbox_min).max(), np.abs(g.bbox_max).max()) >= index_limit - 4096:
            raise ConversionError(f"grid {g.name!r} of {base} reaches index coordinates beyond "
                                  f"{index_limit:,}: too far from the origin to store exactly")
    return chosen, seconds


def read_color_grid(filepath, name, vector_magnitude=False, max_bytes=None):
    """The colour grid ``name`` of ``filepath`` (a scalar grid; a vec3 one as its magnitude with
    ``vector_magnitude``), NaN/Inf voxels made inactive; ConversionError naming the grid and file
    when the file holds no such grid."""
    from . import vdb

    base = os.path.basename(filepath)
    try:
        names = [g.name for g in vdb.read_topology(filepath).grids]
        if name not in names:
            raise ConversionError(f"colour grid {name!r} not in {base} (it holds "
                                  f"{', '.join(names) or 'no grids'})")
        g = vdb.read_vdb(filepath, [name], max_bytes=max_bytes).grids[0]
    except vdb.VDBFormatError as err:
        raise ConversionError(f"cannot read colour grid {name!r} of {base}: {err.reason}") from err
    except MemoryError as err:
        raise ConversionError(f"cannot read colour grid {name!r} of {base}: out of memory") from err
    if g.value_type.startswith("vec3") and not vector_magnitude:
        raise ConversionError(f"colour grid {name!r} of {base} is a vector grid (enable 'Vector "
                              "Grids as Magnitude' to colour by its magnitude)")
    vdb.sanitize_nonfinite(g)
    return g


def convert_steps(filepath, options=DEFAULTS, skipped=None, ready=None):
    """Generator: yields (fraction < 1, text) before each step; returns [ConvertedGrid].

    ``options``: a ConvertOptions (which grids and LODs, how; convert_options.py says what each
    field does). ``skipped`` collects (grid, reason) for grids left out. ``ready(jobs)`` is
    called before the kernels of those warm-up jobs (warmup.py: 'lod:medium', 'error') are
    first used, so that a caller whose warm-up process compiles them can wait for it.
    """
    from . import lod, vdb

    o = options.replace(lods=tuple(order_lods(options.lods)))
    if o.weights not in lod.WEIGHTS:
        raise ConversionError(f"unknown weights {o.weights!r}; choose from {', '.join(lod.WEIGHTS)}")
    filepath = os.path.abspath(os.path.expanduser(os.fspath(filepath)))
    yield 0.0, f"reading {os.path.basename(filepath)}"
    cgrid = (read_color_grid(filepath, o.color_grid, o.vector_magnitude, o.max_bytes)
             if o.color_grid else None)
    chosen, seconds_read = read_grids(filepath, None if o.grids is None else list(o.grids),
                                      o.vector_magnitude, o.max_bytes, skipped, o.index_limit)
    steps = len(chosen) * len(o.lods)
    out = []
    k = 0
    for g in chosen:
        cg = ConvertedGrid(filepath, g.name, g.grid_class, g.value_type,
                           np.asarray(g.index_to_world, np.float64), leaf_box(g),
                           seconds_read=seconds_read, active_voxels=int(g.active_voxels),
                           leaves=int(len(g.leaf_origins)), tiles=int(np.count_nonzero(g.tile_active)))
        # NaN/Inf are no density: such voxels become inactive, counted, and the caller is warned.
        cg.nonfinite_voxels = vdb.sanitize_nonfinite(g)
        if cg.nonfinite_voxels:
            warnings.warn(f"{os.path.basename(filepath)}: grid {g.name!r} has "
                          f"{cg.nonfinite_voxels:,} non-finite (NaN/Inf) voxels; they were made "
                          "inactive", RuntimeWarning, stacklevel=2)
        if o.value_figures and g.grid_class != "level_set":  # level sets: coloured by position
            from .render.scene.transfer import voxel_stats

            cg.values = voxel_stats(g)
        cg.seconds_compile = _warm_up(g, o, ready)
        for name in o.lods:
            yield 0.05 + 0.95 * k / steps, f"{g.name}: {lod_label(name)} LOD"
            k += 1
            cg.lods.append((yield from _rounds(
                convert_lod_steps(g, name, o),
                0.05 + 0.95 * (k - 1) / steps, 0.95 / steps, f"{g.name}: {lod_label(name)} LOD")))
            if cgrid is not None and g.grid_class != "level_set":  # level sets: coloured by position
                add_color_values(cg.lods[-1], g, cgrid)
        if cgrid is not None and g.grid_class != "level_set":
            from .render.scene.transfer import voxel_stats

            cg.color_grid = cgrid.name
            cg.color_stats = dict(voxel_stats(cgrid), background=float(cgrid.background or 0.0))
        out.append(cg)
    return out


def _rounds(steps, base, span, text):
    """A LOD's build steps as convert_steps' (fraction, text): one per adaptive round, within
    [base, base + span)."""
    while True:
        try:
            r, fig = next(steps)
        except StopIteration as stop:
            return stop.value
        yield base + span * (1.0 - 0.5 ** r), \
            f"{text}, round {r}: {fig['gaussians']:,} Gaussians, NRMSE {fig['nrmse']:.4f}"


def run(steps, progress=None, cancel=None):
    """Drive a ``convert_steps`` generator: ``progress(fraction, text)`` before each step,
    ConversionCancelled as soon as ``cancel()`` is true; returns what the generator returns."""
    try:
        while True:
            try:
                fraction, text = next(steps)
            except StopIteration as stop:
                return stop.value
            if progress is not None:
                progress(fraction, text)
            if cancel is not None and cancel():
                raise ConversionCancelled()
    finally:
        steps.close()


def convert_file(filepath, grids=None, lods=None, *, options=None, progress=None, cancel=None,
                 skipped=None, **changes) -> list:
    """Read and convert one file; [ConvertedGrid]. ``grids``, ``lods`` and ``changes``
    (ConvertOptions fields) over ``options`` (default: the defaults)."""
    return run(convert_steps(filepath, options_of(options, grids, lods, **changes), skipped),
               progress, cancel)


def convert_frame(path, grid, lod, options=DEFAULTS):
    """One grid of one frame of a sequence at one LOD, no error measured, with the object
    settings and index limit of ``options`` (a frame is converted as the sequence's object
    says, whatever else the options hold): (ConvertedGrid, ''); (None, '') when the grid is
    absent or empty in this frame (nothing to draw, no error); (None, why) when the frame
    cannot be converted."""
    from . import vdb

    frame = ConvertOptions(grids=(grid,), lods=(lod,), compute_error=False,
                           index_limit=options.index_limit, **options.object_settings())
    try:
        converted = convert_file(path, options=frame)
    except ConversionError as err:
        try:  # an empty or absent grid is not an error, a file that cannot be read is
            topo = vdb.read_topology(path)
        except (vdb.VDBFormatError, OSError, MemoryError) as why:
            return None, f"cannot read {os.path.basename(path)}: {getattr(why, 'reason', None) or why}"
        g = next((g for g in topo.grids if g.name == grid), None)
        if g is None or not g.active_voxels:
            return None, ""
        return None, str(err)
    return next(c for c in converted if c.name == grid), ""
