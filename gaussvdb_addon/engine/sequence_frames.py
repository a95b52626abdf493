"""The Gaussians of a sequence object at a scene frame: the engine's per-frame provider.

    frame = frame_at(obj, "low", scene)   # -> Frame (gaussians None: nothing to draw)

The object's source Volume says which file a scene frame shows (Blender's sequence rules,
kernels.sequence.map_frame). That file's grid is converted at the LOD asked for, on demand, and
kept in one process-wide LRU cache bounded by the scene's memory budget; with the scene's disk
cache on, the frame's compact encoding is written to (and next time read from) the cache
folder, so a second playback or another machine does not convert again.

What can go wrong per frame, without stopping the animation: a file missing inside the range
holds the last frame before it (one warning per sequence naming the missing files); a grid
absent or empty in that frame draws nothing; a file that cannot be read draws nothing for that
frame and earns an error naming it (``Frame.error``).
"""

import os
import time
from dataclasses import dataclass, field

import numpy as np

from ...kernels import sequence as seq
from ...kernels.convert_options import DEFAULTS

MB = 1 << 20
CACHE = seq.LRUCache(2048 * MB)  # converted frames; the budget follows scene.gaussvdb
_PRESENT = {}  # (directory, head, tail) -> (directory mtime, present frame numbers)
_WARNED = set()  # sequences whose missing frames were reported
STATS = {"converted": 0, "disk_hits": 0, "disk_writes": 0, "seconds_convert": 0.0}


@dataclass
class Frame:
    number: object = None  # the file number drawn (None: nothing this frame)
    requested: object = None  # the number the timeline asked for (differs when held)
    path: str = ""
    gaussians: object = None  # GaussianSet, or None (empty, absent, unreadable)
    values: object = None  # this frame's voxel figures (kernels.render.voxel_stats), if known
    index_to_world: object = None  # this frame's grid transform
    error: str = ""
    warnings: list = field(default_factory=list)

    @property
    def key(self):
        return (self.path, self.number, self.gaussians is not None)


def volume(obj):
    vol = obj.gaussvdb.source_volume
    return vol if vol is not None and vol.is_sequence else None


def pattern(vol):
    import bpy

    return seq.parse(os.path.abspath(bpy.path.abspath(vol.filepath, library=vol.library)))


def present(pat):
    """Frame numbers on disk, listed again only when the folder changes."""
    key = (pat.directory, pat.head, pat.tail)
    try:
        mtime = os.stat(pat.directory or ".").st_mtime_ns
    except OSError:
        return []
    hit = _PRESENT.get(key)
    if hit is None or hit[0] != mtime:
        hit = (mtime, pat.scan())
        _PRESENT[key] = hit
    return hit[1]


def file_number(obj, scene_frame):
    """(Pattern, number the timeline asks for or None, number drawn or None)."""
    vol = volume(obj)
    pat = pattern(vol)
    asked = seq.map_frame(scene_frame, vol.frame_start, vol.frame_offset, vol.frame_duration,
                          vol.sequence_mode)
    return pat, asked, seq.held_frame(asked, present(pat) if pat is not None else [])


def _missing_warning(obj, pat, vol):
    """One warning per sequence naming the files missing inside its range (None when none)."""
    key = (pat.text, pat.directory)
    if key in _WARNED:
        return None
    _WARNED.add(key)
    first = vol.frame_offset + 1
    have = set(present(pat))
    gone = [n for n in range(first, first + vol.frame_duration) if n not in have]
    if not gone:
        return None
    names = ", ".join(pat.name(n) for n in gone[:8]) + (f" and {len(gone) - 8} more" if len(gone) > 8 else "")
    return f"{obj.name}: missing {names}: the previous frame is held"


def disk_cache_dir(scene):
    """The scene's on-disk cache folder, or '' when the disk cache is off (or the folder is
    relative to a .blend never saved)."""
    import bpy

    st = scene.gaussvdb
    if not st.use_sequence_disk_cache:
        return ""
    text = st.sequence_cache_dir or "//gaussvdb_cache"
    if text.startswith("//") and not bpy.data.filepath:
        return ""
    return os.path.abspath(bpy.path.abspath(text))


