"""Import .vdb grids as Gaussian point clouds: the plain functions behind the import operator.

Scripts, the operator, the Reload button and the CLI all call these:

    objs = import_vdb("smoke.vdb", lods=("low", "medium"))       # -> list of Objects
    import_vdb("fire.vdb", ["density"], color_grid="temperature")  # coloured by temperature
    import_vdb("smoke.vdb", options=ConvertOptions(lods=("adaptive",), tolerance=0.01))
    import_vdb("smoke.vdb", lods=())           # the grid alone: drawn in Reference mode only
    gset = gaussian_set_from_object(objs[0], "medium")            # -> kernels.lod.GaussianSet

The options are one ``ConvertOptions`` (kernels/convert_options.py); the keywords of
``import_vdb``, ``import_files`` and ``convert_file`` are a script's shorthand for its fields.
Two phases, so an error or a cancel leaves nothing half-built: ``convert_file`` reads and converts
everything (io/conversion.py, kernels.pipeline, no datablock), then ``build_objects``
(io/datablocks.py) creates the datablocks (and removes them again if creating them fails). The
layout of an imported object is io/schema.py's.
"""

from __future__ import annotations

import json
import os

import numpy as np

from ...kernels.convert_options import ConvertOptions, options_of  # noqa: F401  (scripting API)
from ...kernels.pipeline import (  # noqa: F401  (the scripting API: importer.X)
    ConvertedGrid,
    ConvertedLOD,
    default_grids,
    lod_label,
    order_lods,
    split_names,
)
from ..properties import lod_figures
from . import conversion, sequence_import
from .conversion import ImportCancelled, VDBImportError, bpy_abspath, convert_steps  # noqa: F401
from .datablocks import build_objects
from .schema import (  # noqa: F401  (the scripting API: importer.X)
    gaussian_set_from_object,
    lod_names,
    object_stats,
    stored_index_to_world,
)


def default_grids_hint(filepath) -> str:
    """One line for the import dialog: what an empty Grids field imports from this file."""
    generic = "Empty Grids: every scalar grid (a Mantaflow cache: density only)"
    path = bpy_abspath(filepath)
    if not path or not os.path.isfile(path):
        return generic
    from ..engine import kernel_cache

    if not kernel_cache.compiled("vdb"):  # never compile inside a dialog's draw
        return generic
    try:
        st = os.stat(path)
        key = (path, st.st_mtime_ns, st.st_size)
        hint = _HINTS.get(key)
        if hint is None:
            from ...kernels import vdb

            names = [g.name for g in vdb.read_topology(path).grids]
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


def selected_paths(filepath, directory="", files=()) -> list:
    """The files chosen in the file browser (several when shift-selected), else ``filepath``."""
    names = [f.name for f in files if getattr(f, "name", "")] if files else []
    if directory and names:
        return [os.path.join(directory, n) for n in names]
    return [filepath] if filepath else []


# -- the entry points ------------------------------------------------------------------------------
def convert_file(filepath, grids=None, lods=None, *, options=None, progress=None, cancel=None,
                 skipped=None, **changes) -> list:
    """Read and convert one file (no Blender data is touched). Raises VDBImportError or
    ImportCancelled. ``grids``, ``lods`` and ``changes`` (ConvertOptions fields) over ``options``."""
    return conversion.convert_file(filepath, options_of(options, grids, lods, **changes), progress,
                                   cancel, skipped)


def import_vdb(filepath, grids=None, lods=None, *, options=None, collection=None, progress=None,
               cancel=None, skipped=None, **changes) -> list:
    """Import the grids of one .vdb file; returns the new objects (one per grid). ``grids``,
    ``lods`` and ``changes`` (ConvertOptions fields) over ``options``. A ``color_grid`` the file
    does not hold raises VDBImportError naming the grid and the file."""
    opts = options_of(options, grids, lods, **changes)
    converted = conversion.convert_file(filepath, opts, progress, cancel, skipped)
    return build_objects(converted, collection, opts)


def import_files(context, paths, grids=None, lods=None, *, options=None, sequence=True,
                 progress=None, cancel=None, **changes):
    """Import several files; all are converted before any object is created. -> (objects, message)

    With ``sequence`` a numbered file with numbered siblings (or several numbered files
    selected) imports as one sequence: one object per grid following the timeline (sequences
    take no colour grid: ``color_grid`` applies to single files)."""
    opts = options_of(options, grids, lods, **changes)
    if not paths:
        raise VDBImportError("no file selected")
    import time

    t0 = time.perf_counter()

    converted = []
    skipped = []
    for pat, items, is_seq in sequence_import.sequences(paths) if sequence else [(None, paths, False)]:
        if is_seq:
            if opts.color_grid:
                raise VDBImportError(f"{os.path.basename(items[0])}: a colour grid is for single "
                                     "files, not sequences (turn Sequence off)")
            converted += sequence_import.convert_sequence(
                pat.path(items[0]), items if len(items) > 1 else None, opts, progress, cancel,
                skipped)
            continue
        for path in items if pat is None else [pat.path(n) for n in items]:
            converted += conversion.convert_file(path, opts, progress, cancel, skipped)
    collection = None
    if context is not None and getattr(context, "view_layer", None) is not None:
        collection = context.view_layer.active_layer_collection.collection
    t1 = time.perf_counter()
    objs = build_objects(converted, collection, opts)
    sequence_import.name_objects(objs)
    t2 = time.perf_counter()
    if context is not None and getattr(context, "view_layer", None) is not None and objs:
        for obj in context.view_layer.objects.selected:
            obj.select_set(False)
        for obj in objs:
            if context.view_layer.objects.get(obj.name) is not None:
                obj.select_set(True)
        if context.view_layer.objects.get(objs[-1].name) is not None:
            context.view_layer.objects.active = objs[-1]
    note = sequence_import.unreadable_note(objs)
    timing = import_timing(converted, time.perf_counter() - t0, t2 - t1)
    return objs, status_message(objs, skipped, timing) + (f"; {note}" if note else "")


