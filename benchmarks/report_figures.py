"""The report's pictures: the error-vs-time chart (one panel per dataset/grid) and a contact sheet
of the renders per dataset."""
from __future__ import annotations

import math

from report_front import front_rows

MODE_COLORS = {"particles": "tab:blue", "field": "tab:green", "splat": "tab:olive", "paper": "tab:red"}
LOD_MARKERS = {"low": "v", "medium": "s", "high": "^", "variance": "D", "merged": "P", "adaptive": "*"}
CURVES = (("reference", "tab:gray", "reference (labels: step)"),  # (which rows, colour, legend)
          ("vtk", "tab:purple", "VTK fixed point (labels: step)"),
          ("cycles", "tab:orange", "Cycles (labels: samples)"))


def _f(x, fmt="{:.1f}"):
    return "-" if x is None else fmt.format(x)


def _curve(sub, which):
    if which == "reference":
        pts = [r for r in sub if r["renderer"] == "gaussvdb" and r["mode"] == "reference"]
        return sorted(pts, key=lambda r: -r["step"]), lambda r: f"{r['step']:g}"
    if which == "vtk":
        return sorted((r for r in sub if r["renderer"] == "vtk"), key=lambda r: -r["step"]), \
            lambda r: f"{r['step']:g}"
    return sorted((r for r in sub if r["renderer"] == "cycles"), key=lambda r: r["samples"]), \
        lambda r: f"{r['samples']}"


def figure_error_vs_time(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    keys = list(dict.fromkeys((r["dataset"], r["grid"]) for r in rows))
    n = len(keys)
    cols = min(3, n)
    nr = math.ceil(n / cols)
    fig, axes = plt.subplots(nr, cols, figsize=(5.2 * cols, 4.2 * nr), squeeze=False)
    for ax, k in zip(axes.flat, keys):
        sub = [r for r in rows if (r["dataset"], r["grid"]) == k and r["psnr"] is not None]
        for r in sub:
            if r["renderer"] == "gaussvdb" and r["mode"] in MODE_COLORS:
                ax.scatter(r["seconds_render"], r["psnr"], c=MODE_COLORS[r["mode"]],
                           marker=LOD_MARKERS.get(r["lod"], "o"), s=45, edgecolors="k", linewidths=0.4,
                           zorder=3)
        for which, colour, _ in CURVES:
            pts, name = _curve(sub, which)
            if not pts:
                continue
            ax.plot([r["seconds_render"] for r in pts], [r["psnr"] for r in pts], "-o", c=colour, ms=3)
            for r in pts:
                ax.annotate(name(r), (r["seconds_render"], r["psnr"]), fontsize=7, xytext=(3, -8),
                            textcoords="offset points", color=colour)
        front = front_rows(sub)
        ax.step([r["seconds_render"] for r in front], [r["psnr"] for r in front], "k--", where="post",
                lw=0.7, alpha=0.6)
        ax.set_xscale("log")
        ax.set_xlabel("render time [s] (log)")
        ax.set_ylabel("PSNR vs reference [dB]")
        ax.set_title(f"{k[0]} / {k[1]}", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    gauss = [r for r in rows if r["renderer"] == "gaussvdb" and r["mode"] in MODE_COLORS]
    modes = [m for m in MODE_COLORS if any(r["mode"] == m for r in gauss)]
    lods = [lod for lod in LOD_MARKERS if any(r["lod"] == lod for r in gauss)]
    handles = [Line2D([], [], ls="", marker="o", c=MODE_COLORS[m], label=m) for m in modes]
    handles += [Line2D([], [], ls="", marker=LOD_MARKERS[lod], c="w", mec="k", label=lod) for lod in lods]
    for which, colour, text in CURVES:
        if any(_curve([r for r in rows if r["psnr"] is not None], which)[0]):
            handles.append(Line2D([], [], c=colour, marker="o", ms=3, label=text))
    handles.append(Line2D([], [], c="k", ls="--", lw=0.7, label="Pareto front"))
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 8), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def contact_sheet(ds, sheets, path, ref_step):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = []  # rows of (image, title)
    for s in sheets:
        panels.append([(s["ref"], f"{s['grid']}: reference (step {ref_step})")]
                      + [(im, f"Cycles {n} spp, {_f(p)} dB") for n, im, p in s["cycles"]])
        voxels = [(im, f"{label}, {_f(p)} dB") for label, im, p in s["voxels"]]
        if voxels:
            panels.append(voxels)
        lods = list(dict.fromkeys(lod for lod, _, _, _ in s["cells"]))
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
