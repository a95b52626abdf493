"""The GPU machine's run is one call: it carries the working tree, the shared .vdb files (.data),
the wheels its Python lacks (.whl: moderngl, glcontext, blosc) and the EGL/GL packages (.gl), under
the 64 MiB a call may carry with gpu_real.MARGIN to spare, and makes every shared case there
(gpu_cases.build, no Blender) before timing them."""
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

# what `gpu_real.py prepare` left in .whl and the .gl packages weighed (bytes), for a checkout
# that has not prepared them
RECORDED = {".whl": 3_085_842, ".gl": 376_104}
LODS = ["low", "medium", "high"]


def _shared():
    files = gpu_real.shared_files()
    if not files:
        pytest.skip("no shared data")
    return files


def test_the_one_call_fits():
    """The working tree as it is now, the shared files (those in .data where prepared, else the
    shared folder's), the wheels and the GL packages (measured where present, else as recorded)."""
    files = _shared()
    parts = {"working tree": gpu_real.tree_bytes(),
             ".data": gpu_real.folder_bytes(os.path.join(ROOT, gpu_real.DATA))
             or sum(os.path.getsize(f) for f in files)}
    for name in (".whl", ".gl"):
        parts[name] = gpu_real.folder_bytes(os.path.join(ROOT, name)) or RECORDED[name]
    total = sum(parts.values())
    assert total <= gpu_real.CARRY_LIMIT - gpu_real.MARGIN, {k: round(v / 2 ** 20, 1) for k, v in parts.items()}
    if os.path.isdir(os.path.join(ROOT, gpu_real.DATA)):  # what payload reports is the same sum
        assert gpu_real.payload()["total"] == total


def test_every_shared_case_is_made_there():
    """build's units (a file's LOD each, reference with Low's load) hold every shared case once,
    largest first."""
    files = _shared()
    cases = list(gpu_cases.shared_cases(files, gpu_cases.MODES, LODS))
    assert len(cases) == len(files) * (1 + 4 * len(LODS))
    us = gpu_cases.largest_first(gpu_cases.units(cases))
    assert len(us) == len(files) * len(LODS)
    flat = [c for _, cs in us for c in cs]
    assert sorted(flat) == sorted(cases)
    for (src, lod), cs in us:
        assert all(c[0] == src and (c[2] == lod or (c[2] == "voxels" and lod == "low")) for c in cs)
    biggest = max(files, key=os.path.getsize)
    assert us[0][0] == (biggest, "high")


def test_cores_shared_out():
    assert gpu_cases.share_cores(8, cores=16) == (8, 2)
    assert gpu_cases.share_cores(3, cores=16) == (3, 5)
    assert gpu_cases.share_cores(4, 3, cores=16) == (4, 3)
    assert gpu_cases.share_cores(32, cores=16) == (32, 1)


def test_the_run_script_parses():
    r = subprocess.run(["sh", "-n", os.path.join(ROOT, "benchmarks", "gpu_real.sh")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


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
def test_cases_made_without_blender_in_two_processes(tmp_path):
    """The fire's cases as the GPU machine makes them: no bpy in any process (a bpy that fails to
    import comes first on the path), two processes after the kernels are compiled in one; each
    case reads back in the standalone backend with its 512x512 CPU image."""
    src = os.path.join(DATA_DIR, "mantaflow_fire_r96_f035.vdb")
    if not os.path.exists(src):
        pytest.skip("no shared data")
    block = tmp_path / "block"
    block.mkdir()
    (block / "bpy.py").write_text("raise ImportError('bpy imported')\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(block), ROOT]))
    out = tmp_path / "cases"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "gpu_cases.py"), str(out), src,
                        "--modes", "reference,splat", "--lods", "low,medium", "--sizes", "512x512",
                        "--jobs", "2", "--threads", "1"], cwd=ROOT, capture_output=True, text=True,
                       timeout=900, env=env)
    assert r.returncode == 0, r.stderr[-3000:]
    rec = json.loads((out / "build.json").read_text())
    assert rec["jobs"] == 2 and rec["cases"] == 3 and not rec["skipped"] and rec["warm_seconds"] is not None
    import gl_backend

    for name in json.loads((out / "sizes.json").read_text()):
        case = gl_backend.Case(str(out / name))
        assert case.cpu("512x512").shape == (512, 512, 4)
