"""Are the Gaussians the same as another version's? Saves what `convert` writes and what the
importer stores and reads back, then compares two such folders byte for byte.

    python benchmarks/bench_identity_gaussians.py --save DIR [FILES...]   (default: the sample)
    python benchmarks/bench_identity_gaussians.py --compare OLD NEW

--save runs `./gaussvdb convert FILE --lod L --out DIR/...npz --json` for L in low, medium,
adaptive, then imports each file at Low + Medium in Blender and dumps every point attribute and
the read-back GaussianSet of each LOD (run it from each checkout: copy the script into an older
one). --compare exits 1 when an array differs or a JSON field other than a time or a path does.
"""
import argparse
import glob
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LODS = ("low", "medium", "adaptive")
SETS = ("group_origins", "group_start", "offsets", "sigmas", "values", "amplitudes", "voxels")


def save(out, files):
    os.makedirs(out, exist_ok=True)
    for f in files:
        b = os.path.splitext(os.path.basename(f))[0]
        for lod in LODS:
            res = subprocess.run([os.path.join(ROOT, "gaussvdb"), "convert", f, "--lod", lod, "--out",
                                  os.path.join(out, f"conv_{b}_{lod}.npz"), "--json"],
                                 capture_output=True, text=True)
            with open(os.path.join(out, f"conv_{b}_{lod}.json"), "w") as fh:
                fh.write(res.stdout.strip().splitlines()[-1] if res.stdout.strip() else "{}")
            print(b, lod, "rc", res.returncode, flush=True)
    subprocess.run([sys.executable, __file__, "--dump", out, *files], check=True)


def dump(out, files):
    import numpy as np

    sys.path[:0] = [ROOT, os.path.join(ROOT, "tools")]
    from blender_session import addon_module, start

    bpy = start()
    try:
        imp = addon_module("gaussvdb_addon.io.importer")
    except ImportError:  # an older layout of the add-on
        imp = addon_module("gaussvdb_addon.importer")
    try:
        schema = addon_module("gaussvdb_addon.io.schema")
    except ImportError:
        schema = imp
    for f in files:
        bpy.ops.wm.read_homefile(use_empty=True)
        for obj in imp.import_vdb(f, lods=("low", "medium"), collection=bpy.context.scene.collection):
            arrays = {"attr_" + k: v for k, v in schema.read_attributes(obj).items()}
            for lod in ("low", "medium"):
                gs = imp.gaussian_set_from_object(obj, lod)
                arrays.update({f"{lod}_{k}": np.asarray(getattr(gs, k)) for k in SETS})
                arrays[f"{lod}_i2w"] = np.asarray(gs.index_to_world)
            name = f"import_{os.path.basename(f)}_{obj.gaussvdb.grid_name}.npz"
            np.savez(os.path.join(out, name), **arrays)
            print(name, len(arrays["attr_position"]), flush=True)


def compare(old, new) -> int:
    import numpy as np

    bad = n = 0
    for f in sorted(glob.glob(os.path.join(old, "*.npz"))):
        g = os.path.join(new, os.path.basename(f))
        n += 1
        if not os.path.exists(g):
            print("missing", os.path.basename(f))
            bad += 1
            continue
        a, b = np.load(f), np.load(g)
        diff = [k for k in sorted(set(a.files) | set(b.files)) if k not in a.files or k not in b.files
                or a[k].dtype != b[k].dtype or a[k].shape != b[k].shape or a[k].tobytes() != b[k].tobytes()]
        if diff:
            bad += 1
            print("differs", os.path.basename(f), diff[:8])
    for f in sorted(glob.glob(os.path.join(old, "*.json"))):
        n += 1
        with open(f) as fa, open(os.path.join(new, os.path.basename(f))) as fb:
            a, b = json.load(fa), json.load(fb)
        keys = [k for k in set(a) & set(b) if not k.startswith("seconds") and k not in ("out", "mvoxels_per_second")]
        d = [k for k in keys if a[k] != b[k]]
        if d:
            bad += 1
            print("differs", os.path.basename(f), {k: (a[k], b[k]) for k in d})
    print(f"compared {n} files, {bad} differ")
    return 1 if bad else 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--save", metavar="DIR")
    ap.add_argument("--dump", metavar="DIR", help=argparse.SUPPRESS)
    ap.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"))
    ap.add_argument("files", nargs="*")
    a = ap.parse_args(argv)
    files = [os.path.abspath(f) for f in a.files] or [os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")]
    if a.compare:
        return compare(*a.compare)
    if a.dump:
        return dump(a.dump, files) or 0
    if a.save:
        return save(a.save, files) or 0
    ap.error("give --save DIR or --compare OLD NEW")


if __name__ == "__main__":
    sys.exit(main())
