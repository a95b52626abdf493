"""Files written by older versions, upgraded when they load (Cycles' version_update.py pattern):
a load_post handler brings every GaussVDB object of the file to schema.LAYOUT_VERSION in place.

Layout 0 is an object with no layout version stored: its points may come in any order and may
lack ``gs_origin``/``gs_sigma``, and it may name no LOD (it holds one: Medium). The upgrade makes
each (LOD, group) contiguous, adds the attributes the reader needs, names the LOD and stores the
version. Objects linked from a library cannot be written: the reader upgrades those in memory
(schema.upgrade_arrays), and refuses a layout newer than it knows.
"""

import bpy
from bpy.app.handlers import persistent

from ..properties import lod_figures
from . import schema


def upgrade_object(obj) -> bool:
    """Bring one object to the current layout in place; True when something changed."""
    st = obj.gaussvdb
    version = schema.check_version(obj)
    if version >= schema.LAYOUT_VERSION or obj.type != "POINTCLOUD" or obj.library is not None \
            or obj.data is None or obj.data.library is not None:
        return False
    arrays = schema.upgrade_arrays(schema.read_attributes(obj), version)
    typed = {}
    for name, arr in arrays.items():
        if name in schema.ATTRIBUTES:
            btype = "FLOAT_VECTOR" if arr.ndim == 2 else schema.ATTRIBUTES[name][0] or "FLOAT"
            typed[name] = (btype, arr.astype(schema.ATTRIBUTES[name][1]), 3 if arr.ndim == 2 else 1)
    schema.write_attributes(obj.data, typed)
    if not st.lods:
        st.lods = ",".join(schema.lod_names(obj))
    st.layout_version = schema.LAYOUT_VERSION
    obj.data.update_tag()
    return True


def upgrade_weights(obj) -> bool:
    """The weight rule of an older file, stored as text (``weights``), into the enum."""
    st = obj.gaussvdb
    if not st.weights or obj.library is not None:
        return False
    st.weight_rule = st.weights_rule()
    st.weights = ""
    return True


def do_versions() -> list:
    """Upgrade every GaussVDB object of the open file; the names of those upgraded."""
    done = []
    for obj in bpy.data.objects:
        gs = getattr(obj, "gaussvdb", None)
        if gs is None or not gs.is_gaussvdb:
            continue
        try:
            moved = lod_figures.upgrade(obj)  # per-LOD figures: JSON -> collection
            moved = upgrade_weights(obj) or moved
            if upgrade_object(obj) or moved:
                done.append(obj.name)
        except (ValueError, KeyError) as err:  # newer layout, or no positions: the reader says so
            print(f"GaussVDB: {obj.name} not upgraded: {err}")
    return done


@persistent
def load_post(_filepath=None):
    do_versions()


def register_extra():
    if load_post not in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.append(load_post)


def unregister_extra():
    if load_post in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(load_post)


CLASSES = ()
