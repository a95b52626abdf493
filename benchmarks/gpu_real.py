"""The GPU device's shaders timed on a real GPU with no Blender: every saved case (gpu_cases.py:
file x mode x LOD, a view per image size) drawn by the standalone OpenGL backend (gl_backend.py)
as the GPU device draws it.

    python benchmarks/gpu_real.py prepare CASES [--wheels .whl]    # here: the wheels for Python 3.12
    python benchmarks/gpu_real.py run CASES OUT [--budget-s 420]   # there (benchmarks/gpu_real.sh)

Per case and view: the upload of the scene's tables (ms, wall clock to glFinish, median of 3), the
screen-tile lists' three passes with their counts' readback (ms, wall clock, median of 5; the
Gaussian modes), the mode's dispatch (ms from GL_TIME_ELAPSED queries, median of 20 after 3
warm-ups; beside it the wall clock to glFinish), the scene's bytes on the GPU (tables, atlas and
lists; the per-Gaussian tables' bytes a Gaussian), and the image's PSNR against the CPU device's
image saved in the case (tiles the device would redraw on the CPU taken from it, as it does).
Every fallback to the CPU device is counted: frames the GPU device hands to it (saved beside the
cases as CASE.fallback.json), tile lists past this GPU's textures (the device then uploads the
CPU's, which the case does not hold: not timed), tables past its texture size, screen tiles
redrawn on the CPU. Writes OUT/gpu_real.json and OUT/gpu_real.md; cases not started within
--budget-s are listed as skipped.
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import statistics
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
NVIDIA_EGL = "/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json"
WHEELS = ("moderngl==5.13.0", "glcontext==3.1.0")
WARM, TIMED = 3, 20


def prepare(cases, wheels):
    """Download the moderngl and glcontext wheels for the GPU machine's Python 3.12; print what a
    run carries (cases and wheels must stay under 64 MiB together)."""
    os.makedirs(wheels, exist_ok=True)
    subprocess.run([sys.executable, "-m", "pip", "download", "--only-binary=:all:", "--no-deps",
                    "--python-version", "3.12", "--platform", "manylinux2014_x86_64",
                    "--platform", "manylinux_2_17_x86_64", *WHEELS, "-d", wheels], check=True)
    files = sorted(glob.glob(os.path.join(cases, "*.npz"))) + sorted(glob.glob(os.path.join(wheels, "*.whl")))
    mib = sum(os.path.getsize(f) for f in files) / 2 ** 20
    print(f"{len(files)} files, {mib:.1f} MiB to carry" + ("" if mib < 60 else ": over 60 MiB, split the cases"))


def psnr(a, b):
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def wall_ms(fn, gl, n):
    out = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        gl.ctx.finish()
        out.append(1e3 * (time.perf_counter() - t))
    return statistics.median(out)


def measure(gl, path, view, fallbacks):
    """One row: the case's view drawn and timed (see the docstring)."""
    import gl_backend as B

    case = B.Case(path)
    info = case.info
    row = {"case": os.path.basename(path), "source": info.get("source"), "mode": info["mode"],
           "mode_asked": info.get("mode_asked"), "lod": info.get("lod"), "view": view,
           "gaussians": info["gaussians"]}
    f = B.Frame(gl, case, view)
    try:
        f.upload()
    except B.TooMany as e:
        fallbacks["texture_too_large"] += 1
        return dict(row, fallback=str(e))
    row["upload_ms"] = wall_ms(f.upload, gl, 3)
    try:
        row["tile_entries"] = f.lists()
    except B.TooMany as e:
        fallbacks["cpu_tile_lists"] += 1
        return dict(row, fallback=f"CPU tile lists: {e}")
    if info["on_gpu_tiles"]:
        row["lists_ms"] = wall_ms(f.lists, gl, 5)
    for _ in range(WARM):
        f.draw()
    gl.ctx.finish()
    gpu_ms, wall = [], []
    for _ in range(TIMED):
        t = time.perf_counter()
        gpu_ms.append(gl.timed(f.draw))
        gl.ctx.finish()
        wall.append(1e3 * (time.perf_counter() - t))
    # (llvmpipe's timer queries read ~0: it runs a dispatch when the CPU waits on it; the wall
    # clock to glFinish is its time there)
    row["dispatch_ms"], row["dispatch_wall_ms"] = statistics.median(gpu_ms), statistics.median(wall)
    rgba, dv = f.read()
    over = B.overflow_tiles(case, dv)
    tile = int(case.define("TILE"))
    if f"{view}.cpu" in case.z.files:
        cpu = case.cpu(view)
        for ty, tx in over:  # the device redraws these tiles on the CPU device
            rgba[ty * tile:(ty + 1) * tile, tx * tile:(tx + 1) * tile] = cpu[ty * tile:(ty + 1) * tile,
                                                                             tx * tile:(tx + 1) * tile]
        row["psnr_db"] = psnr(rgba, cpu)
    row["overflow_tiles"] = len(over)
    fallbacks["overflow_tiles"] += len(over)
    fallbacks["frames_with_overflow"] += bool(over)
    row["gpu_bytes"] = f.gpu_bytes()
    if "g_rec" in f.tex:  # the per-Gaussian tables' bytes (gpu.tables_gauss.bytes_per_gaussian)
        per = {"g_rec": 16 * -(-int(case.define("GREC_SIZE")) // 4), "g_cval": 4, "g_grad": 16}
        row["gauss_bytes_each"] = sum(b for n, b in per.items() if n in f.tex)
    return row


def table(rows, renderer, software):
    label = " (software: llvmpipe, not a GPU)" if software else ""
    out = [f"GPU: {renderer}{label}", "",
           "| file | mode | LOD | size | dispatch ms | (wall) | lists ms | upload ms | scene MiB | B/Gaussian "
           "| PSNR dB | CPU tiles | fallback |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def f(v, fmt):
        return "" if v is None else format(v, fmt)

    for r in rows:
        mib = r["gpu_bytes"] / 2 ** 20 if "gpu_bytes" in r else None
        out.append(f"| {r.get('source', r['case'])} | {r.get('mode_asked') or r.get('mode')} | {r.get('lod', '')} | "
                   f"{r.get('view', '')} | {f(r.get('dispatch_ms'), '.2f')} | "
                   f"{f(r.get('dispatch_wall_ms'), '.1f')} | {f(r.get('lists_ms'), '.1f')} | "
                   f"{f(r.get('upload_ms'), '.1f')} | {f(mib, '.1f')} | "
                   f"{f(r.get('gauss_bytes_each'), '.0f')} | {f(r.get('psnr_db'), '.1f')} | "
                   f"{r.get('overflow_tiles', '')} | {r.get('fallback', '')} |")
    return "\n".join(out) + "\n"


def run(cases, out, budget_s):
    import gl_backend as B

    if os.path.exists(NVIDIA_EGL):
        os.environ.setdefault("__EGL_VENDOR_LIBRARY_FILENAMES", NVIDIA_EGL)
    t0 = time.perf_counter()
    gl = B.GL()
    software = "llvmpipe" in gl.renderer or "softpipe" in gl.renderer
    fallbacks = {"frame_to_cpu": 0, "cpu_tile_lists": 0, "texture_too_large": 0, "overflow_tiles": 0,
                 "frames_with_overflow": 0}
    rows, skipped = [], []
    for fb in sorted(glob.glob(os.path.join(cases, "*.fallback.json"))):
        with open(fb) as fh:
            d = json.load(fh)
        fallbacks["frame_to_cpu"] += 1
        rows.append({"case": os.path.basename(fb), "source": d.get("source"), "mode_asked": d.get("mode_asked"),
                     "lod": d.get("lod"), "fallback": d["fallback"]})
    for path in sorted(glob.glob(os.path.join(cases, "*.npz"))):
        for view in B.Case(path).views:
            if time.perf_counter() - t0 > budget_s:
                skipped.append(f"{os.path.basename(path)} {view}")
                continue
            t = time.perf_counter()
            r = measure(gl, path, view, fallbacks)
            r["seconds"] = round(time.perf_counter() - t, 2)
            rows.append(r)
            print(json.dumps(r), flush=True)
    os.makedirs(out, exist_ok=True)
    res = {"renderer": gl.renderer, "software": software, "gl_version": gl.ctx.info["GL_VERSION"],
           "max_texture_size": gl.max_texture,
           "timer": f"GL_TIME_ELAPSED, median of {TIMED} after {WARM} warm-ups",
           "fallbacks": fallbacks, "rows": rows, "skipped": skipped,
           "seconds": round(time.perf_counter() - t0, 1)}
    with open(os.path.join(out, "gpu_real.json"), "w") as fh:
        json.dump(res, fh, indent=1)
    md = table(rows, gl.renderer, software) + (
        f"\nFallbacks to the CPU device: {json.dumps(fallbacks)}; skipped (budget): {len(skipped)}; "
        f"run {res['seconds']} s.\n")
    with open(os.path.join(out, "gpu_real.md"), "w") as fh:
        fh.write(md)
    print(md)
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("prepare")
    p.add_argument("cases")
    p.add_argument("--wheels", default=".whl")
    r = sub.add_parser("run")
    r.add_argument("cases")
    r.add_argument("out")
    r.add_argument("--budget-s", type=float, default=420.0)
    a = ap.parse_args(argv)
    if a.cmd == "prepare":
        prepare(a.cases, a.wheels)
        return 0
    return run(a.cases, a.out, a.budget_s)


if __name__ == "__main__":
    sys.exit(main())
