"""Import .vdb grids as Gaussian point clouds: the plain functions behind the import operator.

Scripts, the operator, the Reload button and the CLI all call these:

    objs = import_vdb("smoke.vdb", lods=("low", "medium"))       # -> list of Objects
    gset = gaussian_set_from_object(objs[0], "medium")            # -> kernels.lod.GaussianSet

Two phases, so an error or a cancel leaves nothing half-built: ``convert_file`` reads and converts
everything (kernels only, no datablock), then ``build_objects`` creates the datablocks (and removes
them again if creating them fails).

Layout of an imported object (one object per grid; see ATTRIBUTES below and README "Point-cloud
layout"): ONE PointCloud holds every LOD, concatenated in the order of the object's ``lods`` list,
each LOD's Gaussians in the kernel's order (groups ascending). Point attributes:

  position      FLOAT_VECTOR  Gaussian centre, grid INDEX space (float32 of origin + offset)
  radius        FLOAT         display size: the largest sigma (index units), for the point display
  gs_lod        INT8          index into the object's ``gaussvdb.lods`` list (0 = first LOD held)
  gs_origin     FLOAT_VECTOR  origin of the Gaussian's group (leaf/tile min corner; integers)
  gs_sigma      FLOAT         sigma, when every Gaussian of every LOD held is a sphere
                FLOAT_VECTOR  (sx, sy, sz) otherwise
  gs_value      FLOAT         value the Gaussian stands for (absent for level sets)
  gs_amplitude  FLOAT         peak occupancy (absent when all are 1: paper weights)
  gs_voxels     INT           voxels the Gaussian represents

The object's ``matrix_world`` is the grid's index-to-world transform.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

# Gaussian centres are half-integers: float32 holds them exactly below 2**23 voxels from the
# origin; group origins are integers, exact in float32 below 2**24.
MAX_EXACT_INDEX = 1 << 23
ORIGIN_LIMIT = 1 << 24

ATTRIBUTES = {  # name -> (Blender type, numpy dtype, components)
    "position": ("FLOAT_VECTOR", np.float32, 3),
    "radius": ("FLOAT", np.float32, 1),
    "gs_lod": ("INT8", np.int8, 1),
    "gs_origin": ("FLOAT_VECTOR", np.float32, 3),
    "gs_sigma": (None, np.float32, None),  # FLOAT (1) or FLOAT_VECTOR (3)
    "gs_value": ("FLOAT", np.float32, 1),
    "gs_amplitude": ("FLOAT", np.float32, 1),
    "gs_voxels": ("INT", np.int32, 1),
}
LAYOUT_VERSION = 1


class ImportError_(Exception):
    """An import failed; the message says why, for the status bar. Nothing was created."""


class ImportCancelled(ImportError_):
    """The user cancelled (Esc) or the cancel callback said so. Nothing was created."""

    def __init__(self, message="import cancelled: nothing was created"):
        super().__init__(message)


def _kernels():
    from ..kernels import lod, vdb

    return vdb, lod


def lod_presets() -> tuple:
    return _kernels()[1].PRESETS


def lod_label(name: str) -> str:
    from ..kernels.lod.build import PRESET_LABELS

    return PRESET_LABELS.get(name, name.title())


# -- small helpers the operator uses ---------------------------------------------------------------
def split_names(text) -> list | None:
    """'density, temperature' -> ['density', 'temperature']; '' -> None (every scalar grid)."""
    if not text:
        return None
    if not isinstance(text, str):
        return list(text) or None
    names = [n.strip() for n in text.split(",") if n.strip()]
    return names or None


# Grids of a Blender Mantaflow (smoke/fire) cache. `shadow` is a domain-wide constant -1 that
# Blender does not bake: importing it by default would cover the whole domain.
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
    """The grids an import picks when the user names none: (wanted or None for every scalar
    grid, [(name, reason) left out])."""
    if cache_layout(names) == "mantaflow":
        wanted = [n for n in MANTAFLOW_DEFAULT if n in names]
        return wanted, [(n, MANTAFLOW_LEFT_OUT) for n in names if n not in wanted]
    return None, []


def default_grids_hint(filepath) -> str:
    """One line for the import dialog: what an empty Grids field imports from this file."""
    generic = "Empty Grids: every scalar grid (a Mantaflow cache: density only)"
    path = bpy_abspath(filepath)
    if not path or not os.path.isfile(path):
        return generic
    from . import kernel_cache

    if not kernel_cache.compiled("vdb"):  # never compile inside a dialog's draw
        return generic
    try:
        st = os.stat(path)
        key = (path, st.st_mtime_ns, st.st_size)
        hint = _HINTS.get(key)
        if hint is None:
            names = [g.name for g in _kernels()[0].read_topology(path).grids]
            wanted, _ = default_grids(names)
            if wanted is not None:
                rest = [n for n in names if n not in wanted]
                hint = (f"Mantaflow cache: importing {', '.join(wanted)}; name "
                        f"{', '.join(rest)} under Grids to add them")
            else:
                hint = "Empty Grids: every scalar grid (" + ", ".join(names) + ")"
            _HINTS.clear()
            _HINTS[key] = hint
        return hint
    except Exception:  # noqa: BLE001  (a broken file is reported by the import itself)
        return generic


_HINTS = {}


def bpy_abspath(path) -> str:
    if not path:
        return ""
    try:
        import bpy

        return os.path.abspath(bpy.path.abspath(path))
    except ImportError:
        return os.path.abspath(path)


def selected_paths(filepath, directory="", files=()) -> list:
    """The files chosen in the file browser (several when shift-selected), else ``filepath``."""
    names = [f.name for f in files if getattr(f, "name", "")] if files else []
    if directory and names:
        return [os.path.join(directory, n) for n in names]
    return [filepath] if filepath else []


def order_lods(lods) -> list:
    """LOD names in the kernels' preset order (coarse first), validated, duplicates dropped."""
    presets = lod_presets()
    if isinstance(lods, str):
        lods = [lods]
    lods = list(lods or ())
    bad = [name for name in lods if name not in presets]
    if bad:
        raise ImportError_(f"unknown LOD preset {bad[0]!r}; choose from {', '.join(presets)}")
    if not lods:
        raise ImportError_("choose at least one LOD preset")
    return [p for p in presets if p in lods]


