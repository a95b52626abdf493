"""Where an imported object's .vdb file is, kept as a Blender file path.

The path lives in a Volume datablock (``Object.gaussvdb.source_volume``, one per file, shared
by the objects imported from it, never linked into a scene so Blender never loads it): Volume
paths are the ones Blender's own tools handle, so File > External Data > Make Paths Relative,
Find Missing Files, Report Missing Files and ``bpy.utils.blend_paths()`` see it.
``Object.gaussvdb.source_file`` reads and writes that path.
"""

import os

import bpy
from bpy.app.handlers import persistent

MARK = "gaussvdb_source"  # custom property marking the Volumes this add-on made


def _same_file(a, b):
    return os.path.normcase(os.path.abspath(bpy.path.abspath(a))) == \
        os.path.normcase(os.path.abspath(bpy.path.abspath(b)))


def source_volume(path):
    """The add-on's Volume datablock for ``path`` (made on first use)."""
    for vol in bpy.data.volumes:
        if vol.get(MARK) and vol.library is None and not vol.is_sequence \
                and _same_file(vol.filepath, path):
            return vol
    vol = bpy.data.volumes.new(os.path.basename(path) or "GaussVDB source")
    vol[MARK] = True
    vol.filepath = path
    return vol


def sequence_volume(first_path, frame_start=1, frame_offset=0, frame_duration=1,
                    sequence_mode="REPEAT"):
    """The Volume datablock of a numbered sequence: ``first_path`` is its first file, and
    Blender's own sequence fields (is_sequence, frame start/offset/duration, sequence mode) say
    which file each scene frame shows, as for a Volume object. The grids of one sequence share
    it (one with the same file and settings is reused), so their timing stays together."""
    fields = (int(frame_start), int(frame_offset), max(1, int(frame_duration)), sequence_mode)
    for vol in bpy.data.volumes:
        if vol.get(MARK) and vol.library is None and vol.is_sequence \
                and _same_file(vol.filepath, first_path) \
                and (vol.frame_start, vol.frame_offset, vol.frame_duration, vol.sequence_mode) == fields:
            return vol
    vol = bpy.data.volumes.new(os.path.basename(first_path) or "GaussVDB sequence")
    vol[MARK] = True
    vol.filepath = first_path
    vol.is_sequence = True
    vol.frame_start, vol.frame_offset = int(frame_start), int(frame_offset)
    vol.frame_duration, vol.sequence_mode = max(1, int(frame_duration)), sequence_mode
    return vol


def is_sequence(settings) -> bool:
    vol = settings.source_volume
    return vol is not None and bool(vol.is_sequence)


def get_source_file(settings):
    vol = settings.source_volume
    return vol.filepath if vol is not None else ""


def set_source_file(settings, value):
    settings.source_volume = source_volume(value) if value else None


def absolute(settings):
    """The source file as an absolute path ('' when none)."""
    vol = settings.source_volume
    if vol is None or not vol.filepath:
        return ""
    return os.path.abspath(bpy.path.abspath(vol.filepath, library=vol.library))


def migrate(obj):
    """Files of older versions hold the path as a plain string property: move it to a Volume."""
    st = getattr(obj, "gaussvdb", None)
    if st is None or st.source_volume is not None:
        return False
    old = st.get("source_file")
    if not isinstance(old, str) or not old:
        return False
    set_source_file(st, old)
    del st["source_file"]
    return True


@persistent
def _migrate_on_load(_filepath=""):
    for obj in bpy.data.objects:
        if obj.library is None:
            migrate(obj)


CLASSES = ()


def register_extra():
    if _migrate_on_load not in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.append(_migrate_on_load)


def unregister_extra():
    if _migrate_on_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_migrate_on_load)
