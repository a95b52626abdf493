"""The point-cloud schema: how an imported object holds its Gaussians, written and read here only.

ONE PointCloud holds every LOD, concatenated in the order of the object's ``gaussvdb.lods``
list, each LOD's Gaussians in the kernel's order (groups ascending). Point attributes (README
"Point-cloud layout"):

  position      FLOAT_VECTOR  Gaussian centre, grid INDEX space (float32 of origin + offset)
  radius        FLOAT         display size: the largest sigma (index units), for the point display
  gs_lod        INT8          index into the object's ``gaussvdb.lods`` list (0 = first LOD held)
  gs_origin     FLOAT_VECTOR  origin of the Gaussian's group (leaf/tile min corner; integers)
  gs_sigma      FLOAT         sigma, when every Gaussian of every LOD held is a sphere
                FLOAT_VECTOR  (sx, sy, sz) otherwise
  gs_value      FLOAT         value the Gaussian stands for (absent for level sets)
  gs_amplitude  FLOAT         peak occupancy (absent when all are 1: paper weights)
  gs_voxels     INT           voxels the Gaussian represents
  gs_color      FLOAT         the colour grid's value at the Gaussian (only when imported with one:
                              ``gaussvdb.color_grid``; kernels/lod/second_grid.py)
  gs_distance   FLOAT         level sets: the mean signed distance of the voxels the Gaussian
                              stands for (GaussianSet.distances; absent in older files)

The object's ``matrix_world`` is the grid's index-to-world transform (also stored exactly, as
float64 text, in ``gaussvdb.index_to_world``); ``gaussvdb.stats_json`` holds the per-LOD figures
(``lod_stats``); ``gaussvdb.layout_version`` says which version of this layout the object holds
(0: written before the version was stored; versioning.py upgrades those when a file loads).
"""

from __future__ import annotations

import numpy as np

from ...kernels.pipeline import ConversionError, lod_label

LAYOUT_VERSION = 1

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
    "gs_color": ("FLOAT", np.float32, 1),
    "gs_distance": ("FLOAT", np.float32, 1),
}
BLENDER_DTYPES = {"FLOAT": np.float32, "INT": np.int32, "INT8": np.int8, "BOOLEAN": bool}


# -- writing -----------------------------------------------------------------------------------------
def point_arrays(cg) -> dict:
    """name -> (Blender type, numpy array, components) for every attribute of a ConvertedGrid's
    object; ConversionError when a centre is too far out to be exact in float32."""
    sets = [cl.gset for cl in cg.lods]
    m = sum(s.count for s in sets)
    centres = np.empty((m, 3), np.float32)
    origins = np.empty((m, 3), np.float32)
    sig = np.empty((m, 3), np.float32)
    lod = np.empty(m, np.int8)
    vals = np.empty(m, np.float32)
    amps = np.empty(m, np.float32)
    vox = np.empty(m, np.int32)
    colors = np.empty(m, np.float32) if cg.color_grid else None
    dist = np.empty(m, np.float32) if all(s.distances is not None for s in sets) else None
    at = 0
    for i, s in enumerate(sets):
        n = s.count
        o = np.repeat(np.asarray(s.group_origins, np.int64), np.diff(s.group_start), axis=0)
        c = o.astype(np.float64) + np.asarray(s.offsets, np.float64)
        if n and np.abs(c).max() >= MAX_EXACT_INDEX:
            raise ConversionError(f"{cg.name}: Gaussian centres beyond {MAX_EXACT_INDEX:,} voxels "
                                  "from the origin lose float32 precision")
        sl = slice(at, at + n)
        centres[sl] = c
        origins[sl] = o
        sig[sl] = s.sigmas
        lod[sl] = i
        vals[sl] = s.values
        amps[sl] = s.amplitudes
        vox[sl] = s.voxels
        if colors is not None:
            colors[sl] = s.color_values
        if dist is not None:
            dist[sl] = s.distances
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
    if colors is not None:
        out["gs_color"] = ("FLOAT", colors, 1)
    if dist is not None and cg.is_level_set:
        out["gs_distance"] = ("FLOAT", dist, 1)
    return out