# -- phase 1: read and convert (no Blender data) ---------------------------------------------------
@dataclass
class ConvertedLOD:
    name: str
    gset: object
    seconds: float
    error: dict = field(default_factory=dict)


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
    sequence: dict = None  # a sequence's settings and per-frame figures (sequence_import.py)

    @property
    def is_level_set(self) -> bool:
        return self.grid_class == "level_set"


_WARM = set()  # (grid class, LOD, weights, band, error) converted once in this process


def _warm_up(lod, grid, lods, weights, level_set_band, compute_error) -> float:
    """Convert a few leaves of ``grid`` first, so that compiling (or loading) the kernels on
    first use is timed apart from the LODs' own conversion times; seconds it took."""
    todo = [n for n in lods if (grid.grid_class, n, weights, level_set_band, compute_error) not in _WARM]
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
        gset = lod.build_lod(small, name, weights, level_set_band=level_set_band)
        if compute_error:
            lod.field_error(small, gset)
        _WARM.add((grid.grid_class, name, weights, level_set_band, compute_error))
    return time.perf_counter() - t0


def _leaf_box(grid):
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


def convert_steps(filepath, grids=None, lods=("medium",), weights="field", level_set_band=True,
                  vector_magnitude=False, max_bytes=None, compute_error=True, skipped=None, *,
                  tolerance=0.02):
    """Generator: yields (fraction, text) before each step; returns [ConvertedGrid].
    ``tolerance``: the adaptive LOD's field NRMSE bound (the other presets ignore it).

    Drive it with ``convert_file`` (synchronously) or one step per timer event (the modal operator).
    ``skipped`` (a list) collects (grid, reason) for grids left out.
    """
    vdb, lod = _kernels()
    from ..kernels.render.transfer import voxel_stats

    lods = order_lods(lods)
    if weights not in lod.WEIGHTS:
        raise ImportError_(f"unknown weights {weights!r}; choose from {', '.join(lod.WEIGHTS)}")
    filepath = os.path.abspath(os.path.expanduser(os.fspath(filepath)))
    base = os.path.basename(filepath)
    skipped = [] if skipped is None else skipped
    wanted = split_names(grids)
    from . import kernel_cache

    kernel_cache.announce("vdb", "lod")
    yield 0.0, f"reading {base}"
    try:
        if wanted is None:  # defaults per known cache layout (a Mantaflow cache: density)
            wanted, left_out = default_grids([g.name for g in vdb.read_topology(filepath).grids])
            skipped.extend(left_out)
        vfile = vdb.read_vdb(filepath, wanted, max_bytes=max_bytes)
    except vdb.VDBFormatError as err:
        raise ImportError_(f"cannot import {base}: {err.reason}"
                           + (f" (grid {err.grid!r})" if err.grid else "")) from err
    except MemoryError as err:
        raise ImportError_(f"cannot import {base}: out of memory while reading") from err
    skipped.extend(vfile.skipped)
    chosen = []
    for g in vfile.grids:
        is_vector = g.value_type.startswith("vec3")
        if is_vector and not vector_magnitude:
            skipped.append((g.name, "vector grid (enable 'Vector Grids as Magnitude' to import it)"))
        elif g.active_voxels == 0:
            skipped.append((g.name, "empty grid (no active voxels)"))
        else:
            chosen.append(g)
    if not chosen:
        why = "; ".join(f"{n}: {r}" for n, r in skipped) or "the file holds no grids"
        raise ImportError_(f"no scalar grid to import in {base} ({why})")
    for g in chosen:
        if max(np.abs(g.bbox_min).max(), np.abs(g.bbox_max).max()) >= ORIGIN_LIMIT - 4096:
            raise ImportError_(f"grid {g.name!r} of {base} reaches index coordinates beyond "
                               f"{ORIGIN_LIMIT:,}: too far from the origin to store exactly")
    steps = len(chosen) * len(lods)
    out = []
    k = 0
    for g in chosen:
        cg = ConvertedGrid(filepath, g.name, g.grid_class, g.value_type,
                           np.asarray(g.index_to_world, np.float64), _leaf_box(g))
        # NaN/Inf are no density: such voxels become inactive, counted, and the user is warned.
        cg.nonfinite_voxels = vdb.sanitize_nonfinite(g)
        if cg.nonfinite_voxels:
            warnings.warn(f"{base}: grid {g.name!r} has {cg.nonfinite_voxels:,} non-finite (NaN/Inf) "
                          "voxels; they were made inactive", RuntimeWarning, stacklevel=2)
        if g.grid_class != "level_set":  # level sets are coloured by position, not value
            cg.values = voxel_stats(g)
        cg.seconds_compile = _warm_up(lod, g, lods, weights, level_set_band, compute_error)
        for name in lods:
            yield 0.05 + 0.95 * k / steps, f"{g.name}: {lod_label(name)} LOD"
            k += 1
            t0 = time.perf_counter()
            try:
                extra = dict(tolerance=tolerance) if name == "adaptive" else {}
                gset = lod.build_lod(g, name, weights, level_set_band=level_set_band, **extra)
            except MemoryError as err:
                raise ImportError_(f"{g.name}: out of memory building the {name} LOD") from err
            seconds = time.perf_counter() - t0
            error = {}
            if compute_error:
                try:
                    measured = gset.params.get("field_error") or lod.field_error(g, gset)
                    error = {k_: v for k_, v in measured.items() if isinstance(v, (int, float, str))}
                except MemoryError:
                    error = {}
            cg.lods.append(ConvertedLOD(name, gset, seconds, error))
        out.append(cg)
    yield 1.0, "creating objects"
    return out


