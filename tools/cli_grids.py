"""Which grid of a .vdb file `render` and `convert` use, decided from the topology alone (cheap:
no values are decoded); when none can be used, the refusal says why per grid. Read with the
kernels the process runs (blender_session.kernels_module: the extension's once Blender is up).
The default is the import's (kernels.pipeline.default_grids: a Mantaflow cache gives density),
the first of those that can be used. A sequence's grid: the first of its frames that has one."""
from __future__ import annotations

import os

from blender_session import kernels_module
from cli_errors import InputError


def unusable(grid, vector_magnitude=False):
    """Why ``grid`` (a GridData, topology is enough) gives no scalar field, or None."""
    if grid.value_type.startswith("vec3") and not vector_magnitude:
        return f"{grid.value_type} grid, use --vector-magnitude"
    if not grid.active_voxels:
        return "empty grid (no active voxels)"
    return None


def check_color_grid(path, name, vector_magnitude=False) -> str:
    """The colour grid ``name`` (--color-grid), checked like --grid: InputError naming the grid and
    the file when the file holds no such usable grid."""
    topo = kernels_module("vdb").read_topology(path)
    listed = [g.name for g in topo.grids] + [n for n, _ in topo.skipped]
    if name not in listed:
        raise InputError(f"no colour grid {name!r} in {path} (grids: {', '.join(listed) or 'none'})")
    reasons = dict(topo.skipped)
    reasons.update((g.name, why) for g in topo.grids
                   if g.value_type.startswith("vec3") and not vector_magnitude
                   and (why := unusable(g, vector_magnitude)))
    if name in reasons:
        raise InputError(f"colour grid {name!r} of {path} cannot be used: {reasons[name]}")
    return name


def choose_grid(path, grid=None, vector_magnitude=False) -> str:
    """The named grid, or the first usable default one; InputError naming the file and each
    grid's reason. A file the reader refuses raises its VDBFormatError (which names the file and
    byte offset)."""
    topo = kernels_module("vdb").read_topology(path)
    # the reader's own reasons for grids it skips (points, integers, ...), then ours
    reasons = dict(topo.skipped)
    reasons.update((g.name, why) for g in topo.grids if (why := unusable(g, vector_magnitude)))
    listed = [g.name for g in topo.grids] + [n for n, _ in topo.skipped]
    if grid is not None:
        if grid not in listed:
            raise InputError(f"no grid {grid!r} in {path} (grids: {', '.join(listed) or 'none'})")
        if grid in reasons:
            raise InputError(f"grid {grid!r} of {path} cannot be used: {reasons[grid]}")
        return grid
    wanted, left_out = kernels_module("pipeline").default_grids(listed)
    reasons.update((n, "left out by default in a Mantaflow cache (name it with --grid)")
                   for n, _ in left_out if n not in reasons)
    usable = [name for name in (listed if wanted is None else wanted) if name not in reasons]
    if not usable:
        why = "; ".join(f"{n}: {r}" for n, r in reasons.items()) or "the file holds no grids"
        raise InputError(f"no scalar grid in {path} ({why})")
    return usable[0]


def sequence_frames(pattern, frames=None, grid=None, vector_magnitude=False):
    """(Pattern, the frames on disk within ``frames``, the grid: named, or the default one of
    the first frame with one) of a sequence `convert` writes into a disk cache, serially or on a
    cluster; refusals name the pattern."""
    from kernels import sequence as seq

    pat = seq.parse(os.path.abspath(pattern))
    if pat is None:
        raise InputError(f"{pattern}: no frame number or #### in the file name")
    present = pat.scan()
    if not present:
        raise InputError(f"no frames of {pat.text} in {pat.directory}")
    if frames:
        present = [n for n in present if frames[0] <= n <= frames[-1]]
        if not present:
            raise InputError(f"no frames of {pat.text} between {frames[0]} and {frames[-1]}")
    name, last = None, None
    for n in present:  # the grid: named, or the default one of the first frame with one
        try:
            name = choose_grid(pat.path(n), grid, vector_magnitude)
            break
        except (InputError, ValueError) as err:
            last = err
    if name is None:
        raise last
    return pat, present, name
