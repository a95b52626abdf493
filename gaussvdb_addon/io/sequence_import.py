"""Import of a numbered .vdb sequence (``fluid_data_0001.vdb`` ...) as one object per grid.

    objs = import_sequence("cache/fluid_data_0001.vdb", lods=("low", "medium"))
    import_sequence(path, options=ConvertOptions(grids=("density",), compute_error=False))

Like Blender's Volume import: the frames are the files sharing the name with another trailing
number (zero padding kept, gaps allowed), the object's source Volume holds the first file with
``is_sequence`` on, frame start 1, offset (first number - 1), duration (last - first + 1) and
the Repeat mode. The object's point cloud holds one frame (the first where its grid has voxels):
its display in Solid view and its bounds. The engine converts the frame each scene frame shows
on demand (sequence_frames.py).

At import every frame is read once for its value figures (the transfer function's automatic
range over the whole sequence, stored on the object with each frame's own figures) and its
leaf box; a frame that cannot be read is named in the report and left out of the range.
"""

import os

import numpy as np

from ...kernels import pipeline
from ...kernels import sequence as seq
from ...kernels.convert_options import DEFAULTS, options_of
from . import conversion
from .conversion import VDBImportError
from .datablocks import build_objects


def sequence_of(path, numbers=None):
    """(Pattern, frame numbers) of the sequence ``path`` belongs to: every numbered sibling on
    disk, or those between the smallest and largest of ``numbers`` (the files selected)."""
    pat = seq.parse(conversion.bpy_abspath(path) if path else path)
    if pat is None:
        raise VDBImportError(f"{os.path.basename(path)} has no frame number: not a sequence")
    present = pat.scan()
    if numbers:
        lo, hi = min(numbers), max(numbers)
        present = [n for n in present if lo <= n <= hi]
    if not present:
        raise VDBImportError(f"no frames of {pat.text} in {pat.directory or '.'}")
    return pat, present


def has_siblings(path) -> bool:
    """True when ``path`` is a numbered file whose next or previous frame is beside it (so
    'bunny_256.vdb' beside 'bunny_512.vdb' is no sequence, 'smoke_0007.vdb' beside
    'smoke_0008.vdb' is)."""
    pat = seq.parse(path) if path else None
    n = seq.frame_number(path) if pat is not None else None
    if n is None:
        return False
    present = set(pat.scan())
    return n + 1 in present or n - 1 in present


def sequences(paths) -> list:
    """The selected files grouped: [(Pattern or None, numbers or [path], is a sequence?)]."""
    out = []
    for pat, items in seq.group(paths):
        is_seq = pat is not None and (len(items) > 1 or has_siblings(pat.path(items[0])))
        out.append((pat, items, is_seq))
    return out


def any_sequence(paths) -> bool:
    return any(is_seq for _, _, is_seq in sequences(paths))


def _frame_pass(pat, present, wanted, progress, known=None):
    """Every frame's figures (kernels.sequence.frame_figures; ``known``: {number: those figures}
    already read, e.g. by cluster tasks): per grid and frame the value figures and leaf box;
    frames that cannot be read -> {number: reason}. Returns (figures {grid: {number: stats}},
    boxes {grid: (lo, hi)}, {grid: frames holding voxels}, grid names in order of appearance,
    unreadable)."""
    figures, boxes, holds, names, unreadable = {}, {}, {}, [], {}
    for i, n in enumerate(present):
        path = pat.path(n)
        if progress is not None:
            progress(0.5 * i / len(present), f"reading {os.path.basename(path)}")
        got = (known or {}).get(n) or seq.frame_figures(path, wanted)
        if "error" in got:
            unreadable[n] = got["error"]
            continue
        names += [g for g in got["names"] if g not in names]
        for name, fig in got["grids"].items():
            holds.setdefault(name, []).append(n)
            if fig["values"] is not None:
                figures.setdefault(name, {})[n] = fig["values"]
            lo, hi = fig["box"]
            blo, bhi = boxes.get(name, (lo, hi))
            boxes[name] = (np.minimum(blo, lo), np.maximum(bhi, hi))
    return figures, boxes, holds, names, unreadable