class _Progress:
    """Adapts a WindowManager (progress_begin/update/end) or a callable(fraction, text)."""

    def __init__(self, target):
        self.target = target
        self.wm = target if hasattr(target, "progress_update") else None
        if self.wm is not None:
            try:
                self.wm.progress_begin(0, 1000)
            except Exception:  # noqa: BLE001 - no window (some headless contexts)
                self.wm = None

    def __call__(self, fraction, text):
        if self.wm is not None:
            try:
                self.wm.progress_update(int(1000 * fraction))
            except Exception:  # noqa: BLE001
                pass
        elif callable(self.target):
            self.target(fraction, text)

    def end(self):
        if self.wm is not None:
            try:
                self.wm.progress_end()
            except Exception:  # noqa: BLE001
                pass


def convert_file(filepath, grids=None, lods=("medium",), weights="field", level_set_band=True,
                 vector_magnitude=False, max_bytes=None, compute_error=True, progress=None,
                 cancel=None, skipped=None, *, tolerance=0.02) -> list:
    """Read and convert one file (no Blender data is touched). Raises ImportError_/ImportCancelled."""
    steps = convert_steps(filepath, grids, lods, weights, level_set_band, vector_magnitude,
                          max_bytes, compute_error, skipped, tolerance=tolerance)
    report = _Progress(progress) if progress is not None else None
    try:
        while True:
            try:
                fraction, text = next(steps)
            except StopIteration as stop:
                return stop.value
            if report is not None:
                report(fraction, text)
            if cancel is not None and cancel():
                raise ImportCancelled()
    finally:
        steps.close()
        if report is not None:
            report.end()