def bytes_per_point(arrays: dict) -> int:
    return sum(a.dtype.itemsize * comps for _, a, comps in arrays.values())


def lod_stats(cg, per_point: int) -> list:
    """The per-LOD figures stored in ``stats_json['lods']`` (the reader takes the group count,
    sigma scale and value range from them)."""
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


def write_attributes(geometry, arrays):
    """Set the attributes of ``arrays`` (``point_arrays``) on a Mesh or PointCloud with as many
    points, creating those missing; ``position`` included."""
    attrs = geometry.attributes
    for key, (btype, arr, _) in arrays.items():
        attr = attrs.get(key)
        if attr is not None and attr.data_type != btype:
            attrs.remove(attr)
            attr = None
        if attr is None:
            attr = attrs.new(key, btype, "POINT")
        attr.data.foreach_set("vector" if btype == "FLOAT_VECTOR" else "value", arr.ravel())


def index_to_world_text(m) -> str:
    return " ".join(repr(float(v)) for v in np.asarray(m, np.float64).ravel())  # exact float64


# -- reading -----------------------------------------------------------------------------------------
DEFAULT_LODS = ["medium"]  # what an object that names no LOD (layout 0) holds


def lod_names(obj) -> list:
    """The LODs the object holds, in ``gs_lod`` order; none for a grid imported alone (no
    Gaussians: the reference mode draws its voxels)."""
    st = obj.gaussvdb
    names = [n for n in st.lods.split(",") if n]
    return names or (list(DEFAULT_LODS) if int(getattr(st, "layout_version", 0)) == 0 else [])


def lod_index(obj, lod) -> int:
    """gs_lod value of ``lod`` (a name, or an int passed through)."""
    if isinstance(lod, (int, np.integer)):
        return int(lod)
    names = lod_names(obj)
    if lod not in names:
        raise KeyError(f"{obj.name} holds no {lod!r} LOD (it holds {', '.join(names)})")
    return names.index(lod)


def active_lod(obj, render=False) -> str:
    """The LOD the engine draws: the object's Render LOD for final renders, else Viewport; ''
    when it holds none."""
    st = obj.gaussvdb
    names = lod_names(obj)
    if not names:
        return ""
    try:
        name = st.render_lod if render else st.viewport_lod
    except (TypeError, ValueError):  # an enum whose items no longer hold the stored name
        name = ""
    return name if name in names else (names[-1] if render else names[0])


def object_stats(obj) -> list:
    from ..properties import lod_figures

    return lod_figures.as_dicts(obj.gaussvdb)


