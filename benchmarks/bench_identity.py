"""Bit-identity check for kernel refactors: render a fixed set of small scenes and save them, or
render them again and compare.

    python benchmarks/bench_identity.py --save DIR [FILES...] [--size 96]
    python benchmarks/bench_identity.py --compare DIR [FILES...] [--size 96]

Scenes, for every mode (particles, field, paper, reference): each fog volume given (default: the
bundled sample) with a clip plane, Depth and Value passes; the same volume beside a level-set
sphere written here (two objects, a lit opaque surface, a sun and a point light); the sphere as a
translucent shell; particles and field once more without screen tiles (the leaf walk); and a
render border. --compare prints the max abs difference per image and exits 1 if any differs.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from kernels.lod import build_lod  # noqa: E402  (after the sys.path set-up above)
from kernels.render import MODES, Camera, CPUDevice, RenderObject, RenderScene, TransferFunction  # noqa: E402
from kernels.render.scene import clip  # noqa: E402
from kernels.render.scene.lights import Light  # noqa: E402
from kernels.render.scene.synthetic import grid_from_dense  # noqa: E402
from kernels.vdb import read_vdb  # noqa: E402

SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")


def fog(path):
    grids = read_vdb(path).grids
    g = next(x for x in grids if x.active_voxels and x.value_type != "vec3s")
    return g, build_lod(g, "low")


def sphere(n=32, r=10.0):
    x = np.arange(n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    phi = np.sqrt((X - 15.7) ** 2 + (Y - 15.4) ** 2 + (Z - 15.6) ** 2) - r
    grid = grid_from_dense(np.clip(phi, -3, 3), active=np.abs(phi) < 3, background=3.0,
                           grid_class="level_set")
    return grid, build_lod(grid, "medium")


def box_of(grid, m):
    lo = np.asarray(grid.bbox_min, float) - 0.5
    hi = np.asarray(grid.bbox_max, float) + 0.5
    c = np.array([[x, y, z, 1] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                  for z in (lo[2], hi[2])]) @ m.T
    return c[:, :3].min(0), c[:, :3].max(0)


def cases(files, size):
    """(name, device, scene, camera, tf, render kwargs) for every image."""
    tiles, walk = CPUDevice(), CPUDevice(screen_tiles=False)
    sg, sgs = sphere()
    lights = (Light("sun", (1.0, -1.0, -0.5), (1.0, 0.9, 0.8), 2.0), Light("point", (0, -40, 40), strength=4e4))
    for path in files:
        fname = os.path.splitext(os.path.basename(path))[0]
        g, gs = fog(path)
        m = np.asarray(g.index_to_world, float)
        lo, hi = box_of(g, m)
        mid = 0.5 * (lo + hi)
        vals = np.asarray(gs.values, float)
        vmin, vmax = float(np.nanmin(vals)), float(np.nanmax(vals))
        tfs = {mode: TransferFunction.from_colormap(
            "viridis", vmin, vmax if vmax > vmin else vmin + 1,
            # the paper's closest-hit weights need far more density to show
            density=(4e4 if mode == "paper" else 40.0) / float(np.max(hi - lo))) for mode in MODES}
        tf = tfs["particles"]
        cam = Camera.frame_box(lo, hi, size, size, direction=(1.0, 1.0, -0.6))
        cut = clip.plane_from_point_normal(mid, (1.0, 0.3, 0.2))
        vol = RenderObject(gs, m, grid=g, clip=cut, name="fog")
        # the sphere beside the volume, half its size
        ms = np.eye(4)
        ms[:3, :3] *= float(np.max(hi - lo)) / 2.0 / 32.0
        ms[:3, 3] = mid + np.array([0.0, -0.25, 0.0]) * (hi - lo) - ms[:3, :3] @ np.full(3, 16.0)
        ls = RenderObject(sgs, ms, grid=sg, is_level_set=True, surface=True, level_set_color="z",
                          name="sphere")
        shell = RenderObject(sgs, ms, grid=sg, is_level_set=True, surface=False,
                             level_set_color=(0.9, 0.4, 0.2), name="shell")
        for mode in MODES:
            tf = tfs[mode]
            yield f"{fname}/{mode}/clip", tiles, RenderScene([vol], mode=mode), cam, tf, {}
            yield (f"{fname}/{mode}/two-objects", tiles,
                   RenderScene([vol, ls], mode=mode, lights=lights), cam, tf, {})
            yield f"{fname}/{mode}/shell", tiles, RenderScene([shell, vol], mode=mode), cam, tf, {}
        tf = tfs["particles"]
        for mode in ("particles", "field"):
            yield (f"{fname}/{mode}/walk", walk, RenderScene([vol, ls], mode=mode, lights=lights),
                   cam, tf, {})
        yield (f"{fname}/particles/border", tiles, RenderScene([vol], mode="particles"), cam, tf,
               dict(rows=(size // 5, size - 7), cols=(3, size // 2 + 5)))


def render_all(files, size):
    out = {}
    for name, dev, sc, cam, tf, kw in cases(files, size):
        t = time.perf_counter()
        img = dev.render(sc, cam, tf, **kw)
        for p, a in img.items():
            out[f"{name}/{p}"] = np.asarray(a)
        print(f"  {name:<48} {time.perf_counter() - t:6.2f} s", flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", help=".vdb fog volumes (default: the bundled sample)")
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", metavar="DIR")
    g.add_argument("--compare", metavar="DIR")
    ap.add_argument("--size", type=int, default=96)
    a = ap.parse_args(argv)
    files = a.files or [SAMPLE]
    for f in files:
        if not os.path.isfile(f):
            print(f"error: no such file: {f}")
            return 2
    imgs = render_all(files, a.size)
    path = os.path.join(a.save or a.compare, f"identity_{a.size}.npz")
    if a.save:
        os.makedirs(a.save, exist_ok=True)
        np.savez_compressed(path, **imgs)
        print(f"saved {len(imgs)} images to {path}")
        return 0
    if not os.path.isfile(path):
        print(f"error: nothing saved at {path} (run --save first)")
        return 2
    ref = np.load(path)
    bad = 0
    for k in sorted(set(ref.files) | set(imgs)):
        if k not in ref.files or k not in imgs:
            print(f"  {k:<56} {'missing in ' + ('saved' if k not in ref.files else 'new')}")
            bad += 1
            continue
        a0, a1 = ref[k], imgs[k]
        same = a0.shape == a1.shape and np.array_equal(a0, a1, equal_nan=True)
        d = float(np.nanmax(np.abs(a0.astype(np.float64) - a1))) if a0.shape == a1.shape else np.inf
        print(f"  {k:<56} max abs diff {d:.3g}{'' if same else '  DIFFERS'}")
        bad += not same
    print(f"{len(imgs) - bad} of {len(imgs)} images identical" if bad else f"all {len(imgs)} images identical")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