# -- phase 2: Blender datablocks -----------------------------------------------------------------
def point_arrays(cg: ConvertedGrid) -> dict:
    """name -> (Blender type, flat numpy array, components) for every attribute the object gets."""
    sets = [cl.gset for cl in cg.lods]
    m = sum(s.count for s in sets)
    centres = np.empty((m, 3), np.float32)
    origins = np.empty((m, 3), np.float32)
    sig = np.empty((m, 3), np.float32)
    lod = np.empty(m, np.int8)
    vals = np.empty(m, np.float32)
    amps = np.empty(m, np.float32)
    vox = np.empty(m, np.int32)
    at = 0
    for i, s in enumerate(sets):
        n = s.count
        o = np.repeat(np.asarray(s.group_origins, np.int64), np.diff(s.group_start), axis=0)
        c = o.astype(np.float64) + np.asarray(s.offsets, np.float64)
        if n and np.abs(c).max() >= MAX_EXACT_INDEX:
            raise ImportError_(f"{cg.name}: Gaussian centres beyond {MAX_EXACT_INDEX:,} voxels "
                               "from the origin lose float32 precision")
        sl = slice(at, at + n)
        centres[sl] = c
        origins[sl] = o
        sig[sl] = s.sigmas
        lod[sl] = i
        vals[sl] = s.values
        amps[sl] = s.amplitudes
        vox[sl] = s.voxels
        at += n
    out = {
        "position": ("FLOAT_VECTOR", centres, 3),
        "radius": ("FLOAT", sig.max(axis=1) if m else np.zeros(0, np.float32), 1),
        "gs_lod": ("INT8", lod, 1),
        "gs_origin": ("FLOAT_VECTOR", origins, 3),
    }
    sphere = bool(np.all((sig[:, 0] == sig[:, 1]) & (sig[:, 1] == sig[:, 2])))
    out["gs_sigma"] = ("FLOAT", np.ascontiguousarray(sig[:, 0]), 1) if sphere else ("FLOAT_VECTOR", sig, 3)
    if not cg.is_level_set:
        out["gs_value"] = ("FLOAT", vals, 1)
    if not np.all(amps == 1.0):
        out["gs_amplitude"] = ("FLOAT", amps, 1)
    out["gs_voxels"] = ("INT", vox, 1)
    return out


def bytes_per_point(arrays: dict) -> int:
    return sum(a.dtype.itemsize * comps for _, a, comps in arrays.values())


def _lod_stats(cg: ConvertedGrid, per_point: int) -> list:
    out = []
    start = 0
    for cl in cg.lods:
        s = cl.gset
        item = {"lod": cl.name, "label": lod_label(cl.name), "count": s.count, "start": start,
                "bytes": s.count * per_point, "seconds": round(cl.seconds, 6),
                "spheres": s.n_spheres, "groups": int(len(s.group_origins)),
                "n_leaf_groups": int(getattr(s, "n_leaf_groups", 0)),
                "sigma_scale": float(getattr(s, "sigma_scale", 0.0)),
                "weights": s.weights}
        for key in ("nrmse", "rmse", "max_abs", "seconds", "surface_iou", "reference"):
            if key in cl.error:
                item["error_seconds" if key == "seconds" else key] = cl.error[key]
        params = getattr(s, "params", {}) or {}
        for key in ("value_min", "value_max", "band_threshold", "tolerance"):
            if isinstance(params.get(key), (int, float)):
                item[key] = float(params[key])
        if "tolerance_met" in params:  # adaptive: whether the field met the tolerance
            item["tolerance_met"] = bool(params["tolerance_met"])
        out.append(item)
        start += s.count
    return out


def _new_pointcloud_object(name, arrays, collection):
    """A mesh of loose vertices with the attributes, converted to a POINTCLOUD object (5.0 has no
    Python API to add points to a point cloud)."""
    import bpy

    n = len(arrays["position"][1])
    mesh = bpy.data.meshes.new(name)
    created = [mesh]
    try:
        mesh.vertices.add(n)
        mesh.vertices.foreach_set("co", arrays["position"][1].ravel())
        for key, (btype, arr, _) in arrays.items():
            if key == "position":
                continue
            attr = mesh.attributes.new(key, btype, "POINT")
            attr.data.foreach_set("vector" if btype == "FLOAT_VECTOR" else "value", arr.ravel())
        obj = bpy.data.objects.new(name, mesh)
        created.append(obj)
        collection.objects.link(obj)
    except BaseException:
        _remove_ids(created)
        raise
    return obj, mesh


def _remove_ids(ids):
    import bpy

    for idb in reversed(ids):
        try:
            if isinstance(idb, bpy.types.Object):
                bpy.data.objects.remove(idb)
            elif isinstance(idb, bpy.types.Mesh):
                bpy.data.meshes.remove(idb)
            elif isinstance(idb, bpy.types.PointCloud):
                bpy.data.pointclouds.remove(idb)
        except ReferenceError:
            pass


