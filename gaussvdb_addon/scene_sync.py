"""Depsgraph -> kernels RenderScene: the visible GaussVDB objects, their LOD, placement, the
transfer function and the render settings.

``SceneSync`` keeps one cache entry per object, keyed by (name, evaluated data pointer, LOD,
update counter). The viewport bumps an object's counter when the depsgraph reports a geometry
update for it (``note_updates``); a transform-only update refreshes the placement without reading
the Gaussians again; no update at all returns the cached RenderScene without touching the
depsgraph (an unchanged scene costs nothing). Final renders use a fresh SceneSync per render
(the render depsgraph is a new one), but share the module-level source-grid cache that the
reference mode needs.
"""

import os
import threading

import numpy as np

from ..kernels.render import RenderObject, RenderScene, TransferFunction, value_range
from . import blender_settings

_GRID_CACHE = {}  # (abspath, grid, mtime, size) -> GridData
_GRID_LOCK = threading.Lock()

LEVEL_SET_AXES = {"X": "x", "Y": "y", "Z": "z", "HEIGHT": "z"}


# -- Gaussians of one object --------------------------------------------------------------------
def lod_names(obj):
    return [n for n in obj.gaussvdb.lods.split(",") if n] or ["medium"]


def chosen_lod(obj, viewport):
    s = obj.gaussvdb
    try:
        lod = s.viewport_lod if viewport else s.render_lod
    except (TypeError, ValueError):
        lod = ""
    return lod or lod_names(obj)[0]


def _read_attr(attrs, name, width, dtype):
    a = attrs.get(name)
    if a is None:
        return None
    n = len(a.data)
    if width == 3:
        out = np.empty(n * 3, np.float32)
        a.data.foreach_get("vector", out)
        return out.reshape(n, 3)
    out = np.empty(n, dtype)
    a.data.foreach_get("value", out)
    return out


def gaussian_set_from_points(obj, lod):
    """Fallback reader of the point-cloud contract (the importer's ``gaussian_set_from_object``
    is used when present): point attributes ``position``, ``gs_sigma``, ``gs_value``,
    ``gs_amplitude``, ``gs_voxels``, ``gs_lod`` (int8: index into ``obj.gaussvdb.lods``).
    Positions are index space; groups are rebuilt from the 8^3 leaf cells."""
    from ..kernels.lod.gaussian_set import GaussianSet

    data = obj.data
    attrs = data.attributes
    pos = _read_attr(attrs, "position", 3, np.float32)
    if pos is None:
        raise ValueError(f"object {obj.name!r} has no point positions")
    names = lod_names(obj.original if hasattr(obj, "original") else obj)
    sel = np.ones(len(pos), bool)
    lod_attr = _read_attr(attrs, "gs_lod", 1, np.int32)
    if lod_attr is not None:
        if lod not in names:
            raise ValueError(f"object {obj.name!r} holds no {lod!r} LOD (has {', '.join(names)})")
        sel = lod_attr == names.index(lod)
    sig = _read_attr(attrs, "gs_sigma", 3, np.float32)
    val = _read_attr(attrs, "gs_value", 1, np.float32)
    amp = _read_attr(attrs, "gs_amplitude", 1, np.float32)
    vox = _read_attr(attrs, "gs_voxels", 1, np.int32)
    if sig is None or amp is None:
        raise ValueError(f"object {obj.name!r} lacks the gs_sigma/gs_amplitude attributes")
    m = int(sel.sum())
    pos, sig = pos[sel].astype(np.float64), sig[sel]
    val = val[sel] if val is not None else np.ones(m, np.float32)
    amp = amp[sel]
    vox = vox[sel] if vox is not None else np.ones(m, np.int32)
    cell = np.floor((pos + 0.5) / 8.0).astype(np.int64) * 8
    order = np.lexsort((cell[:, 2], cell[:, 1], cell[:, 0]))
    cell, pos, sig, val, amp, vox = cell[order], pos[order], sig[order], val[order], amp[order], vox[order]
    if m:
        new = np.ones(m, bool)
        new[1:] = np.any(cell[1:] != cell[:-1], axis=1)
        starts = np.flatnonzero(new)
    else:
        starts = np.zeros(0, np.int64)
    origins = cell[starts].astype(np.int32)
    group_start = np.append(starts, m).astype(np.int64)
    offsets = (pos - np.repeat(origins, np.diff(group_start), axis=0)).astype(np.float32)
    s = obj.gaussvdb if hasattr(obj, "gaussvdb") else None
    return GaussianSet(origins.reshape(-1, 3), group_start, offsets, np.ascontiguousarray(sig, np.float32),
                       np.ascontiguousarray(val, np.float32), np.ascontiguousarray(amp, np.float32),
                       np.ascontiguousarray(vox, np.int32),
                       grid_class=(s.grid_class if s is not None and s.grid_class else "fog_volume"),
                       lod=lod, n_leaf_groups=len(origins))


