"""Blender operators. Thin: each one calls a plain function that scripts and the CLI call too."""

from . import import_vdb, reload

CLASSES = (*import_vdb.CLASSES, *reload.CLASSES)


def register_extra():
    import_vdb.register_extra()


def unregister_extra():
    import_vdb.unregister_extra()
