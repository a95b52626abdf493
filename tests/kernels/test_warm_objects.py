"""The synthetic scenes a device's load_kernels draws (kernels/render/scene/synthetic.py): their
Gaussians equal what build_lod makes of the same block, and drawing them compiles no LOD kernel
(a render's warm-up runs beside an import that compiles those itself)."""
import dataclasses
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from conftest import ROOT

from kernels.lod import build_lod
from kernels.lod.synthetic import full_block_set, grid_from_dense


@pytest.mark.parametrize("shape", [(16, 8, 8), (8, 24, 16)])
@pytest.mark.parametrize("lod, edge", [("low", 8), ("high", 2)])
def test_full_block_sets_equal_build_lod(shape, lod, edge):
    made = build_lod(grid_from_dense(np.ones(shape, np.float32)), lod)
    ours = full_block_set(shape, edge, lod)
    assert ours.count == made.count > 0
    for f in dataclasses.fields(made):
        if f.name == "params":  # the LOD's build settings: no render reads them
            continue
        a, b = getattr(made, f.name), getattr(ours, f.name)
        if isinstance(a, np.ndarray):  # numba's type: dtype, dimensions and layout
            assert a.dtype == b.dtype and np.array_equal(a, b), f.name
            assert a.flags.c_contiguous == b.flags.c_contiguous, f.name
        else:
            assert a == b, f.name


SCRIPT = """
import json, sys
from numba.core.registry import CPUDispatcher
from kernels.render import CPUDevice
CPUDevice(threads=1).load_kernels(modes=(sys.argv[1],), variants=("plain",))
lod = {f"{m}.{n}": len(d.signatures) for m, mod in list(sys.modules.items())
       if m.startswith("kernels.lod") for n, d in vars(mod).items() if isinstance(d, CPUDispatcher)}
from kernels.render.cpu import gauss
print(json.dumps(dict(lod=lod, sweep=len(gauss.sweep_particles.signatures))))
"""


def test_a_render_warm_up_compiles_no_lod_kernel(tmp_path):
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(SCRIPT), "particles"], cwd=ROOT,
                       capture_output=True, text=True, timeout=900,
                       env=dict(os.environ, GAUSSVDB_CACHE_DIR=str(tmp_path)))
    assert r.returncode == 0, r.stderr[-4000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["sweep"] > 0, "the particles warm-up drew no Gaussians: the check proves nothing"
    assert out["lod"], "no LOD module was seen: the check proves nothing"
    assert not {k: v for k, v in out["lod"].items() if v}
