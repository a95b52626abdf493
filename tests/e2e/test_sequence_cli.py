"""`./gaussvdb render 'DIR/blob_####.vdb' --frames ...` and `./gaussvdb convert` of a sequence
into the disk cache the add-on then reads (real processes, real files)."""

import json
import os
import subprocess
import sys

import numpy as np
from conftest import ROOT
from test_sequence_import import _drawn, _import, _mods, write_frames

CLI = os.path.join(ROOT, "tools", "cli.py")


def cli(*argv):
    env = {k: v for k, v in os.environ.items() if k != "GAUSSVDB_DEBUG"}
    # the suite's extensions folder: the render reuses the kernels the suite compiled
    env["GAUSSVDB_BLENDER_EXTENSIONS"] = os.environ["BLENDER_USER_EXTENSIONS"]
    return subprocess.run([sys.executable, CLI, *argv], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=900)


def json_line(stdout):
    """The command's JSON object (Blender may print its report lines around it)."""
    return json.loads(next(ln for ln in stdout.splitlines() if ln.startswith("{")))


def test_render_frames_missing_and_unreadable(bpy_module, tmp_path):
    folder = str(tmp_path / "seq")
    write_frames(folder, [1, 2, 4, 5], broken=(4,))
    out = tmp_path / "out" / "frame_####.png"
    proc = cli("render", os.path.join(folder, "blob_####.vdb"), "--frames", "1-5", "--grid",
               "density", "--lod", "low", "--size", "32x24", "--out", str(out), "--json")
    assert proc.returncode == 1, proc.stderr[-3000:]  # frame 4 cannot be read; the rest rendered
    stats = json_line(proc.stdout)
    assert [f["frame"] for f in stats["frames"]] == [1, 2, 3, 4, 5]
    for f in stats["frames"]:
        assert os.path.isfile(f["out"]) and f["out"].endswith(f"frame_{f['frame']:04d}.png")
        assert f["seconds"] > 0 and f["seconds_render"] >= 0
    g = {f["frame"]: f["gaussians"] for f in stats["frames"]}
    assert g[3] == g[2] > 0 and g[4] == 0 and g[5] > g[2]  # 3 holds 2; 4 draws nothing
    assert any("blob_0003.vdb" in w for w in stats["warnings"])
    assert len(stats["errors"]) == 1 and "frame 4" in stats["errors"][0]
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("gaussvdb render: error")]
    assert len(errors) == 1 and "blob_0004.vdb" in errors[0]
    assert "Traceback" not in proc.stderr


def test_convert_sequence_into_the_disk_cache_the_addon_reads(bpy_module, scene, tmp_path):
    bpy = bpy_module
    _, _, sf = _mods()
    folder = str(tmp_path / "seq")
    first = write_frames(folder, [1, 2, 3])
    cache = tmp_path / "cache"
    proc = cli("convert", os.path.join(folder, "blob_####.vdb"), "--grid", "heat", "--lod", "low",
               "--cache-dir", str(cache), "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json_line(proc.stdout)
    assert [f["frame"] for f in res["frames"]] == [1, 2, 3]
    assert res["frames"][0]["gaussians"] == 0 and res["frames"][1]["gaussians"] > 0  # heat from 2
    assert sorted(os.listdir(cache)) == [f"blob_000{n}.heat.low.npz" for n in (1, 2, 3)]
    assert 0 < res["cache_bytes"] < res["vdb_bytes"]
    # the add-on pointed at that folder converts nothing
    objs, _ = _import(bpy, first, grids="heat")
    scene = bpy.context.scene
    scene.gaussvdb.use_sequence_disk_cache = True
    scene.gaussvdb.sequence_cache_dir = str(cache)
    converted, hits = sf.STATS["converted"], sf.STATS["disk_hits"]
    drawn = {f: _drawn(bpy, scene, f)[0] for f in (1, 2, 3)}
    assert sf.STATS["converted"] == converted and sf.STATS["disk_hits"] == hits + 3
    assert drawn[1] == {} and drawn[3]["blob_heat"].count > 0
    scene.gaussvdb.use_sequence_disk_cache = False  # the same Gaussians as converting here
    sf.CACHE.clear()
    fresh = _drawn(bpy, scene, 3)[0]["blob_heat"]
    assert np.array_equal(fresh.offsets, drawn[3]["blob_heat"].offsets)
    assert np.array_equal(fresh.voxels, drawn[3]["blob_heat"].voxels)
