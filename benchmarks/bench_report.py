"""Error-vs-run-time benchmark and report (issue 7).

    ./gaussvdb bench [--data DIR] [--size WxH] [--out DIR] [--quick]
    ./gaussvdb bench --out docs/bench          # the README's "Choosing a LOD" figures

For every .vdb in DIR (default ../shared/data beside the repository), every scalar grid (float,
double, half; vector grids, empty grids and constant grids are listed as skipped), every LOD preset
and every render mode:
- conversion: Gaussians, compact bytes, bytes/Gaussian, the paper's storage model, read and convert
  seconds, field RMSE/NRMSE/max (level sets: of the occupancy, plus the surface IoU);
- rendering with the kernels directly (no Blender): seconds, and PSNR/SSIM/max abs error against our
  `reference` render of the voxels at a fine step (1/8 voxel);
- splat mode at one sample a lattice cell (kernels.lod.splat.STEP: its lattice follows the Gaussians' scale);
- our `reference` mode itself at steps 2, 1, 0.5 and 0.25 voxel (a curve of time vs error);
- VTK's CPU volume renderer (vtkFixedPointVolumeRayCastMapper, the `vtk` module, off-screen, in a
  subprocess: benchmarks/vtk_ref.py) with our camera and transfer function at sample distances 1, 0.5
  and 0.25 voxel; skipped with a printed line where `import vtk` fails;
- Cycles (CPU, the bpy module, in a subprocess: benchmarks/cycles_ref.py) from the source .vdb with a
  matched emission-absorption material, at increasing sample counts: seconds and the same errors.
Camera (fixed per dataset and grid): `Camera.frame_box` of the grid's world box (its active index
bbox through index_to_world), looking along (0.35, 1, -0.3) (as `./gaussvdb render`), 50 mm lens on a
36 mm sensor, margin 1.05. Transfer function: viridis through the add-on's 32 ColorRamp stops
(`stops_from_table`, the exact stops Cycles gets), alpha ramp 0 -> 1 over the grid's active value range, density
10 / (world box diagonal) per world unit (about 10 optical depths across the box at alpha 1).
Level sets are rendered as occupancy (their reference is the reference mode's occupancy render);
Cycles and VTK are skipped for them (a level set's signed distance has no emission-absorption
meaning that their volume shaders could share with our occupancy model). The summary names, per
dataset, the configurations on the Pareto front of render time vs PSNR.

Writes to --out (default out/bench): results.json, report.md, error_vs_time.png and one contact
sheet per dataset (contact_<dataset>.png). --quick: one file (the bundled sample's name if present,
else the smallest), its first scalar grid, 128x128, LODs low and high, Cycles at 4 and 16 samples.
"""
from __future__ import annotations

