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
- Cycles (CPU, the bpy module, in a subprocess: benchmarks/cycles_ref.py) from the source .vdb with a
  matched emission-absorption material, at increasing sample counts: seconds and the same errors.
Camera (fixed per dataset and grid): `Camera.frame_box` of the grid's world box (its active index
bbox through index_to_world), looking along (0.35, 1, -0.3) (as `./gaussvdb render`), 50 mm lens on a
36 mm sensor, margin 1.05. Transfer function: viridis through the add-on's 32 ColorRamp stops
(`stops_from_table`, the exact stops Cycles gets), alpha ramp 0 -> 1 over the grid's active value range, density
10 / (world box diagonal) per world unit (about 10 optical depths across the box at alpha 1).
Level sets are rendered as occupancy (their reference is the reference mode's occupancy render);
Cycles is skipped for them (a level set's signed distance has no emission-absorption meaning that
Cycles' volume shader could share with our occupancy model).

Writes to --out (default out/bench): results.json, report.md, error_vs_time.png and one contact
sheet per dataset (contact_<dataset>.png). --quick: one file (the bundled sample's name if present,
else the smallest), its first scalar grid, 128x128, LODs low and high, Cycles at 4 and 16 samples.
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import subprocess
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
from metrics import image_errors, time_to_reach, to_display  # noqa: E402

VIEW = (0.35, 1.0, -0.3)
COLORMAP = "viridis"
REF_STEP = 0.125
SAMPLE_NAME = "mantaflow_smoke_r128_f040.vdb"
SCALAR_TYPES = ("float", "double", "half")
MODE_COLORS = {"particles": "tab:blue", "field": "tab:green", "paper": "tab:red", "reference": "tab:gray"}
LOD_MARKERS = {"low": "v", "medium": "s", "high": "^", "variance": "D", "merged": "P", "voxels": "o"}


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
    from kernels.render.colormaps import colormap, stops_from_table

    m = np.asarray(g.index_to_world, np.float64)
    lo, hi = world_box(g, m)
    cam = Camera.frame_box(lo, hi, a.width, a.height, direction=VIEW)
    diag = float(np.linalg.norm(hi - lo))
    vmin, vmax = (0.0, 1.0) if g.grid_class == "level_set" else value_range(g)
    pos, rgba = stops_from_table(colormap(COLORMAP))
    tf = TransferFunction.from_ramp(pos, rgba, vmin, vmax, density=a.density / max(diag, 1e-12))
    return {"m": m, "lo": lo, "hi": hi, "cam": cam, "tf": tf, "vmin": float(vmin), "vmax": float(vmax),
                "density": tf.density, "positions": pos, "colors": rgba, "diag": diag}


def render(dev, objs, mode, cam, tf, threads, step=None):
    from kernels.render import RenderScene

    kw = {} if step is None else {"step": step}
    sc = RenderScene(objs, mode=mode, threads=threads or None, passes=(), **kw)
    dev.sync(sc)
    sync = dev.stats.get("seconds_sync", 0.0)
    t0 = time.perf_counter()
    out = dev.render(sc, cam, tf)
    return out["Combined"], time.perf_counter() - t0, sync


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


def run_cycles(path, grid, view, a, workdir):
    d = float(np.linalg.norm(view["cam"].cam_to_world[:3, 3] - 0.5 * (view["lo"] + view["hi"])))
    job = {"vdb": os.path.abspath(path), "grid": grid, "width": a.width, "height": a.height,
               "cam_to_world": view["cam"].cam_to_world.tolist(), "fov_x": view["cam"].fov_x,
               "clip": [max(1e-6, d * 1e-3), d * 10.0], "vmin": view["vmin"], "vmax": view["vmax"],
               "density": view["density"], "positions": np.asarray(view["positions"]).tolist(),
               "colors": np.asarray(view["colors"]).tolist(), "samples": a.samples, "out_dir": workdir,
               "volume_biased": a.cycles_biased, "threads": a.threads}
    jp = os.path.join(workdir, "job.json")
    os.makedirs(workdir, exist_ok=True)
    with open(jp, "w") as f:
        json.dump(job, f)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, os.path.join(HERE, "cycles_ref.py"), jp], capture_output=True, check=False,
                       text=True, cwd=ROOT)
    total = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"Cycles failed ({r.returncode}): {r.stderr[-1500:]}")
    with open(os.path.join(workdir, "cycles.json")) as f:
        info = json.load(f)
    imgs = {row["samples"]: np.load(os.path.join(workdir, f"cycles_{row['samples']}.npy"))
            for row in info["rows"]}
    info["seconds_subprocess"] = total
    return info, imgs


