"""Presets shipped in presets/ (LOD presets for the import operator, colormap presets)."""

import os

import bpy

PRESET_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "presets")

CLASSES = ()


def register_extra():
    bpy.utils.register_preset_path(PRESET_DIR)


def unregister_extra():
    bpy.utils.unregister_preset_path(PRESET_DIR)