def frame_at(obj, lod, scene, scene_frame=None) -> Frame:
    """The Frame ``obj`` (an original sequence object) shows at ``scene_frame`` (default: the
    scene's current frame) at ``lod``."""
    st = obj.gaussvdb
    CACHE.set_budget(int(scene.gaussvdb.sequence_memory * MB))
    f = scene.frame_current if scene_frame is None else scene_frame
    pat, asked, number = file_number(obj, f)
    out = Frame(number=number, requested=asked)
    if pat is None or number is None:
        return out
    if asked != number:
        msg = _missing_warning(obj, pat, volume(obj))
        if msg:
            out.warnings.append(msg)
    out.path = pat.path(number)
    try:
        stat = os.stat(out.path)
    except OSError as err:
        out.error = f"{obj.name}: frame {f}: cannot read {os.path.basename(out.path)} ({err.strerror})"
        return out
    key = (out.path, stat.st_mtime_ns, stat.st_size, st.grid_name, lod, st.convert_options())
    hit = CACHE.get(key)
    if hit is None:
        hit = _load(obj, out.path, lod, scene)
        if not hit[3]:  # errors are not cached: a file being written may be readable next time
            CACHE.put(key, hit, _nbytes(hit[0]))
    out.gaussians, out.values, out.index_to_world, out.error = hit
    if out.error:
        out.error = f"{obj.name}: frame {f}: {out.error}"
    return out


def _nbytes(gset):
    if gset is None:
        return 256
    return int(sum(np.asarray(getattr(gset, k)).nbytes for k in
                   ("group_origins", "group_start", "offsets", "sigmas", "values", "amplitudes",
                    "voxels")) + (0 if gset.size_codes is None else gset.size_codes.nbytes))


def _load(obj, path, lod, scene):
    """(GaussianSet or None, value figures, index_to_world, error) of one frame: from the disk
    cache when it holds this file, else converted (and written there)."""
    st = obj.gaussvdb
    opts = st.convert_options()
    folder = disk_cache_dir(scene)
    cache_file = os.path.join(folder, seq.cache_name(path, st.grid_name, lod, opts)) if folder else ""
    found = seq.read_frame(cache_file, path) if cache_file else None
    if found is not None:
        STATS["disk_hits"] += 1
        gset, values = found
        return gset, values, None if gset is None else np.asarray(gset.index_to_world), ""
    gset, values, i2w, error, original = convert_frame(path, st.grid_name, lod, opts)
    if cache_file and not error:
        try:
            seq.write_frame(cache_file, original, values, path, st.grid_name, lod)
            STATS["disk_writes"] += 1
        except (OSError, ValueError):  # a read-only folder, or a set the encoding refuses
            pass
    return gset, values, i2w, error


def convert_frame(path, grid, lod, options=DEFAULTS):
    """Convert one frame's grid at one LOD with the ConvertOptions ``options`` (an object's:
    ObjectSettings.convert_options): (GaussianSet as an import of that file alone would read
    it, value figures, index_to_world, error text, the converted set itself). A grid absent or
    empty in this frame gives (None, None, None, '', None): nothing to draw, no error."""
    from ...kernels import pipeline
    from ..io import conversion, schema
    from . import kernel_cache

    kernel_cache.announce("vdb", "lod")
    t0 = time.perf_counter()
    cg, error = pipeline.convert_frame(path, grid, lod, conversion.import_options(options))
    if cg is None:
        return None, None, None, error, None
    STATS["converted"] += 1
    STATS["seconds_convert"] += time.perf_counter() - t0
    return (schema.converted_gaussian_set(cg), cg.values or None, cg.index_to_world, "",
            cg.lods[0].gset)


def values_tuple(stats):
    """voxel_stats dict -> the (lo, hi, positive min, fraction <= 0) scene_sync uses."""
    if not stats or "min" not in stats:
        return None
    n = max(int(stats.get("voxels", 0)), 1)
    return (float(stats["min"]), float(stats["max"]), stats.get("positive_min"),
            int(stats.get("nonpositive", 0)) / n)
