"""The benchmark's other renderers, each in its own subprocess: Cycles (benchmarks/cycles_ref.py,
from the source .vdb) and VTK's fixed-point ray caster (benchmarks/vtk_ref.py, from a dense copy of
the grid's active box). Each returns (info, {key: image}) or raises RuntimeError with the reason;
VTK raises VTKMissing when the environment has no `vtk` module."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


class VTKMissing(RuntimeError):
    pass


def _run(script, job, workdir, name):
    os.makedirs(workdir, exist_ok=True)
    jp = os.path.join(workdir, "job.json")
    with open(jp, "w") as f:
        json.dump(job, f)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, os.path.join(HERE, script), jp], capture_output=True, check=False,
                       text=True, cwd=ROOT)
    return r, time.perf_counter() - t0


def run_cycles(path, grid, view, a, workdir):
    d = float(np.linalg.norm(view["cam"].cam_to_world[:3, 3] - 0.5 * (view["lo"] + view["hi"])))
    job = {"vdb": os.path.abspath(path), "grid": grid, "width": a.width, "height": a.height,
           "cam_to_world": view["cam"].cam_to_world.tolist(), "fov_x": view["cam"].fov_x,
           "clip": [max(1e-6, d * 1e-3), d * 10.0], "vmin": view["vmin"], "vmax": view["vmax"],
           "density": view["density"], "positions": np.asarray(view["positions"]).tolist(),
           "colors": np.asarray(view["colors"]).tolist(), "samples": a.samples, "out_dir": workdir,
           "volume_biased": a.cycles_biased, "threads": a.threads}
    r, total = _run("cycles_ref.py", job, workdir, "Cycles")
    if r.returncode != 0:
        raise RuntimeError(f"Cycles failed ({r.returncode}): {r.stderr[-1500:]}")
    with open(os.path.join(workdir, "cycles.json")) as f:
        info = json.load(f)
    imgs = {row["samples"]: np.load(os.path.join(workdir, f"cycles_{row['samples']}.npy"))
            for row in info["rows"]}
    info["seconds_subprocess"] = total
    return info, imgs


def dense_box(g):
    """float32 (X, Y, Z) of the grid's active index box padded by one voxel (the background there),
    and the index of its voxel (0, 0, 0): leaf values (inactive ones too, as the reference mode
    samples them) and active tiles; elsewhere the background."""
    from kernels.render.inputs.accel import _grid_leaves

    lo = np.asarray(g.bbox_min, np.int64) - 1
    hi = np.asarray(g.bbox_max, np.int64) + 2
    vol = np.full(tuple(hi - lo), np.float32(g.background or 0.0), np.float32)
    org, val = _grid_leaves(g)
    for o, v in zip(org, val):
        a, b = np.maximum(o, lo), np.minimum(o + 8, hi)
        if np.any(b <= a):
            continue
        vol[a[0] - lo[0]:b[0] - lo[0], a[1] - lo[1]:b[1] - lo[1], a[2] - lo[2]:b[2] - lo[2]] = \
            v[a[0] - o[0]:b[0] - o[0], a[1] - o[1]:b[1] - o[1], a[2] - o[2]:b[2] - o[2]]
    return vol, lo


def axis_aligned(m):
    """True when index -> world is a positive per-axis scale plus a translation (what vtkImageData's
    origin and spacing can hold)."""
    r = np.asarray(m, np.float64)[:3, :3]
    return bool(np.all(np.abs(r - np.diag(np.diag(r))) <= 1e-9 * np.abs(r).max()) and np.all(np.diag(r) > 0))


def run_vtk(g, view, a, workdir, steps, repeat=3):
    m = view["m"]
    if not axis_aligned(m):
        raise RuntimeError("VTK: the grid's index-to-world is not an axis-aligned scale (vtkImageData "
                           "origin + spacing cannot hold it)")
    os.makedirs(workdir, exist_ok=True)
    vol, lo = dense_box(g)
    vp = os.path.join(workdir, "volume.npy")
    np.save(vp, vol)
    cam = view["cam"]
    c2w = cam.cam_to_world
    pos = c2w[:3, 3]
    fwd = -c2w[:3, 2] / np.linalg.norm(c2w[:3, 2])
    dist = float(np.linalg.norm(0.5 * (view["lo"] + view["hi"]) - pos))
    spacing = np.diag(m)[:3]
    job = {"volume": vp, "origin": (m @ np.append(lo.astype(float), 1.0))[:3].tolist(),
           "spacing": spacing.tolist(), "width": a.width, "height": a.height, "position": pos.tolist(),
           "focal_point": (pos + fwd * dist).tolist(), "view_up": c2w[:3, 1].tolist(), "fov_x": cam.fov_x,
           "lut": view["tf"].lut.astype(float).tolist(), "vmin": view["vmin"], "vmax": view["vmax"],
           "density": view["density"], "steps": list(steps), "voxel": float(np.min(spacing)),
           "threads": a.threads or os.cpu_count(), "repeat": repeat, "out_dir": workdir}
    r, total = _run("vtk_ref.py", job, workdir, "VTK")
    os.remove(vp)
    if r.returncode == 3:
        raise VTKMissing(r.stderr.strip().splitlines()[-1] if r.stderr.strip() else "VTK: not available")
    if r.returncode != 0:
        raise RuntimeError(f"VTK failed ({r.returncode}): {r.stderr[-1500:]}")
    with open(os.path.join(workdir, "vtk.json")) as f:
        info = json.load(f)
    imgs = {row["step"]: np.load(os.path.join(workdir, f"vtk_{i}.npy")) for i, row in enumerate(info["rows"])}
    info["seconds_subprocess"] = total
    info["volume_shape"] = list(vol.shape)
    return info, imgs
