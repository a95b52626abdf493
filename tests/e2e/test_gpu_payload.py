"""What each run on the GPU machine carries (the working tree, one folder of the packed cases of
the shared files, every mode and LOD at 512x512 and 1920x1080, the moderngl/glcontext wheels and
the EGL/GL packages) stays under the 64 MiB a call may carry, with gpu_real.MARGIN to spare, and
the folders together hold every shared case.

Making every case takes far longer than a test may (each LOD of each file built, the CPU device's
image of each case drawn), so the folders' sizes come from the record the full set's commands
wrote (benchmarks/gpu_payload.json: ``python benchmarks/gpu_cases.py .cases`` then ``python
benchmarks/gpu_pack.py .cases .carry --record benchmarks/gpu_payload.json``); the working tree is
measured now, and one small case is made again here and must still have its recorded size (a
change to what a case holds fails it: then make the set and the record again)."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import DATA_DIR, ROOT

sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
import gpu_cases  # noqa: E402
import gpu_real  # noqa: E402

RECORD = os.path.join(ROOT, "benchmarks", "gpu_payload.json")
SMALL = ("mantaflow_fire_r96_f035.vdb", "reference", "voxels")


def _record():
    with open(RECORD) as f:
        return json.load(f)


def _shared():
    if not os.path.isdir(DATA_DIR):
        pytest.skip("no shared data")
    return sorted(os.path.join(DATA_DIR, f) for f in os.listdir(DATA_DIR) if f.endswith(".vdb"))


def test_the_record_covers_every_shared_case():
    carried = {n for g in _record()["groups"] for n in g["names"]}
    missing = []
    for src, mode, lod in gpu_cases.shared_cases(_shared(), gpu_cases.MODES, ["low", "medium", "high"]):
        name = gpu_cases.case_name(src, mode, lod)
        if name not in carried and name[:-4] + ".fallback.json" not in carried:
            missing.append(name)
    assert not missing, f"cases in no folder of {RECORD}: {missing}"


def test_each_call_fits():
    """Each folder gpu_pack.py made, with the working tree as it is now and the wheels and GL
    packages (measured where present here, else as recorded), under the limit less the margin."""
    rec = _record()
    fixed = gpu_real.tree_bytes()
    for name in (".whl", ".gl"):
        fixed += gpu_real.folder_bytes(os.path.join(ROOT, name)) or rec["fixed"][name]
    assert rec["fixed"][".whl"] > 0, "the record must count the wheels (gpu_real.py prepare first)"
    over = [(g["folder"], round((fixed + g["bytes"]) / 2 ** 20, 1)) for g in rec["groups"]
            if fixed + g["bytes"] > gpu_real.CARRY_LIMIT - gpu_real.MARGIN]
    assert not over, f"calls past {(gpu_real.CARRY_LIMIT - gpu_real.MARGIN) / 2 ** 20} MiB: {over}"


def test_packed_cpu_image_round_trip(tmp_path):
    from kernels.render.gpu import case as gpu_case

    rng = np.random.default_rng(1)
    img = (rng.random((6, 5, 4)) ** 3).astype(np.float32)
    img[0] = 0.0
    packed = gpu_case.pack_image(img)
    assert packed.dtype == np.uint8 and packed.shape == (4, img.size)
    back = gpu_case.unpack_image(packed, img.shape)
    assert np.all(np.abs(back - img) <= img * 2.0 ** -(gpu_case.CPU_BITS + 1))
    assert np.array_equal(back[0], img[0])
    import gl_backend  # the standalone backend reads it the same way

    path = tmp_path / "c.npz"
    info = {"views": [{"name": "5x6", "width": 5, "height": 6}]}
    np.savez_compressed(path, **{"case.json": np.array(json.dumps(info)), "5x6.cpu": packed})
    assert np.array_equal(gl_backend.Case(str(path)).cpu("5x6"), back)


@pytest.mark.slow
def test_a_small_case_has_its_recorded_size(tmp_path):
    src = os.path.join(DATA_DIR, SMALL[0])
    if not os.path.exists(src):
        pytest.skip("no shared data")
    name = gpu_cases.case_name(src, SMALL[1], SMALL[2])
    r = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "gpu_cases.py"), str(tmp_path), src,
                        "--modes", SMALL[1], "--lods", "low"], cwd=ROOT, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    size, recorded = os.path.getsize(tmp_path / name), _record()["saved"][name]
    assert abs(size - recorded) <= 0.05 * recorded + 65536, (size, recorded)


def test_packed_folder_reads_back_the_saved_tables(tmp_path):
    """gpu_pack.py's pool (tables stored once, as byte planes) gives gl_backend.Case the arrays
    the cases saved, bit for bit."""
    import gl_backend
    import gpu_pack

    rng = np.random.default_rng(2)
    big = rng.random((40, 512, 4)).astype(np.float32)  # past POOL_MIN: pooled, shared
    info = {"views": [{"name": "8x8", "width": 8, "height": 8}]}
    src = tmp_path / "src"
    src.mkdir()
    for i in range(2):
        own = rng.random((3, 4)).astype(np.float32)
        np.savez_compressed(src / f"f.m{i}.low.npz", **{"t.big": big, "t.own": own, "8x8.t.own": own + 1,
                                                          "case.json": np.array(json.dumps(info))})
    gpu_pack.write(sorted(str(p) for p in src.glob("*.npz")), str(tmp_path / "dst"))
    for i in range(2):
        with np.load(src / f"f.m{i}.low.npz") as z:
            want = {"big": z["t.big"], "own": z["8x8.t.own"]}  # (the view's own table first)
        case = gl_backend.Case(str(tmp_path / "dst" / f"f.m{i}.low.npz"))
        assert case.pooled == {"t.big": gpu_pack._key(big)}
        got = case.tables("8x8")
        assert set(got) == set(want) and all(np.array_equal(got[k], want[k]) for k in want)
    gl_backend._POOLS.clear()
