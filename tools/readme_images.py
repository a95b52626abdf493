"""The README's pictures, rendered by `./gaussvdb render` from the shared data files:

    .venv/bin/python tools/readme_images.py [--data DIR] [--out docs/images] [--width 448]

bunny_lit.png (the bunny level set as a lit surface), fire_temperature.png (the Mantaflow fire
coloured by temperature, opacity by density) and mni_clipped.png (the MNI brain volume cut open by
a clip plane). DIR defaults to ../shared/data beside the repository; an image whose file is not
there is skipped with a note (exit status 0), so the command runs on a bare clone.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = os.path.join(ROOT, "tools", "cli.py")


def mni_cut(path):
    """--clip-plane through the volume's centre, normal +y (the camera looks along +y): the front
    half is cut away and the cut face shows the inside."""
    sys.path.insert(0, ROOT)
    import numpy as np

    from kernels.vdb import read_topology

    g = next(g for g in read_topology(path).grids if g.active_voxels)
    m = np.asarray(g.index_to_world, np.float64)
    c = m[:3, :3] @ (0.5 * (np.asarray(g.bbox_min) + np.asarray(g.bbox_max))) + m[:3, 3]
    return ",".join(f"{v:.4g}" for v in (*c, 0.0, 1.0, 0.0))


# name -> (data file, render options): what each picture shows
IMAGES = {
    "bunny_lit.png": ("bunny_ls_256.vdb", ["--lod", "high", "--mode", "field",
                                           "--level-set", "surface", "--colormap", "viridis",
                                           "--view", "0.3,-0.25,-1", "--up", "0,1,0"]),  # y-up data
    "fire_temperature.png": ("mantaflow_fire_r96_f035.vdb",
                             ["--grid", "density", "--color-grid", "temperature",
                              "--color-map", "inferno", "--lod", "high", "--mode", "field"]),
    "mni_clipped.png": ("mni152_t1_fog.vdb", ["--mode", "reference", "--colormap", "grayscale",
                                              "--clip-plane", None]),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=os.path.join(os.path.dirname(ROOT), "shared", "data"))
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "images"))
    ap.add_argument("--width", type=int, default=448)
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    size = f"{a.width}x{a.width * 3 // 4}"
    for name, (data, opts) in IMAGES.items():
        path = os.path.join(a.data, data)
        if not os.path.isfile(path):
            print(f"{name}: skipped ({data} not in {a.data})")
            continue
        opts = [mni_cut(path) if o is None else o for o in opts]
        out = os.path.join(a.out, name)
        proc = subprocess.run([sys.executable, CLI, "render", path, "--size", size, "--out", out,
                               *opts], cwd=ROOT, capture_output=True, text=True)
        if proc.returncode:
            print(f"{name}: {proc.stderr.strip().splitlines()[-1]}", file=sys.stderr)
            return proc.returncode
        print(f"{name}: {' '.join(opts)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