def read_gaussians(obj, lod, depsgraph=None):
    """The object's Gaussians at one LOD, through the importer's reader when it exists."""
    try:
        from . import importer
    except ImportError:
        importer = None
    reader = getattr(importer, "gaussian_set_from_object", None)
    if reader is not None:
        return reader(obj, lod, depsgraph=depsgraph)
    return gaussian_set_from_points(obj, lod)


def source_grid(obj):
    """The source GridData of an imported object (reference mode), read once and cached."""
    import bpy

    s = obj.gaussvdb
    path = bpy.path.abspath(s.source_file) if s.source_file else ""
    if not path or not os.path.isfile(path):
        raise ValueError(f"reference mode: source file of {obj.name!r} not found ({s.source_file!r})")
    st = os.stat(path)
    key = (os.path.realpath(path), s.grid_name, st.st_mtime_ns, st.st_size)
    with _GRID_LOCK:
        grid = _GRID_CACHE.get(key)
        if grid is None:
            from ..kernels.vdb import read_vdb

            f = read_vdb(path, [s.grid_name] if s.grid_name else None)
            grids = [g for g in f.grids if not s.grid_name or g.name == s.grid_name]
            if not grids:
                raise ValueError(f"reference mode: grid {s.grid_name!r} not in {path}")
            grid = grids[0]
            _GRID_CACHE.clear()  # keep one file's grids: they can be large
            _GRID_CACHE[key] = grid
    return grid


# -- settings -> kernel objects -----------------------------------------------------------------
def transfer_function(settings, value_lo=None, value_hi=None, lut=None, size=None):
    """``size``: the largest rendered object's world box diagonal (the density unit's scale)."""
    from . import transfer_ramp

    if lut is None:
        lut = transfer_ramp.sample(settings, 256)
    if settings.auto_range and value_lo is not None:
        lo, hi = value_lo, value_hi
    else:
        lo, hi = settings.value_min, settings.value_max
        if hi <= lo:
            hi = lo + 1e-6
    if settings.log_scale and not (lo > 0 and hi > 0):
        lo, hi = (max(hi * 1e-3, 1e-12), max(hi, 1e-9)) if hi > 0 else (1e-3, 1.0)
    return TransferFunction(lut, lo, hi, settings.log_scale,
                            blender_settings.extinction(settings, size))


def level_set_color(settings):
    if settings.level_set_color == "CONSTANT":
        # COLOR subtype properties hold scene-linear values already
        return tuple(float(c) for c in settings.level_set_constant)
    return LEVEL_SET_AXES.get(settings.level_set_color, "z")


class _Entry:
    __slots__ = ("key", "gaussians", "grid", "vrange", "count")