def _convert_to_pointclouds(objs):
    """object.convert(target='POINTCLOUD') on the given objects, each linked to the view layer."""
    import bpy

    scene = bpy.context.scene
    view_layer = bpy.context.view_layer
    temp_links = []
    in_scene = {scene.collection, *scene.collection.children_recursive}
    for obj in objs:
        if not any(c in in_scene for c in obj.users_collection):  # e.g. an unlinked collection
            scene.collection.objects.link(obj)
            temp_links.append(obj)
    try:
        override = dict(active_object=objs[0], object=objs[0], selected_objects=list(objs),
                        selected_editable_objects=list(objs), scene=scene, view_layer=view_layer)
        with bpy.context.temp_override(**override):
            result = bpy.ops.object.convert(target="POINTCLOUD", keep_original=False)
        if "FINISHED" not in result or any(o.type != "POINTCLOUD" for o in objs):
            raise ImportError_("Blender could not convert the points to a point cloud")
    finally:
        for obj in temp_links:
            scene.collection.objects.unlink(obj)


def _settings_to_object(obj, cg, stats, options):
    st = obj.gaussvdb
    st.is_gaussvdb = True
    if cg.sequence:  # the first file, with Blender's Volume sequence settings
        from . import source_path

        st.source_volume = source_path.sequence_volume(cg.filepath, **cg.sequence["settings"])
    else:
        st.source_file = cg.filepath
    st.grid_name = cg.name
    st.grid_class = cg.grid_class
    st.value_type = cg.value_type
    st.lods = ",".join(cl.name for cl in cg.lods)
    st.weights = options["weights"]
    st.level_set_band = bool(options["level_set_band"])
    st.vector_magnitude = bool(options["vector_magnitude"])
    st.index_to_world = " ".join(repr(float(v)) for v in cg.index_to_world.ravel())  # exact float64
    st.leaf_box_min = [float(v) for v in cg.leaf_box[0]]
    st.leaf_box_max = [float(v) for v in cg.leaf_box[1]]
    st.layout_version = LAYOUT_VERSION
    figures = {"lods": stats, "nonfinite_voxels": cg.nonfinite_voxels, "values": cg.values,
               "seconds_compile": cg.seconds_compile}
    if cg.sequence:
        figures["sequence"] = cg.sequence["figures"]
    from . import lod_figures

    lod_figures.store(st, figures)
    names = [cl.name for cl in cg.lods]
    # Like the Subdivision modifier: the viewport shows the coarsest LOD held, renders the finest.
    st.viewport_lod = names[0]
    st.render_lod = names[-1]


def build_objects(converted, collection=None, options=None) -> list:
    """Create one point-cloud object per ConvertedGrid; on any failure remove everything created."""
    import bpy
    from mathutils import Matrix

    options = {"weights": "field", "level_set_band": True, "vector_magnitude": False, **(options or {})}
    if collection is None:
        collection = bpy.context.view_layer.active_layer_collection.collection
    prepared = []
    for cg in converted:  # still no datablock: arrays first, so a precision error creates nothing
        arrays = point_arrays(cg)
        prepared.append((cg, arrays, _lod_stats(cg, bytes_per_point(arrays))))
    created = []
    try:
        objs = []
        for cg, arrays, _ in prepared:
            stem = os.path.splitext(os.path.basename(cg.filepath))[0]
            obj, mesh = _new_pointcloud_object(f"{stem}_{cg.name}", arrays, collection)
            created += [mesh, obj]
            objs.append(obj)
        _convert_to_pointclouds(objs)
        for (cg, _, stats), obj in zip(prepared, objs):
            created.append(obj.data)
            pc = obj.data
            pc.name = obj.name
            if ".select_vert" in pc.attributes:
                pc.attributes.remove(pc.attributes[".select_vert"])
            obj.matrix_world = Matrix(cg.index_to_world.tolist())
            _settings_to_object(obj, cg, stats, options)
        for idb in created:  # the meshes the conversion left without users
            if isinstance(idb, bpy.types.Mesh) and idb.users == 0:
                bpy.data.meshes.remove(idb)
        return objs
    except BaseException:
        _remove_ids([c for c in created if _alive(c)])
        raise


def _alive(idb):
    try:
        idb.name  # noqa: B018
        return True
    except ReferenceError:
        return False


# -- the entry points ------------------------------------------------------------------------------
def import_vdb(filepath, grids=None, lods=("medium",), weights="field", level_set_band=True,
               vector_magnitude=False, collection=None, progress=None, cancel=None, max_bytes=None,
               compute_error=True, skipped=None) -> list:
    """Import the grids of one .vdb file; returns the new objects (one per grid)."""
    converted = convert_file(filepath, grids, lods, weights, level_set_band, vector_magnitude,
                             max_bytes, compute_error, progress, cancel, skipped)
    return build_objects(converted, collection, dict(weights=weights, level_set_band=level_set_band,
                                                     vector_magnitude=vector_magnitude))


