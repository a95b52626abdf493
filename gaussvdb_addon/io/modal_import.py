"""An import of the UI, one short step at a time: the modal operator (operators/import_vdb.py)
calls ``next()`` once per timer event, and closes the generator on Esc (nothing is created before
the last step, so nothing is left half-built).

    steps = import_steps(context, paths, options, sequence=True, wait=["reader", "lod:medium"])
    fraction, text = next(steps)     # ... until StopIteration.value == (objects, message)

First, when ``wait`` names warm-up jobs (kernels/warmup.py) not compiled yet, it starts or joins
the background warm-up (engine/warmup_service.py) and waits for it, each step only reading its
status; if the warm-up fails, the kernels compile here as before (said in the text). Then it runs
the conversion's own steps (one grid x one LOD each) on a worker thread, each UI step only asking
whether the one under way is done: a step of a large grid takes seconds, and even on a small one
the first use of the kernels in a session (loading them from the cache) takes most of a second.
A sequence is imported in one go. The objects are created last, on Blender's thread.
"""

import threading
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
        steps = on_a_thread(importer.convert_steps(path, options, skipped))
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


def on_a_thread(steps, poll=0.02):
    """``steps`` (a generator of (fraction, text) that touches no bpy data) with each of its
    next() calls run on a worker thread: while one runs, this yields the last (fraction, text)
    again after at most ``poll`` s. Closed early (Esc), the step under way finishes on its thread,
    which then closes ``steps`` (nothing is created before the last step)."""
    last = (0.0, "")
    while True:
        box = {}
        worker = threading.Thread(target=_advance, args=(steps, box), daemon=True,
                                  name="gaussvdb-import")
        worker.start()
        try:
            while worker.is_alive():
                worker.join(poll)
                if worker.is_alive():
                    yield last
        except GeneratorExit:
            threading.Thread(target=_close_after, args=(worker, steps), daemon=True).start()
            raise
        if "error" in box:
            steps.close()
            raise box["error"]
        if "done" in box:
            return box["done"]
        last = box["item"]
        try:
            yield last
        except GeneratorExit:
            steps.close()
            raise


def _advance(steps, box):
    try:
        box["item"] = next(steps)
    except StopIteration as stop:
        box["done"] = stop.value
    except BaseException as err:  # noqa: BLE001  (raised again on Blender's thread)
        box["error"] = err


def _close_after(worker, steps):
    worker.join()
    steps.close()
