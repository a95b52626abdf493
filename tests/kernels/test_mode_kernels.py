"""A frame compiles the kernels of its own mode only (cpu.per_mode): a reference frame runs no
Gaussian kernel and a particles frame no voxel or field kernel, so a first frame compiles a part
of the renderer, not all of it; a reference frame of one fog volume only the one-fog sampler, one
of two volumes only the general one (cpu.launch.kernel_code). Each case runs in a fresh process
on an empty kernel cache (a kernel loaded from the cache brings its callees' code without their
dispatchers, so only a compile lists them all), and the mode's band kernel draws the same bits on
1 and 2 threads."""
import json
import os
import subprocess
import sys
import textwrap

import pytest
from conftest import ROOT

GAUSSIAN = ("gauss.sweep_particles", "gauss.sweep_field", "gauss.trace_tiles", "gauss.trace_gauss",
            "pieces.paper_piece", "surface.mixture_normal")
VOXEL = ("pieces.reference_piece", "fog.reference_fog")

SCRIPT = """
import json, sys
import numpy as np
from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.scene.synthetic import grid_from_dense
from kernels.render.cpu import fog, gauss, pieces, surface

case = sys.argv[1]
mode = case.split(":")[0]  # "reference:two": two fog volumes (the general piece sampler)
x = np.arange(24) - 11.5
v = np.exp(-(x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2) / 40.0)
grid = grid_from_dense(v.astype(np.float32))
gs = None
if mode != "reference":
    from kernels.lod import build_lod
    gs = build_lod(grid, "low")
cam = Camera.frame_box([0.0] * 3, [24.0] * 3, 40, 32)
scene = RenderScene([RenderObject(gs, grid=grid)] * (2 if case.endswith(":two") else 1), mode=mode)
tf = TransferFunction.from_colormap("viridis", 0.0, 1.0)
images = [CPUDevice(threads=t).render(scene, cam, tf)["Combined"] for t in (1, 2)]
mods = dict(fog=fog, gauss=gauss, pieces=pieces, surface=surface)
compiled = {f"{m}.{f}": len(getattr(mods[m], f).signatures)
            for m, f in (n.split(".") for n in sys.argv[2:])}
print(json.dumps(dict(compiled=compiled, same=bool(np.array_equal(images[0], images[1])),
                      drawn=float(images[0][..., 3].max()))))
"""


def _frame(mode, cache):
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(SCRIPT), mode, *GAUSSIAN, *VOXEL],
                       cwd=ROOT, capture_output=True, text=True, timeout=900,
                       env=dict(os.environ, GAUSSVDB_CACHE_DIR=str(cache)))
    assert r.returncode == 0, r.stderr[-4000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("mode, used, unused", [
    ("reference", ("fog.reference_fog",), GAUSSIAN + ("pieces.reference_piece",)),
    ("reference:two", ("pieces.reference_piece",), GAUSSIAN + ("fog.reference_fog",)),
    ("particles", ("gauss.sweep_particles",), VOXEL + ("gauss.sweep_field", "pieces.paper_piece",
                                                       "surface.mixture_normal")),
])
def test_a_frame_compiles_its_own_mode_only(mode, used, unused, tmp_path):
    out = _frame(mode, tmp_path)
    assert out["drawn"] > 0.05, "the frame drew nothing: the check below would prove nothing"
    assert out["same"], "1 and 2 threads drew different bits"
    for name in used:
        assert out["compiled"][name] > 0, f"a {mode} frame did not run {name}"
    ran = [name for name in unused if out["compiled"][name]]
    assert not ran, f"a {mode} frame compiled (or loaded) kernels it does not use: {ran}"


def test_a_constant_mode_is_required():
    """The per-mode calls refuse a mode that is not a compile-time constant (one line that says
    where to draw from), rather than compiling every mode's code."""
    code = textwrap.dedent("""
        import numpy as np
        from numba import njit
        from kernels.render.cpu.pixels import gauss_normal
        @njit
        def f(mode):
            gauss_normal(mode, None, None, None, None, None, None)
        try:
            f(3)
        except Exception as err:
            print("refused:", "compile-time constant" in str(err))
    """)
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                       timeout=300, env=dict(os.environ))
    assert "refused: True" in r.stdout, r.stdout + r.stderr[-2000:]