def import_files(context, paths, grids=None, lods=("medium",), weights="field",
                 level_set_band=True, vector_magnitude=False, progress=None, cancel=None,
                 max_bytes=None, compute_error=True, sequence=True, *, tolerance=0.02):
    """Import several files; all are converted before any object is created. -> (objects, message)

    With ``sequence`` a numbered file with numbered siblings (or several numbered files
    selected) imports as one sequence: one object per grid following the timeline."""
    if not paths:
        raise ImportError_("no file selected")
    from . import sequence_import

    converted = []
    skipped = []
    for pat, items, is_seq in sequence_import.sequences(paths) if sequence else [(None, paths, False)]:
        if is_seq:
            converted += sequence_import.convert_sequence(
                pat.path(items[0]), items if len(items) > 1 else None, grids, lods, weights,
                level_set_band, vector_magnitude, max_bytes, compute_error, progress, cancel, skipped,
                tolerance=tolerance)
            continue
        for path in items if pat is None else [pat.path(n) for n in items]:
            converted += convert_file(path, grids, lods, weights, level_set_band, vector_magnitude,
                                      max_bytes, compute_error, progress, cancel, skipped,
                                      tolerance=tolerance)
    collection = None
    if context is not None and getattr(context, "view_layer", None) is not None:
        collection = context.view_layer.active_layer_collection.collection
    objs = build_objects(converted, collection, dict(weights=weights, level_set_band=level_set_band,
                                                     vector_magnitude=vector_magnitude))
    sequence_import.name_objects(objs)
    if context is not None and getattr(context, "view_layer", None) is not None and objs:
        for obj in context.view_layer.objects.selected:
            obj.select_set(False)
        for obj in objs:
            if context.view_layer.objects.get(obj.name) is not None:
                obj.select_set(True)
        if context.view_layer.objects.get(objs[-1].name) is not None:
            context.view_layer.objects.active = objs[-1]
    note = sequence_import.unreadable_note(objs)
    return objs, status_message(objs, skipped) + (f"; {note}" if note else "")


def _fmt_bytes(n):
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} B"


def object_stats(obj) -> list:
    from . import lod_figures

    return lod_figures.as_dicts(obj.gaussvdb)


def status_message(objs, skipped=()) -> str:
    """'density: 366,112 Gaussians (Medium) in 0.41 s, field NRMSE 0.8%, 2.9 MB; ...'"""
    parts = []
    for obj in objs:
        stats = object_stats(obj)
        if not stats:
            continue
        labels = " / ".join(s["label"] for s in stats)
        counts = " / ".join(f"{s['count']:,}" for s in stats)
        secs = sum(s["seconds"] for s in stats)
        errs = [s.get("nrmse") for s in stats]
        text = f"{obj.gaussvdb.grid_name}: {counts} Gaussians ({labels}) in {secs:.2f} s"
        if all(e is not None for e in errs):
            text += ", field NRMSE " + " / ".join(f"{100 * e:.1f}%" for e in errs)
        text += f", {_fmt_bytes(sum(s['bytes'] for s in stats))}"
        bad = json.loads(obj.gaussvdb.stats_json or "{}").get("nonfinite_voxels", 0)
        if bad:
            text += f", {bad:,} NaN/Inf voxels made inactive"
        parts.append(text)
    if skipped:
        parts.append("skipped " + ", ".join(sorted({str(n) for n, _ in skipped})))
    compile_s = sum(json.loads(o.gaussvdb.stats_json or "{}").get("seconds_compile", 0.0) for o in objs)
    if compile_s >= 1.0:
        parts.append(f"kernels compiled or loaded in {compile_s:.1f} s (not in the times above)")
    return "; ".join(parts) or "nothing imported"


# -- reading back (the engine calls this at render time) ------------------------------------------
def lod_names(obj) -> list:
    return [n for n in obj.gaussvdb.lods.split(",") if n]


def lod_index(obj, lod) -> int:
    """gs_lod value of ``lod`` (a name, or an int passed through)."""
    if isinstance(lod, (int, np.integer)):
        return int(lod)
    names = lod_names(obj)
    if lod not in names:
        raise KeyError(f"{obj.name} holds no {lod!r} LOD (it holds {', '.join(names) or 'none'})")
    return names.index(lod)


def active_lod(obj, render=False) -> str:
    """The LOD the engine should draw: the object's Render LOD for final renders, else Viewport."""
    st = obj.gaussvdb
    name = st.render_lod if render else st.viewport_lod
    names = lod_names(obj)
    return name if name in names else (names[-1] if render else names[0])


