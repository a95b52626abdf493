"""Depsgraph -> kernels RenderScene: the visible GaussVDB objects, their LOD, placement, the
transfer function and the render settings.

``SceneSync`` keeps one cache entry per object, keyed by (name, evaluated data pointer, LOD,
update counter). The viewport bumps an object's counter when the depsgraph reports a geometry
update for it (``note_updates``); a transform-only update refreshes the placement without reading
the Gaussians again; no update at all returns the cached RenderScene without touching the
depsgraph (an unchanged scene costs nothing). Final renders use a fresh SceneSync per render
(the render depsgraph is a new one), but share the module-level source-grid cache that the
reference mode needs.

Transfer functions: an object with "Use Scene Transfer Function" off gets its own
(``RenderObject.tf``); the scene's auto range is the union over the objects that use the scene's.
Auto ranges come from the voxel figures stored at import (the same for every LOD), else from the
drawn LOD's values. An object imported with a colour grid (``gaussvdb.color_grid``) gets its
colour map over that grid (``RenderObject.color_tf``; reference mode: that grid's voxels too).
``warnings`` lists what the render should report (log scale on values <= 0).
"""

import os
import threading

import numpy as np

from ...kernels.render import RenderObject, RenderScene, TransferFunction, value_range, voxel_stats
from ...kernels.render.scene import clip
from ...kernels.render.scene.legend import LegendEntry
from ...kernels.render.scene.lights import Light
from ..io import schema
from . import blender_settings, sequence_frames

_GRID_CACHE = {}  # (abspath, grid, mtime, size) -> GridData
_GRID_LOCK = threading.Lock()

LEVEL_SET_AXES = {"X": "x", "Y": "y", "Z": "z", "HEIGHT": "z"}


# -- Gaussians of one object --------------------------------------------------------------------
def read_gaussians(obj, lod, depsgraph=None):
    """The object's Gaussians at one LOD: the point-cloud schema's reader (io/schema.py)."""
    return schema.gaussian_set_from_object(obj, lod, depsgraph=depsgraph)


def source_grid(obj, path=None, name=None):
    """The source GridData of an imported object (reference mode), read once and cached;
    ``path``: the file of a sequence's current frame; ``name``: another grid of that file (the
    colour grid) instead of the object's own."""
    import bpy

    s = obj.gaussvdb
    name = s.grid_name if name is None else name
    if path is None:
        path = bpy.path.abspath(s.source_file) if s.source_file else ""
    if not path or not os.path.isfile(path):
        raise ValueError(f"reference mode: source file of {obj.name!r} not found ({s.source_file!r})")
    st = os.stat(path)
    key = (os.path.realpath(path), name, st.st_mtime_ns, st.st_size)
    with _GRID_LOCK:
        grid = _GRID_CACHE.get(key)
        if grid is None:
            from ...kernels.vdb import read_vdb

            f = read_vdb(path, [name] if name else None)
            grids = [g for g in f.grids if not name or g.name == name]
            if not grids:
                raise ValueError(f"reference mode: grid {name!r} not in {path}")
            grid = grids[0]
            for k in [k for k in _GRID_CACHE if k[0] != key[0]]:
                del _GRID_CACHE[k]  # keep one file's grids: they can be large
            _GRID_CACHE[key] = grid
    return grid


def color_transfer(gs):
    """The colour map over the object's colour grid (its colormap, range, log scale), or None
    when it has no colour grid; alpha 1: the opacity is the transfer function's."""
    if not gs.color_grid:
        return None
    st = gs.color_stats()
    auto = None
    if st is not None:
        auto = value_range([st["positive_min"], st["max"]] if gs.color_log_scale and
                           st.get("positive_min") is not None else [st["min"], st["max"]],
                           gs.color_log_scale)
    if gs.color_auto_range and auto is not None:
        lo, hi = auto
    else:
        lo, hi = float(gs.color_min), float(gs.color_max)
        if hi <= lo:
            hi = lo + 1e-6
    if gs.color_log_scale and not (lo > 0 and hi > 0):
        lo, hi = (max(hi * 1e-3, 1e-12), max(hi, 1e-9)) if hi > 0 else (1e-3, 1.0)
    return TransferFunction.from_colormap(gs.color_colormap, lo, hi, alpha="constant",
                                          log_scale=gs.color_log_scale)


