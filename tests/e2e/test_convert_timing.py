"""`gaussvdb convert --json` accounts for its whole run: every phase, and a total that matches the
command's wall time measured from outside."""

import json
import os
import time

import pytest

from tests.conftest import ROOT, run_cli

SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")
PHASES = ("seconds_start", "seconds_topology", "seconds_read", "seconds_prepare", "seconds_compile",
          "seconds_build", "seconds_error", "seconds_encode", "seconds_write")


@pytest.mark.parametrize("extra", [[], ["--no-error"]])
def test_phases_sum_to_a_total_that_matches_the_wall_time(extra, tmp_path):
    t0 = time.perf_counter()
    p = run_cli(ROOT, "convert", SAMPLE, "--lod", "medium", "--json", "--out",
                str(tmp_path / "m.npz"), *extra)
    wall = time.perf_counter() - t0
    assert p.returncode == 0, p.stderr
    res = json.loads(p.stdout)
    assert all(res[k] >= 0.0 for k in PHASES)
    assert res["seconds_build"] > 0 and res["seconds_encode"] > 0 and res["seconds_write"] > 0
    assert (res["seconds_error"] > 0) == (not extra)
    assert abs(res["seconds_total"] - wall) <= 0.1 * wall, (res["seconds_total"], wall)
    assert abs(sum(res[k] for k in PHASES) + res["seconds_other"] - res["seconds_total"]) < 1e-9
    # the process start is known to a clock tick (10 ms): seconds_start may be a tick long
    assert -0.02 <= res["seconds_other"] <= 0.05 * res["seconds_total"]
    conv = res["seconds_build"] + res["seconds_error"] + res["seconds_encode"]
    assert res["seconds_convert"] == pytest.approx(conv)
    assert res["mvoxels_per_second"] == pytest.approx(
        res["active_voxels"] / (res["seconds_read"] + conv) / 1e6)