def _read_attr(attrs, name, n, comps):
    attr = attrs.get(name)
    if attr is None:
        return None
    if attr.data_type == "FLOAT_VECTOR":
        a = np.empty(n * 3, np.float32)
        attr.data.foreach_get("vector", a)
        return a.reshape(n, 3)
    dtype = {"FLOAT": np.float32, "INT": np.int32, "INT8": np.int8, "BOOLEAN": bool}.get(attr.data_type)
    if dtype is None:
        return None
    a = np.empty(n, dtype)
    attr.data.foreach_get("value", a)
    return a


def read_attributes(obj, depsgraph=None) -> dict:
    """Every point attribute of the (evaluated) object as numpy arrays (name -> array)."""
    src = obj.evaluated_get(depsgraph) if depsgraph is not None else obj
    data = src.data
    attrs = data.attributes
    n = attrs.domain_size("POINT") if hasattr(attrs, "domain_size") else len(data.points)
    out = {}
    for attr in attrs:
        if attr.domain != "POINT" or attr.name.startswith("."):
            continue
        arr = _read_attr(attrs, attr.name, n, None)
        if arr is not None:
            out[attr.name] = arr
    return out


def gaussian_set_from_object(obj, lod=None, depsgraph=None):
    """The GaussianSet of one LOD of an imported object: the exact inverse of what the import wrote.

    ``lod``: a name ('medium'), a gs_lod index, or None (the object's Render LOD; the engine passes
    ``active_lod(obj, render)``). With ``depsgraph`` the evaluated object is read, so Geometry Nodes
    edits show up (moved points move their Gaussians: the centre is ``position``).
    """
    st = obj.gaussvdb
    if lod is None:
        lod = active_lod(obj, render=True)
    idx = lod_index(obj, lod)
    return gaussian_set_from_arrays(read_attributes(obj, depsgraph), idx, lod_names(obj),
                                    object_stats(obj), st.grid_class, st.weights,
                                    stored_index_to_world(obj), fallback_name=str(lod))


def gaussian_set_from_arrays(a, idx, names, stats, grid_class, weights, index_to_world,
                             fallback_name=""):
    """A GaussianSet from point attributes (name -> array, as ``read_attributes`` returns or
    ``point_arrays`` makes): the Gaussians with ``gs_lod == idx``. ``stats``: the per-LOD
    figures of ``_lod_stats``. One reader for objects and for the frames of a sequence, so a
    frame converted on demand is bit-identical to the same file imported alone."""
    from ..kernels.lod import GaussianSet

    n = len(a["position"])
    sel = a["gs_lod"] == idx if "gs_lod" in a else np.ones(n, bool)
    centre = a["position"][sel].astype(np.float64)
    m = len(centre)
    if "gs_origin" in a:
        origins = a["gs_origin"][sel].astype(np.float64)
    else:  # not ours (or stripped by nodes): one group per leaf cell
        origins = np.floor((centre + 0.5) / 8.0) * 8.0
    offsets = (centre - origins).astype(np.float32)
    origins = origins.astype(np.int32)
    if m:
        change = np.any(origins[1:] != origins[:-1], axis=1)
        starts = np.concatenate([[0], np.nonzero(change)[0] + 1])
    else:
        starts = np.zeros(0, np.int64)
    group_start = np.append(starts, m).astype(np.int64)
    group_origins = np.ascontiguousarray(origins[starts]).reshape(-1, 3)
    if "gs_sigma" in a:
        s = a["gs_sigma"][sel]
        sigmas = np.repeat(s[:, None], 3, axis=1) if s.ndim == 1 else s.copy()
    else:
        r = a.get("radius", np.full(n, 0.5, np.float32))[sel]
        sigmas = np.repeat(r[:, None], 3, axis=1).astype(np.float32)
    values = a["gs_value"][sel].copy() if "gs_value" in a else np.ones(m, np.float32)
    amps = a["gs_amplitude"][sel].copy() if "gs_amplitude" in a else np.ones(m, np.float32)
    voxels = a["gs_voxels"][sel].copy() if "gs_voxels" in a else np.ones(m, np.int32)
    name = names[idx] if idx < len(names) else fallback_name
    stats = next((s for s in stats if s.get("lod") == (names[idx] if idx < len(names) else None)), {})
    scale = float(stats.get("sigma_scale") or 0.0)
    codes = np.rint(sigmas / scale).astype(np.int32) if scale > 0 else None
    params = {k: stats[k] for k in ("value_min", "value_max", "band_threshold") if k in stats}
    return GaussianSet(
        group_origins=group_origins, group_start=group_start, offsets=offsets,
        sigmas=np.ascontiguousarray(sigmas, np.float32).reshape(-1, 3),
        values=values.astype(np.float32), amplitudes=amps.astype(np.float32),
        voxels=voxels.astype(np.int32), grid_class=grid_class or "fog_volume", lod=name,
        weights=weights or "field", index_to_world=index_to_world,
        background=0.0, n_leaf_groups=int(stats.get("n_leaf_groups", len(group_origins))),
        size_codes=codes, sigma_scale=scale or 0.6, params=params)