def convert_sequence(path, numbers=None, options=DEFAULTS, progress=None, cancel=None,
                     skipped=None, known=None):
    """Phase 1 of a sequence import (no Blender data): [ConvertedGrid] with ``sequence`` set.
    ``options``: a ConvertOptions (its tolerance is the shown frame's; frames converted later
    use the object's settings, kept by build_objects, with the default tolerance). ``known``:
    {frame number: kernels.sequence.frame_figures} read elsewhere, not read again."""
    if not options.lods:
        raise VDBImportError("a sequence needs a LOD preset: its frames are drawn as Gaussians")
    pat, present = sequence_of(path, numbers)
    skipped = [] if skipped is None else skipped
    wanted = None if options.grids is None else list(options.grids)
    report = conversion.Progress(progress) if progress is not None else None
    try:
        if wanted is None:  # defaults per cache layout, from the first frame that can be read
            from ...kernels import vdb

            for n in present:
                try:
                    names = [g.name for g in vdb.read_topology(pat.path(n)).grids]
                except (vdb.VDBFormatError, OSError):
                    continue
                wanted, left_out = pipeline.default_grids(names)
                skipped.extend(left_out)
                break
        figures, boxes, holds, names, unreadable = _frame_pass(pat, present, wanted, report, known)
        if len(unreadable) == len(present):
            n, why = next(iter(unreadable.items()))
            raise VDBImportError(f"no frame of {pat.text} can be read ({os.path.basename(pat.path(n))}: "
                               f"{why})")
        chosen = [g for g in (wanted or names) if g in boxes]
        for g in wanted or ():
            if g not in names:
                skipped.append((g, f"not in any frame of {pat.text}"))
            elif g not in boxes:
                skipped.append((g, "no voxels in any frame (or a vector grid)"))
        if not chosen:
            why = "; ".join(f"{n}: {r}" for n, r in skipped) or "the frames hold no scalar grid"
            raise VDBImportError(f"no scalar grid to import in {pat.text} ({why})")
        settings = dict(frame_start=1, frame_offset=present[0] - 1,
                        frame_duration=present[-1] - present[0] + 1, sequence_mode="REPEAT")
        out = []
        for k, name in enumerate(chosen):
            per = figures.get(name, {})
            shown = holds[name][0]  # the object's own frame: the first with voxels of this grid
            if report is not None:
                report(0.5 + 0.5 * k / len(chosen), f"{name}: converting frame {shown}")
            if cancel is not None and cancel():
                raise pipeline.ConversionCancelled()
            cg = next(c for c in conversion.convert_file(
                pat.path(shown), options.replace(grids=(name,)), None, cancel) if c.name == name)
            cg.filepath = pat.path(present[0])
            cg.values = seq.union_stats(per.values()) or cg.values
            cg.leaf_box = boxes[name]
            cg.sequence = {"settings": settings, "figures": {
                "pattern": pat.text, "frames": [present[0], present[-1]], "present": len(present),
                "shown": shown, "values": {str(n): st for n, st in per.items()},
                "unreadable": {str(n): why for n, why in unreadable.items()}}}
            out.append(cg)
        return out
    finally:
        if report is not None:
            report.end()


def import_sequence(path, numbers=None, grids=None, lods=None, *, options=None, collection=None,
                    progress=None, cancel=None, skipped=None, known=None, **changes) -> list:
    """Import a numbered sequence: one object per grid for all its frames. ``grids``, ``lods``
    and ``changes`` (ConvertOptions fields) over ``options``; ``known``: frames' figures
    already read (convert_sequence)."""
    opts = options_of(options, grids, lods, **changes)
    converted = convert_sequence(path, numbers, opts, progress, cancel, skipped, known)
    objs = build_objects(converted, collection, opts)
    name_objects(objs)
    return objs


def name_objects(objs):
    """A sequence's objects are named without the frame number: 'fluid_data_density'."""
    for obj in objs:
        vol = obj.gaussvdb.source_volume
        if vol is None or not vol.is_sequence:
            continue
        pat = seq.parse(vol.filepath)
        stem = (pat.head.rstrip("_.- ") if pat is not None else "") or "sequence"
        obj.name = obj.data.name = f"{stem}_{obj.gaussvdb.grid_name}"


def unreadable_note(objs) -> str:
    """'frames not read: fluid_data_0012.vdb (reason)' for the status line, or ''."""
    seen = {}
    for obj in objs:
        fig = obj.gaussvdb.stats().get("sequence", {})
        pat = seq.parse(fig.get("pattern", ""))
        for n, why in fig.get("unreadable", {}).items():
            if pat is not None:
                seen[pat.name(int(n))] = why
    return "; ".join(f"cannot read {k}: {v}" for k, v in seen.items())