import argparse
import atexit
import datetime
import json
import math
import os
import platform
import shutil
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for _p in (ROOT, HERE, os.path.join(ROOT, "tools")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import cli_errors  # noqa: E402  (after the sys.path set-up above)
from bench_lod import warm_up  # noqa: E402
from bench_render import world_box  # noqa: E402
from metrics import covered_pixels, image_errors, to_display  # noqa: E402
from report_external import VTKMissing, run_cycles, run_vtk  # noqa: E402
from report_figures import contact_sheet, figure_error_vs_time  # noqa: E402
from report_markdown import slug, write_report  # noqa: E402

VIEW = (0.35, 1.0, -0.3)
COLORMAP = "viridis"
REF_STEP = 0.125  # the error reference
REF_STEPS = (2.0, 1.0, 0.5, 0.25)  # our voxel renderer's curve
VTK_STEPS = (1.0, 0.5, 0.25)
SAMPLE_NAME = "mantaflow_smoke_r128_f040.vdb"
SCALAR_TYPES = ("float", "double", "half")


# -- progress ------------------------------------------------------------------------------------
class Progress:
    def __init__(self, total, stream=sys.stderr):
        self.total, self.done, self.t0, self.s = max(total, 1), 0, time.perf_counter(), stream
        self.tty = stream.isatty()

    def step(self, label, n=1):
        self.done = min(self.total, self.done + n)
        el = time.perf_counter() - self.t0
        eta = el / self.done * (self.total - self.done) if self.done else 0
        w = 30
        bar = "#" * int(w * self.done / self.total) + "." * (w - int(w * self.done / self.total))
        msg = (f"[{bar}] {self.done:3d}/{self.total} {el:6.0f} s (eta {eta:5.0f} s)  {label}")
        if self.tty:
            self.s.write("\r" + msg[:150].ljust(150))
            if self.done >= self.total:
                self.s.write("\n")
        else:
            self.s.write(msg + "\n")
        self.s.flush()

    def add(self, n):
        self.total += n


# -- set-up ----------------------------------------------------------------------------------------

def _shown_path(path):
    """A data folder as the report shows it: relative to the repository root, never a machine path."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    rel = os.path.relpath(os.path.abspath(path), root)
    return rel if not os.path.isabs(rel) else os.path.basename(os.path.abspath(path))

def parse(argv):
    from kernels.lod import PRESETS
    from kernels.render import MODES

    ap = cli_errors.ArgumentParser(prog="gaussvdb bench", description=__doc__.split("\n\n")[1],
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.path.join(os.path.dirname(ROOT), "shared", "data"))
    ap.add_argument("--size", default=None, type=cli_errors.size, help="WxH (default 512x512; --quick 128x128)")
    ap.add_argument("--out", default=None, help="output folder (default out/bench, --quick out/bench_quick)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--files", help="comma-separated substrings of file names")
    ap.add_argument("--grids", help="comma-separated grid names")
    ap.add_argument("--lods", default=None, type=cli_errors.names(PRESETS),
                    help=f"comma-separated presets (default {','.join(PRESETS)})")
    ap.add_argument("--modes", default=list(MODES), type=cli_errors.names(MODES))
    ap.add_argument("--samples", default=None, type=cli_errors.positive_ints,
                    help="Cycles sample counts (default 1,4,16,64,256; quick 4,16)")
    ap.add_argument("--no-cycles", action="store_true")
    ap.add_argument("--cycles-biased", action="store_true", help="Cycles' biased ray-marching volumes")
    ap.add_argument("--no-vtk", action="store_true", help="leave out VTK's volume renderer")
    ap.add_argument("--repeat", type=cli_errors.positive_int, default=3,
                    help="timed renders per voxel-renderer point (ours and VTK; the median is reported)")
    ap.add_argument("--density", type=cli_errors.nonnegative, default=10.0,
                    help="optical depth across the box diagonal")
    ap.add_argument("--threads", type=cli_errors.threads, default=0,
                    help="CPU threads for both renderers (0: all)")
    a = ap.parse_args(argv)
    a.width, a.height = a.size or ((128, 128) if a.quick else (512, 512))
    a.lods = a.lods or (["low", "high"] if a.quick else list(PRESETS))
    a.samples = a.samples or ([4, 16] if a.quick else [1, 4, 16, 64, 256])
    a.out = os.path.abspath(a.out or os.path.join(ROOT, "out", "bench_quick" if a.quick else "bench"))
    return a


def pick_files(a):
    paths = cli_errors.vdb_folder(a.data)
    if a.files:
        paths = [p for p in paths if any(f in os.path.basename(p) for f in a.files.split(","))]
    if a.quick and len(paths) > 1:
        named = [p for p in paths if os.path.basename(p) == SAMPLE_NAME]
        paths = named or [min(paths, key=os.path.getsize)]
    return paths


def plan(a, paths):
    """[(path, [grid names]), ...] and the skipped grids with reasons."""
    from kernels.lod import value_range
    from kernels.vdb import read_vdb

    todo, skipped = [], []
    for path in paths:
        names = []
        topo = read_vdb(path, topology_only=True).grids
        for g in topo:
            why = None
            if a.grids and g.name not in a.grids.split(","):
                continue
            if g.value_type not in SCALAR_TYPES:
                why = f"not a scalar grid ({g.value_type})"
            elif not g.active_voxels:
                why = "no active voxels"
            if why is None and g.grid_class != "level_set":
                full = read_vdb(path, grids=[g.name]).grids[0]
                lo, hi = value_range(full)
                if not hi > lo:
                    why = f"constant grid (every active value {lo:g}): nothing to see or compare"
            if why:
                skipped.append({"dataset": os.path.basename(path), "grid": g.name, "reason": why})
            else:
                names.append(g.name)
        if a.quick:
            names = names[:1]
        if names:
            todo.append((path, names))
    return todo, skipped


def setup_view(g, a):
    """World box, camera, transfer function for one grid (documented in the module docstring)."""
    from kernels.lod import value_range
    from kernels.render import Camera, TransferFunction
    from kernels.render.scene.colormaps import colormap, stops_from_table

    m = np.asarray(g.index_to_world, np.float64)
    lo, hi = world_box(g, m)
    cam = Camera.frame_box(lo, hi, a.width, a.height, direction=VIEW)
    diag = float(np.linalg.norm(hi - lo))
    vmin, vmax = (0.0, 1.0) if g.grid_class == "level_set" else value_range(g)
    pos, rgba = stops_from_table(colormap(COLORMAP))
    tf = TransferFunction.from_ramp(pos, rgba, vmin, vmax, density=a.density / max(diag, 1e-12))
    return {"m": m, "lo": lo, "hi": hi, "cam": cam, "tf": tf, "vmin": float(vmin), "vmax": float(vmax),
                "density": tf.density, "positions": pos, "colors": rgba, "diag": diag}


def render(dev, objs, mode, cam, tf, threads, step=None, repeat=1):
    """(image, seconds, seconds of the scene sync, work): one sync, then the median of `repeat`
    renders; work: the frame's segments (device stats: Gaussian segments, field terms or voxel
    samples), the pixels it covers and the threads it ran on."""
    from kernels.render import RenderScene

    kw = {} if step is None else {"step": step}
    sc = RenderScene(objs, mode=mode, threads=threads or None, passes=(), **kw)
    dev.sync(sc)
    sync = dev.stats.get("seconds_sync", 0.0)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = dev.render(sc, cam, tf)
        times.append(time.perf_counter() - t0)
    img = out["Combined"]
    work = dict(segments=float(dev.stats["segments"]), covered_pixels=covered_pixels(img),
                threads=int(dev.stats["threads"]))
    return img, float(np.median(times)), sync, work


def warm_render(dev, threads, modes):
    """Load/compile the render kernels on a tiny synthetic scene (not timed)."""
    from bench_render import synthetic

    from kernels.render import Camera, RenderObject, TransferFunction

    g, gs = synthetic()
    m = np.eye(4)
    lo, hi = world_box(g, m)
    cam = Camera.frame_box(lo, hi, 8, 8, direction=VIEW)
    tf = TransferFunction.from_colormap(COLORMAP, 0, 1, density=0.1)
    for mode in modes:
        render(dev, [RenderObject(gs, m, grid=g)], mode, cam, tf, threads)


# -- the run ---------------------------------------------------------------------------------------
VOXEL_ROW = dict(lod="voxels", gaussians=0, bytes=None, bytes_per_gaussian=None, paper_model_bytes=None,
                 seconds_convert=0.0, field_rmse=None, field_nrmse=None, field_max_abs=None, surface_iou=None,
                 samples=None, step=None)


class Grid:
    """One grid's run: its view, the fine-step reference image, its rows and contact-sheet cells."""

    def __init__(self, a, dev, path, name, rows, prog):
        from kernels.render import RenderObject
        from kernels.vdb import read_vdb

        self.a, self.dev, self.path, self.name, self.rows, self.prog = a, dev, path, name, rows, prog
        self.ds = os.path.basename(path)
        t0 = time.perf_counter()
        self.g = read_vdb(path, grids=[name]).grids[0]
        t_read = time.perf_counter() - t0
        self.is_ls = self.g.grid_class == "level_set"
        self.view = setup_view(self.g, a)
        self.voxel_objs = [RenderObject(None, self.view["m"], grid=self.g, is_level_set=self.is_ls)]
        # the error reference: voxels, trilinear, 1/8-voxel step
        self.ref, t_ref, _, _ = self.render(self.voxel_objs, "reference", step=REF_STEP)
        prog.step(f"{self.ds}/{name} reference (step {REF_STEP})")
        self.sheet = {"grid": name, "ref": to_display(self.ref), "cells": [], "cycles": [], "voxels": []}
        v = self.view
        self.common = dict(dataset=self.ds, grid=name, **{"class": self.g.grid_class},
                           active_voxels=int(self.g.active_voxels), width=a.width, height=a.height,
                           seconds_read=t_read, reference_seconds=t_ref, reference_step=REF_STEP,
                           tf_vmin=v["vmin"], tf_vmax=v["vmax"], tf_density=v["density"])

    def render(self, objs, mode, step=None, repeat=1):
        return render(self.dev, objs, mode, self.view["cam"], self.view["tf"], self.a.threads, step, repeat)

    def add(self, img, **row):
        err = image_errors(self.ref, img)
        self.rows.append(dict(self.common, **row, **err))
        return err

    def gaussian_modes(self, lod, gmodes):
        from kernels.lod import encode_compact, encoded_nbytes, paper_model_bytes
        from kernels.lod.splat import STEP as SPLAT_STEP
        from kernels.pipeline import convert_lod
        from kernels.render import RenderObject

        cl = convert_lod(self.g, lod)  # the import's conversion: timed, with its field error
        gs, t_conv, e = cl.gset, cl.seconds, cl.error
        nb = encoded_nbytes(encode_compact(gs))
        conv = {"lod": lod, "gaussians": int(gs.count), "bytes": int(nb), "bytes_per_gaussian": nb / max(gs.count, 1),
                "paper_model_bytes": int(paper_model_bytes(gs)), "seconds_convert": t_conv,
                "field_rmse": e["rmse"], "field_nrmse": e["nrmse"], "field_max_abs": e["max_abs"],
                "surface_iou": e.get("surface_iou"), "samples": None, "step": None}
        self.prog.step(f"{self.ds}/{self.name} {lod}: convert")
        objs = [RenderObject(gs, self.view["m"], grid=self.g, is_level_set=self.is_ls)]
        for mode in gmodes:
            step = SPLAT_STEP if mode == "splat" else None  # one sample a lattice cell
            img, t_r, t_s, work = self.render(objs, mode, step=step)
            err = self.add(img, **dict(conv, step=step), **work, mode=mode, renderer="gaussvdb",
                           seconds_render=t_r, seconds_sync=t_s)
            self.sheet["cells"].append((lod, mode, to_display(img), err["psnr"]))
            self.prog.step(f"{self.ds}/{self.name} {lod} {mode}: {t_r:.2f} s, PSNR {_f(err['psnr'])}")

    def reference_curve(self):
        """Our voxel renderer at each of REF_STEPS: no LOD involved."""
        for step in REF_STEPS:
            img, t_r, t_s, work = self.render(self.voxel_objs, "reference", step=step, repeat=self.a.repeat)
            err = self.add(img, **dict(VOXEL_ROW, step=step, field_rmse=0.0, field_nrmse=0.0, field_max_abs=0.0),
                           **work, mode="reference", renderer="gaussvdb", seconds_render=t_r, seconds_sync=t_s)
            self.sheet["voxels"].append((f"reference step {step:g}", to_display(img), err["psnr"]))
        self.prog.step(f"{self.ds}/{self.name} reference at steps {', '.join(f'{s:g}' for s in REF_STEPS)}")

    def cycles(self, work):
        """Cycles' rows; returns its run's facts, or None (skipped: the reason is in `skipped`)."""
        info, imgs = run_cycles(self.path, self.name, self.view, self.a, os.path.join(work, f"{self.ds}_{self.name}"))
        for row in info["rows"]:
            img = imgs[row["samples"]]
            err = self.add(img, **dict(VOXEL_ROW, samples=row["samples"]), mode="cycles", renderer="cycles",
                           seconds_render=row["seconds_render"], seconds_sync=info.get("seconds_warmup"),
                           volume_biased=info["volume_biased"])
            self.sheet["cycles"].append((row["samples"], to_display(img), err["psnr"]))
        self.prog.step(f"{self.ds}/{self.name} Cycles {self.a.samples}: " + ", ".join(
            f"{r['samples']} spp {r['seconds_render']:.2f} s" for r in info["rows"]))
        return {k: v for k, v in info.items() if k != "rows"}

    def vtk(self, work):
        info, imgs = run_vtk(self.g, self.view, self.a, os.path.join(work, f"vtk_{self.ds}_{self.name}"),
                             VTK_STEPS, self.a.repeat)
        for row in info["rows"]:
            img = imgs[row["step"]]
            err = self.add(img, **dict(VOXEL_ROW, step=row["step"]), mode="vtk", renderer="vtk",
                           seconds_render=row["seconds_render"], seconds_sync=row["seconds_warmup"])
            self.sheet["voxels"].append((f"VTK step {row['step']:g}", to_display(img), err["psnr"]))
        self.prog.step(f"{self.ds}/{self.name} VTK: " + ", ".join(
            f"step {r['step']:g} {r['seconds_render']:.2f} s" for r in info["rows"]))
        return {k: v for k, v in info.items() if k not in ("rows", "volume_shape", "seconds_subprocess")}