def converted_gaussian_set(cg):
    """The GaussianSet of the first LOD of a ConvertedGrid, through the arrays an object would
    hold (float32 centres and all): what ``gaussian_set_from_object`` reads after an import."""
    arrays = point_arrays(cg)
    a = {k: arr for k, (_, arr, _) in arrays.items()}
    names = [cl.name for cl in cg.lods]
    return gaussian_set_from_arrays(a, 0, names, _lod_stats(cg, bytes_per_point(arrays)),
                                    cg.grid_class, cg.lods[0].gset.weights, cg.index_to_world)


def stored_index_to_world(obj) -> np.ndarray:
    """The grid's index-to-world transform as imported (float64 4x4, column-vector form)."""
    try:
        v = np.array([float(x) for x in obj.gaussvdb.index_to_world.split()], np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.size != 16:
        return np.asarray(obj.matrix_world, np.float64)
    return v.reshape(4, 4)


# -- reload ------------------------------------------------------------------------------------------
def reload_object(obj, progress=None, cancel=None, max_bytes=None, compute_error=True):
    """Re-read the object's source file with the same settings and replace its Gaussians.

    The object keeps its name, collections, modifiers and Viewport/Render LOD; its matrix follows the
    file's transform unless the user moved the object since the import (then the placement stays).
    On error nothing changes.
    """
    import bpy
    from mathutils import Matrix

    st = obj.gaussvdb
    if not st.is_gaussvdb:
        raise ImportError_(f"{obj.name} is not a GaussVDB object")
    from . import source_path

    path = source_path.absolute(st)
    vol = st.source_volume
    if vol is not None and vol.is_sequence:  # every frame's figures again, one frame converted
        from . import sequence_import

        converted = sequence_import.convert_sequence(
            path, None, [st.grid_name], lod_names(obj) or ["medium"], st.weights or "field",
            st.level_set_band, st.vector_magnitude, max_bytes, compute_error, progress, cancel)
        for c in converted:  # keeps the object's own Volume and its timing
            c.sequence["settings"] = dict(frame_start=vol.frame_start, frame_offset=vol.frame_offset,
                                          frame_duration=vol.frame_duration,
                                          sequence_mode=vol.sequence_mode)
    else:
        converted = convert_file(path, [st.grid_name], lod_names(obj) or ["medium"],
                                 st.weights or "field", st.level_set_band, st.vector_magnitude,
                                 max_bytes, compute_error, progress, cancel)
    cg = next((c for c in converted if c.name == st.grid_name), None)
    if cg is None:
        raise ImportError_(f"{os.path.basename(path)} no longer holds grid {st.grid_name!r}")
    old_matrix = stored_index_to_world(obj)
    moved = not np.allclose(np.asarray(obj.matrix_world, np.float64), old_matrix, rtol=1e-6, atol=1e-9)
    viewport, render = st.viewport_lod, st.render_lod
    new = build_objects([cg], obj.users_collection[0] if obj.users_collection else None,
                        dict(weights=st.weights, level_set_band=st.level_set_band,
                             vector_magnitude=st.vector_magnitude))[0]
    old_data = obj.data
    try:
        obj.data = new.data
        # (the source path stays as the user left it: relative, or found elsewhere)
        for key in ("grid_class", "value_type", "lods", "layout_version"):
            setattr(st, key, getattr(new.gaussvdb, key))
        from . import lod_figures

        lod_figures.copy(new.gaussvdb, st)
        st.index_to_world = new.gaussvdb.index_to_world
        st.leaf_box_min = new.gaussvdb.leaf_box_min
        st.leaf_box_max = new.gaussvdb.leaf_box_max
        names = lod_names(obj)
        st.viewport_lod = viewport if viewport in names else names[0]
        st.render_lod = render if render in names else names[-1]
        if not moved:
            obj.matrix_world = Matrix(cg.index_to_world.tolist())
    finally:
        pc = new.data
        bpy.data.objects.remove(new)
        if obj.data is not pc and pc.users == 0:
            bpy.data.pointclouds.remove(pc)
    if old_data is not None and old_data.users == 0:
        bpy.data.pointclouds.remove(old_data)
    obj.data.name = obj.name
    obj.update_tag()
    return obj