def import_timing(converted, total, objects) -> str:
    """'import 15.62 s: read 0.21, build 0.16, field error 14.20, kernels 0.05, objects 0.90, other
    0.10 s': the whole import (total seconds) and its parts, from the ConvertedGrids' figures and
    the seconds spent creating the objects. A file's read time is counted once per file."""
    read = {}
    for cg in converted:
        read[cg.filepath] = max(read.get(cg.filepath, 0.0), cg.seconds_read)
    lods = [cl for cg in converted for cl in cg.lods]
    build = sum(cl.seconds for cl in lods)
    error = sum(cl.seconds_error for cl in lods if cl.name != "adaptive")  # adaptive: in its build
    kernels = sum(cg.seconds_compile for cg in converted)
    other = max(total - sum(read.values()) - build - error - kernels - objects, 0.0)
    return (f"import {total:.2f} s: read {sum(read.values()):.2f}, build {build:.2f}, field error "
            f"{error:.2f}, kernels {kernels:.2f}, objects {objects:.2f}, other {other:.2f} s")


def status_message(objs, skipped=(), timing=None) -> str:
    """'density: 366,112 Gaussians (Medium), field NRMSE 0.8%, 2.9 MB; ...; import 0.52 s: read
    ...' (timing: import_timing's text, where the caller timed the whole import)."""
    parts = []
    for obj in objs:
        stats = object_stats(obj)
        if not stats:
            continue
        labels = " / ".join(s["label"] for s in stats)
        counts = " / ".join(f"{s['count']:,}" for s in stats)
        errs = [s.get("nrmse") for s in stats]
        text = f"{obj.gaussvdb.grid_name}: {counts} Gaussians ({labels})"
        if all(e is not None for e in errs):
            text += ", field NRMSE " + " / ".join(f"{100 * e:.1f}%" for e in errs)
        text += f", {lod_figures.fmt_bytes(sum(s['bytes'] for s in stats))}"
        bad = json.loads(obj.gaussvdb.stats_json or "{}").get("nonfinite_voxels", 0)
        if bad:
            text += f", {bad:,} NaN/Inf voxels made inactive"
        parts.append(text)
    if skipped:
        parts.append("skipped " + ", ".join(sorted({str(n) for n, _ in skipped})))
    if timing:
        parts.append(timing)
    return "; ".join(parts) or "nothing imported"


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
        raise VDBImportError(f"{obj.name} is not a GaussVDB object")
    from . import source_path

    path = source_path.absolute(st)
    vol = st.source_volume
    opts = st.convert_options(grids=(st.grid_name,), lods=tuple(lod_names(obj)),
                              max_bytes=max_bytes, compute_error=compute_error)
    if vol is not None and vol.is_sequence:  # every frame's figures again, one frame converted
        converted = sequence_import.convert_sequence(path, None, opts, progress, cancel)
        for c in converted:  # keeps the object's own Volume and its timing
            c.sequence["settings"] = dict(frame_start=vol.frame_start, frame_offset=vol.frame_offset,
                                          frame_duration=vol.frame_duration,
                                          sequence_mode=vol.sequence_mode)
    else:
        converted = conversion.convert_file(path, opts.replace(color_grid=st.color_grid),
                                            progress, cancel)
    cg = next((c for c in converted if c.name == st.grid_name), None)
    if cg is None:
        raise VDBImportError(f"{os.path.basename(path)} no longer holds grid {st.grid_name!r}")
    old_matrix = stored_index_to_world(obj)
    moved = not np.allclose(np.asarray(obj.matrix_world, np.float64), old_matrix, rtol=1e-6, atol=1e-9)
    viewport, render = st.viewport_lod, st.render_lod
    new = build_objects([cg], obj.users_collection[0] if obj.users_collection else None, opts)[0]
    old_data = obj.data
    try:
        obj.data = new.data
        # (the source path stays as the user left it: relative, or found elsewhere)
        for key in ("grid_class", "value_type", "lods", "layout_version", "color_grid"):
            setattr(st, key, getattr(new.gaussvdb, key))
        lod_figures.copy(new.gaussvdb, st)
        st.index_to_world = new.gaussvdb.index_to_world
        st.leaf_box_min = new.gaussvdb.leaf_box_min
        st.leaf_box_max = new.gaussvdb.leaf_box_max
        names = lod_names(obj)
        if names:
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