# -- the run ---------------------------------------------------------------------------------------
def run(a):
    import numba

    from kernels.lod import (
        build_lod,
        encode_compact,
        encoded_nbytes,
        field_error,
        paper_model_bytes,
    )
    from kernels.render import CPUDevice, RenderObject
    from kernels.vdb import read_vdb

    paths = pick_files(a)
    if not paths:
        raise cli_errors.InputError(f"no .vdb file in {a.data} matches --files {a.files}")
    todo, skipped = plan(a, paths)
    gmodes = [m for m in a.modes if m != "reference"]
    n_grids = sum(len(n) for _, n in todo)
    prog = Progress(2 + n_grids * (1 + len(a.lods) * (1 + len(gmodes)) + ("reference" in a.modes)
                                   + (0 if a.no_cycles else 1)))
    t_start = time.perf_counter()
    warm_up()
    prog.step("warm-up: LOD kernels")
    dev = CPUDevice()
    warm_render(dev, a.threads, a.modes)
    prog.step("warm-up: render kernels")
    rows, sheets, cycles_meta = [], {}, {}
    work = tempfile.mkdtemp(prefix="gaussvdb-bench-")
    for path, names in todo:
        ds = os.path.basename(path)
        sheets[ds] = []
        for name in names:
            t0 = time.perf_counter()
            g = read_vdb(path, grids=[name]).grids[0]
            t_read = time.perf_counter() - t0
            is_ls = g.grid_class == "level_set"
            view = setup_view(g, a)
            cam, tf = view["cam"], view["tf"]
            base = dict(dataset=ds, grid=name, **{"class": g.grid_class}, active_voxels=int(g.active_voxels),
                        width=a.width, height=a.height)
            # the reference: voxels, trilinear, 1/8-voxel step
            ref_gs = build_lod(g, a.lods[0])
            ref, t_ref, _ = render(dev, [RenderObject(ref_gs, view["m"], grid=g, is_level_set=is_ls)],
                                   "reference", cam, tf, a.threads, step=REF_STEP)
            prog.step(f"{ds}/{name} reference (step {REF_STEP})")
            sheet = {"grid": name, "ref": to_display(ref), "cells": [], "cycles": []}
            sheets[ds].append(sheet)
            common = dict(base, seconds_read=t_read, reference_seconds=t_ref, reference_step=REF_STEP,
                          tf_vmin=view["vmin"], tf_vmax=view["vmax"], tf_density=view["density"])
            for lod in a.lods:
                t0 = time.perf_counter()
                gs = build_lod(g, lod)
                t_conv = time.perf_counter() - t0
                nb = encoded_nbytes(encode_compact(gs))
                e = field_error(g, gs)
                conv = {"lod": lod, "gaussians": int(gs.count), "bytes": int(nb),
                            "bytes_per_gaussian": nb / max(gs.count, 1),
                            "paper_model_bytes": int(paper_model_bytes(gs)),
                            "seconds_convert": t_conv, "field_rmse": e["rmse"], "field_nrmse": e["nrmse"],
                            "field_max_abs": e["max_abs"], "surface_iou": e.get("surface_iou")}
                prog.step(f"{ds}/{name} {lod}: convert")
                objs = [RenderObject(gs, view["m"], grid=g, is_level_set=is_ls)]
                for mode in gmodes:
                    img, t_r, t_s = render(dev, objs, mode, cam, tf, a.threads)
                    err = image_errors(ref, img)
                    rows.append(dict(common, **conv, mode=mode, renderer="gaussvdb", samples=None,
                                     seconds_render=t_r, seconds_sync=t_s, **err))
                    sheet["cells"].append((lod, mode, to_display(img), err["psnr"]))
                    prog.step(f"{ds}/{name} {lod} {mode}: {t_r:.2f} s, PSNR {_f(err['psnr'])}")
            if "reference" in a.modes:  # the voxel renderer at its default step: no LOD involved
                img, t_r, t_s = render(dev, [RenderObject(ref_gs, view["m"], grid=g, is_level_set=is_ls)],
                                       "reference", cam, tf, a.threads)
                err = image_errors(ref, img)
                rows.append(dict(common, lod="voxels", gaussians=0, bytes=None, bytes_per_gaussian=None,
                                 paper_model_bytes=None, seconds_convert=0.0, field_rmse=0.0, field_nrmse=0.0,
                                 field_max_abs=0.0, surface_iou=None, mode="reference", renderer="gaussvdb",
                                 samples=None, seconds_render=t_r, seconds_sync=t_s, **err))
                sheet["cells"].append(("voxels", "reference", to_display(img), err["psnr"]))
                prog.step(f"{ds}/{name} reference (step 0.5)")
            if a.no_cycles:
                continue
            if is_ls:
                skipped.append({"dataset": ds, "grid": name, "reason": "Cycles: level set (see report)"})
                prog.step(f"{ds}/{name} Cycles skipped (level set)")
                continue
            try:
                info, imgs = run_cycles(path, name, view, a, os.path.join(work, f"{ds}_{name}"))
            except RuntimeError as err:
                skipped.append({"dataset": ds, "grid": name, "reason": str(err)[:500]})
                prog.step(f"{ds}/{name} Cycles FAILED")
                continue
            cycles_meta = {k: v for k, v in info.items() if k != "rows"}
            for row in info["rows"]:
                img = imgs[row["samples"]]
                err = image_errors(ref, img)
                rows.append(dict(common, lod="voxels", gaussians=0, bytes=None, bytes_per_gaussian=None,
                                 paper_model_bytes=None, seconds_convert=0.0, field_rmse=None,
                                 field_nrmse=None, field_max_abs=None, surface_iou=None, mode="cycles",
                                 renderer="cycles", samples=row["samples"], seconds_render=row["seconds_render"],
                                 seconds_sync=info.get("seconds_warmup"), volume_biased=info["volume_biased"],
                                 **err))
                sheet["cycles"].append((row["samples"], to_display(img), err["psnr"]))
            prog.step(f"{ds}/{name} Cycles {a.samples}: " + ", ".join(
                f"{r['samples']} spp {r['seconds_render']:.2f} s" for r in info["rows"]))
    meta = {"when": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
                "cpu_count": os.cpu_count(), "numba_threads": numba.config.NUMBA_NUM_THREADS,
                "threads": a.threads or None, "platform": platform.platform(), "python": platform.python_version(),
                "data": _shown_path(a.data), "size": [a.width, a.height], "lods": a.lods, "modes": a.modes,
                "cycles_samples": None if a.no_cycles else a.samples, "quick": a.quick, "view_direction": VIEW,
                "colormap": COLORMAP, "reference_step": REF_STEP, "density_optical_depth": a.density,
                "cycles": cycles_meta, "seconds_total": time.perf_counter() - t_start}
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