def run(a):
    import numba

    from kernels.render import CPUDevice

    paths = pick_files(a)
    if not paths:
        raise cli_errors.InputError(f"no .vdb file in {a.data} matches --files {a.files}")
    todo, skipped = plan(a, paths)
    gmodes = [m for m in a.modes if m != "reference"]
    n_grids = sum(len(n) for _, n in todo)
    prog = Progress(2 + n_grids * (1 + len(a.lods) * (1 + len(gmodes)) + ("reference" in a.modes)
                                   + (0 if a.no_cycles else 1) + (0 if a.no_vtk else 1)))
    t_start = time.perf_counter()
    warm_up()
    prog.step("warm-up: LOD kernels")
    dev = CPUDevice()
    warm_render(dev, a.threads, a.modes)
    prog.step("warm-up: render kernels")
    rows, sheets, cycles_meta, vtk_meta = [], {}, {}, {}
    vtk_missing = None
    work = tempfile.mkdtemp(prefix="gaussvdb-bench-")  # the peers' files: removed at exit
    atexit.register(shutil.rmtree, work, True)
    for path, names in todo:
        ds = os.path.basename(path)
        sheets[ds] = []
        for name in names:
            gr = Grid(a, dev, path, name, rows, prog)
            sheets[ds].append(gr.sheet)
            for lod in a.lods:
                gr.gaussian_modes(lod, gmodes)
            if "reference" in a.modes:
                gr.reference_curve()
            for what, off, call in (("Cycles", a.no_cycles, gr.cycles), ("VTK", a.no_vtk, gr.vtk)):
                if off:
                    continue
                if what == "VTK" and vtk_missing:
                    prog.step(f"{ds}/{name} VTK skipped")
                    continue
                if gr.is_ls:
                    skipped.append({"dataset": ds, "grid": name, "reason": f"{what}: level set (see report)"})
                    prog.step(f"{ds}/{name} {what} skipped (level set)")
                    continue
                try:
                    facts = call(work)
                except VTKMissing as err:
                    vtk_missing = str(err)
                    print(f"gaussvdb bench: VTK skipped: {vtk_missing}", file=sys.stderr)
                    skipped.append({"dataset": "all", "grid": "all", "reason": vtk_missing})
                    prog.step(f"{ds}/{name} VTK skipped")
                    continue
                except RuntimeError as err:
                    skipped.append({"dataset": ds, "grid": name, "reason": str(err)[:500]})
                    prog.step(f"{ds}/{name} {what} FAILED")
                    continue
                (cycles_meta if what == "Cycles" else vtk_meta).update(facts)
    meta = {"when": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "cpu_count": os.cpu_count(), "numba_threads": numba.config.NUMBA_NUM_THREADS,
            "threads": a.threads or None, "platform": platform.platform(), "python": platform.python_version(),
            "data": _shown_path(a.data), "size": [a.width, a.height], "lods": a.lods, "modes": a.modes,
            "cycles_samples": None if a.no_cycles else a.samples, "quick": a.quick, "view_direction": VIEW,
            "colormap": COLORMAP, "reference_step": REF_STEP, "reference_steps": list(REF_STEPS),
            "vtk_steps": None if a.no_vtk or vtk_missing else list(VTK_STEPS), "repeat": a.repeat,
            "density_optical_depth": a.density, "cycles": cycles_meta, "vtk": vtk_meta,
            "seconds_total": time.perf_counter() - t_start}
    return meta, rows, skipped, sheets


