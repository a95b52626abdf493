"""The data contract of the reader (docs/design.md, GridData)."""

from dataclasses import dataclass, field
from typing import Optional

import numpy as np


@dataclass
class GridData:
    name: str
    grid_class: str            # fog_volume, level_set, staggered or unknown
    value_type: str            # float, double, vec3s, vec3d
    background: float
    file_version: int
    compression: str
    half: bool
    index_to_world: np.ndarray  # float64 (4, 4), world = M @ (i, j, k, 1)
    leaf_origins: np.ndarray    # int32 (N, 3)
    leaf_masks: np.ndarray      # uint64 (N, 8)
    leaf_values: Optional[np.ndarray]  # float32 (N, 512); None after a topology-only read
    tile_origins: np.ndarray    # int32 (T, 3)
    tile_sizes: np.ndarray      # int32 (T,)
    tile_values: np.ndarray     # float32 (T,)
    tile_active: np.ndarray     # bool (T,)
    active_voxels: int
    bbox_min: np.ndarray        # int64 (3,), inclusive; (0,0,0) > bbox_max when empty
    bbox_max: np.ndarray
    leaf_vectors: Optional[np.ndarray] = None  # float32 (N, 512, 3) for vec3 grids


@dataclass
class VDBFile:
    path: str
    version: int
    library_version: tuple
    grids: list = field(default_factory=list)
    skipped: list = field(default_factory=list)  # (name, reason)
    metadata: dict = field(default_factory=dict)
    grid_info: dict = field(default_factory=dict)  # name -> extra facts (map type, byte range, ...)
