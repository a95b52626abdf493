"""The report's text: report.md with Table 1, the error-vs-time tables, the Pareto front summary
and the voxel renderers side by side (ours at each step vs VTK at the same sample distance)."""
from __future__ import annotations

import os

from metrics import time_to_reach
from report_front import front_rows, is_gaussian, label, same_step, why_not, work


def _f(x, fmt="{:.1f}"):
    return "-" if x is None else fmt.format(x)


def slug(ds):
    return os.path.splitext(ds)[0]


def _samples_or_step(r):
    return r["samples"] if r["samples"] else ("" if r.get("step") is None else f"{r['step']:g}")


def _keys(rows):
    return list(dict.fromkeys((r["dataset"], r["grid"]) for r in rows))


def front_summary(rows):
    """Markdown lines: per dataset/grid, the configurations on the time-vs-PSNR front and whether a
    Gaussian one is among them."""
    L = ["## The front: render time vs PSNR\n",
         "A configuration is on the front when no other one is both as fast and as accurate (one of them "
         "strictly). Gaussian configurations are mode/LOD; `reference step s` is our voxel renderer at a "
         "step of s voxels, `VTK step s` VTK's fixed-point ray caster at a sample distance of s voxels.\n",
         "Where none is Gaussian, the last column says why, in work per covered pixel (the device's "
         "statistics; ns per segment per thread): the fastest Gaussian configuration's segments (particles: "
         "a Gaussian's exact, erf, integral over one stretch of the ray; field: a Gaussian term at a sample) "
         "against our fastest voxel step's trilinear samples. A segment costs about what a sample does, so "
         "a Gaussian mode is faster only where it has fewer of them.\n",
         "| dataset | grid | on the front (fastest first: s, dB) | Gaussian on the front |",
         "|---|---|---|---|"]
    for ds, g in _keys(rows):
        sub = [r for r in rows if r["dataset"] == ds and r["grid"] == g]
        front = front_rows(sub)
        gauss = [label(r) for r in front if is_gaussian(r)]
        L.append(f"| {ds} | {g} | " + "; ".join(
            f"{label(r)} ({r['seconds_render']:.2f}, {_f(r['psnr'])})" for r in front)
                 + f" | {', '.join(gauss) or 'none' + _why(sub)} |")
    L.append("")
    return L


def _why(rows):
    w = why_not(rows)
    return f" ({w})" if w else ""


def voxel_renderers(rows):
    """Markdown lines: our reference mode vs VTK at the same step, per dataset/grid."""
    pairs = []
    for ds, g in _keys(rows):
        sub = [r for r in rows if r["dataset"] == ds and r["grid"] == g]
        for v in sorted((r for r in sub if r["renderer"] == "vtk"), key=lambda r: -r["step"]):
            ours = same_step(sub, "gaussvdb", v["step"])
            if ours:
                pairs.append((ds, g, v, ours))
    if not pairs:
        return []
    L = ["## Voxel renderers at the same sample distance\n",
         "Our `reference` mode against VTK's `vtkFixedPointVolumeRayCastMapper` (same camera, transfer "
         "function, image size and threads; both medians of the timed renders after a warm-up). "
         "Speed ratio = VTK seconds / ours (> 1: ours faster).\n",
         "| dataset | grid | step (voxels) | ours s | VTK s | speed ratio | ours PSNR | VTK PSNR | "
         "VTK/ours mean brightness |",
         "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for ds, g, v, o in pairs:
        br = "" if v.get("brightness") is None else f"{v['brightness']:.3f}"
        L.append(f"| {ds} | {g} | {v['step']:g} | {o['seconds_render']:.3f} | {v['seconds_render']:.3f} "
                 f"| {v['seconds_render'] / o['seconds_render']:.2f} | {_f(o['psnr'], '{:.2f}')} "
                 f"| {_f(v['psnr'], '{:.2f}')} | {br} |")
    L.append("")
    return L


VTK_MATCH = (
    "VTK {vtk} (`vtkFixedPointVolumeRayCastMapper`, off-screen through {window}, {threads} threads) gets "
    "the grid's active index box padded by one background voxel as a `vtkImageData` (origin and spacing "
    "from the grid's axis-aligned index-to-world), our camera (position, focal point, up, the view angle "
    "across the larger image side) and our transfer function: colours from our LUT, scalar opacity "
    "1 - exp(-density x alpha x u) per unit distance u = one voxel, so a sample d apart gets "
    "1 - exp(-density x alpha x d), our extinction; shading off, trilinear, post-classification. The "
    "image is the window's 8-bit RGB over black (quantisation alone caps its PSNR near 59 dB). The "
    "residual is VTK's fixed-point arithmetic and its end-of-ray handling: VTK/ours mean brightness "
    "is in the table above.\n")


def write_report(meta, rows, skipped, out, files):
    L = []
    L.append("# GaussVDB error vs run time\n")
    L.append(f"Run {meta['when']} on {meta['cpu_count']} cores ({meta['platform']}), images "
             f"{meta['size'][0]}x{meta['size'][1]}, data `{meta['data']}`"
             f"{' (--quick)' if meta['quick'] else ''}; total {meta['seconds_total']:.0f} s. Errors are "
             f"against our `reference` render of the voxels (trilinear, step {meta['reference_step']} voxel), in "
             "linear premultiplied RGB with data range 1. Gaussian modes: one render after a warm-up; the "
             f"voxel renderers (ours at steps {', '.join(f'{s:g}' for s in meta['reference_steps'])}, VTK): "
             f"the median of {meta['repeat']} renders after a warm-up; a shared machine (noise +-30%).\n")
    L.append("![error vs time](error_vs_time.png)\n")
    L += front_summary(rows)
    L += voxel_renderers(rows)
    if meta.get("vtk"):
        L.append(VTK_MATCH.format(**meta["vtk"]))
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
    for ds, g in _keys(rows):
        sub = [r for r in rows if r["dataset"] == ds and r["grid"] == g]
        L.append(f"### {ds} / {g} ({sub[0]['class']})\n")
        L.append("| renderer | mode | LOD | samples / step | s render | PSNR dB | SSIM | max abs "
                 "| segments / covered px | ns / segment |")
        L.append("|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
        for r in sorted(sub, key=lambda r: (r["renderer"] != "gaussvdb", r["seconds_render"])):
            w = work(r)
            L.append(f"| {r['renderer']} | {r['mode']} | {r['lod']} | {_samples_or_step(r)} "
                     f"| {r['seconds_render']:.3f} | {_f(r['psnr'], '{:.2f}')} | {r['ssim']:.4f} "
                     f"| {r['max_abs_error']:.4f} | {_f(w and w[0], '{:,.0f}')} | {_f(w and w[1], '{:.0f}')} |")
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
        L.append(f"\n![contact sheet](contact_{slug(ds)}.png)\n")
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


