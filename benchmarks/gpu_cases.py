"""GPU frames saved as files (kernels/render/gpu/case.py's ``.npz``, one per file, mode and LOD,
with one view per image size and the CPU device's image of the views in --cpu-sizes): scenes
synced here through the CPU device's packing and the GPU device's frame set-up (numba; no Blender:
the GPU device's module is imported on its own, ``gpu_device``), for the standalone OpenGL backend
(benchmarks/gl_backend.py) and the GPU machine's run (gpu_real.py, which makes them there from
the .vdb files it carries).

    python benchmarks/gpu_cases.py OUT [FILES.vdb ...] [--modes reference,splat,particles,field,paper]
                                   [--lods low,medium,high] [--sizes 512x512,1920x1080]
                                   [--cpu-sizes 512x512] [--jobs 1] [--threads N] [--budget-s S]
                                   [--synthetic]

Default files: the shared data (../shared/data). Reference mode draws the voxels: one case per
file (no LOD). The two sizes of a case share its tables (only the camera's and the tile lists'
inputs differ); the CPU device's image, what PSNR is measured against, is saved at 512x512 only
by default (packed: kernels/render/gpu/case.py). --synthetic: the small written scenes the
equality test uses (a fog volume, a level set, two objects, a lit volume, a volume coloured by a
second grid).

--jobs J: the cases made in J processes of --threads numba threads each (default: the cores
shared out), in units of one file's LOD (its modes share the built LOD), largest first; the
kernels are compiled (or loaded from the cache) once first (kernels/warmup.py's jobs: the
reader's alone, then the LODs' and modes' side by side in the J processes), so the cases load
them from the cache rather than each process compiling them.
--budget-s: cases not started by then (seconds from the start) are skipped and listed.
Prints one line per case: its size, seconds and the GPU device's fallback where it hands the frame
to the CPU device; writes OUT/sizes.json ({case file: bytes}) and OUT/build.json (the run's
figures: seconds, each case's seconds, the skipped ones, the failed ones with their error: a
case that fails is listed, not the end of the run)."""
from __future__ import annotations

import argparse
import importlib.abc
import importlib.util
import json
import os
import sys
import time
import types

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA_DIR = os.path.join(os.path.dirname(ROOT), "shared", "data")  # as tests/conftest.py
MODES = ("reference", "splat", "particles", "field", "paper")
SYNTHETIC = ("fog", "level set", "two objects", "lit", "colored")
for p in (ROOT, os.path.join(ROOT, "tools"), HERE):
    if p not in sys.path:
        sys.path.insert(0, p)


# -- the small written scenes --------------------------------------------------------------------
N = 24
_LODS = {}


def _grids():
    from kernels.render.scene.synthetic import grid_from_dense

    g = np.arange(N)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    r2 = (X - 11.5) ** 2 + (Y - 12.0) ** 2 + (Z - 11.0) ** 2
    fog = np.exp(-r2 / 40.0) * (1 + 0.3 * np.sin(X / 2.0))
    temp = 0.5 + 0.5 * np.cos(Y / 3.0) * np.exp(-r2 / 80.0)
    phi = np.sqrt((X - 11.8) ** 2 + (Y - 11.6) ** 2 + (Z - 11.7) ** 2) - 7.0
    return (grid_from_dense(fog, active=fog > 0.03), grid_from_dense(temp, active=fog > 0.03),
            grid_from_dense(np.clip(phi, -3, 3), active=np.abs(phi) < 3, background=3.0,
                            grid_class="level_set"))


def _lod(key, build):
    if key not in _LODS:
        _LODS[key] = build()
    return _LODS[key]


