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


# what a frame's segments are, per mode (the device's statistics)
SEGMENT = {"particles": "Gaussian segments", "field": "Gaussian terms", "splat": "lattice samples", "paper": "samples",
           "reference": "samples"}


def work(r):
    """(segments per covered pixel, ns per segment per thread) of one of our rows, else None: what a
    frame costs and why (a Gaussian segment or term, or a voxel sample)."""
    if r.get("segments") is None or not r.get("covered_pixels"):
        return None
    per_px = r["segments"] / r["covered_pixels"]
    ns = r["seconds_render"] * r["threads"] / r["segments"] * 1e9 if r["segments"] else None
    return per_px, ns


def why_not(rows):
    """Where no Gaussian configuration is on the front: the fastest Gaussian one against our fastest
    voxel step, segments per covered pixel and their cost (None where one of them is missing)."""
    g = min((r for r in rows if is_gaussian(r) and work(r)), key=lambda r: r["seconds_render"], default=None)
    v = min((r for r in rows if r["renderer"] == "gaussvdb" and r["mode"] == "reference" and work(r)),
            key=lambda r: r["seconds_render"], default=None)
    if g is None or v is None:
        return None
    (gp, gns), (vp, vns) = work(g), work(v)
    return (f"{label(g)} {g['seconds_render']:.2f} s: {gp:,.0f} {SEGMENT[g['mode']]} a covered pixel, "
            f"{gns:.0f} ns each; {label(v)} {v['seconds_render']:.2f} s: {vp:,.0f} samples, {vns:.0f} ns each")