class SceneSync:
    """Builds and caches the RenderScene of one depsgraph (one per viewport / per render)."""

    def __init__(self, viewport=False):
        self.viewport = viewport
        self.entries = {}  # object name -> _Entry
        self.counters = {}  # object name -> geometry update counter
        self.scene = None  # last RenderScene
        self.dirty = True
        self.settings_dirty = True
        self.reads = 0  # Gaussian sets read (tests check an unchanged depsgraph adds none)
        self.builds = 0  # RenderScenes built
        self.gaussians = 0
        self.value_range = (0.0, 1.0)
        self.size = 0.0  # largest world box diagonal of the objects rendered

    # -- change tracking (viewport) ---------------------------------------------------------
    def note_updates(self, updates):
        """Feed ``depsgraph.updates``. Returns True when something we draw may have changed."""
        import bpy

        changed = False
        for u in updates:
            idv = u.id
            if isinstance(idv, bpy.types.Object):
                name = idv.original.name if hasattr(idv, "original") else idv.name
                if u.is_updated_geometry:
                    self.counters[name] = self.counters.get(name, 0) + 1
                changed = True
            elif isinstance(idv, (bpy.types.Scene, bpy.types.Collection, bpy.types.ViewLayer,
                                  bpy.types.Texture, bpy.types.PointCloud, bpy.types.Mesh)):
                changed = True
                if isinstance(idv, (bpy.types.PointCloud, bpy.types.Mesh)):
                    # data edited: every user object re-reads (names are not known here)
                    for k in self.counters:
                        self.counters[k] += 1
                    self.entries.clear()
        if changed:
            self.dirty = True
        return changed

    # -- build --------------------------------------------------------------------------------
    def _entry(self, obj_eval, lod, need_grid, depsgraph):
        orig = obj_eval.original
        name = orig.name
        data = obj_eval.data
        key = (name, data.as_pointer() if data is not None else 0, lod,
               self.counters.get(name, 0))
        e = self.entries.get(name)
        if e is None or e.key != key:
            e = _Entry()
            e.key = key
            e.gaussians = read_gaussians(obj_eval, lod, depsgraph)
            e.grid = None
            v = np.asarray(e.gaussians.values)
            is_ls = e.gaussians.grid_class == "level_set"
            e.vrange = None if is_ls or v.size == 0 else (float(np.nanmin(v)), float(np.nanmax(v)))
            e.count = int(len(e.gaussians.values))
            self.entries[name] = e
            self.reads += 1
        if need_grid and e.grid is None:
            e.grid = source_grid(orig)
        return e

    def sync(self, depsgraph, force=False):
        """The RenderScene for this depsgraph (cached unless something changed)."""
        if self.scene is not None and not self.dirty and not force:
            return self.scene
        scene = depsgraph.scene
        settings = scene.gaussvdb
        mode = settings.mode.lower()
        objects, seen, ranges = [], set(), []
        total = 0
        size = 0.0
        ls_color = level_set_color(settings)
        for inst in depsgraph.object_instances:
            ob = inst.object
            orig = ob.original
            gs = getattr(orig, "gaussvdb", None)
            if gs is None or not gs.is_gaussvdb or ob.type not in ("POINTCLOUD", "MESH"):
                continue
            if not inst.show_self:
                continue
            lod = chosen_lod(orig, self.viewport)
            e = self._entry(ob, lod, mode == "reference", depsgraph)
            seen.add(orig.name)
            mw = np.array(inst.matrix_world, np.float64)
            objects.append(RenderObject(e.gaussians, mw, grid=e.grid, level_set_color=ls_color,
                                        name=orig.name))
            total += e.count
            size = max(size, blender_settings.world_box_diagonal(ob, inst.matrix_world))
            if e.vrange is not None:
                ranges.extend(e.vrange)
            elif mode == "reference" and e.grid is not None and e.grid.grid_class != "level_set":
                ranges.extend(_grid_range(e.grid))
        for name in list(self.entries):
            if name not in seen:
                del self.entries[name]
        rs = RenderScene(objects=objects, background=blender_settings.background(scene), mode=mode,
                         transmittance_min=settings.early_termination, step=settings.step_scale,
                         tau_max=settings.tau_max, threads=blender_settings.threads(scene),
                         passes=tuple(blender_settings.passes(depsgraph.view_layer)))
        self.value_range = value_range(ranges, settings.log_scale) if ranges else (0.0, 1.0)
        self.gaussians = total
        self.size = size
        self.scene = rs
        self.dirty = False
        self.builds += 1
        return rs

    def transfer_function(self, settings, lut=None):
        lo, hi = self.value_range
        return transfer_function(settings, lo, hi, lut, self.size)


def _grid_range(grid):
    try:
        from ..kernels.lod.build import value_range as vr

        return list(vr(grid))
    except Exception:
        v = np.asarray(grid.leaf_values)
        return [float(v.min()), float(v.max())] if v.size else []
