"""The warm-up table (kernels/warmup.py): which jobs a need maps to, the markers, the status file,
cancelling. No job runs here (tests/e2e/test_warmup_cli.py compiles a few)."""

import json
import os
import subprocess
import sys

import pytest
from conftest import ROOT

from kernels import lod_names, mode_names, warmup


def test_the_table_has_a_job_per_lod_and_mode_in_order():
    assert warmup.NAMES[0] == "reader"
    assert warmup.NAMES[1] == f"lod:{lod_names.DEFAULT}"
    assert {f"lod:{n}" for n in lod_names.PRESETS} | {"error"} | \
        {f"render:{m}" for m in mode_names.NAMES} | {"reader"} | \
        {f"render:{m}:general" for m in warmup.GENERAL} == set(warmup.NAMES)
    general = [n for n in warmup.NAMES if n.endswith(":general")]
    assert list(warmup.NAMES[-len(general):]) == general  # the plain scenes' kernels first
    # a first session's needs first: an import with the dialog's defaults, an F12 in the default mode
    assert warmup.NAMES[2:4] == ("error", f"render:{mode_names.DEFAULT}")


def test_jobs_for_a_need():
    assert warmup.jobs_for(lods=("medium",)) == ["reader", "lod:medium"]
    assert warmup.jobs_for(lods=("high", "low"), error=True) == ["reader", "lod:low", "lod:high", "error"]
    assert warmup.jobs_for(modes=("reference",)) == ["render:reference", "render:reference:general"]
    assert warmup.jobs_for(modes=("reference",), general=False) == ["render:reference"]
    assert warmup.jobs_for(modes="splat") == ["render:splat"]
    assert warmup.jobs_for() == []
    with pytest.raises(ValueError, match="unknown warm-up job 'lod:nope'; choose from reader"):
        warmup.jobs_for(lods=("nope",))
    assert warmup.check_names(["error", "reader", "error"]) == ["error", "reader"]


def test_markers_say_what_is_compiled(tmp_path):
    root = str(tmp_path)
    assert warmup.missing(["reader", "lod:low"], root=root) == ["reader", "lod:low"]
    warmup.mark_done("lod:low", 1.5, root=root)
    assert warmup.missing(["reader", "lod:low"], root=root) == ["reader"]
    assert warmup.is_done("lod:low", root=root)
    # beside the kernels of this identity, under the key of these sources, Python and numba
    assert warmup.marker_dir(root).startswith(os.path.join(root, "kernels", "warmup") + os.sep)
    assert warmup.cache_key() == warmup.cache_key() and len(warmup.cache_key()) == 12
    assert warmup.cache_size(root) > 0


def test_status_file_is_whole_json(tmp_path):
    path = str(tmp_path / "w" / "status.json")
    w = warmup.StatusWriter(path, ["reader", "lod:low"])
    w.progress(1, 2, "lod:low")
    w.done("reader", 2.0)
    st = warmup.read_status(path)
    assert st["pid"] == os.getpid() and st["name"] == "lod:low" and st["index"] == 1
    assert st["seconds"] == {"reader": 2.0} and st["state"] == "running"
    assert not [f for f in os.listdir(tmp_path / "w") if f.endswith(".tmp")]
    (tmp_path / "bad.json").write_text("{half")
    assert warmup.read_status(str(tmp_path / "bad.json")) == {}
    assert warmup.read_status(str(tmp_path / "none.json")) == {}


def test_cancel_before_a_job_runs_nothing(tmp_path):
    seen = []
    with pytest.raises(warmup.WarmupCancelled):
        warmup.run(["reader"], progress=lambda *a: seen.append(a), cancel=lambda: True)
    assert seen == []


def test_the_process_refuses_an_unknown_job_in_one_line(tmp_path):
    r = subprocess.run([sys.executable, os.path.join(ROOT, "kernels", "warmup_boot.py"), "--jobs",
                        "nope", "--cache-root", str(tmp_path)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 1
    assert r.stderr.strip().splitlines() == [
        f"gaussvdb warm-up: unknown warm-up job 'nope'; choose from {', '.join(warmup.NAMES)}"]


def test_import_as_names_the_kernels_after_the_extension(tmp_path):
    """The stub packages give the kernels the extension's module names without running its
    __init__ (bpy) and without loading numba."""
    code = ("import sys; sys.path.insert(0, %r)\n"
            "from kernels.warmup_boot import import_as\n"
            "w = import_as('bl_ext.user_default.gaussvdb')\n"
            "import json; print(json.dumps([w.__name__, w._identity(), 'bpy' in sys.modules, "
            "'numba' in sys.modules]))" % ROOT)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == ["bl_ext.user_default.gaussvdb.kernels.warmup",
                                    "bl_ext.user_default.gaussvdb", False, False]


def test_an_update_s_old_kernels_are_pruned(tmp_path):
    """Folders of other versions of a subpackage's sources, and other versions' markers, go;
    the current ones and anything not ours stay."""
    from kernels import cachedir

    base = tmp_path / warmup._identity()
    keep = [base / f"render-{cachedir.sources_tag('render')}" / "a.nbi",
            base / "warmup" / warmup.cache_key() / "reader.done", base / "notes" / "x.txt"]
    gone = [base / "render-000000000000" / "b.nbi", base / "vdb-111111111111" / "c.nbc",
            base / "warmup" / "oldkey" / "reader.done"]
    for f in keep + gone:
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_bytes(b"12345")
    assert warmup.prune_stale(str(tmp_path)) == 5 * len(gone)
    assert all(f.exists() for f in keep) and not any(f.parent.exists() for f in gone)


def test_a_pool_worker_answers_each_job_in_one_line():
    """warmup_pool.serve: one JSON answer per job name read (seconds, or the error in one line),
    and it returns at the end of its input."""
    import io

    from kernels import warmup_pool

    def job(name):
        if name == "bad":
            raise ValueError("no such grid")
        return 1.5

    out = io.StringIO()
    assert warmup_pool.serve(job, io.StringIO("reader\nbad\nlod:low\n"), out) == 0
    answers = [json.loads(line) for line in out.getvalue().splitlines()]
    assert answers == [{"job": "reader", "seconds": 1.5},
                       {"job": "bad", "error": "ValueError: no such grid"},
                       {"job": "lod:low", "seconds": 1.5}]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_stopping_a_pool_warm_up_ends_its_workers(tmp_path):
    """A warm-up on two processes, stopped (SIGTERM, as warmup_service.stop does) while both
    workers compile: the workers end with it, not after their job."""
    import time

    boot = os.path.join(ROOT, "kernels", "warmup_boot.py")
    status = tmp_path / "status.json"
    proc = subprocess.Popen([sys.executable, boot, "--package", "", "--cache-root", str(tmp_path),
                             "--jobs", "render:field,render:paper", "--processes", "2",
                             "--status", str(status)])
    children = f"/proc/{proc.pid}/task/{proc.pid}/children"
    try:
        deadline = time.time() + 60
        while time.time() < deadline and "+" not in warmup.read_status(str(status)).get("name", ""):
            time.sleep(0.1)  # until both workers have a job
        with open(children) as fh:
            workers = fh.read().split()
        assert len(workers) == 2
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    time.sleep(0.5)
    alive = [w for w in workers if os.path.exists(f"/proc/{w}")
             and open(f"/proc/{w}/stat").read().split()[2] != "Z"]
    assert not alive, f"workers {alive} outlived the stopped warm-up"
