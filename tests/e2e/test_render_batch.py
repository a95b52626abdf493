"""`./gaussvdb render` as a batch tool (real processes, real files): --json leaves stdout to one
JSON document, every LOD of a file renders the same view, and --range gives files of different
value ranges the same colours."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, SAMPLE
from test_engine_helpers import read_image
from vdb_fixtures import write_grid

CLI = os.path.join(ROOT, "tools", "cli.py")


def cli(*argv):
    env = {k: v for k, v in os.environ.items() if k != "GAUSSVDB_DEBUG"}
    # the suite's extensions folder: the render reuses the kernels the suite compiled
    env["GAUSSVDB_BLENDER_EXTENSIONS"] = os.environ["BLENDER_USER_EXTENSIONS"]
    return subprocess.run([sys.executable, CLI, *argv], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=900)


def render_json(*argv):
    """Run `render ... --json`; its stdout must be one JSON document, as `| python -m json.tool`
    reads it. Returns the document."""
    proc = cli("render", *argv, "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    tool = subprocess.run([sys.executable, "-m", "json.tool"], input=proc.stdout,
                          capture_output=True, text=True)
    assert tool.returncode == 0, (tool.stderr, proc.stdout[:2000])
    assert "Saved:" in proc.stderr  # Blender's line still comes, on stderr
    return json.loads(proc.stdout)


def test_json_is_the_whole_stdout_and_reference_mode_builds_no_lod(bpy_module, tmp_path):
    """Reference mode draws the voxels: the file is imported without Gaussians (no LOD built,
    whatever --lod says), and its picture is the one of the same grid imported with a LOD
    (tests/blender/test_grid_alone.py) under the camera and density the active voxels set."""
    images = {}
    for lod in ("low", "high"):
        out = tmp_path / f"{lod}.png"
        stats = render_json(SAMPLE, "--lod", lod, "--mode", "reference", "--size", "64x48",
                            "--out", str(out))
        assert stats["lod"] is None and stats["gaussians"] == 0 and stats["out"] == str(out)
        images[lod] = read_image(bpy_module, out)
    assert images["low"][..., 3].max() > 0.5  # the smoke is in the picture
    np.testing.assert_array_equal(images["low"], images["high"])
    stats = render_json(SAMPLE, "--lod", "low", "--size", "16x12", "--out", str(tmp_path / "p.png"))
    assert stats["lod"] == "low" and stats["gaussians"] > 0  # a Gaussian mode builds its LOD


def test_tolerance_reaches_the_adaptive_conversion(tmp_path):
    """A looser field tolerance gives Adaptive fewer Gaussians (a rough 16^3 field)."""
    noise = np.random.default_rng(3).random((16, 16, 16)).astype(np.float32) + 0.1
    path = str(write_grid(tmp_path / "noise.vdb", noise))
    out = str(tmp_path / "a.png")
    loose, tight = (render_json(path, "--lod", "adaptive", "--tolerance", t, "--size", "16x12",
                                "--out", out)["gaussians"] for t in ("0.5", "0.01"))
    assert 0 < loose < tight


@pytest.fixture(scope="module")
def two_ranges(tmp_path_factory):
    """Two files sharing a block of value 0.5 (x 0-5) beside a block (x 10-15) of 1.0 in one and
    0.25 in the other: their own ranges are 0.5-1 and 0.25-0.5, so 0.5 is the bottom of one and
    the top of the other."""
    d = tmp_path_factory.mktemp("ranges")
    paths = []
    for other in (1.0, 0.25):
        v = np.zeros((16, 4, 6), np.float32)
        v[:6] = 0.5
        v[10:] = other
        paths.append(str(write_grid(d / f"other_{other}.vdb", v, voxel_size=0.1)))
    return paths


def _shared_block(bpy, path):
    """The pixels where only the shared block is seen (its half of the image, looking along +y
    over the 4-voxel gap between the blocks)."""
    img = read_image(bpy, path)
    return img[:, : img.shape[1] * 5 // 16]


def test_range_gives_two_files_the_same_colours(bpy_module, two_ranges, tmp_path):
    view = ["--mode", "reference", "--size", "64x32", "--view", "0,1,0"]
    fixed, auto = [], []
    for k, path in enumerate(two_ranges):
        stats = render_json(path, *view, "--range", "0,1", "--out", str(tmp_path / f"fixed{k}.png"))
        assert stats["value_range"] == [0.0, 1.0]
        fixed.append(_shared_block(bpy_module, tmp_path / f"fixed{k}.png"))
        render_json(path, *view, "--out", str(tmp_path / f"auto{k}.png"))
        auto.append(_shared_block(bpy_module, tmp_path / f"auto{k}.png"))
    assert fixed[0][..., 3].max() > 0.2  # 0.5 of 0-1: drawn, half opaque by the ramp
    np.testing.assert_array_equal(fixed[0], fixed[1])
    # each file's own range colours 0.5 apart (the bottom of one, the top of the other)
    assert np.abs(auto[0] - auto[1]).max() > 0.2


def test_range_fixes_a_sequence(bpy_module, two_ranges, tmp_path):
    folder = tmp_path / "seq"
    folder.mkdir()
    for n, path in enumerate(two_ranges, 1):
        os.symlink(path, folder / f"f_{n:04d}.vdb")
    stats = render_json(str(folder / "f_####.vdb"), "--range", "0,4", "--size", "16x12",
                        "--out", str(tmp_path / "out" / "f_####.png"))
    assert [f["frame"] for f in stats["frames"]] == [1, 2] and stats["value_range"] == [0.0, 4.0]