def stored_index_to_world(obj) -> np.ndarray:
    """The grid's index-to-world transform as imported (float64 4x4, column-vector form)."""
    try:
        v = np.array([float(x) for x in obj.gaussvdb.index_to_world.split()], np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.size != 16:
        return np.asarray(obj.matrix_world, np.float64)
    return v.reshape(4, 4)


def _read_attr(attr, n):
    if attr.data_type == "FLOAT_VECTOR":
        a = np.empty(n * 3, np.float32)
        attr.data.foreach_get("vector", a)
        return a.reshape(n, 3)
    dtype = BLENDER_DTYPES.get(attr.data_type)
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
        arr = _read_attr(attr, n)
        if arr is not None:
            out[attr.name] = arr
    return out


def upgrade_arrays(a, version) -> dict:
    """Point attributes of layout ``version`` (0: no version stored; points in any order, maybe
    without ``gs_origin``/``gs_sigma``) as the current layout holds them: every attribute the
    reader needs, each (LOD, group) contiguous. Points already in order keep it, so an object
    that only lacked the version number reads bit-identically."""
    if version >= LAYOUT_VERSION:
        return a
    a = dict(a)
    n = len(a["position"])
    lod = a.setdefault("gs_lod", np.zeros(n, np.int8))
    if "gs_origin" not in a:  # one group per leaf cell
        a["gs_origin"] = (np.floor((a["position"].astype(np.float64) + 0.5) / 8.0) * 8.0).astype(np.float32)
    if "gs_sigma" not in a:
        a["gs_sigma"] = a.get("radius", np.full(n, 0.5, np.float32)).astype(np.float32)
    if "radius" not in a:
        s = a["gs_sigma"]
        a["radius"] = (s if s.ndim == 1 else s.max(axis=1)).astype(np.float32)
    o = a["gs_origin"]
    if n:
        run = np.ones(n, bool)
        run[1:] = (lod[1:] != lod[:-1]) | np.any(o[1:] != o[:-1], axis=1)
        keys = np.column_stack([lod[run].astype(np.float64), o[run]])
        if len(np.unique(keys, axis=0)) < len(keys) or np.any(np.diff(lod[run].astype(np.int64)) < 0):
            order = np.lexsort((o[:, 2], o[:, 1], o[:, 0], lod))  # stable: LOD, then origin
            a = {k: v[order] for k, v in a.items()}
    return a


def check_version(obj) -> int:
    """The object's layout version; ValueError when a newer GaussVDB wrote it."""
    version = int(getattr(obj.gaussvdb, "layout_version", 0))
    if version > LAYOUT_VERSION:
        raise ValueError(f"{obj.name}: its point cloud has layout version {version}, newer than "
                         f"this GaussVDB reads ({LAYOUT_VERSION}); update the add-on")
    return version


def gaussian_set_from_object(obj, lod=None, depsgraph=None):
    """The GaussianSet of one LOD of an imported object: the exact inverse of what the import wrote.

    ``lod``: a name ('medium'), a gs_lod index, or None (the object's Render LOD; the engine passes
    ``active_lod(obj, render)``). With ``depsgraph`` the evaluated object is read, so Geometry Nodes
    edits show up (moved points move their Gaussians: the centre is ``position``). None for a
    grid imported alone (no LOD held).
    """
    orig = getattr(obj, "original", None) or obj
    st = orig.gaussvdb
    version = check_version(orig)
    if not lod_names(orig):
        return None
    if lod is None:
        lod = active_lod(orig, render=True)
    idx = lod_index(orig, lod)
    arrays = upgrade_arrays(read_attributes(obj, depsgraph), version)
    gs = gaussian_set_from_arrays(arrays, idx, lod_names(orig), object_stats(orig), st.grid_class,
                                  st.weights_rule(), stored_index_to_world(orig), fallback_name=str(lod))
    if gs.color_values is not None:
        gs.color_background = float((st.color_stats() or {}).get("background", 0.0))
    return gs


def gaussian_set_from_arrays(a, idx, names, stats, grid_class, weights, index_to_world,
                             fallback_name=""):
    """A GaussianSet from point attributes (name -> array, as ``read_attributes`` returns or
    ``point_arrays`` makes): the Gaussians with ``gs_lod == idx``. ``stats``: the per-LOD
    figures of ``lod_stats``. One reader for objects and for the frames of a sequence, so a
    frame converted on demand is bit-identical to the same file imported alone."""
    from ...kernels.lod import GaussianSet

    if "position" not in a:
        raise ValueError("the point cloud has no point positions")
    n = len(a["position"])
    sel = a["gs_lod"] == idx if "gs_lod" in a else np.ones(n, bool)
    centre = a["position"][sel].astype(np.float64)
    m = len(centre)
    if "gs_origin" in a:
        origins = a["gs_origin"][sel].astype(np.float64)
    else:  # stripped by Geometry Nodes: one group per leaf cell
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
    colors = a["gs_color"][sel].astype(np.float32) if "gs_color" in a else None
    dist = a["gs_distance"][sel].astype(np.float32) if "gs_distance" in a else None
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
        size_codes=codes, sigma_scale=scale or 0.6, params=params, color_values=colors,
        distances=dist)


def converted_gaussian_set(cg):
    """The GaussianSet of the first LOD of a ConvertedGrid, through the arrays an object would
    hold (float32 centres and all): what ``gaussian_set_from_object`` reads after an import."""
    arrays = point_arrays(cg)
    a = {k: arr for k, (_, arr, _) in arrays.items()}
    names = [cl.name for cl in cg.lods]
    gs = gaussian_set_from_arrays(a, 0, names, lod_stats(cg, bytes_per_point(arrays)),
                                  cg.grid_class, cg.lods[0].gset.weights, cg.index_to_world)
    gs.color_background = cg.lods[0].gset.color_background
    return gs
