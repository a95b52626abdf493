"""Computation for GaussVDB: plain numpy/numba, never bpy, testable without Blender."""
