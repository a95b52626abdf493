"""GaussianSet: the output contract of kernels/lod (see docs/design.md).

Gaussians are grouped by the leaf (or tile) they come from; leaf groups come first, sorted by
origin (x, then y, then z), then tile groups. A group never is empty.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class GaussianSet:
    group_origins: np.ndarray  # int32 (G, 3)
    group_start: np.ndarray  # int64 (G + 1,)
    offsets: np.ndarray  # float32 (M, 3): centre - group origin, index units
    sigmas: np.ndarray  # float32 (M, 3): standard deviations, index units
    values: np.ndarray  # float32 (M,): mean of the represented voxels (level sets: 1.0)
    amplitudes: np.ndarray  # float32 (M,): peak occupancy (field: V/((2pi)^1.5 sx sy sz), paper: 1)
    voxels: np.ndarray  # int32 (M,): voxels represented
    grid_class: str = "fog_volume"
    lod: str = "medium"
    weights: str = "field"
    index_to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    background: float = 0.0
    # not in the minimal contract: what the encoder and the error need to know
    n_leaf_groups: int = 0  # groups [0, n_leaf_groups) are leaves, the rest tiles
    size_codes: np.ndarray | None = None  # int32 (M, 3): sigma = sigma_scale * code (exact)
    sigma_scale: float = 0.6
    params: dict = field(default_factory=dict)
    # a second grid of the same file on these Gaussians (second_grid.py): float32 (M,) or None
    color_values: np.ndarray | None = None
    color_background: float = 0.0  # that grid's background: its value away from the Gaussians
    # level sets: float32 (M,) the mean signed distance (the grid's units) of the voxels each
    # Gaussian stands for (the voxels its value averages); None where unknown (older files)
    distances: np.ndarray | None = None

    # ---- derived -------------------------------------------------------------------------
    @property
    def count(self) -> int:
        return int(self.offsets.shape[0])

    def __len__(self) -> int:
        return self.count

    @property
    def is_sphere(self) -> np.ndarray:
        s = self.sigmas
        return (s[:, 0] == s[:, 1]) & (s[:, 1] == s[:, 2])

    @property
    def n_spheres(self) -> int:
        return int(np.count_nonzero(self.is_sphere))

    @property
    def n_ellipsoids(self) -> int:
        return self.count - self.n_spheres

    @property
    def has_values(self) -> bool:
        """False for level sets: one uniform opacity, no per-Gaussian value."""
        return self.grid_class != "level_set"

    def group_of(self) -> np.ndarray:
        """int64 (M,): the group index of every Gaussian."""
        counts = np.diff(self.group_start)
        return np.repeat(np.arange(len(counts), dtype=np.int64), counts)

    def centers(self) -> np.ndarray:
        """float64 (M, 3) absolute index-space centres."""
        return self.group_origins[self.group_of()].astype(np.float64) + self.offsets

    def true_voxels(self, first=0) -> np.ndarray:
        """Represented voxels as float64 (of rows ``first`` on), tiles from their true edge
        (int32 voxels saturate)."""
        vox = self.voxels[first:].astype(np.float64)
        ml = max(int(self.group_start[self.n_leaf_groups]), first)
        if ml < self.count:
            if self.size_codes is not None:
                e = self.size_codes[ml:].astype(np.float64)
            else:
                e = np.rint(self.sigmas[ml:].astype(np.float64) / np.float64(self.sigma_scale))
            vox[ml - first:] = e[:, 0] * e[:, 1] * e[:, 2]
        return vox
