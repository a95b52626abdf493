"""`convert` and `render` of a sequence on a Dask cluster (tools/cluster.py): a LocalCluster and a
real `dask scheduler` with two `dask worker` processes on 127.0.0.1, against the serial run
(real processes, real files, bounded timeouts)."""

import json
import os
import pty
import select
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import DATA_DIR, ROOT, SAMPLE

pytest.importorskip("distributed")

CLI = os.path.join(ROOT, "tools", "cli.py")
FIRE = os.path.join(DATA_DIR, "mantaflow_fire_r96_f035.vdb")
TIMEOUT = 300


def _env():
    env = {k: v for k, v in os.environ.items() if k != "GAUSSVDB_DEBUG"}
    # the suite's extensions folder: Blender in the workers reuses the kernels the suite compiled
    env["GAUSSVDB_BLENDER_EXTENSIONS"] = os.environ["BLENDER_USER_EXTENSIONS"]
    return env


def cli(*argv, timeout=TIMEOUT):
    return subprocess.run([sys.executable, CLI, *argv], cwd=ROOT, env=_env(), capture_output=True,
                          text=True, timeout=timeout)


def json_line(stdout):
    return json.loads(next(ln for ln in stdout.splitlines() if ln.startswith("{")))


def write_sequence(folder, count, corrupt=()):
    """``count`` frames alternating copies of the Mantaflow smoke and fire grids (smoke only
    where the shared data is absent); a frame of ``corrupt`` is a truncated copy."""
    os.makedirs(folder, exist_ok=True)
    sources = [SAMPLE, FIRE] if os.path.isfile(FIRE) else [SAMPLE]
    for n in range(1, count + 1):
        dst = os.path.join(folder, f"m_{n:04d}.vdb")
        shutil.copyfile(sources[(n - 1) % len(sources)], dst)
        if n in corrupt:
            with open(dst, "r+b") as f:
                f.truncate(4096)
    return os.path.join(folder, "m_####.vdb")


def same_cache(a, b):
    """Two cache folders hold the same files with bit-identical arrays and metadata (np.savez
    stamps the zip entries with the time, so the files' bytes differ)."""
    names = sorted(n for n in os.listdir(a) if n.endswith(".npz"))
    assert names == sorted(n for n in os.listdir(b) if n.endswith(".npz"))
    for n in names:
        with np.load(os.path.join(a, n)) as za, np.load(os.path.join(b, n)) as zb:
            assert za.files == zb.files, n
            for k in za.files:
                x, y = za[k], zb[k]
                assert (x.dtype, x.shape) == (y.dtype, y.shape) and x.tobytes() == y.tobytes(), (n, k)
    return names


