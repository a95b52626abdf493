"""Scaling benchmark: one volume resampled by integer factors (a resolution series made here, in a
temporary folder that is removed at exit), and per step the seconds and peak memory of reading it,
converting it per LOD (with and without the field error), importing it into Blender per LOD (the
add-on's import, field error included, as the dialog's default), rendering it per mode and LOD and,
in the same run, Blender's Volume object with Cycles at 16 samples (benchmarks/cycles_ref.py; the
same camera and transfer function as ours, from bench_report.setup_view; its seconds are the
frame's after a warm-up that syncs the scene, reported as seconds_sync), then the scaling exponent
of each (the slope of log seconds over log active voxels).

    python benchmarks/bench_scale.py [--source FILE.vdb] [--factors 1,2,3] [--lods low,medium]
                                     [--modes particles,reference] [--size 512] [--quick]
                                     [--no-cycles] [--no-import] [--markdown FILE.md]

--quick: the 3x file only. Each measurement runs in a process of its own, so its peak memory
(ru_maxrss, which includes reading the file the step starts from) is its own; the series is
written with the bundled openvdb (trilinear upsampling, slab by slab, so making it needs memory
for a few slabs only). A read is timed the second time in its process (the kernels loaded); a
render's seconds are its first frame (sync, set-up, drawing) and seconds_frame the next one.
--markdown writes the table and the exponents (docs/bench/scale.md is made so).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")
CYCLES_SAMPLES = 16


def _openvdb():
    import bpy

    bpy.utils.expose_bundled_modules()
    import openvdb
    return openvdb


def resample(src, dst, factor, grid_name=None):
    """Write ``src``'s first float grid upsampled by ``factor`` (trilinear, voxel size / factor) to
    ``dst``; values at the background stay inactive. Returns the active voxel count."""
    ov = _openvdb()
    grids = ov.readAll(src)[0]
    g = next(x for x in grids if (grid_name is None or x.name == grid_name)
             and isinstance(x, ov.FloatGrid))
    lo, hi = (np.array(c) for c in g.evalActiveVoxelBoundingBox())
    dims = hi - lo + 2  # one voxel beyond for the interpolation's upper neighbour
    dense = np.full(tuple(dims), g.background, np.float32)
    g.copyToArray(dense, ijk=tuple(int(c) for c in lo))
    out = ov.FloatGrid()
    out.background = g.background
    out.name = g.name
    out.gridClass = g.gridClass
    out.transform = ov.createLinearTransform(voxelSize=float(g.transform.voxelSize()[0]) / factor)
    f = int(factor)
    u = np.arange(f) / f  # the output voxels' fractions between two source voxels
    n = dims - 1
    for x0 in range(0, n[0]):  # one source slab at a time: x0 .. x0 + 1
        a, b = dense[x0], dense[x0 + 1]
        slab = a[None] * (1 - u)[:, None, None] + b[None] * u[:, None, None]  # (f, ny+1, nz+1)
        for ax in (1, 2):
            s0 = np.take(slab, np.arange(n[ax]), axis=ax)
            s1 = np.take(slab, np.arange(1, n[ax] + 1), axis=ax)
            slab = _lerp(s0, s1, u, ax)
        out.copyFromArray(np.ascontiguousarray(slab, np.float32),
                          ijk=(int(lo[0] + x0) * f, int(lo[1]) * f, int(lo[2]) * f),
                          tolerance=0.0)
    ov.write(dst, grids=[out])
    return int(out.activeVoxelCount())


def _lerp(s0, s1, u, ax):
    """Between neighbours s0, s1 along axis ax: u.size samples each (the axis grows that much)."""
    a, b = np.expand_dims(s0, ax + 1), np.expand_dims(s1, ax + 1)
    w = np.expand_dims(u, [k for k in range(4) if k != ax + 1])
    shape = list(s0.shape)
    shape[ax] *= u.size
    return (a * (1 - w) + b * w).reshape(shape)


# -- one measurement per process ----------------------------------------------------------------
def step(kind, path, lod=None, mode=None, size=256, error=True):
    """Run one measurement here; returns its figures with this process's peak memory."""
    from kernels import pipeline
    from kernels.vdb import read_topology, read_vdb

    out = {"step": kind, "lod": lod, "mode": mode, "error": error if kind == "convert" else None}
    # an import reads the file itself: only the topology here, so the peak is the import's
    reader = read_topology if kind == "import" else read_vdb
    for _ in range(2 if kind == "read" else 1):  # a read: the second, with the kernels loaded
        # and without the first's values held (they doubled the peak, and on a VM host the
        # second read then paid first-touch costs on fresh memory: 2.2-2.6 s instead of 1.0 s at x5)
        grid = None
        t = time.perf_counter()
        grid = next(g for g in reader(path).grids if g.active_voxels)
        out["seconds_read"] = time.perf_counter() - t
    out["active_voxels"] = int(grid.active_voxels)
    if kind == "convert":
        pipeline._warm_up(grid, [lod], "field", True, error)  # kernels loaded apart
        t = time.perf_counter()
        cl = pipeline.convert_lod(grid, lod, compute_error=error)
        out["seconds"] = time.perf_counter() - t
        out["gaussians"] = int(cl.gset.count)
    elif kind == "render":
        from metrics import covered_pixels

        from kernels.lod.splat import STEP as SPLAT_STEP
        from kernels.render import CPUDevice, RenderObject, RenderScene

        gs = pipeline.convert_lod(grid, lod, compute_error=False).gset if mode != "reference" else None
        obj = RenderObject(gs, np.asarray(grid.index_to_world, np.float64),
                           grid=grid if mode == "reference" else None)
        view = _view(grid, size)
        from bench_report import warm_render

        dev = CPUDevice()
        warm_render(dev, None, [mode])  # this mode's kernels loaded apart (splat: its lattice's too)
        sc = RenderScene([obj], mode=mode, **({"step": SPLAT_STEP} if mode == "splat" else {}))
        t = time.perf_counter()
        dev.render(sc, view["cam"], view["tf"])
        out["seconds"] = time.perf_counter() - t  # the first frame: sync, set-up, drawing
        out["seconds_sync"] = dev.stats["seconds_sync"]
        t = time.perf_counter()
        img = dev.render(sc, view["cam"], view["tf"])["Combined"]
        out["seconds_frame"] = time.perf_counter() - t  # a frame after it (camera moves: this)
        # its work per covered pixel: Gaussian segments (particles), or voxel samples (reference)
        out["segments_per_pixel"] = dev.stats["segments"] / max(covered_pixels(img), 1)
        out["gaussians"] = int(gs.count) if gs is not None else 0
    elif kind == "import":  # the add-on's import in Blender, as the dialog runs it
        sys.path.insert(0, os.path.join(ROOT, "tools"))
        from blender_session import start

        bpy = start()
        from bl_ext.user_default.gaussvdb.gaussvdb_addon.io import importer

        for o in importer.import_files(bpy.context, [SAMPLE], lods=(lod,), sequence=False)[0]:
            bpy.data.objects.remove(o)  # kernels (conversion, objects) loaded apart, as for convert
        t = time.perf_counter()
        objs, msg = importer.import_files(bpy.context, [path], lods=(lod,), sequence=False)
        out["seconds"] = time.perf_counter() - t
        out["gaussians"] = sum(len(o.data.points) for o in objs)
        out["status"] = msg
    elif kind == "cycles":  # Blender's Volume object + Cycles, same camera and transfer function
        from report_external import run_cycles

        work = tempfile.mkdtemp(prefix="gaussvdb_scale_cycles_")
        try:
            info, _ = run_cycles(path, grid.name, _view(grid, size), argparse.Namespace(
                width=size, height=size, samples=[CYCLES_SAMPLES], cycles_biased=False, threads=0),
                work)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        out["seconds"] = info["rows"][0]["seconds_render"]  # the frame, the scene synced before
        out["seconds_sync"] = info["seconds_warmup"]
        out["samples"] = CYCLES_SAMPLES
        out["peak_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        return out
    else:
        out["seconds"] = out["seconds_read"]
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def _view(grid, size):
    """bench_report's camera and transfer function for this grid at size x size (optical depth 10
    across the box's diagonal), so our frames and Cycles' see the same thing."""
    from bench_report import setup_view

    return setup_view(grid, argparse.Namespace(width=size, height=size, density=10.0))


def measure(kind, path, **kw):
    cmd = [sys.executable, os.path.abspath(__file__), "--step", json.dumps(dict(kind=kind, path=path, **kw))]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode:
        return {"step": kind, **kw, "failed": (p.stderr.strip().splitlines() or ["?"])[-1]}
    return json.loads(p.stdout.strip().splitlines()[-1])


def exponent(rows):
    """Slope of log seconds over log active voxels (None with fewer than two sizes)."""
    pts = [(r["active_voxels"], r["seconds"]) for r in rows if "seconds" in r and r["seconds"] > 0]
    if len({v for v, _ in pts}) < 2:
        return None
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", default=None, help="a .vdb fog volume (default: the bundled sample)")
    ap.add_argument("--factors", default="1,2,3")
    ap.add_argument("--lods", default="low,medium")
    ap.add_argument("--modes", default="particles,reference")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--quick", action="store_true", help="the 3x file only")
    ap.add_argument("--no-cycles", action="store_true", help="leave out Cycles (16 samples)")
    ap.add_argument("--no-import", action="store_true", help="leave out the import into Blender")
    ap.add_argument("--markdown", help="write the table and exponents to this Markdown file")
    ap.add_argument("--keep", metavar="DIR", help="make the series in DIR and keep it (files already "
                    "there are reused) instead of a temporary folder")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--step", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.step:
        print(json.dumps(step(**json.loads(a.step))))
        return 0
    src = a.source or SAMPLE
    factors = [3] if a.quick else [int(f) for f in a.factors.split(",")]
    lods = a.lods.split(",")
    modes = a.modes.split(",")
    tmp = a.keep or tempfile.mkdtemp(prefix="gaussvdb_scale_")
    os.makedirs(tmp, exist_ok=True)
    rows = []
    load = [os.getloadavg()[0]]
    try:
        for f in factors:
            path = os.path.join(tmp, f"x{f}.vdb")
            t = time.perf_counter()
            if a.keep and os.path.exists(path):
                pass
            elif f == 1:
                shutil.copy(src, path)
            else:
                resample(src, path, f)
            print(f"x{f}: made in {time.perf_counter() - t:.1f} s, {os.path.getsize(path) / 1e6:.1f} MB",
                  file=sys.stderr)
            todo = [("read", {})]
            todo += [("convert", dict(lod=lod, error=e)) for lod in lods for e in (False, True)]
            todo += [] if a.no_import else [("import", dict(lod=lod)) for lod in lods]
            todo += [("render", dict(lod=lod, mode=mode, size=a.size)) for mode in modes
                     for lod in (lods if mode != "reference" else [None])]
            todo += [] if a.no_cycles else [("cycles", dict(size=a.size))]
            for kind, kw in todo:
                r = measure(kind, path, **kw)
                r["factor"] = f
                rows.append(r)
                print(json.dumps(r) if a.json else
                      f"x{f} {kind:8} {str(kw.get('lod') or ''):7} {str(kw.get('mode') or ''):10} "
                      f"{'err' if kw.get('error') else '   '} "
                      + (f"FAILED: {r['failed']}" if "failed" in r else
                         f"{r['active_voxels'] / 1e6:8.2f} Mvox {r['seconds']:8.2f} s {r['peak_mb']:8.0f} MB"),
                      flush=True)
    finally:
        if not a.keep:
            shutil.rmtree(tmp, ignore_errors=True)
    load.append(os.getloadavg()[0])
    exps = exponents(rows)
    for name, e in exps:
        print(f"exponent {name}: {e:.2f}")
    if a.markdown:
        with open(a.markdown, "w") as fh:
            fh.write(markdown(rows, exps, src, a, load))
    return 0


def _label(r):
    return " ".join(x for x in (r["step"], r.get("lod") or "", r.get("mode") or "",
                                "+ error" if r.get("error") else "") if x)


def exponents(rows):
    """[(step label, exponent)] for every step measured at two sizes or more."""
    out = []
    for lab in dict.fromkeys(_label(r) for r in rows):
        e = exponent([r for r in rows if _label(r) == lab])
        if e is not None:
            out.append((lab, e))
    return out


def markdown(rows, exps, src, a, load):
    """The series as a Markdown page: one row per step and size, then the exponents."""
    cmd = "python benchmarks/bench_scale.py " + " ".join(
        x for x in (f"--source {os.path.basename(src)}" if a.source else "", f"--factors {a.factors}"
                    if not a.quick else "--quick", f"--lods {a.lods}", f"--modes {a.modes}",
                    f"--size {a.size}", "--no-cycles" if a.no_cycles else "",
                    "--no-import" if a.no_import else "") if x)
    out = [f"# Scaling: {os.path.basename(src)} resampled\n",
           f"`{cmd}`, {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, load average "
           f"{load[0]:.1f} at the start and {load[-1]:.1f} at the end. Each step runs in a process of "
           "its own; peak = that process's resident high-water mark (Cycles: its render process). "
           "render: s = the first frame (sync, set-up, drawing), frame = the next one; cycles: s = "
           "a frame at 16 samples after a warm-up frame that synced the scene (sync).\n",
           "segments / px: a render's work per covered pixel (particles: Gaussian segments, a "
           "Gaussian's exact integral over one stretch of a ray; reference: voxel samples).\n",
           "| size | M voxels | step | s | frame s | sync s | peak MB | Gaussians | segments / px |",
           "|---|---:|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        if "failed" in r:
            out.append(f"| x{r['factor']} | | {_label(r)} | failed: {r['failed']} | | | | | |")
            continue
        f = (lambda k, fmt="{:.2f}": fmt.format(r[k]) if r.get(k) is not None else "")  # noqa: E731
        out.append(f"| x{r['factor']} | {r['active_voxels'] / 1e6:.1f} | {_label(r)} | {f('seconds')} | "
                   f"{f('seconds_frame')} | {f('seconds_sync')} | {f('peak_mb', '{:,.0f}')} | "
                   f"{f('gaussians', '{:,}')} | {f('segments_per_pixel', '{:,.0f}')} |")
    out += ["", "Scaling exponent (slope of log seconds over log active voxels):", "",
            "| step | exponent |", "|---|---:|"]
    out += [f"| {n} | {e:.2f} |" for n, e in exps]
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    sys.exit(main())