# -- settings -> kernel objects -----------------------------------------------------------------
def effective_range(settings, auto=None):
    """(lo, hi) a transfer function's settings use: ``auto`` (the data's range) when Auto Range is
    on and known, else Min/Max; made positive for a log scale."""
    if settings.auto_range and auto is not None:
        lo, hi = auto
    else:
        lo, hi = settings.value_min, settings.value_max
        if hi <= lo:
            hi = lo + 1e-6
    if settings.log_scale and not (lo > 0 and hi > 0):
        lo, hi = (max(hi * 1e-3, 1e-12), max(hi, 1e-9)) if hi > 0 else (1e-3, 1.0)
    return float(lo), float(hi)


def transfer_function(settings, value_lo=None, value_hi=None, lut=None, *, create=True, size=None):
    """``size``: the world box diagonal the density unit "Per Object Size" is relative to (the
    largest of the objects using this transfer function)."""
    from ..properties import transfer_ramp

    if lut is None:
        lut = transfer_ramp.sample(settings, 256, create=create)
    lo, hi = effective_range(settings, None if value_lo is None else (value_lo, value_hi))
    return TransferFunction(lut, lo, hi, settings.log_scale,
                            blender_settings.extinction(settings, size))


def values_of(settings, gaussians=None):
    """(lo, hi, positive min, fraction of voxels <= 0) of an object's data for its transfer
    function; None for level sets (coloured by position) and when nothing is known. The voxel
    figures stored at import are used when present (any LOD colours a value alike), else the
    Gaussians of the drawn LOD (weighted by the voxels each stands for)."""
    is_ls = (settings.grid_class or getattr(gaussians, "grid_class", "")) == "level_set"
    if is_ls:
        return None
    st = settings.voxel_stats()
    if st is not None:
        n = max(int(st.get("voxels", 0)), 1)
        return (float(st["min"]), float(st["max"]), st.get("positive_min"),
                int(st.get("nonpositive", 0)) / n)
    if gaussians is None:
        return None
    v = np.asarray(gaussians.values, np.float64)
    if v.size == 0:
        return None
    vox = getattr(gaussians, "voxels", None)
    w = np.ones(v.size) if vox is None else np.asarray(vox, np.float64)
    fin = np.isfinite(v)
    pos = v[v > 0]
    return (float(v[fin].min()) if fin.any() else 0.0, float(v[fin].max()) if fin.any() else 0.0,
            float(pos.min()) if pos.size else None, float(w[~(v > 0)].sum() / max(w.sum(), 1.0)))


def auto_range(items, log_scale):
    """Union of the ``values_of`` of the objects sharing one transfer function (log: from the
    smallest positive value)."""
    vals = []
    for it in items:
        if it is None:
            continue
        lo, hi, pmin, _ = it
        vals += ([pmin, hi] if pmin is not None else []) if log_scale else [lo, hi]
    return value_range(vals, log_scale) if vals else None


def log_warning(grid, fraction):
    """The message a log scale over values <= 0 earns (None when every voxel can be shown)."""
    if not fraction > 0:
        return None
    pct = f"{100 * fraction:.0f}" if fraction >= 0.01 else f"{100 * fraction:.2g}"
    return f"log scale: {pct}% of the voxels of {grid!r} are <= 0 and not shown"


def scene_tf_users(scene):
    """The GaussVDB objects of ``scene`` that render with the scene's transfer function."""
    return [o for o in scene.objects if o.gaussvdb.is_gaussvdb and o.gaussvdb.use_scene_tf
            and not o.hide_render]


def stored_range(settings, objects):
    """The (lo, hi) a transfer function uses for ``objects`` from what is stored on them (the
    panel's "Range in use"), or None when an object has no stored figures (then it is known only
    once a LOD is drawn)."""
    items = [values_of(o.gaussvdb) for o in objects if o.gaussvdb.grid_class != "level_set"]
    if settings.auto_range and any(it is None for it in items):
        return None
    return effective_range(settings, auto_range(items, settings.log_scale) or (0.0, 1.0))


def level_set_color(settings):
    if settings.level_set_color == "CONSTANT":
        # COLOR subtype properties hold scene-linear values already
        return tuple(float(c) for c in settings.level_set_constant)
    return LEVEL_SET_AXES.get(settings.level_set_color, "z")


def _frame_matrix(obj, matrix_world, frame_i2w):
    """A sequence frame whose grid transform differs from the object's frame (an adaptive
    domain moves): placed by the object's matrix times the change of transform."""
    if frame_i2w is None:
        return matrix_world
    own = schema.stored_index_to_world(obj)
    if np.array_equal(own, frame_i2w):
        return matrix_world
    return matrix_world @ np.linalg.inv(own) @ np.asarray(frame_i2w, np.float64)