def same_images(a, b):
    """Two folders hold the same PNGs, pixel for pixel (the files carry a time stamp)."""
    import matplotlib.image as mpimg

    names = sorted(n for n in os.listdir(a) if n.endswith(".png"))
    assert names == sorted(n for n in os.listdir(b) if n.endswith(".png"))
    for n in names:
        x, y = mpimg.imread(os.path.join(a, n)), mpimg.imread(os.path.join(b, n))
        assert x.shape == y.shape and x.tobytes() == y.tobytes(), n
    return names


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    """A 6-frame sequence converted the serial way (2 threads): the reference."""
    tmp = tmp_path_factory.mktemp("cluster")
    pattern = write_sequence(str(tmp / "seq"), 6)
    proc = cli("convert", pattern, "--lod", "medium", "--cache-dir", str(tmp / "serial"),
               "--threads", "2", "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    return tmp, pattern


def test_local_cluster_equals_serial_then_skips(serial):
    tmp, pattern = serial
    cache = tmp / "local"
    proc = cli("convert", pattern, "--lod", "medium", "--cache-dir", str(cache), "--workers", "2",
               "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json_line(proc.stdout)
    assert len(same_cache(tmp / "serial", cache)) == 6
    assert [f["frame"] for f in res["frames"]] == list(range(1, 7))
    assert not res["errors"] and res["skipped"] == 0 and len(res["workers"]) == 2
    assert res["seconds_load"] > 0  # every worker loaded a frame's kernels before its first frame
    for f in res["frames"]:
        assert f["worker"] in res["workers"] and f["seconds"] > 0
        assert f["peak_rss_bytes"] >= f["rss_before_bytes"] > 0
    # the run's JSON beside the outputs: what was printed, written whole
    with open(res["run_json"]) as fh:
        assert json.load(fh)["frames"] == res["frames"]
    assert "\r" not in proc.stderr and "ETA" not in proc.stderr  # no bar when piped
    assert not [n for n in os.listdir(cache) if n.endswith(".tmp")]

    again = cli("convert", pattern, "--lod", "medium", "--cache-dir", str(cache), "--workers", "2",
                "--json")
    assert again.returncode == 0, again.stderr[-3000:]
    res2 = json_line(again.stdout)
    assert res2["skipped"] == 6 and all(f["skipped"] for f in res2["frames"])
    assert res2["workers"] == [] and "seconds_load" not in res2  # nothing to do: no cluster

    # a frame re-baked (another source): only that one is converted again
    rebaked = os.path.join(os.path.dirname(pattern), "m_0002.vdb")
    if os.path.isfile(FIRE):  # frame 2 is the fire: the smoke instead
        shutil.copyfile(SAMPLE, rebaked)
    else:  # frame 2 is the smoke already: a small Mantaflow-like bake
        from vdb_fixtures import write_mantaflow_like

        write_mantaflow_like(rebaked)
    third = json_line(cli("convert", pattern, "--lod", "medium", "--cache-dir", str(cache),
                          "--workers", "1", "--json").stdout)
    assert [f["frame"] for f in third["frames"] if not f.get("skipped")] == [2]
    shutil.copyfile(FIRE if os.path.isfile(FIRE) else SAMPLE,
                    os.path.join(os.path.dirname(pattern), "m_0002.vdb"))


def test_corrupt_frame_named_others_complete(tmp_path):
    pattern = write_sequence(str(tmp_path / "seq"), 5, corrupt=(3,))
    proc = cli("convert", pattern, "--grid", "density", "--lod", "medium", "--cache-dir",
               str(tmp_path / "cache"), "--workers", "2", "--json")
    assert proc.returncode == 1, proc.stderr[-3000:]
    res = json_line(proc.stdout)
    bad = [f for f in res["frames"] if f.get("error")]
    assert [f["frame"] for f in bad] == [3] and "m_0003.vdb" in bad[0]["error"]
    assert len(res["errors"]) == 1 and "frame 3" in res["errors"][0]
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("gaussvdb convert: error")]
    assert len(errors) == 1 and "m_0003.vdb" in errors[0]
    assert "Traceback" not in proc.stderr
    assert sorted(os.listdir(tmp_path / "cache")) == sorted(
        [f"m_000{n}.density.medium.npz" for n in (1, 2, 4, 5)] + ["m_####.density.medium.run.json"])


def test_progress_bar_on_a_terminal(tmp_path):
    pattern = write_sequence(str(tmp_path / "seq"), 4)
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, CLI, "convert", pattern, "--lod", "low",
                             "--cache-dir", str(tmp_path / "cache"), "--workers", "1", "--json"],
                            cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=slave)
    os.close(slave)
    seen, deadline = b"", time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # the terminal's other end closed: the command is done
                break
            if not chunk:
                break
            seen += chunk
        elif proc.poll() is not None:
            break
    os.close(master)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, seen.decode(errors="replace")[-3000:]
    text = seen.decode(errors="replace")
    assert "\r" in text and "4/4 frames" in text and "0/4 frames" in text and "ETA" in text
    assert "/s" in text  # a worker's frames per second
    assert json_line(out.decode())["skipped"] == 0


def _start(argv, env, log):
    return subprocess.Popen([sys.executable, "-m", *argv], cwd=str(log.parent), env=env,
                            stdout=open(log, "w"), stderr=subprocess.STDOUT)