def synthetic_scene(name, mode, lod="medium"):
    """(scene, camera, tf) of one small written scene in a mode, 48x48."""
    from kernels.lod import build_lod
    from kernels.lod.second_grid import attach
    from kernels.render import Camera, RenderObject, RenderScene, TransferFunction
    from kernels.render.scene.lights import Light

    fog, temp, ls = _lod("grids", _grids)
    g_fog = _lod(("fog", lod), lambda: build_lod(fog, lod))
    g_ls = _lod(("ls", lod), lambda: build_lod(ls, lod))
    surf = dict(is_level_set=True, surface=True, level_set_color="z")
    m = np.eye(4)
    m[:3, 3] = (6.0, 3.0, -2.0)
    sun = (Light("sun", (-1.0, 1.0, -0.3)), Light("point", (40.0, -10.0, 40.0), strength=2000.0))
    tf = TransferFunction.from_colormap("viridis", 0, 1.0, density=0.4)
    kw = {}
    if name == "fog":
        objs = [RenderObject(g_fog, grid=fog)]
    elif name == "level set":
        objs = [RenderObject(g_ls, grid=ls, **surf)]
        kw["lights"] = sun[:1]
    elif name == "two objects":
        objs = [RenderObject(g_fog, grid=fog), RenderObject(g_ls, m, grid=ls, **surf)]
    elif name == "lit":
        objs = [RenderObject(g_fog, grid=fog, shading="lit", shadows=True)]
        kw["lights"] = sun
    elif name == "colored":
        g_col = _lod(("col", lod), lambda: attach(build_lod(fog, lod), fog, temp))
        ctf = TransferFunction.from_colormap("inferno", 0.0, 1.0, alpha="constant")
        objs = [RenderObject(g_col, grid=fog, color_tf=ctf, color_grid=temp)]
    else:
        raise ValueError(f"no synthetic scene {name!r}; choose from {SYNTHETIC}")
    cam = Camera.frame_box([0] * 3, [N + 6] * 3, 48, 48, direction=(0.3, 1.0, -0.2))
    return RenderScene(objs, mode=mode, **kw), cam, tf


# -- the GPU device without Blender --------------------------------------------------------------
PKG = "gaussvdb_standalone"  # the extension's package, here without its Blender registration


class _KernelsAlias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """PKG.kernels[.x] is the top-level kernels[.x] this process already uses: one copy of the
    kernels (the scenes built here and the device's classes the same) and of their numba cache."""

    def __init__(self):
        self._specs = {}

    def find_spec(self, name, path=None, target=None):
        if name == PKG + ".kernels" or name.startswith(PKG + ".kernels."):
            return importlib.util.spec_from_loader(name, self)
        return None

    def create_module(self, spec):
        mod = importlib.import_module(spec.name[len(PKG) + 1:])
        self._specs[spec.name] = mod.__spec__
        return mod

    def exec_module(self, module):
        module.__spec__ = self._specs.pop(module.__spec__.name, module.__spec__)  # (its own again)


def gpu_device():
    """The GPUDevice class (gaussvdb_addon/gpu/device.py) imported with no bpy: the repository as
    a package whose __init__ (Blender's registration) is not run, its kernels the top-level ones.
    Its frame set-up runs on the CPU (Blender's ``gpu`` module is only imported to draw)."""
    name = PKG + ".gaussvdb_addon.gpu.device"
    if name not in sys.modules:
        if PKG not in sys.modules:
            pkg = types.ModuleType(PKG)
            pkg.__path__ = [ROOT]
            sys.modules[PKG] = pkg
        if not any(isinstance(f, _KernelsAlias) for f in sys.meta_path):
            sys.meta_path.insert(0, _KernelsAlias())
    return importlib.import_module(name).GPUDevice


# -- saving ----------------------------------------------------------------------------------------
def save_case(gdev, path, scene, cams, tf, meta, cpu=None, cpu_views=None):
    """One case file of a scene at each camera (gpu_case.save) from the GPU device's frame set-up
    (gdev: a GPUDevice; no GPU context needed); cpu: a CPUDevice for the images beside the tables
    (None: none saved), of the cameras whose (width, height) is in cpu_views (None: every one).
    Returns the GPU device's fallback (then no file) or None."""
    from kernels.render.gpu import case as gpu_case

    def views():
        for cam in cams:
            want = cpu is not None and (cpu_views is None or (cam.width, cam.height) in cpu_views)
            image = cpu.render(scene, cam, tf)["Combined"] if want else None
            frame = gdev.begin_frame(scene, cam, tf)
            name, spec = gdev._spec(frame)
            yield frame, name, spec, image

    frame = gdev.begin_frame(scene, cams[0], tf)
    why = gdev.fallback(frame)
    if why is not None:
        return why
    gpu_case.save(path, views(), meta)
    return None


def shared_cases(files, modes, lods):
    """(file, mode, lod) per case: reference once per file (its voxels, with the Low LOD's
    load), the others per LOD; ordered by file and LOD, so each LOD is built once."""
    for f in files:
        for lod in lods:
            for mode in modes:
                if mode == "reference":
                    if lod == lods[0]:
                        yield f, mode, "voxels"
                else:
                    yield f, mode, lod


def case_name(src, mode, lod):
    return f"{os.path.splitext(os.path.basename(src))[0].replace(' ', '_')}.{mode}.{lod}.npz"


