"""GPU frames saved as files (kernels/render/gpu/case.py's ``.npz``, one per file, mode and LOD,
with one view per image size and the CPU device's image of the views in --cpu-sizes): scenes
synced here through the CPU device's packing and the GPU device's frame set-up (numba, the bpy
module), for the standalone OpenGL backend (benchmarks/gl_backend.py) and the GPU machine's run
(gpu_real.py).

    python benchmarks/gpu_cases.py OUT [FILES.vdb ...] [--modes reference,splat,particles,field,paper]
                                   [--lods low,medium,high] [--sizes 512x512,1920x1080]
                                   [--cpu-sizes 512x512] [--synthetic]

Default files: the shared data (../shared/data). Reference mode draws the voxels: one case per
file (no LOD). The two sizes of a case share its tables (only the camera's and the tile lists'
inputs differ); the CPU device's image, what PSNR is measured against, is saved at 512x512 only
by default (packed: kernels/render/gpu/case.py), which shrinks what the GPU machine's calls carry
(gpu_pack.py shares the set out among them). --synthetic: the small
written scenes the equality test uses (a fog volume, a level set, two objects, a lit volume, a
volume coloured by a second grid). Prints one line per case: its size and the GPU device's
fallback where it hands the frame to the CPU device; writes OUT/sizes.json ({case file: bytes})."""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("files", nargs="*")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--lods", default="low,medium,high")
    ap.add_argument("--sizes", default="512x512,1920x1080")
    ap.add_argument("--cpu-sizes", default="512x512", help="the views with the CPU device's image "
                    "(PSNR measured there; 'all': every size, as --synthetic's one 48x48 view)")
    ap.add_argument("--synthetic", action="store_true")
    a = ap.parse_args(argv)
    from blender_session import addon_module, start

    start()
    from bench_render import frame_setup, load

    from kernels.render import CPUDevice

    GPUDevice = addon_module("gaussvdb_addon.gpu.device").GPUDevice
    modes = [m for m in a.modes.split(",") if m]
    for m in modes:
        if m not in MODES:
            raise SystemExit(f"gpu_cases: unknown mode {m!r} (choose from {','.join(MODES)})")
    sizes = parse_sizes(a.sizes)
    cpu_views = None if a.cpu_sizes == "all" or a.synthetic else set(parse_sizes(a.cpu_sizes))
    os.makedirs(a.out, exist_ok=True)
    cpu = CPUDevice()
    if a.synthetic:
        cases = [(name, mode, "medium") for name in SYNTHETIC for mode in modes]
    else:
        files = a.files or sorted(os.path.join(DATA_DIR, f) for f in os.listdir(DATA_DIR) if f.endswith(".vdb"))
        cases = list(shared_cases(files, modes, [x for x in a.lods.split(",") if x]))
    loaded = {}
    record = os.path.join(a.out, "sizes.json")
    sizes_json = {}
    if os.path.exists(record):
        with open(record) as f:
            sizes_json = json.load(f)
    for src, mode, lod in cases:
        t = time.perf_counter()
        path = os.path.join(a.out, case_name(src, mode, lod))
        if a.synthetic:
            sc, cam, tf = synthetic_scene(src, mode, lod)
            cams = [cam]
        else:
            key = (src, "low" if lod == "voxels" else lod)
            if key not in loaded:
                loaded.clear()  # (one file's LOD at a time: memory)
                loaded[key] = load(src, key[1])[:2]
            g, gs = loaded[key]
            cams = []
            for w, h in sizes:
                sc, cam, tf = frame_setup(g, gs, (w, h), mode)
                cams.append(cam)
        meta = {"source": os.path.basename(src), "mode_asked": mode, "lod": lod}
        why = save_case(GPUDevice(), path, sc, cams, tf, meta, cpu, cpu_views)
        if why is not None:  # the GPU run counts it
            path = path[:-4] + ".fallback.json"
            with open(path, "w") as f:
                json.dump(dict(meta, fallback=why), f)
        sizes_json[os.path.basename(path)] = os.path.getsize(path)
        with open(record, "w") as f:
            json.dump(dict(sorted(sizes_json.items())), f, indent=0)
        print(json.dumps({"case": os.path.basename(path), "MiB": round(os.path.getsize(path) / 2 ** 20, 2),
                          "fallback": why, "seconds": round(time.perf_counter() - t, 1)}), flush=True)
    print(json.dumps({"cases": len(sizes_json), "MiB": round(sum(sizes_json.values()) / 2 ** 20, 2)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
