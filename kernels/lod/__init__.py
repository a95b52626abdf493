"""Gaussian LOD generation (issue 4): OpenVDB leaves and tiles -> axis-aligned Gaussians.

Presets (names, labels and descriptions: kernels/lod_names.py, which registration reads without numba):
  low, medium, high  the paper's three spatial schemes (section 4.2.2)
  variance           variance-based intra-leaf clustering (recursive bisection)
  merged             inter-leaf clustering: `high` plus the 26-neighbourhood merge pass
  adaptive           error-bounded: the fewest Gaussians whose field meets a tolerance (adaptive.py)
Weights: "field" (default, normalized kernels, partition of unity) or "paper" (as written).
"""
from .build import DEFAULTS, PRESETS, WEIGHTS, build_lod
from .encoding import decode_compact, encode_compact, encoded_nbytes, paper_model_bytes
from .gaussian_set import GaussianSet
from .gridprep import effective_masks, value_range
from .mixture import field_error

__all__ = ["PRESETS", "WEIGHTS", "DEFAULTS", "GaussianSet", "build_lod",
           "field_error", "encode_compact", "decode_compact", "encoded_nbytes",
           "paper_model_bytes", "value_range", "effective_masks"]