def _f(x, fmt="{:.1f}"):
    return "-" if x is None else fmt.format(x)


# -- outputs ---------------------------------------------------------------------------------------
def _clean(o):
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, np.generic):
        return _clean(o.item())
    return o


def main(argv=None) -> int:
    a = parse(argv if argv is not None else sys.argv[1:])
    cli_errors.vdb_folder(a.data)  # before any work: a missing or empty folder is refused here
    os.makedirs(a.out, exist_ok=True)
    meta, rows, skipped, sheets = run(a)
    meta["command"] = "./gaussvdb bench " + " ".join(argv if argv is not None else sys.argv[1:])
    files = ["results.json", "report.md", "error_vs_time.png"]
    for ds, sh in sheets.items():
        if sh:
            contact_sheet(ds, sh, os.path.join(a.out, f"contact_{slug(ds)}.png"), REF_STEP)
            files.append(f"contact_{slug(ds)}.png")
    figure_error_vs_time(rows, os.path.join(a.out, "error_vs_time.png"))
    with open(os.path.join(a.out, "results.json"), "w") as f:
        json.dump(_clean({"meta": meta, "rows": rows, "skipped": skipped}), f, indent=1, allow_nan=False)
    write_report(meta, rows, skipped, a.out, files)
    print(f"gaussvdb bench: {len(rows)} rows in {meta['seconds_total']:.0f} s -> {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(cli_errors.run("gaussvdb bench", main, sys.argv[1:]))
