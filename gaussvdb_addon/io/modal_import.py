"""An import of the UI, one short step at a time: the modal operator (operators/import_vdb.py)
calls ``next()`` once per timer event, and closes the generator on Esc (nothing is created before
the last step, so nothing is left half-built).

    steps = import_steps(context, paths, options, sequence=True, wait=["reader", "lod:medium"])
    fraction, text = next(steps)     # ... until StopIteration.value == (objects, message)

First, when ``wait`` names warm-up jobs (kernels/warmup.py) not compiled yet, it starts or joins
the background warm-up (engine/warmup_service.py) and waits for it, each step only reading its
status; if the warm-up fails, the kernels compile here as before (said in the text). Then it runs
the conversion's own steps (one grid x one LOD each), or a sequence in one go, then creates the
objects.
"""

import time

from ..engine import warmup_service
from . import importer, sequence_import


def wait_steps(jobs):
    """Yields (fraction, text) while the background warm-up compiles ``jobs``; returns '' when
    they are compiled, else why the warm-up failed (the caller then compiles them itself)."""
    if not jobs:
        return ""
    warmup_service.ensure(jobs)
    while True:
        p = warmup_service.progress(jobs)
        if p["done"]:
            return ""
        if p["failed"]:
            return p["failed"]
        yield p["fraction"], p["text"]


def import_steps(context, paths, options, sequence=True, wait=()):
    """Generator: yields (fraction in [0, 1], text) before each step; returns (objects, message).
    ``wait``: the warm-up jobs to wait for first (the operator passes warmup_service.needed)."""
    failed = yield from wait_steps(list(wait))
    t0 = time.perf_counter()
    note = f"background compile failed ({failed}): compiling here" if failed else ""
    if note:
        yield 0.0, note
    if sequence and sequence_import.any_sequence(paths):  # in one go: every frame is read once
        yield 0.0, "importing the sequence"
        objs, message = importer.import_files(context, paths, options=options, sequence=True)
        return objs, message
    skipped, done = [], []
    for i, path in enumerate(paths):
        steps = importer.convert_steps(path, options, skipped)
        try:
            while True:
                try:
                    fraction, text = next(steps)
                except StopIteration as stop:
                    done.append(stop.value)
                    break
                yield (i + fraction) / len(paths), text
        finally:
            steps.close()
    converted = [cg for part in done for cg in part]
    t1 = time.perf_counter()
    objs = importer.build_objects(converted, None, options)
    t2 = time.perf_counter()
    view_layer = getattr(context, "view_layer", None)
    if view_layer is not None:
        for obj in view_layer.objects.selected:
            obj.select_set(False)
        for obj in objs:
            obj.select_set(True)
        if objs:
            view_layer.objects.active = objs[-1]
    timing = importer.import_timing(converted, t2 - t0, t2 - t1)
    return objs, importer.status_message(objs, skipped, timing)
