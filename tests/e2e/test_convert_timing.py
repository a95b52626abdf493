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


def test_adaptive_rounds_on_a_terminal_only(tmp_path):
    """On a terminal, `convert --lod adaptive` reports each round on stderr as it ends (a long
    conversion is not silent); piped, stderr stays free of them (scripts parse it)."""
    import pty
    import subprocess
    import sys
    import threading

    args = [sys.executable, os.path.join(ROOT, "tools", "cli.py"), "convert", SAMPLE, "--lod",
            "adaptive", "--tolerance", "0.05", "--json", "--no-error"]
    leader, follower = pty.openpty()
    chunks = []

    def drain():  # read as it comes: a full terminal buffer would block the command
        while True:
            try:
                chunk = os.read(leader, 65536)
            except OSError:  # the other end is closed: all read
                return
            if not chunk:
                return
            chunks.append(chunk)

    reader = threading.Thread(target=drain)
    reader.start()
    try:
        p = subprocess.run(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=follower, timeout=900)
    finally:
        os.close(follower)
        reader.join(timeout=60)
        os.close(leader)
    err = b"".join(chunks)
    assert p.returncode == 0, err
    res = json.loads(p.stdout)
    lines = [s for s in err.decode().splitlines() if ", round " in s]
    assert len(lines) == res["rounds"] >= 2
    assert lines[-1].startswith(f"gaussvdb convert: density: Adaptive LOD, round {res['rounds']}: ")
    piped = run_cli(ROOT, *args[2:])
    assert piped.returncode == 0 and ", round " not in piped.stderr
