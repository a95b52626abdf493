"""Every `./gaussvdb` subcommand refuses bad files and bad options with one line on stderr,
`gaussvdb <cmd>: ...` naming the file, grid or option, exit status 2 for bad arguments and 1 for
a file that cannot be used, and no traceback (unless --debug). Each case runs tools/cli.py in a
subprocess on fixtures written here with the bundled openvdb.

Refusals of options and files that the topology already rules out come before Blender starts:
those cases point GAUSSVDB_BLENDER_EXTENSIONS at a folder that blender_session.start() would
create, and assert it was never created.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, SAMPLE
from vdb_fixtures import openvdb, write_grid

CLI = os.path.join(ROOT, "tools", "cli.py")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """name -> path of each bad input (plus the folders the options point at)."""
    d = tmp_path_factory.mktemp("bad")
    ov = openvdb()
    p = {k: str(d / f"{k}.vdb") for k in ("empty", "vec", "int", "points", "mixed", "zero", "text",
                                          "garbage", "trunc")}
    empty = ov.FloatGrid()
    empty.name = "density"
    ov.write(p["empty"], grids=[empty])
    vel = ov.Vec3SGrid()
    vel.name = "vel"
    acc = vel.getAccessor()
    for ijk in np.ndindex(8, 8, 8):
        acc.setValueOn(ijk, (1.0, 2.0, 2.0))  # magnitude 3 everywhere
    ov.write(p["vec"], grids=[vel])
    ids = ov.Int32Grid()
    ids.name = "ids"
    acc = ids.getAccessor()
    for ijk in np.ndindex(4, 4, 4):
        acc.setValueOn(ijk, 3)
    ov.write(p["int"], grids=[ids])
    # a point-data grid: the binding writes its topology (active voxels), no point attributes
    points = ov.PointDataGrid()
    points.name = "points"
    acc = points.getAccessor()
    for ijk in np.ndindex(4, 4, 4):
        acc.setValueOn(ijk, 1)
    ov.write(p["points"], grids=[points])
    ov.write(p["mixed"], grids=[empty, vel, ids])
    open(p["zero"], "wb").close()
    with open(p["text"], "w") as f:
        f.write("not a volume, only text renamed .vdb\n" * 8)
    with open(p["garbage"], "wb") as f:
        f.write(np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with open(SAMPLE, "rb") as f:
        raw = f.read()
    with open(p["trunc"], "wb") as f:
        f.write(raw[: len(raw) // 2])
    p["dir"] = str(d)
    p["missing"] = str(d / "missing.vdb")
    p["nodata"] = str(d / "no_such_folder")
    (d / "emptydir").mkdir()
    p["emptydir"] = str(d / "emptydir")
    p["density"] = write_grid(d / "density.vdb", np.ones((8, 8, 8), np.float32))
    p["sample"] = SAMPLE
    p["out"] = str(d / "out")
    (d / "seq").mkdir()
    for n in (1, 2):
        write_grid(d / "seq" / f"s_{n:04d}.vdb", np.ones((8, 8, 8), np.float32))
    p["seq"] = str(d / "seq" / "s_####.vdb")
    return p


# (argv with {name} for the files above, exit status, words the line must hold, refused before
# Blender starts). Options are checked first, so bad options come with a good file. What the file's
# header shows is refused before Blender starts; its grids are checked after, with the
# extension's own reader (one compile of the reader, not two).
S = "{sample}"
CASES = [
    # render: files
    (["render", "{missing}"], 1, ["missing.vdb", "no such file"], True),
    (["render", "{dir}"], 1, ["directory"], True),
    (["render", "{zero}"], 1, ["zero.vdb", "empty file"], True),
    (["render", "{text}"], 1, ["text.vdb", "not a VDB file"], True),
    (["render", "{garbage}"], 1, ["garbage.vdb"], True),
    (["render", "{trunc}"], 1, ["trunc.vdb", "grid"], False),
    (["render", "{empty}"], 1, ["empty.vdb", "density: empty grid"], False),
    (["render", "{vec}"], 1, ["vec.vdb", "vel: vec3s grid", "--vector-magnitude"], False),
    (["render", "{int}"], 1, ["int.vdb", "ids: integer grid"], False),
    (["render", "{points}"], 1, ["points.vdb", "points: point"], False),
    (["render", "{mixed}"], 1, ["mixed.vdb", "density: empty", "vel: vec3s", "ids: integer"], False),
    (["render", S, "--grid", "nosuch"], 1, ["'nosuch'", "density"], False),
    (["render", S, "--grid", "velocity"], 1, ["'velocity'", "--vector-magnitude"], False),
    # render: options
    (["render", S, "--lod", "ultra"], 2, ["--lod", "'ultra'", "merged"], True),
    (["render", S, "--size", "0x10"], 2, ["--size", "0x10"], True),
    (["render", S, "--view", "0,0,0"], 2, ["--view", "must not be zero"], True),
    (["render", S, "--up", "1,2"], 2, ["--up", "1,2"], True),
    (["convert", S, "--merge-check", "maybe"], 2, ["--merge-check", "on or off"], True),
    (["render", S, "--size", "abc"], 2, ["--size", "abc"], True),
    (["render", S, "--threads", "-3"], 2, ["--threads", "-3"], True),
    (["render", S, "--density", "-1"], 2, ["--density", "-1"], True),
    (["render", S, "--density", "nan"], 2, ["--density", "nan"], True),
    (["render", S, "--colormap", "nope"], 2, ["--colormap", "'nope'", "viridis"], True),
    (["render", S, "--mode", "nope"], 2, ["--mode", "'nope'", "particles"], True),
    (["render", S, "--clip-plane", "1,2,3"], 2, ["--clip-plane", "6 finite numbers"], True),
    (["render", S, "--clip-plane", "1,2,3,0,0,0"], 2, ["--clip-plane", "normal"], True),
    (["render", S, "--clip-box", "0,0,0,1,-1,1"], 2, ["--clip-box", "y0 < y1"], True),
    (["render", S, "--bogus"], 2, ["--bogus"], True),
    (["render", S, "--range", "1"], 2, ["--range", "2 finite numbers"], True),
    (["render", S, "--range", "2,1"], 2, ["--range", "MIN < MAX"], True),
    (["render", S, "--range", "0,inf"], 2, ["--range", "finite"], True),
    (["render", S, "--range=-1,1", "--log-scale"], 2, ["--range", "log scale", "MIN > 0"], True),
    (["render", S, "--tolerance", "0.1"], 2, ["--tolerance", "adaptive", "medium"], True),
    (["render", S, "--lod", "adaptive", "--tolerance", "-1"], 2, ["--tolerance", "-1"], True),
    (["render"], 2, ["file"], True),
    (["render", S, "--out", "{out}/x.bmp"], 2, ["--out", "x.bmp", ".bmp", ".png"], False),
    # render: sequences
    (["render", "{seq}", "--out", "{out}/x.png"], 2, ["--out", "x.png", "####"], True),
    (["render", "{seq}", "--frames", "7-9"], 1, ["no frames of s_####.vdb between 7 and 9",
                                                 "1-2 exist"], True),
    (["render", "{seq}", "--frames", "a-b"], 2, ["--frames", "'a-b'"], True),
    (["render", "{dir}/none_####.vdb"], 1, ["no frames of none_####.vdb"], True),
    (["convert", "{seq}"], 2, ["--cache-dir"], True),
    (["convert", "{seq}", "--cache-dir", "{out}/c", "--frames", "5-6"], 1,
     ["no frames of s_####.vdb between 5 and 6"], True),
    (["convert", "{seq}", "--cache-dir", "{out}/c", "--out", "{out}/x.npz"], 2,
     ["--cache-dir", "--out"], True),
    # convert
    (["convert", S, "--lod", "ultra"], 2, ["--lod", "'ultra'"], True),
    (["convert", S, "--threads", "x"], 2, ["--threads", "'x'"], True),
    (["convert", S, "--sigma-factor", "abc"], 2, ["--sigma-factor", "'abc'"], True),
    (["convert", "{zero}"], 1, ["zero.vdb", "empty file"], True),
    (["convert", "{trunc}"], 1, ["trunc.vdb"], True),
    (["convert", "{vec}"], 1, ["vec.vdb", "vel: vec3s grid", "--vector-magnitude"], True),
    (["convert", "{points}"], 1, ["points.vdb", "points: point"], True),
    (["convert", "{empty}", "--grid", "density"], 1, ["empty.vdb", "'density'", "empty grid"], True),
    (["convert", S, "--grid", "nosuch"], 1, ["'nosuch'", "density"], True),
    (["convert", S, "--color-grid", "nosuch"], 1, ["colour grid 'nosuch'", "density"], True),
    (["render", S, "--color-grid", "nosuch"], 1, ["colour grid 'nosuch'", "density"], False),
    (["render", "{seq}", "--color-grid", "density"], 2, ["--color-grid", "sequence"], True),
    # info
    (["info", "{missing}"], 1, ["missing.vdb", "no such file"], True),
    (["info", "{dir}"], 1, ["directory"], True),
    (["info", "{garbage}"], 1, ["garbage.vdb", "not a VDB file"], True),
    (["info", "{trunc}"], 1, ["trunc.vdb"], True),
    (["info", S, "--bogus"], 2, ["--bogus"], True),
    # bench
    (["bench", "nosuch"], 2, ["'nosuch'", "lod"], True),
    (["bench", "lod", "--data", "{nodata}"], 1, ["bench lod:", "no_such_folder"], True),
    (["bench", "lod", "--presets", "low,ultra"], 2, ["bench lod:", "--presets", "'ultra'"], True),
    (["bench", "ingest", "--data", "{emptydir}"], 1, ["bench ingest:", "no .vdb files", "emptydir"], True),
    (["bench", "render", "--lod", "ultra"], 2, ["bench render:", "--lod", "'ultra'"], True),
    (["bench", "--data", "{nodata}"], 1, ["no_such_folder"], True),
    (["bench", "--size", "0x1"], 2, ["--size", "0x1"], True),
    (["bench", "stability", "--bogus"], 2, ["bench stability:", "--bogus"], True),
    # demo
    (["demo", "--size", "abc"], 2, ["--size", "abc"], True),
    (["demo", "--weights", "nope"], 2, ["--weights", "'nope'"], True),
    (["demo", "--file", "{missing}"], 1, ["missing.vdb", "no such file"], True),
    (["demo", "--file", "{garbage}"], 1, ["garbage.vdb", "not a VDB file"], True),
    (["demo", "--file", "{density}", "--grids", "nosuch"], 1, ["density.vdb", "'nosuch'"], False),
    # build, and the command itself
    (["build", "--platform", "nope"], 2, ["--platform", "'nope'", "linux-x64"], True),
    (["build", "--python", "cp99"], 2, ["--python", "'cp99'", "cp311"], True),
    (["nosuch"], 2, ["unknown command 'nosuch'", "render"], True),
]


def cli(argv, env_extra=None, timeout=300):
    env = {k: v for k, v in os.environ.items() if k != "GAUSSVDB_DEBUG"}
    env.update(env_extra or {})
    return subprocess.run([sys.executable, CLI, *argv], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout)


def case_id(case):
    return "-".join(a.strip("{}-") for a in case[0])[:60]


@pytest.mark.parametrize("case", CASES, ids=[case_id(c) for c in CASES])
def test_refusal_is_one_line(case, files, tmp_path):
    argv, code, words, before_blender = case
    argv = [a.format(**files) for a in argv]
    ext = tmp_path / "blender_extensions"  # blender_session.start() creates it
    proc = cli(argv, {"GAUSSVDB_BLENDER_EXTENSIONS": str(ext)})
    both = proc.stdout + proc.stderr
    assert "Traceback" not in both, both[-3000:]
    lines = proc.stderr.splitlines()
    assert lines, f"nothing on stderr; stdout: {proc.stdout[-2000:]}"
    last = lines[-1]
    assert proc.returncode == code, (proc.returncode, last)
    prefix = "gaussvdb:" if argv[0] == "nosuch" else f"gaussvdb {argv[0]}"
    assert last.startswith(prefix), last
    assert [ln for ln in lines if ln.startswith("gaussvdb")] == [last], proc.stderr[-2000:]
    for w in words:
        assert w.format(**files) in last, (w, last)
    if before_blender:
        assert not ext.exists(), f"Blender was started before refusing: {last}"


def test_debug_shows_the_traceback(files, tmp_path):
    for extra, argv in (({}, ["render", files["zero"], "--debug"]),
                        ({"GAUSSVDB_DEBUG": "1"}, ["--debug", "info", files["garbage"]]),
                        ({"GAUSSVDB_DEBUG": "1"}, ["convert", files["vec"]])):
        proc = cli(argv, extra)
        assert proc.returncode != 0
        assert "Traceback" in proc.stderr, (argv, proc.stderr[-2000:])


def test_help_is_not_a_refusal():
    proc = cli(["render", "--help"])
    assert proc.returncode == 0 and "--vector-magnitude" in proc.stdout, proc.stderr


def test_render_vector_magnitude(files, tmp_path):
    """--vector-magnitude renders a vec3 grid as its magnitude (3 everywhere here)."""
    out = tmp_path / "vel.png"
    # the suite's extensions folder, so the render reuses the kernels the suite compiled
    env = {"GAUSSVDB_BLENDER_EXTENSIONS": os.environ["BLENDER_USER_EXTENSIONS"]}
    proc = cli(["render", files["vec"], "--vector-magnitude", "--size", "24x18", "--out", str(out),
                "--json"], env, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    stats = json.loads(proc.stdout.strip().splitlines()[-1])
    assert stats["grid"] == "vel" and stats["gaussians"] > 0
    # |(1, 2, 2)| = 3 everywhere: a constant range is widened down to 0, so 3 is its top
    assert stats["value_range"] == pytest.approx([0.0, 3.0], rel=1e-5)
    assert out.stat().st_size > 0
