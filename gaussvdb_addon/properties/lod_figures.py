"""The per-LOD figures of an import (Object.gaussvdb.lod_stats): one item per LOD held, in gs_lod
order, written from the importer's list of dicts (``store``) and read back as that list
(``as_dicts``: the status line, the panel's list, reading the Gaussians back).

Typed properties where float32 is enough (counts, times, errors: what the panel shows); the
figures the Gaussians are read back with (sigma_scale, the value range, the band threshold) as
exact float64 reprs, as index_to_world is, because Blender float properties are float32. Files
from before the collection hold the list in stats_json: it is moved over when they load, and read
from there where it cannot be (a linked object).
"""

import json
import math

import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty

from ...kernels import lod_names

INTS = ("count", "start", "spheres", "groups", "n_leaf_groups")
FLOATS = ("bytes", "seconds", "nrmse", "rmse", "max_abs", "error_seconds", "surface_iou",
          "tolerance")  # NaN: not measured
EXACT = ("sigma_scale", "value_min", "value_max", "band_threshold")  # repr; '': none


def _exact(name, text):
    return StringProperty(name=name, description=f"{text} (exact float64; empty: none)")


class GaussVDBLODFigures(bpy.types.PropertyGroup):
    """One LOD's figures; ``name`` is the LOD preset."""

    count: IntProperty(name="Gaussians")
    start: IntProperty(name="First Point", description="Index of the LOD's first point")
    spheres: IntProperty(name="Spheres", description="Gaussians with equal sigmas")
    groups: IntProperty(name="Groups", description="Leaf and tile groups")
    n_leaf_groups: IntProperty(name="Leaf Groups")
    bytes: FloatProperty(name="Memory", description="Bytes of point attributes (an IntProperty "
                                                    "stops at 2 GiB)")
    seconds: FloatProperty(name="Time", description="Seconds to build the LOD")
    nrmse: FloatProperty(name="NRMSE", default=math.nan,
                         description="Field error over the active voxels, over the value range")
    rmse: FloatProperty(name="RMSE", default=math.nan)
    max_abs: FloatProperty(name="Max Error", default=math.nan)
    error_seconds: FloatProperty(name="Error Time", default=math.nan)
    surface_iou: FloatProperty(name="Surface IoU", default=math.nan)
    tolerance: FloatProperty(name="Tolerance", default=math.nan)
    tolerance_met: BoolProperty(name="Tolerance Met")
    reference: StringProperty(name="Reference", description="What the error is measured against")
    sigma_scale: _exact("Sigma Scale", "Sigma step of the compact encoding")
    value_min: _exact("Value Min", "Smallest active value")
    value_max: _exact("Value Max", "Largest active value")
    band_threshold: _exact("Band Threshold", "Level sets: |phi| kept")


def store(settings, figures):
    """Write an import's figures: figures["lods"] (a list of dicts, one per LOD) into the
    collection, the rest as JSON into stats_json."""
    figures = dict(figures)
    settings.lod_stats.clear()
    for d in figures.pop("lods", ()):
        item = settings.lod_stats.add()
        item.name = d["lod"]
        for key in INTS:
            setattr(item, key, int(d.get(key, 0)))
        for key in FLOATS:
            v = d.get(key)
            setattr(item, key, math.nan if v is None else float(v))
        for key in EXACT:
            v = d.get(key)
            setattr(item, key, repr(float(v)) if isinstance(v, (int, float)) else "")
        item.reference = str(d.get("reference", ""))
        item.tolerance_met = bool(d.get("tolerance_met", False))
    settings.stats_json = json.dumps(figures)


def as_dicts(settings) -> list:
    """The figures as the importer wrote them, with each LOD's label (lod_names)."""
    if not len(settings.lod_stats):
        return _legacy(settings)
    out = []
    for item in settings.lod_stats:
        d = {"lod": item.name, "label": lod_names.label(item.name)}
        d.update((key, getattr(item, key)) for key in INTS)
        d.update((key, getattr(item, key)) for key in FLOATS if not math.isnan(getattr(item, key)))
        d.update((key, float(getattr(item, key))) for key in EXACT if getattr(item, key))
        if item.reference:
            d["reference"] = item.reference
        if item.name in lod_names.TOLERANCE_PRESETS:
            d["tolerance_met"] = item.tolerance_met
        out.append(d)
    return out


def copy(source, target):
    """The figures of ``source`` (settings) onto ``target`` (a reload keeps its object)."""
    figures = dict(json.loads(source.stats_json or "{}"), lods=as_dicts(source))
    store(target, figures)


def _legacy(settings) -> list:
    try:
        lods = json.loads(settings.stats_json or "{}").get("lods", [])
    except ValueError:
        return []
    return [dict(d, label=lod_names.label(d.get("lod", "?"))) for d in lods if isinstance(d, dict)]


def upgrade(obj) -> bool:
    """Move an older file's per-LOD figures from stats_json into the collection (run by
    io/versioning.do_versions when a file loads)."""
    st = obj.gaussvdb
    if not st.is_gaussvdb or len(st.lod_stats) or obj.library is not None:
        return False
    lods = _legacy(st)
    if not lods:
        return False
    store(st, dict(json.loads(st.stats_json), lods=lods))
    return True


def fmt_bytes(n) -> str:
    """'2.9 MB': memory as the status line and the panel show it."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} B"


CLASSES = (GaussVDBLODFigures,)