def _wait(pred, timeout, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def dask_cluster(tmp_path):
    """A `dask scheduler` and two `dask worker` processes (no nanny: a killed one stays dead)
    on 127.0.0.1, one Dask thread and one numba thread each, the repository on their path
    through the tasks' preload, as the README's recipe starts them. Yields (address, [worker processes])."""
    env = dict(_env(), NUMBA_NUM_THREADS="1")
    sched_file = tmp_path / "scheduler.json"
    preload = os.path.join(ROOT, "tools", "cluster_tasks.py")
    procs = [_start(["distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
                     "--no-dashboard", "--scheduler-file", str(sched_file), "--preload", preload],
                    env, tmp_path / "scheduler.log")]
    try:
        _wait(sched_file.is_file, 60, "the scheduler")
        addr = json.loads(sched_file.read_text())["address"]
        workers = [_start(["distributed.cli.dask_worker", addr, "--nthreads", "1", "--no-nanny",
                           "--host", "127.0.0.1", "--no-dashboard", "--preload", preload], env,
                          tmp_path / f"worker{k}.log") for k in range(2)]
        procs += workers
        from distributed import Client

        with Client(addr, timeout=60) as c:
            c.wait_for_workers(2, timeout=120)
        yield addr, workers
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()


def test_scheduler_and_workers_equal_serial_survive_a_killed_worker(bpy_module, serial,
                                                                    dask_cluster, tmp_path):
    tmp, pattern = serial
    addr, workers = dask_cluster
    # conversion: the cluster's cache equals the serial one
    proc = cli("convert", pattern, "--lod", "medium", "--cache-dir", str(tmp_path / "cache"),
               "--scheduler", addr, "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert len(same_cache(tmp / "serial", tmp_path / "cache")) == 6
    assert len(json_line(proc.stdout)["workers"]) == 2

    # rendering, one worker SIGKILLed once the first image is out: every image still written,
    # each equal to the serial render's
    args = ["render", pattern, "--lod", "low", "--size", "160x120", "--json"]
    ref = cli(*args, "--out", str(tmp_path / "serial" / "f_####.png"), "--threads", "2")
    assert ref.returncode == 0, ref.stderr[-3000:]
    out = tmp_path / "cluster"
    run = subprocess.Popen([sys.executable, CLI, *args, "--out", str(out / "f_####.png"),
                            "--scheduler", addr], cwd=ROOT, env=_env(), stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        _wait(lambda: run.poll() is not None or (
            out.is_dir() and any(n.endswith(".png") for n in os.listdir(out))),
            TIMEOUT, "the first image")
        workers[0].send_signal(signal.SIGKILL)
        stdout, stderr = run.communicate(timeout=TIMEOUT)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, stderr[-3000:]
    res = json_line(stdout)
    assert len(same_images(tmp_path / "serial", out)) == 6 and not res["errors"]
    assert not [n for n in os.listdir(out) if ".tmp" in n]
    assert workers[0].wait(timeout=30) == -signal.SIGKILL


# One render worker's frames in one process, as a Dask worker runs them (cluster_tasks.render_frame
# called in turn), with what it holds printed after each frame.
_WORKER_FRAMES = r"""
import json, os, sys, tracemalloc
root, pattern, out, count = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
sys.path[:0] = [os.path.join(root, "tools"), root]
import cluster_tasks, cmd_render
args = cmd_render.parse([pattern, "--lod", "medium", "--size", "64x48", "--threads", "1",
                         "--out", os.path.join(out, "f_####.png")])
tracemalloc.start()
for f in range(1, count + 1):
    item = cluster_tasks.render_frame(args, "run", f, os.path.join(out, f"f_{f:04d}.png"))
    import bpy
    from blender_session import addon_module
    cache = addon_module("gaussvdb_addon.engine.sequence_frames").CACHE
    kinds = ("objects", "meshes", "pointclouds", "volumes", "images", "materials", "textures",
             "node_groups", "collections", "cameras", "lights", "worlds", "scenes")
    print(json.dumps({"frame": f, "error": item.get("error"), "gaussians": item.get("gaussians"),
                      "cache_entries": len(cache), "cache_bytes": cache.nbytes,
                      "datablocks": {k: len(getattr(bpy.data, k)) for k in kinds},
                      "orphans": sum(1 for k in kinds for d in getattr(bpy.data, k) if d.users == 0),
                      "traced_bytes": tracemalloc.get_traced_memory()[0],
                      "rss_bytes": item["rss_after_bytes"]}), flush=True)
"""


def test_render_worker_memory_does_not_grow_with_frames(tmp_path):
    """A render worker keeps its Blender session across frames; what it holds after a frame is
    one frame's, not every frame's it has drawn: the engine's frame cache keeps one entry, no
    datablock is added or orphaned, the memory Python allocators (numpy included) hold and the
    resident memory are those of two frames earlier (the same source file)."""
    n = 6
    pattern = write_sequence(str(tmp_path / "seq"), n)
    proc = subprocess.run([sys.executable, "-c", _WORKER_FRAMES, ROOT, pattern,
                           str(tmp_path / "out"), str(n)], cwd=ROOT, env=_env(),
                          capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = [json.loads(ln) for ln in proc.stdout.splitlines() if ln.startswith('{"frame"')]
    assert [r["frame"] for r in rows] == list(range(1, n + 1))
    assert all(not r["error"] and r["gaussians"] > 0 for r in rows)
    assert sorted(os.listdir(tmp_path / "out")) == [f"f_{f:04d}.png" for f in range(1, n + 1)]
    for r in rows:
        assert r["cache_entries"] == 1, r  # the frame being drawn, not the ones before
        assert r["datablocks"] == rows[0]["datablocks"] and r["orphans"] == 0, r
    for a, b in zip(rows[1:], rows[3:]):  # frames 2 and 4, 3 and 5, 4 and 6: the same source file
        assert b["cache_bytes"] == a["cache_bytes"], (a, b)
        # the engine's and the device's buffers of one frame, whichever frame it is
        assert b["traced_bytes"] - a["traced_bytes"] < 256 * 1024, (a, b)
    # resident memory: settled after the second frame (allowance for the allocators)
    assert rows[-1]["rss_bytes"] - rows[1]["rss_bytes"] < 48 * 2**20, rows
