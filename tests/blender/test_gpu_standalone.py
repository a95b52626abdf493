"""The GPU device's shaders outside Blender (benchmarks/gl_backend.py: plain OpenGL 4.3 on
moderngl, a headless EGL context, in a process of its own with no bpy) draw the frame the GPU
device saved (kernels/render/gpu/case.py) to the image Blender's ``gpu`` module draws, bit for bit
(Combined, Depth, Value; llvmpipe here), in every mode on a fog volume, a level set, two objects, a
lit volume (with shadows) and a volume coloured by a second grid: the shaders come from one
assembly (kernels/render/gpu/assembly.py) in both."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("moderngl")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
import gpu_cases  # noqa: E402

CASES = [(name, mode) for name in gpu_cases.SYNTHETIC for mode in gpu_cases.MODES]


def _stem(name, mode):
    return f"{name.replace(' ', '_')}.{mode}"


@pytest.fixture(scope="module")
def drawn(gpu, tmp_path_factory):
    """Per case: the GPU device's passes, and the standalone backend's (one process for all)."""
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.gpu.device import GPUDevice

    tmp = tmp_path_factory.mktemp("standalone")
    blender = {}
    for name, mode in CASES:
        sc, cam, tf = gpu_cases.synthetic_scene(name, mode)
        out = gpu.render(sc, cam, tf)
        assert "fallback" not in gpu.stats, (name, mode, gpu.stats.get("fallback"))
        assert gpu.stats.get("overflow_tiles", 0) == 0
        blender[name, mode] = out
        why = gpu_cases.save_case(GPUDevice(), str(tmp / f"{_stem(name, mode)}.npz"), sc, [cam], tf, {})
        assert why is None
    env = {k: v for k, v in os.environ.items() if not k.startswith("BLENDER_")}
    run = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "gl_backend.py"),
                          *sorted(str(p) for p in tmp.glob("*.npz")), "--out", str(tmp / "out")],
                         capture_output=True, text=True, env=env, timeout=1800)
    assert run.returncode == 0, run.stderr[-3000:]
    report = [json.loads(line) for line in run.stdout.splitlines() if line.startswith("{")]
    assert len(report) == len(CASES) and all(r["overflow_tiles"] == 0 for r in report)
    return blender, {c: np.load(tmp / "out" / f"{_stem(*c)}.npz") for c in CASES}, report


@pytest.mark.parametrize("name, mode", CASES)
def test_standalone_backend_draws_blenders_image(drawn, name, mode):
    blender, standalone, _ = drawn
    want, got = blender[name, mode], standalone[name, mode]
    assert want["Combined"][..., 3].max() > 0.1  # something drawn
    np.testing.assert_array_equal(got["rgba"], want["Combined"])
    np.testing.assert_array_equal(got["dv"][..., 0], want["Depth"])
    np.testing.assert_array_equal(got["dv"][..., 1], want["Value"])


def test_one_assembly_declares_what_the_create_info_declares():
    """glsl_assembly's GLSL 4.30 header: every sampler, image and push constant of the Program at
    its slot, the defines before the source, the work group; nothing the .glsl files declare."""
    from kernels.render.gpu import assembly as asm

    p = asm.mode_program("reference", "reference.glsl", ("WALK",),
                         {"frame": "FLOAT_2D", "atlas": "FLOAT_3D"}, {"n_obj": 1, "atlas_sx": 2})
    head = asm.glsl_430_header(p)
    assert head.startswith("#version 430\n")
    assert "layout(binding = 0) uniform sampler3D atlas;" in head  # sorted: atlas, frame
    assert "layout(binding = 1) uniform sampler2D frame;" in head
    assert "layout(binding = 1, rgba32f) uniform writeonly image2D out_dv;" in head
    assert "uniform int atlas_sx;" in head and "#define MODE_reference 1" in head
    assert "layout(local_size_x = 8, local_size_y = 8) in;" in head
    assert asm.on_renderer(p, "llvmpipe (LLVM 15)") == p  # reference: no ONE_PER_GROUP
    g = asm.mode_program("paper", ("gauss.glsl", "paper.glsl"), ("ONE_PER_GROUP",), {}, {"n_obj": 3})
    assert asm.on_renderer(g, "llvmpipe (LLVM 15)").local_size == (1, 1)
    assert asm.on_renderer(g, "NVIDIA H200/PCIe/SSE2").local_size == (8, 8)
    assert ("MAX_OBJ", "4") in g.defines  # three objects: arrays of four
    assert asm.from_json(asm.to_json(g)) == g
    body = asm.source(g)
    assert "#version" not in body and "layout(" not in body