def figure_error_vs_time(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = []
    for r in rows:
        k = (r["dataset"], r["grid"])
        if k not in keys:
            keys.append(k)
    n = len(keys)
    cols = min(3, n)
    nr = math.ceil(n / cols)
    fig, axes = plt.subplots(nr, cols, figsize=(5.2 * cols, 4.2 * nr), squeeze=False)
    for ax, k in zip(axes.flat, keys):
        sub = [r for r in rows if (r["dataset"], r["grid"]) == k and r["psnr"] is not None]
        for r in sub:
            if r["renderer"] != "gaussvdb":
                continue
            ax.scatter(r["seconds_render"], r["psnr"], c=MODE_COLORS.get(r["mode"], "k"),
                       marker=LOD_MARKERS.get(r["lod"], "o"), s=45, edgecolors="k", linewidths=0.4)
        cyc = sorted((r for r in sub if r["renderer"] == "cycles"), key=lambda r: r["samples"])
        if cyc:
            ax.plot([r["seconds_render"] for r in cyc], [r["psnr"] for r in cyc], "-o", c="tab:orange",
                    ms=3, label="Cycles")
            for r in cyc:
                ax.annotate(f"{r['samples']}", (r["seconds_render"], r["psnr"]), fontsize=7,
                            xytext=(3, -8), textcoords="offset points", color="tab:orange")
        ax.set_xscale("log")
        ax.set_xlabel("render time [s] (log)")
        ax.set_ylabel("PSNR vs reference [dB]")
        ax.set_title(f"{k[0]} / {k[1]}", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    from matplotlib.lines import Line2D
    modes = sorted({r["mode"] for r in rows if r["renderer"] == "gaussvdb"}, key=list(MODE_COLORS).index)
    lods = [lod for lod in LOD_MARKERS if any(r["lod"] == lod and r["renderer"] == "gaussvdb" for r in rows)]
    handles = [Line2D([], [], ls="", marker="o", c=MODE_COLORS[m], label=m) for m in modes]
    handles += [Line2D([], [], ls="", marker=LOD_MARKERS[lod], c="w", mec="k", label=lod) for lod in lods]
    if any(r["renderer"] == "cycles" for r in rows):
        handles.append(Line2D([], [], c="tab:orange", marker="o", ms=3, label="Cycles (labels: samples)"))
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 10), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def contact_sheet(ds, sheets, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = []  # rows of (image, title)
    for s in sheets:
        panels.append([(s["ref"], f"{s['grid']}: reference (step {REF_STEP})")]
                      + [(im, f"Cycles {n} spp, {_f(p)} dB") for n, im, p in s["cycles"]])
        lods = []
        for lod, _, _, _ in s["cells"]:
            if lod not in lods:
                lods.append(lod)
        for lod in lods:
            panels.append([(im, f"{s['grid']} {lod} {mode}, {_f(p)} dB")
                           for l2, mode, im, p in s["cells"] if l2 == lod])
    cols = max(len(r) for r in panels)
    fig, axes = plt.subplots(len(panels), cols, figsize=(2.3 * cols, 2.45 * len(panels)), squeeze=False)
    for i, row in enumerate(panels):
        for j in range(cols):
            ax = axes[i, j]
            ax.axis("off")
            if j < len(row):
                ax.imshow(row[j][0], interpolation="nearest")
                ax.set_title(row[j][1], fontsize=6.5)
    fig.suptitle(f"{ds}: linear renders shown in sRGB over black", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_report(meta, rows, skipped, out, files):
    L = []
    L.append("# GaussVDB error vs run time\n")
    L.append(f"Run {meta['when']} on {meta['cpu_count']} cores ({meta['platform']}), images "
             f"{meta['size'][0]}x{meta['size'][1]}, data `{meta['data']}`"
             f"{' (--quick)' if meta['quick'] else ''}; total {meta['seconds_total']:.0f} s. Errors are "
             f"against our `reference` render of the voxels (trilinear, step {REF_STEP} voxel), in linear "
             "premultiplied RGB with data range 1. Times are single renders after a warm-up, on a shared "
             "machine (noise +-30%).\n")
    L.append("![error vs time](error_vs_time.png)\n")
    conv = {}
    for r in rows:
        if r["renderer"] == "gaussvdb" and r["lod"] != "voxels":
            conv.setdefault((r["dataset"], r["grid"], r["lod"]), r)
    modes = [m for m in meta["modes"] if m != "reference"]
    L.append("## Table 1 (the paper's layout, extended)\n")
    hdr = ("| file | grid | class | LOD | Gaussians | size (KB) | B/Gaussian | paper-model KB | s read "
           "| s convert | field NRMSE | field max | " + " | ".join(f"{m} s / PSNR / SSIM" for m in modes) + " |")
    L.append(hdr)
    L.append("|" + "---|" * 4 + "---:|" * (8 + len(modes)))
    for (ds, g, lod), c in conv.items():
        cells = []
        for m in modes:
            r = next((x for x in rows if x["dataset"] == ds and x["grid"] == g and x["lod"] == lod
                      and x["mode"] == m), None)
            cells.append("" if r is None else f"{r['seconds_render']:.2f} / {_f(r['psnr'])} / {r['ssim']:.3f}")
        iou = "" if c.get("surface_iou") is None else f" (IoU {c['surface_iou']:.3f})"
        L.append(f"| {ds} | {g} | {c['class']} | {lod} | {c['gaussians']:,} | {c['bytes'] / 1024:.1f} "
                 f"| {c['bytes_per_gaussian']:.2f} | {c['paper_model_bytes'] / 1024:.1f} | {c['seconds_read']:.3f} "
                 f"| {c['seconds_convert']:.3f} | {c['field_nrmse']:.4f}{iou} | {c['field_max_abs']:.3g} | "
                 + " | ".join(cells) + " |")
    L.append("")
    L.append("## Error vs time per dataset\n")
    keys = []
    for r in rows:
        if (r["dataset"], r["grid"]) not in keys:
            keys.append((r["dataset"], r["grid"]))
    for ds, g in keys:
        sub = [r for r in rows if r["dataset"] == ds and r["grid"] == g]
        L.append(f"### {ds} / {g} ({sub[0]['class']})\n")
        L.append("| renderer | mode | LOD | samples | s render | PSNR dB | SSIM | max abs |")
        L.append("|---|---|---|---:|---:|---:|---:|---:|")
        for r in sorted(sub, key=lambda r: (r["renderer"] != "gaussvdb", r["seconds_render"])):
            L.append(f"| {r['renderer']} | {r['mode']} | {r['lod']} | {r['samples'] or ''} "
                     f"| {r['seconds_render']:.3f} | {_f(r['psnr'], '{:.2f}')} | {r['ssim']:.4f} "
                     f"| {r['max_abs_error']:.4f} |")
        cyc = sorted((r for r in sub if r["renderer"] == "cycles"), key=lambda r: r["samples"])
        pm = next((r for r in sub if r["mode"] == "particles" and r["lod"] == "medium"), None)
        if cyc:
            top = cyc[-1]
            L.append(f"\nCycles residual at {top['samples']} samples: PSNR {_f(top['psnr'], '{:.2f}')} dB, "
                     f"max abs {top['max_abs_error']:.4f}.")
        if cyc and pm:
            tc, how = time_to_reach([(r["seconds_render"], r["psnr"]) for r in cyc], pm["psnr"])
            if tc is None:
                L.append(f"Particles/Medium: {_f(pm['psnr'])} dB in {pm['seconds_render']:.2f} s; Cycles does not "
                         f"reach it within {cyc[-1]['samples']} samples.")
            else:
                bound = " (Cycles' fewest samples already beat it: an upper bound)" if how == "below_first" else ""
                L.append(f"Particles/Medium: {_f(pm['psnr'])} dB in {pm['seconds_render']:.2f} s; Cycles needs "
                         f"{tc:.2f} s for that PSNR{bound}: speed-up x{tc / pm['seconds_render']:.2f}.")
        L.append(f"\n![contact sheet](contact_{_slug(ds)}.png)\n")
    L.append("## Figures to reach\n")
    for lod, goal in (("high", 40.0), ("medium", 32.0)):
        got = [r for r in rows if r["mode"] == "field" and r["lod"] == lod and r["psnr"] is not None]
        for r in got:
            ok = "met" if r["psnr"] >= goal else "NOT met"
            L.append(f"- field/{lod} >= {goal:.0f} dB: {r['dataset']}/{r['grid']} {r['psnr']:.2f} dB ({ok})")
    if skipped:
        L.append("\n## Skipped\n")
        for s in skipped:
            L.append(f"- {s['dataset']} / {s['grid']}: {s['reason']}")
    L.append("\nFiles: " + ", ".join(f"`{f}`" for f in files) + "\n")
    with open(os.path.join(out, "report.md"), "w") as f:
        f.write("\n".join(L))


def _slug(ds):
    return os.path.splitext(ds)[0]


def main(argv=None) -> int:
    a = parse(argv if argv is not None else sys.argv[1:])
    cli_errors.vdb_folder(a.data)  # before any work: a missing or empty folder is refused here
    os.makedirs(a.out, exist_ok=True)
    meta, rows, skipped, sheets = run(a)
    meta["command"] = "./gaussvdb bench " + " ".join(argv if argv is not None else sys.argv[1:])
    files = ["results.json", "report.md", "error_vs_time.png"]
    for ds, sh in sheets.items():
        if sh:
            contact_sheet(ds, sh, os.path.join(a.out, f"contact_{_slug(ds)}.png"))
            files.append(f"contact_{_slug(ds)}.png")
    figure_error_vs_time(rows, os.path.join(a.out, "error_vs_time.png"))
    with open(os.path.join(a.out, "results.json"), "w") as f:
        json.dump(_clean({"meta": meta, "rows": rows, "skipped": skipped}), f, indent=1, allow_nan=False)
    write_report(meta, rows, skipped, a.out, files)
    print(f"gaussvdb bench: {len(rows)} rows in {meta['seconds_total']:.0f} s -> {a.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(cli_errors.run("gaussvdb bench", main, sys.argv[1:]))
