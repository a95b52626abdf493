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

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def write(path: str) -> str:
    import bpy

    bpy.utils.expose_bundled_modules()
    import openvdb as ov

    from kernels.warmup import fixture_arrays

    a = fixture_arrays()
    fog = ov.FloatGrid()
    fog.name = "density"
    fog.gridClass = ov.GridClass.FOG_VOLUME
    fog.copyFromArray(a["fog"], ijk=(0, 0, 0), tolerance=a["fog_tolerance"])
    lo, hi, value = a["tile"]
    fog.fill(lo, hi, value, active=True)  # an active tile (and its leaves)
    fog.transform = ov.createLinearTransform(voxelSize=a["voxel_size"])

    ls = ov.FloatGrid()
    ls.background = a["sdf_background"]
    ls.name = "surface"
    ls.gridClass = ov.GridClass.LEVEL_SET
    ls.copyFromArray(a["sdf"], ijk=(0, 0, 0), tolerance=0.0)
    ls.saveFloatAsHalf = True
    ls.transform = ov.createLinearTransform(voxelSize=a["voxel_size"])
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
