"""Splat mode: each object's Gaussian mixture evaluated once on a lattice at the Gaussians' own
scale (kernels.lod.splat), then drawn as the reference mode draws voxels (trilinear,
post-classified, exact exponential per sample), with the step counted in lattice cells. A device
draws a splat scene as the reference scene `drawn` returns; the grids are kept per Gaussian set
while the set is synced, so a new camera or transfer function costs no new lattice.

Level sets are drawn from their voxels (`RenderObject.grid`), as in reference mode: their shell
or surface comes from the signed distances, which a mixture of occupancies does not carry."""
from __future__ import annotations

import dataclasses

import numpy as np

from .objects import RenderScene


class SplatGrids:
    """The splat grids of the synced objects, by Gaussian set, support radius and whether a second
    grid colours it."""

    def __init__(self):
        self._grids = {}

    def drawn(self, scene: RenderScene) -> RenderScene:
        """The scene as a device draws it: itself, or for splat mode the reference scene over
        the objects' splat grids."""
        if scene.mode != "splat":
            return scene
        kept, objs = {}, []
        for o in scene.objects:
            objs.append(self._object(o, float(scene.support_k), kept))
        self._grids = kept  # only the sets of this scene stay
        return dataclasses.replace(scene, objects=objs, mode="reference")

    def _object(self, o, k, kept):
        if o.is_level_set:
            if o.grid is None:
                raise ValueError(f"{o.name or 'object'}: splat mode draws a level set from its "
                                 "voxels (RenderObject.grid)")
            return o
        gs = o.gaussians
        if gs is None:
            raise ValueError(f"{o.name or 'object'}: splat mode needs its Gaussians")
        colored = o.color_tf is not None
        key = (id(gs), k, colored)
        hit = self._grids.get(key)
        if hit is None or hit[0] is not gs:
            hit = (gs, *_grids(gs, k, colored))
        kept[key] = hit
        _, spacing, grid, color = hit
        from ...lod.splat import lattice_to_index

        return dataclasses.replace(o, gaussians=None, grid=grid, color_grid=color,
                                   matrix_world=o.matrix_world @ lattice_to_index(spacing))


def _grids(gs, k, colored):
    """(spacing, the set's splat grid, its colour grid's splat grid or None)."""
    from ...lod.splat import auto_spacing, splat_grid

    spacing = auto_spacing(gs)
    grid = splat_grid(gs, spacing, k)
    color = None
    if colored:
        cv = getattr(gs, "color_values", None)
        bg = float(getattr(gs, "color_background", 0.0) or 0.0)
        color = splat_grid(gs, spacing, k, values=np.asarray(cv, np.float64) - bg, background=bg)
    return spacing, grid, color
