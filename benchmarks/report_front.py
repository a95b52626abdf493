"""The Pareto front of render time vs PSNR, and the report rows' short names."""
from __future__ import annotations

import math


def pareto_front(points):
    """Indices of the (seconds, psnr) points no other point dominates (as fast or faster AND as
    accurate or more, one of them strictly), sorted by time. psnr None (an image identical to the
    reference) counts as infinitely accurate; points without a time are left out."""
    def key(i):
        t, p = points[i]
        return t, -(math.inf if p is None else p)

    idx = sorted((i for i, (t, _) in enumerate(points) if t is not None and math.isfinite(t)), key=key)
    front, best = [], -math.inf
    for i in idx:  # by time, then accuracy: a point is on the front when it beats every faster one
        p = math.inf if points[i][1] is None else points[i][1]
        if p > best:
            front.append(i)
            best = p
    return front


def label(r):
    """One report row's configuration, as the summary and the chart name it."""
    if r["renderer"] == "cycles":
        return f"Cycles {r['samples']} spp"
    if r["renderer"] == "vtk":
        return f"VTK step {r['step']:g}"
    if r["mode"] == "reference":
        return f"reference step {r['step']:g}"
    return f"{r['mode']}/{r['lod']}"


def is_gaussian(r):
    return r["renderer"] == "gaussvdb" and r["mode"] != "reference"


def front_rows(rows):
    """The rows of one dataset/grid on its time-vs-PSNR front, fastest first."""
    return [rows[i] for i in pareto_front([(r["seconds_render"], r["psnr"]) for r in rows])]


def same_step(rows, renderer, step):
    return next((r for r in rows if r["renderer"] == renderer and r.get("step") == step
                 and (renderer != "gaussvdb" or r["mode"] == "reference")), None)
