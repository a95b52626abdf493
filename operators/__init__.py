"""Blender operators. Thin: each one calls a plain function that scripts and the CLI call too."""

from . import colormap, import_vdb, kernels, presets, reload

CLASSES = (*import_vdb.CLASSES, *reload.CLASSES, *colormap.CLASSES, *presets.CLASSES,
           *kernels.CLASSES)


def register_extra():
    import_vdb.register_extra()


def unregister_extra():
    import_vdb.unregister_extra()
