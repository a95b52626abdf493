"""The GPU device's shaders timed on a real GPU with no Blender: every case (gpu_cases.py: file x
mode x LOD, a view per image size) drawn by the standalone OpenGL backend (gl_backend.py) as the
GPU device draws it, the cases made on the GPU machine from the .vdb files the call carries.

    python benchmarks/gpu_real.py prepare [--wheels .whl] [--data .data]   # here: wheels for Python
                                   # 3.12 and the shared .vdb files copied into .data
    python benchmarks/gpu_real.py payload [--data .data]                  # what the call carries,
                                   # in MiB (exit 1: too much)
    python benchmarks/gpu_real.py build DATA OUT [--budget-s 450] [--jobs J] [--threads T]
                                   [--modes ...] [--lods ...] [--sizes ...] [run options]
                                   # there (benchmarks/gpu_real.sh --build): make, then time
    python benchmarks/gpu_real.py run CASES OUT [--budget-s 420] [--views 512x512] [--warm 3]
                                  [--timed 20]                     # time cases made before

One call to the GPU machine carries the repository's working tree (tracked files and untracked
ones git does not ignore), the shared .vdb files (.data), the wheels the machine's Python lacks
(.whl: moderngl, glcontext, blosc for the blosc-compressed files) and, where the machine lacks
EGL, the GL/EGL packages (.gl): 64 MiB in all (CARRY_LIMIT); ``payload`` adds them up and fails
past CARRY_LIMIT less MARGIN. ``build`` makes every case there (gpu_cases.build: the kernels
compiled once, then the files' LODs in processes sharing the cores; the cases go to a folder
outside OUT, so only the results come back), then times them in what is left of --budget-s
(cases not made within --build-budget-s, default --budget-s less --time-reserve-s, are listed as
skipped, as are cases not timed in time).

Per case and view: the upload of the scene's tables (ms, wall clock to glFinish, median of 3), the
screen-tile lists' three passes with their counts' readback (ms, wall clock, median of 5; the
Gaussian modes), the mode's dispatch (ms from GL_TIME_ELAPSED queries, median of 20 after 3
warm-ups; beside it the wall clock to glFinish), the scene's bytes on the GPU (tables, atlas and
lists; the per-Gaussian tables' bytes a Gaussian), and the image's PSNR against the CPU device's
image saved in the case (tiles the device would redraw on the CPU taken from it, as it does).
Every fallback to the CPU device is counted: frames the GPU device hands to it (saved beside the
cases as CASE.fallback.json), tile lists past this GPU's textures (the device then uploads the
CPU's, which the case does not hold: not timed), tables past its texture size, screen tiles
redrawn on the CPU (a ray past the 160 hit slots of the chord cap, or a loop cut short): per
row in ``fallbacks`` and summed over the run. Each row also gives its CPU seconds apart (reading
the case, PSNR) from the GL work, for scaling a software run to a GPU. Writes OUT/gpu_real.json
and OUT/gpu_real.md (with ``build``: the making's figures too, ``build`` in the JSON); cases not
started within the budget are listed as skipped.
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
WHEELS = ("moderngl==5.13.0", "glcontext==3.1.0", "blosc==1.11.4")  # (blosc: the reader's gate
# for blosc-compressed grids, kernels/vdb/reader.py)
WARM, TIMED = 3, 20
ROOT = os.path.dirname(HERE)
CARRY_LIMIT = 64 * 2 ** 20  # what one call to the GPU machine carries: working tree + carried paths
MARGIN = 4 * 2 ** 20
DATA = ".data"  # the shared .vdb files, copied here by prepare
TIME_RESERVE = 180.0  # seconds of a build run kept for the timing
FALLBACKS = ("frame_to_cpu", "cpu_tile_lists", "texture_too_large", "chord_cap_tiles")


def tree_bytes(root=ROOT):
    """The working tree that travels: tracked files and untracked ones git does not ignore."""
    out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                         cwd=root, capture_output=True)
    if out.returncode != 0:  # (not a git checkout: every file but the environment)
        return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(root)
                   if ".venv" not in d and "/.git" not in d for f in fs)
    names = [n for n in out.stdout.decode().split("\0") if n]
    return sum(os.path.getsize(os.path.join(root, n)) for n in names
               if os.path.isfile(os.path.join(root, n)) and not os.path.islink(os.path.join(root, n)))


def folder_bytes(path):
    if not os.path.isdir(path):
        return 0
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)


def payload(data=DATA, wheels=".whl", gl=".gl", root=ROOT):
    """{part: bytes} of what the call carries, and 'total'."""
    parts = {"working tree": tree_bytes(root)}
    for name in (data, wheels, gl):
        parts[name] = folder_bytes(os.path.join(root, name))
    parts["total"] = sum(parts.values())
    return parts


def shared_files(data_dir=None):
    """The shared .vdb files (gpu_cases.DATA_DIR), sorted."""
    import gpu_cases

    d = data_dir or gpu_cases.DATA_DIR
    return sorted(os.path.join(d, f) for f in os.listdir(d) if f.endswith(".vdb")) if os.path.isdir(d) else []


def prepare(wheels, data=DATA):
    """The wheels for the GPU machine's Python 3.12 (moderngl, glcontext, blosc) downloaded, and
    the shared .vdb files copied into data (both ignored by git: carried by name)."""
    import shutil

    os.makedirs(wheels, exist_ok=True)
    plats = [a for p in ("manylinux2014_x86_64", "manylinux_2_17_x86_64", "manylinux_2_28_x86_64",
                         "manylinux1_x86_64", "manylinux_2_5_x86_64") for a in ("--platform", p)]
    subprocess.run([sys.executable, "-m", "pip", "download", "--only-binary=:all:", "--no-deps",
                    "--python-version", "3.12", "--implementation", "cp", *plats, *WHEELS, "-d", wheels],
                   check=True)
    print(f"{folder_bytes(wheels) / 2 ** 20:.2f} MiB of wheels in {wheels}")
    files = shared_files()
    if not files:
        raise SystemExit("gpu_real: no shared .vdb files to copy")
    os.makedirs(data, exist_ok=True)
    for f in files:
        dst = os.path.join(data, os.path.basename(f))
        if not (os.path.exists(dst) and os.path.getsize(dst) == os.path.getsize(f)):
            shutil.copyfile(f, dst)
    print(f"{folder_bytes(data) / 2 ** 20:.2f} MiB of .vdb files in {data} ({len(files)})")
    return 0


def report_payload(data=DATA, wheels=".whl", gl=".gl"):
    """Print what the call carries, in MiB; 1 where past the limit."""
    parts = payload(data, wheels, gl)
    print(json.dumps({k: round(v / 2 ** 20, 2) for k, v in parts.items()}) + " MiB")
    if parts["total"] > CARRY_LIMIT - MARGIN:
        print(f"over {(CARRY_LIMIT - MARGIN) / 2 ** 20:.0f} MiB: the call cannot carry it")
        return 1
    return 0


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


def measure(gl, case, view, fallbacks, warm=WARM, timed=TIMED):
    """One row: the case's view drawn and timed (see the docstring); fallbacks: the run's
    counts, added to (the row has its own)."""
    import gl_backend as B

    t0 = time.perf_counter()
    info = case.info
    mine = dict.fromkeys(FALLBACKS, 0)
    row = {"case": os.path.basename(case.path), "source": info.get("source"), "mode": info["mode"],
           "mode_asked": info.get("mode_asked"), "lod": info.get("lod"), "view": view,
           "gaussians": info["gaussians"], "fallbacks": mine}

    def fell(kind, n=1):
        mine[kind] += n
        fallbacks[kind] += n

    f = B.Frame(gl, case, view)
    f.read_tables()
    row["read_s"] = round(time.perf_counter() - t0, 3)
    try:
        f.upload()
    except B.TooMany as e:
        fell("texture_too_large")
        return dict(row, fallback=str(e))
    row["upload_ms"] = wall_ms(f.upload, gl, 3)
    try:
        row["tile_entries"] = f.lists()
    except B.TooMany as e:
        fell("cpu_tile_lists")
        return dict(row, fallback=f"CPU tile lists: {e}")
    if info["on_gpu_tiles"]:
        row["lists_ms"] = wall_ms(f.lists, gl, 5)
    for _ in range(warm):
        f.draw()
    gl.ctx.finish()
    gpu_ms, wall = [], []
    for _ in range(timed):
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
        t = time.perf_counter()
        cpu = case.cpu(view)
        for ty, tx in over:  # the device redraws these tiles on the CPU device
            rgba[ty * tile:(ty + 1) * tile, tx * tile:(tx + 1) * tile] = cpu[ty * tile:(ty + 1) * tile,
                                                                             tx * tile:(tx + 1) * tile]
        row["psnr_db"] = psnr(rgba, cpu)
        row["psnr_floor_db"] = case.views[view].get("cpu_floor_db")  # (the saved image's rounding)
        row["psnr_s"] = round(time.perf_counter() - t, 3)
    row["overflow_tiles"] = len(over)
    fell("chord_cap_tiles", len(over))
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


def run(cases, out, budget_s, views=None, warm=WARM, timed=TIMED, build=None):
    """Every case's views (those in views, None: all) measured; OUT/gpu_real.json and .md
    (build: the making's figures, gpu_cases.build's, written beside them)."""
    import gl_backend as B

    if os.path.exists(NVIDIA_EGL):
        os.environ.setdefault("__EGL_VENDOR_LIBRARY_FILENAMES", NVIDIA_EGL)
    t0 = time.perf_counter()
    gl = B.GL()
    software = "llvmpipe" in gl.renderer or "softpipe" in gl.renderer
    fallbacks = dict.fromkeys(FALLBACKS + ("frames_with_overflow",), 0)
    rows, skipped = [], []
    for fb in sorted(glob.glob(os.path.join(cases, "*.fallback.json"))):
        with open(fb) as fh:
            d = json.load(fh)
        fallbacks["frame_to_cpu"] += 1
        rows.append({"case": os.path.basename(fb), "source": d.get("source"), "mode_asked": d.get("mode_asked"),
                     "lod": d.get("lod"), "fallback": d["fallback"],
                     "fallbacks": dict(dict.fromkeys(FALLBACKS, 0), frame_to_cpu=1)})
    for path in sorted(glob.glob(os.path.join(cases, "*.npz"))):
        t = time.perf_counter()
        case = B.Case(path)
        open_s = time.perf_counter() - t
        for view in case.views:
            if views is not None and view not in views:
                continue
            if time.perf_counter() - t0 > budget_s:
                skipped.append(f"{os.path.basename(path)} {view}")
                continue
            t = time.perf_counter()
            r = measure(gl, case, view, fallbacks, warm, timed)
            r["read_s"] = round(r["read_s"] + open_s, 3)
            open_s = 0.0
            r["seconds"] = round(time.perf_counter() - t, 2)
            rows.append(r)
            print(json.dumps(r), flush=True)
    os.makedirs(out, exist_ok=True)
    res = {"renderer": gl.renderer, "software": software, "gl_version": gl.ctx.info["GL_VERSION"],
           "max_texture_size": gl.max_texture,
           "timer": f"GL_TIME_ELAPSED, median of {timed} after {warm} warm-ups",
           "fallbacks": fallbacks, "rows": rows, "skipped": skipped,
           "seconds": round(time.perf_counter() - t0, 1)}
    if build is not None:
        res["build"] = build
    with open(os.path.join(out, "gpu_real.json"), "w") as fh:
        json.dump(res, fh, indent=1)
    md = table(rows, gl.renderer, software) + (
        f"\nFallbacks to the CPU device: {json.dumps(fallbacks)}; skipped (budget): {len(skipped)}; "
        f"run {res['seconds']} s.\n")
    if build is not None:
        md += (f"\nCases made here from the .vdb files: {build['cases']} in {build['seconds']} s "
               f"({build['jobs']} processes x {build['threads']} numba threads; kernels compiled "
               f"in {build['warm_seconds']} s first; {build['case_seconds']} CPU-process seconds "
               f"over the cases), {len(build['skipped'])} not made (budget), "
               f"{len(build.get('failed', {}))} failed{'; ' + build['error'] if 'error' in build else ''}.\n")
    with open(os.path.join(out, "gpu_real.md"), "w") as fh:
        fh.write(md)
    print(md)
    return 0


def build_and_run(data, out, budget_s, build_budget_s=None, jobs=None, threads=None, cases_dir=None,
                  modes=None, lods=None, sizes=None, views=None, warm=WARM, timed=TIMED):
    """The cases made from data's .vdb files (gpu_cases.build) in a folder outside out, then timed
    (run) in what is left of budget_s."""
    import tempfile

    import gpu_cases

    t0 = time.perf_counter()
    files = shared_files(data)
    if not files:
        raise SystemExit(f"gpu_real: no .vdb files in {data}")
    cases_dir = cases_dir or tempfile.mkdtemp(prefix="gaussvdb-cases-")
    modes = modes or list(gpu_cases.MODES)
    lods = lods or ["low", "medium", "high"]
    sizes = gpu_cases.parse_sizes(sizes or "512x512,1920x1080")
    cases = list(gpu_cases.shared_cases(files, modes, lods))
    if jobs is None:  # (a unit per process at most; the cores shared out)
        cores = os.cpu_count() or 1
        jobs = max(1, min(len(gpu_cases.units(cases)), cores // 2 if cores >= 4 else cores))
    if build_budget_s is None:
        build_budget_s = max(budget_s - TIME_RESERVE, budget_s / 2)
    try:
        made = gpu_cases.build(cases_dir, cases, sizes, {(512, 512)}, jobs, threads, build_budget_s)
    except Exception as e:  # noqa: BLE001  (one call: time what was made, say why the rest is not)
        made = {"error": f"{type(e).__name__}: {e}", "seconds": round(time.perf_counter() - t0, 1),
                "warm_seconds": None, "jobs": jobs, "threads": threads, "case_seconds": None, "skipped": [],
                "cases": len(glob.glob(os.path.join(cases_dir, "*.npz")))}
    made["files"] = [os.path.basename(f) for f in files]
    print(json.dumps({k: v for k, v in made.items() if k != "each"}), flush=True)
    left = budget_s - (time.perf_counter() - t0)
    return run(cases_dir, out, left, views, warm, timed, build=made)


def _names(text):
    return [x for x in text.split(",") if x] if text else None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("prepare")
    p.add_argument("--wheels", default=".whl")
    p.add_argument("--data", default=DATA)
    q = sub.add_parser("payload")
    q.add_argument("--data", default=DATA)
    r = sub.add_parser("run")
    r.add_argument("cases")
    b = sub.add_parser("build")
    b.add_argument("data")
    b.add_argument("--build-budget-s", type=float, default=None,
                   help=f"cases not started by then are not made (default: --budget-s less {TIME_RESERVE:.0f})")
    b.add_argument("--jobs", type=int, default=None, help="processes making the cases (default: half the cores)")
    b.add_argument("--threads", type=int, default=None, help="numba threads each (default: the cores shared out)")
    b.add_argument("--cases", default=None, help="where the cases go (default: a new temporary folder)")
    b.add_argument("--modes", default=None)
    b.add_argument("--lods", default=None)
    b.add_argument("--sizes", default=None)
    for x, budget in ((r, 420.0), (b, 450.0)):
        x.add_argument("out")
        x.add_argument("--budget-s", type=float, default=budget)
        x.add_argument("--views", default=None, help="only these views, e.g. 512x512 (default: all)")
        x.add_argument("--warm", type=int, default=WARM)
        x.add_argument("--timed", type=int, default=TIMED)
    a = ap.parse_args(argv)
    if a.cmd == "prepare":
        return prepare(a.wheels, a.data)
    if a.cmd == "payload":
        return report_payload(a.data)
    views = set(a.views.split(",")) if a.views else None
    if a.cmd == "build":
        return build_and_run(a.data, a.out, a.budget_s, a.build_budget_s, a.jobs, a.threads, a.cases,
                             _names(a.modes), _names(a.lods), a.sizes, views, a.warm, a.timed)
    return run(a.cases, a.out, a.budget_s, views, a.warm, a.timed)


if __name__ == "__main__":
    sys.exit(main())
