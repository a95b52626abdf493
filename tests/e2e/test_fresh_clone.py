"""On a fresh clone, `render` and then `convert`, `info` (and `bench --quick`, in
test_bench_report) each succeed in their own process, and none writes compiled kernels into the
source tree (conftest.fresh_clone runs them)."""
import json
import os

import pytest
from test_kernel_identity import _compiled_files_in


@pytest.mark.slow
@pytest.mark.parametrize("command", ["render", "convert", "info"])
def test_command_succeeds_after_render(fresh_clone, command):
    _root, _env, runs, _tmp = fresh_clone
    r = runs[command]
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    assert "Traceback" not in r.stdout + r.stderr


@pytest.mark.slow
def test_outputs(fresh_clone):
    _root, _env, runs, tmp = fresh_clone
    assert (tmp / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    render = json.loads(runs["render"].stdout.strip().splitlines()[-1])
    assert render["gaussians"] > 0 and render["lod"] == "low"
    convert = json.loads(runs["convert"].stdout[runs["convert"].stdout.index("{"):])
    assert convert["gaussians"] > render["gaussians"]
    assert "density" in runs["info"].stdout


@pytest.mark.slow
def test_no_compiled_kernels_in_the_tree(fresh_clone):
    root = fresh_clone[0]
    assert not _compiled_files_in(root)
    assert not [d for d, _, _ in os.walk(os.path.join(root, "kernels")) if d.endswith("numba")]
