"""Generate the small files the kernel warm-up reads (run once; committed).

    python tools/gen_warmup_fixture.py [--out kernels/data/warmup.vdb]
        [--cache-out kernels/data/warmup_cache.vdb]

warmup.vdb is written with Blender's bundled openvdb (the bpy module), as the test fixtures are:
a fog volume (float, dense and sparse leaves, an active tile) and a narrow-band level set (half
floats), both blosc-compressed (that binding has no other choice). warmup_cache.vdb is a frame of
a tiny Mantaflow smoke bake with the ZIP cache setting (fog grids stored raw, the velocity zip,
half floats), the other layout users' files come in: the reader compiles its decoders per
compression, so the warm-up reads one file of each.
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


def _mantaflow_in_bpy_module():
    """Baking in the bpy module aborts ("'LevelsetGrid' object has no attribute 'setConst'"):
    its ``manta`` module is made at ``import bpy``, before Mantaflow registers the inherited
    methods. Make it again, from the same library, when the bake's scripts first import it."""
    import ctypes
    import importlib.abc
    import importlib.machinery

    with open("/proc/self/maps") as f:  # the loaded bpy extension (Linux, where the tool runs)
        lib = next(line.split()[-1] for line in f if "/bpy/__init__" in line and ".so" in line)
    init = ctypes.PyDLL(lib).PyInit_manta_main
    init.restype = ctypes.py_object
    keep = [sys.modules.pop("manta", None)]  # both modules share static type objects

    class Finder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
        def find_spec(self, name, path=None, target=None):
            return importlib.machinery.ModuleSpec(name, self) if name == "manta" else None

        def create_module(self, spec):
            keep.append(init())
            return keep[-1]

        def exec_module(self, module):
            pass

    sys.meta_path.insert(0, Finder())


def write_cache_frame(path: str, frame: int = 6) -> str:
    """A Mantaflow gas domain (resolution 16, a smoke inflow) baked to OpenVDB with the ZIP
    setting and half floats; copies the cache's frame ``frame`` to ``path``."""
    import glob
    import shutil
    import tempfile

    import bpy

    _mantaflow_in_bpy_module()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.frame_end = frame
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0, 0, 1.0))
    domain = bpy.context.active_object
    settings = domain.modifiers.new("Fluid", "FLUID")
    settings.fluid_type = "DOMAIN"
    d = settings.domain_settings
    cache = tempfile.mkdtemp(prefix="gaussvdb-manta-")
    d.domain_type, d.resolution_max, d.cache_directory = "GAS", 16, cache
    d.cache_type, d.cache_data_format = "ALL", "OPENVDB"
    d.cache_frame_start, d.cache_frame_end = 1, frame
    d.openvdb_cache_compress_type, d.openvdb_data_depth = "ZIP", "16"
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.3, location=(0, 0, 0.4))
    flow = bpy.context.active_object.modifiers.new("Fluid", "FLUID")
    flow.fluid_type = "FLOW"
    flow.flow_settings.flow_type, flow.flow_settings.flow_behavior = "SMOKE", "INFLOW"
    bpy.context.view_layer.objects.active = domain
    with bpy.context.temp_override(scene=scene, object=domain, active_object=domain):
        bpy.ops.fluid.bake_data()
    src = [p for p in glob.glob(os.path.join(cache, "**", "*.vdb"), recursive=True)
           if p.endswith(f"_{frame:04d}.vdb") and "data" in os.path.basename(p)]
    shutil.copy(src[0], path)
    shutil.rmtree(cache, ignore_errors=True)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default=os.path.join(ROOT, "kernels", "data", "warmup.vdb"))
    ap.add_argument("--cache-out", default=os.path.join(ROOT, "kernels", "data", "warmup_cache.vdb"))
    args = ap.parse_args(argv)
    write(args.out)
    write_cache_frame(args.cache_out)
    for p in (args.out, args.cache_out):
        print(f"{p}: {os.path.getsize(p):,} bytes")
    sys.stdout.flush()
    os._exit(0)  # Mantaflow throws while the bpy module shuts down; everything is written


if __name__ == "__main__":
    sys.exit(main())