def clip_halfspaces(gs, depsgraph, warnings):
    """The world half-spaces (k, 4) that the object's clip Empties keep (object_settings.ClipProps),
    or None. An Empty with a zero scale cuts nothing and adds a warning."""
    empties = [(e, False) for e in (gs.clip_plane,) if e is not None]
    empties += [(e, True) for e in (gs.clip_box,) if e is not None]
    if gs.clip_collection is not None:
        empties += [(e, e.empty_display_type == "CUBE") for e in gs.clip_collection.all_objects
                    if e.type == "EMPTY"]
    rows = []
    for e, is_box in empties:
        m = np.array(e.evaluated_get(depsgraph).matrix_world, np.float64)
        try:
            rows.append(clip.box_from_matrix(m) if is_box else clip.plane_from_matrix(m))
        except ValueError as err:
            msg = f"clip Empty '{e.name}': {err}; it cuts nothing"
            if msg not in warnings:
                warnings.append(msg)
    return np.concatenate(rows) if rows else None


def scene_lights(depsgraph):
    """The visible lights as kernels Lights: suns along their local -Z, strength their irradiance;
    point, spot and area lights as a point at their centre, strength their power."""
    out = []
    for inst in depsgraph.object_instances:
        ob = inst.object
        if ob.type != "LIGHT" or not inst.show_self:
            continue
        data = ob.data
        m = np.array(inst.matrix_world, np.float64)
        color = tuple(float(c) for c in data.color)
        if data.type == "SUN":
            out.append(Light("sun", -m[:3, 2], color, float(data.energy)))
        else:
            out.append(Light("point", m[:3, 3], color, float(data.energy)))
    return tuple(out)


