"""Level-set surfaces: PSNR of the field-mode surface (the zero of the Gaussians' signed-distance
mixture) at each LOD against the reference-mode surface of the voxels (trilinear signed distance, 1/8-voxel step),
both lit by the headlight, coloured by height, seen from the report's view.

    ./gaussvdb bench surface [FILES...] [--size 512x512] [--lods medium,high] [--json out.json]

docs/bench/surface.md holds its output on the shared bunny and teapot.

Default files: the bunny and teapot level sets of the shared data folder. Targets (issue 20):
High >= 35 dB, Medium >= 30 dB.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tools"))
sys.path.insert(0, HERE)

import cli_errors  # noqa: E402  (after the sys.path set-up above)
from bench_render import world_box  # noqa: E402
from metrics import image_errors  # noqa: E402

VIEW = (0.35, 1.0, -0.3)  # as bench_report
TARGETS = {"high": 35.0, "medium": 30.0}


def main(argv=None):
    from kernels.lod import PRESETS, build_lod
    from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
    from kernels.vdb import read_vdb

    ap = cli_errors.ArgumentParser(prog="gaussvdb bench surface", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*")
    ap.add_argument("--size", default=(512, 512), type=cli_errors.size)
    ap.add_argument("--lods", default=["medium", "high"], type=cli_errors.names(PRESETS))
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    data = os.path.join(os.path.dirname(ROOT), "shared", "data")
    files = a.files or [os.path.join(data, f) for f in ("bunny_ls_256.vdb", "teapot_ls_256.vdb")]
    w, h = a.size
    dev = CPUDevice()
    tf = TransferFunction.from_colormap("viridis", 0.0, 1.0)
    rows = []
    for path in files:
        if not os.path.isfile(path):
            raise cli_errors.InputError(f"{path}: no such file")
        g = next((x for x in read_vdb(path).grids if x.grid_class == "level_set"), None)
        if g is None:
            raise cli_errors.InputError(f"{path}: no level-set grid")
        m = np.asarray(g.index_to_world, np.float64)
        cam = Camera.frame_box(*world_box(g, m), w, h, direction=VIEW)
        ref = dev.render(RenderScene([RenderObject(None, m, grid=g, is_level_set=True, surface=True)],
                                     mode="reference", step=0.125), cam, tf)["Combined"]
        for lod in a.lods:
            gs = build_lod(g, lod)
            sc = RenderScene([RenderObject(gs, m, surface=True)], mode="field")
            dev.render(sc, cam, tf)  # set-up and kernels loaded: the next call is the frame
            t0 = time.perf_counter()
            img = dev.render(sc, cam, tf)["Combined"]
            err = image_errors(ref, img)
            row = dict(file=os.path.basename(path), lod=lod, gaussians=int(gs.count), width=w, height=h,
                       seconds_render=time.perf_counter() - t0, psnr=err["psnr"], ssim=err["ssim"],
                       target=TARGETS.get(lod))
            rows.append(row)
            goal = "" if row["target"] is None else (
                f" (target {row['target']:.0f} dB {'met' if err['psnr'] >= row['target'] else 'NOT met'})")
            print(f"{row['file']} {lod}: {row['gaussians']:,} Gaussians, field surface {row['seconds_render']:.2f} s, "
                  f"PSNR {err['psnr']:.2f} dB, SSIM {err['ssim']:.3f}{goal}", flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(cli_errors.run("gaussvdb bench surface", main, sys.argv[1:]))
