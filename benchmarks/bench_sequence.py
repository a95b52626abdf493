"""A .vdb sequence (e.g. a Mantaflow cache): conversion per frame, cached playback, cache sizes.

    ./gaussvdb bench sequence 'DIR/fluid_data_####.vdb' [--frames 1-40] [--grid density]
                              [--lods low,medium,high] [--viewport-lod low] [--json]

Prints, per LOD: seconds per frame to convert (read + Gaussians, the kernels loaded first),
memory per cached frame (the in-memory LRU entry), the on-disk cache file per frame (the
compact encoding) against the .vdb file; and the playback rate at the Viewport LOD once every
frame is cached: frames per second of frame_set + the engine's scene sync (what a viewport
does per frame before drawing), with the first (converting) pass for comparison.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tools"))


def parse(argv):
    ap = argparse.ArgumentParser(prog="gaussvdb bench sequence", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pattern", help="'DIR/name_####.vdb' or one numbered file of the sequence")
    ap.add_argument("--frames", default=None, help="e.g. 1-40 (default: every frame found)")
    ap.add_argument("--grid", default="density")
    ap.add_argument("--lods", default="low,medium,high")
    ap.add_argument("--viewport-lod", default="low")
    ap.add_argument("--json", action="store_true")
    return ap.parse_args(argv)


def main(argv=None):
    import cli_errors

    a = parse(argv if argv is not None else sys.argv[1:])
    from kernels import sequence as seq

    pat = seq.parse(os.path.abspath(a.pattern))
    if pat is None:
        raise cli_errors.InputError(f"{a.pattern}: no frame number or #### in the file name")
    frames = pat.scan()
    if a.frames:
        want = seq.parse_frames(a.frames)
        frames = [n for n in frames if want[0] <= n <= want[-1]]
    if not frames:
        raise cli_errors.InputError(f"no frames of {pat.text} in {pat.directory}")
    lods = a.lods.split(",")
    from blender_session import addon_module, start

    bpy = start()
    sf = addon_module("gaussvdb_addon.engine.sequence_frames")
    si = addon_module("gaussvdb_addon.io.sequence_import")
    scene_sync = addon_module("gaussvdb_addon.engine.scene_sync")
    sf.convert_frame(pat.path(frames[-1]), a.grid, lods[0])  # load the kernels first
    vdb_bytes = [os.path.getsize(pat.path(n)) for n in frames]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for lod in lods:
            secs, mem, disk, count = [], [], [], []
            sf.convert_frame(pat.path(frames[0]), a.grid, lod)  # this LOD's kernels
            for n in frames:
                t0 = time.perf_counter()
                gset, values, _, err, original = sf.convert_frame(pat.path(n), a.grid, lod)
                secs.append(time.perf_counter() - t0)
                if err:
                    raise cli_errors.InputError(err)
                mem.append(sf._nbytes(gset))
                count.append(0 if gset is None else gset.count)
                out = os.path.join(tmp, seq.cache_name(pat.path(n), a.grid, lod))
                disk.append(seq.write_frame(out, original, values, pat.path(n), a.grid, lod))
            rows.append({"lod": lod, "seconds_per_frame": sum(secs) / len(secs),
                         "seconds_max": max(secs), "gaussians_mean": sum(count) / len(count),
                         "memory_per_frame": sum(mem) / len(mem),
                         "disk_per_frame": sum(disk) / len(disk),
                         "vdb_per_frame": sum(vdb_bytes) / len(vdb_bytes)})

    # playback at the Viewport LOD: one viewport-like SceneSync, every frame converted once
    bpy.ops.wm.read_homefile(use_empty=True)
    objs = si.import_sequence(pat.path(frames[0]), [frames[0], frames[-1]], grids=[a.grid],
                              lods=(a.viewport_lod,), compute_error=False,
                              collection=bpy.context.scene.collection)
    vol = objs[0].gaussvdb.source_volume
    vol.frame_start, vol.frame_offset, vol.sequence_mode = frames[0], frames[0] - 1, "CLIP"
    scene = bpy.context.scene
    sf.CACHE.clear()
    sync = scene_sync.SceneSync(viewport=True)

    def play():
        t0 = time.perf_counter()
        for n in frames:
            scene.frame_set(n)
            sync.sync(bpy.context.evaluated_depsgraph_get(), force=True)
        return len(frames) / (time.perf_counter() - t0)

    first = play()
    cached = max(play() for _ in range(3))
    res = {"pattern": pat.text, "directory": pat.directory, "frames": [frames[0], frames[-1]],
           "n_frames": len(frames), "grid": a.grid, "lods": rows, "viewport_lod": a.viewport_lod,
           "playback_fps_cached": cached, "playback_fps_converting": first,
           "cache_frames": len(sf.CACHE), "cache_bytes": sf.CACHE.nbytes}
    if a.json:
        print(json.dumps(res))
        return 0
    print(f"{pat.text}: {len(frames)} frames ({frames[0]}-{frames[-1]}), grid {a.grid}")
    print(f"{'LOD':<8} {'s/frame':>8} {'max s':>7} {'Gaussians':>10} {'memory/frame':>13} "
          f"{'disk/frame':>11} {'.vdb/frame':>11} {'disk/.vdb':>9}")
    for r in rows:
        print(f"{r['lod']:<8} {r['seconds_per_frame']:8.3f} {r['seconds_max']:7.3f} "
              f"{r['gaussians_mean']:10,.0f} {r['memory_per_frame'] / 1e6:10.2f} MB "
              f"{r['disk_per_frame'] / 1e3:8.1f} kB {r['vdb_per_frame'] / 1e3:8.1f} kB "
              f"{r['disk_per_frame'] / r['vdb_per_frame']:9.3f}")
    print(f"playback at the Viewport LOD ({a.viewport_lod}): {cached:.0f} frames/s cached, "
          f"{first:.1f} frames/s converting (frame_set + scene sync, no drawing)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