class _Entry:
    __slots__ = ("key", "gaussians", "grid", "values", "count", "frame", "color_grid")


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
        self.warnings = []  # what the render reports (log scale over values <= 0, missing frames)
        self.errors = []  # sequence frames that could not be read (the rest still renders)
        # (grid name, object TF or None for the scene's) of non-level-set objects; an object
        # coloured by a second grid: (that grid, its colour map)
        self.tf_users = []
        self.size = 0.0  # largest world box diagonal of the objects on the scene's transfer function

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
                                  bpy.types.Texture, bpy.types.PointCloud, bpy.types.Mesh,
                                  bpy.types.Light)):  # a light's colour or strength: surfaces, lit volumes
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
        frame = None
        if sequence_frames.volume(orig) is not None:  # the Gaussians of the frame shown now
            frame = sequence_frames.frame_at(orig, lod, depsgraph.scene)
            key = (name, "frame", frame.key, lod, orig.gaussvdb.sequence_range)
        else:
            data = obj_eval.data
            key = (name, data.as_pointer() if data is not None else 0, lod,
                   self.counters.get(name, 0))
        e = self.entries.get(name)
        if e is None or e.key != key:
            e = _Entry()
            e.key = key
            e.grid = e.color_grid = None
            if frame is not None:
                e.gaussians = frame.gaussians
                own = orig.gaussvdb.sequence_range == "FRAME"
                e.values = (sequence_frames.values_tuple(frame.values) if own else None) \
                    or values_of(orig.gaussvdb, e.gaussians)
            else:
                e.gaussians = read_gaussians(obj_eval, lod, depsgraph)
                e.values = values_of(orig.gaussvdb, e.gaussians)
            e.count = int(len(e.gaussians.values)) if e.gaussians is not None else 0
            self.entries[name] = e
            self.reads += 1
        e.frame = frame
        # (a grid imported alone has no Gaussians: its voxels are all it is drawn from)
        if need_grid and e.grid is None and (e.gaussians is not None or not lod):
            e.grid = source_grid(orig, frame.path if frame is not None else None)
            if orig.gaussvdb.color_grid:
                e.color_grid = source_grid(orig, frame.path if frame is not None else None,
                                           orig.gaussvdb.color_grid)
            if e.values is None and e.grid.grid_class != "level_set" and e.grid.active_voxels:
                st = voxel_stats(e.grid)
                e.values = (st["min"], st["max"], st["positive_min"],
                            st["nonpositive"] / max(st["voxels"], 1))
        return e

    def sync(self, depsgraph, force=False):
        """The RenderScene for this depsgraph (cached unless something changed)."""
        if self.scene is not None and not self.dirty and not force:
            return self.scene
        scene = depsgraph.scene
        settings = scene.gaussvdb
        mode = settings.mode.lower()
        objects, seen, scene_items = [], set(), []
        self.warnings, self.errors, self.tf_users = [], [], []
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
            lod = schema.active_lod(orig, render=not self.viewport)
            # splat mode draws level sets from their voxels (kernels/render/splat_scene)
            need_grid = mode == "reference" or (mode == "splat" and gs.grid_class == "level_set")
            if not lod and mode != "reference":
                msg = f"{orig.name}: imported without Gaussians, drawn in Reference mode only"
                if msg not in self.warnings:
                    self.warnings.append(msg)
                continue
            e = self._entry(ob, lod, need_grid, depsgraph)
            seen.add(orig.name)
            mw = np.array(inst.matrix_world, np.float64)
            if e.frame is not None:
                self.warnings += [w for w in e.frame.warnings if w not in self.warnings]
                if e.frame.error:
                    self.errors.append(e.frame.error)
                if e.gaussians is None:  # nothing this frame (outside Clip, empty, unreadable)
                    continue
                mw = _frame_matrix(orig, mw, e.frame.index_to_world)
            diag = blender_settings.world_box_diagonal(ob, inst.matrix_world)
            own = None if gs.use_scene_tf else self._object_tf(gs, e, diag)
            if own is None:
                scene_items.append(e.values)
                size = max(size, diag)
            tf_of = gs if own is not None else settings
            color = self._color(gs, e)
            if color:  # its colours are the colour map's: that is what the legend shows
                self.tf_users.append((gs.color_grid, color["color_tf"]))
            elif e.values is not None:
                self.tf_users.append((gs.grid_name or orig.name, own))
            if e.values is not None:
                if tf_of.log_scale:
                    msg = log_warning(gs.grid_name or orig.name, e.values[3])
                    if msg and msg not in self.warnings:
                        self.warnings.append(msg)
            objects.append(RenderObject(e.gaussians, mw, grid=e.grid, level_set_color=ls_color,
                                        name=orig.name, tf=own,
                                        clip=clip_halfspaces(gs, depsgraph, self.warnings),
                                        surface=gs.level_set_style == "SURFACE",
                                        shading=gs.shading.lower(), shadows=gs.shadows,
                                        **color))
            total += e.count

        for name in list(self.entries):
            if name not in seen:
                del self.entries[name]
        rs = RenderScene(objects=objects, background=blender_settings.background(scene), mode=mode,
                         transmittance_min=settings.early_termination, step=settings.step_scale,
                         tau_max=settings.tau_max, threads=blender_settings.threads(scene),
                         passes=tuple(blender_settings.passes(depsgraph.view_layer)),
                         lights=scene_lights(depsgraph))
        self.value_range = auto_range(scene_items, settings.log_scale) or (0.0, 1.0)
        self.gaussians = total
        self.size = size
        self.scene = rs
        self.dirty = False
        self.builds += 1
        return rs

    @staticmethod
    def _color(gs, e):
        """RenderObject's colour-grid arguments of an object (none without a colour grid, or when
        its Gaussians carry no colour values: an older file, a Geometry Nodes edit; a grid
        imported alone: its colour grid's voxels)."""
        held = e.color_grid if e.gaussians is None else getattr(e.gaussians, "color_values", None)
        if not gs.color_grid or held is None:
            return {}
        return dict(color_tf=color_transfer(gs), color_grid=e.color_grid)

    def _object_tf(self, gs, e, size):
        """The object's own transfer function (its colormap/ramp, range, log scale, density; the
        density unit relative to its own size)."""
        lo, hi = auto_range([e.values], gs.log_scale) or (0.0, 1.0)  # as the scene's
        return transfer_function(gs, lo, hi, create=not self.viewport, size=size)

    def transfer_function(self, settings, lut=None):
        lo, hi = self.value_range
        return transfer_function(settings, lo, hi, lut, size=self.size)

    def legend_entries(self, scene_tf, units=""):
        """One LegendEntry per transfer function in use by a volume: the scene's (titled with the
        grids that use it) and each object's own."""
        suffix = f" ({units})" if units else ""
        shared = [name for name, tf in self.tf_users if tf is None]
        out = []
        if shared:
            out.append(LegendEntry(", ".join(dict.fromkeys(shared)) + suffix, scene_tf.lut,
                                   scene_tf.vmin, scene_tf.vmax, scene_tf.log_scale))
        for name, tf in self.tf_users:
            if tf is not None:
                out.append(LegendEntry(name + suffix, tf.lut, tf.vmin, tf.vmax, tf.log_scale))
        return out
