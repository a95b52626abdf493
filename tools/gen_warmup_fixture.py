"""Generate kernels/data/warmup.vdb, the small file the kernel warm-up reads (run once; committed).

    python tools/gen_warmup_fixture.py [--out kernels/data/warmup.vdb]

Written with Blender's bundled openvdb (the bpy module), as the test fixtures are: a fog volume
(float, zip, dense and sparse leaves, an active tile) and a narrow-band level set (half floats),
so reading it and converting it runs every codec path and grid class the import compiles.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def write(path: str) -> str:
    import bpy

    bpy.utils.expose_bundled_modules()
    import openvdb as ov

    x, y, z = np.meshgrid(*(np.arange(24, dtype=np.float32),) * 3, indexing="ij")
    r = np.sqrt((x - 11.5) ** 2 + (y - 11.5) ** 2 + (z - 11.5) ** 2)
    fog = ov.FloatGrid()
    fog.name = "density"
    fog.gridClass = ov.GridClass.FOG_VOLUME
    dense = np.where(r < 10.0, np.exp(-(r / 6.0) ** 2), 0.0).astype(np.float32)
    fog.copyFromArray(dense, ijk=(0, 0, 0), tolerance=1e-3)
    fog.fill((32, 0, 0), (47, 15, 15), 0.25, active=True)  # an active tile (and its leaves)
    fog.transform = ov.createLinearTransform(voxelSize=0.1)

    ls = ov.FloatGrid()
    ls.background = 0.3
    ls.name = "surface"
    ls.gridClass = ov.GridClass.LEVEL_SET
    sdf = np.clip((r - 8.0) * 0.1, -0.3, 0.3).astype(np.float32)
    ls.copyFromArray(sdf, ijk=(0, 0, 0), tolerance=0.0)
    ls.saveFloatAsHalf = True
    ls.transform = ov.createLinearTransform(voxelSize=0.1)
    ov.write(path, grids=[fog, ls])
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default=os.path.join(ROOT, "kernels", "data", "warmup.vdb"))
    args = ap.parse_args(argv)
    write(args.out)
    print(f"{args.out}: {os.path.getsize(args.out):,} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