def parse_sizes(text):
    return [tuple(int(v) for v in s.split("x")) for s in text.split(",") if s]


def units(cases):
    """The cases in units of one file's LOD ([(src, load LOD), [(src, mode, lod), ...]]): a unit's
    modes share the LOD built once; reference (lod 'voxels') goes with the Low LOD's load."""
    out = {}
    for src, mode, lod in cases:
        out.setdefault((src, "low" if lod == "voxels" else lod), []).append((src, mode, lod))
    return list(out.items())


_COST = {"low": 1.0, "medium": 2.0, "high": 3.0}


def largest_first(us):
    """Units ordered by a guess of their cost (the file's bytes, the LOD's weight), largest first:
    the longest start first, so J processes end about together."""
    def cost(u):
        (src, lod), cases = u
        size = os.path.getsize(src) if os.path.exists(src) else 0
        return size * _COST.get(lod, 2.0) * (1 + 0.2 * len(cases))
    return sorted(us, key=lambda u: -cost(u))


def share_cores(jobs, threads=None, cores=None):
    """(processes, numba threads each): threads default to the cores shared out (at least 1)."""
    cores = cores or os.cpu_count() or 1
    jobs = max(1, int(jobs))
    return jobs, max(1, int(threads) if threads else cores // jobs)


_WORKER = {}


def make_unit(out, cases, sizes, cpu_views, deadline, synthetic=False):
    """Make one unit's cases in this process; [{case, bytes, fallback, seconds} or {skipped}]."""
    if "gdev" not in _WORKER:
        from bench_render import frame_setup, load

        from kernels.render import CPUDevice

        _WORKER.update(gdev=gpu_device(), cpu=CPUDevice(), frame_setup=frame_setup, load=load)
    GPUDevice, cpu = _WORKER["gdev"], _WORKER["cpu"]
    done, g = [], None
    for src, mode, lod in cases:
        name = case_name(src, mode, lod)
        if deadline is not None and time.time() > deadline:
            done.append({"skipped": name})
            continue
        t = time.perf_counter()
        path = os.path.join(out, name)
        if synthetic:
            sc, cam, tf = synthetic_scene(src, mode, lod)
            cams = [cam]
        else:
            if g is None:
                try:
                    g, gs = _WORKER["load"](src, "low" if lod == "voxels" else lod)[:2]
                except Exception as e:  # noqa: BLE001  (the unit's cases listed as failed)
                    done += [{"failed": case_name(*c), "error": f"{type(e).__name__}: {e}"} for c in cases]
                    print(json.dumps(done[-1]), flush=True)
                    return done
            cams = []
            for w, h in sizes:
                sc, cam, tf = _WORKER["frame_setup"](g, gs, (w, h), mode)
                cams.append(cam)
        meta = {"source": os.path.basename(src), "mode_asked": mode, "lod": lod}
        try:
            why = save_case(GPUDevice(), path, sc, cams, tf, meta, cpu, cpu_views)
        except Exception as e:  # noqa: BLE001  (one case lost, not the run: listed as failed)
            done.append({"failed": name, "error": f"{type(e).__name__}: {e}"})
            print(json.dumps(done[-1]), flush=True)
            continue
        if why is not None:  # the GPU run counts it
            path = path[:-4] + ".fallback.json"
            with open(path, "w") as f:
                json.dump(dict(meta, fallback=why), f)
        row = {"case": os.path.basename(path), "MiB": round(os.path.getsize(path) / 2 ** 20, 2),
               "fallback": why, "seconds": round(time.perf_counter() - t, 1), "pid": os.getpid()}
        print(json.dumps(row), flush=True)
        done.append(dict(row, bytes=os.path.getsize(path)))
    return done


def warm_jobs(modes, lods):
    """kernels/warmup.py's jobs for these modes and LODs: the reader's first (every other job
    reads its fixture), then the others, which compile apart."""
    from kernels import warmup

    return warmup.jobs_for(lods=[x for x in lods if x != "voxels"] or ["low"], modes=modes)


def warm(names):
    """Compile (or load from the cache) the kernels of these warm-up jobs; their seconds."""
    from kernels import warmup

    return warmup.run(names)


def build(out, cases, sizes, cpu_views, jobs=1, threads=None, budget_s=None, synthetic=False):
    """Every case made (in jobs processes: see the docstring); the run's figures (build.json)."""
    t0, w0 = time.perf_counter(), time.time()
    deadline = None if budget_s is None else w0 + budget_s
    os.makedirs(out, exist_ok=True)
    us = units(cases) if synthetic else largest_first(units(cases))
    jobs, threads = share_cores(min(jobs, len(us)) if us else 1, threads)
    rows, warm_s, warm_each = [], None, None
    if jobs == 1:
        if threads and "numba" not in sys.modules:
            os.environ.setdefault("NUMBA_NUM_THREADS", str(threads))
        for _, cs in us:
            rows += make_unit(out, cs, sizes, cpu_views, deadline, synthetic)
    else:
        import concurrent.futures as cf
        import multiprocessing as mp

        os.environ["NUMBA_NUM_THREADS"] = str(threads)  # (the spawned processes read it)
        ctx = mp.get_context("spawn")
        names = warm_jobs(sorted({m for _, cs in us for _, m, _ in cs}), sorted({lod for (_, lod), _ in us}))
        with cf.ProcessPoolExecutor(jobs, mp_context=ctx) as pool:
            warm_each = {}
            futs = [pool.submit(warm, names[:1])]  # the kernels compiled once: the reader's first
            futs[0].exception()
            futs += [pool.submit(warm, [n]) for n in names[1:]]
            for n, f in zip(names, futs):
                try:
                    warm_each.update(f.result())
                except Exception as e:  # noqa: BLE001  (the cases then compile what they need)
                    rows.append({"failed": f"warm-up {n}", "error": f"{type(e).__name__}: {e}"})
            warm_s = time.perf_counter() - t0
            print(json.dumps({"warm_seconds": round(warm_s, 1),
                              "jobs": {k: round(v, 1) for k, v in warm_each.items()}}), flush=True)
            futs = [pool.submit(make_unit, out, cs, sizes, cpu_views, deadline, synthetic) for _, cs in us]
            for (_, cs), f in zip(us, futs):
                try:
                    rows += f.result()
                except Exception as e:  # noqa: BLE001  (a process lost: its unit listed as failed)
                    rows += [{"failed": case_name(*c), "error": f"{type(e).__name__}: {e}"} for c in cs]
    made = [r for r in rows if "case" in r]
    record = os.path.join(out, "sizes.json")
    sizes_json = {}
    if os.path.exists(record):
        with open(record) as f:
            sizes_json = json.load(f)
    sizes_json.update({r["case"]: r["bytes"] for r in made})
    with open(record, "w") as f:
        json.dump(dict(sorted(sizes_json.items())), f, indent=0)
    res = {"seconds": round(time.perf_counter() - t0, 1), "warm_seconds": None if warm_s is None else round(warm_s, 1),
           "warm_jobs": warm_each and {k: round(v, 1) for k, v in warm_each.items()},
           "jobs": jobs, "threads": threads, "cases": len(made),
           "case_seconds": round(sum(r["seconds"] for r in made), 1),
           "MiB": round(sum(r["bytes"] for r in made) / 2 ** 20, 2),
           "skipped": [r["skipped"] for r in rows if "skipped" in r],
           "failed": {r["failed"]: r["error"] for r in rows if "failed" in r},
           "each": {r["case"]: r["seconds"] for r in made}}
    with open(os.path.join(out, "build.json"), "w") as f:
        json.dump(res, f, indent=1)
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("files", nargs="*")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--lods", default="low,medium,high")
    ap.add_argument("--sizes", default="512x512,1920x1080")
    ap.add_argument("--cpu-sizes", default="512x512", help="the views with the CPU device's image "
                    "(PSNR measured there; 'all': every size, as --synthetic's one 48x48 view)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--budget-s", type=float, default=None)
    ap.add_argument("--synthetic", action="store_true")
    a = ap.parse_args(argv)
    modes = [m for m in a.modes.split(",") if m]
    for m in modes:
        if m not in MODES:
            raise SystemExit(f"gpu_cases: unknown mode {m!r} (choose from {','.join(MODES)})")
    sizes = parse_sizes(a.sizes)
    cpu_views = None if a.cpu_sizes == "all" or a.synthetic else set(parse_sizes(a.cpu_sizes))
    if a.synthetic:
        cases = [(name, mode, "medium") for name in SYNTHETIC for mode in modes]
    else:
        files = a.files or sorted(os.path.join(DATA_DIR, f) for f in os.listdir(DATA_DIR) if f.endswith(".vdb"))
        cases = list(shared_cases(files, modes, [x for x in a.lods.split(",") if x]))
    res = build(a.out, cases, sizes, cpu_views, a.jobs, a.threads, a.budget_s, a.synthetic)
    print(json.dumps({k: v for k, v in res.items() if k != "each"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
