"""`./gaussvdb demo` on the bundled sample: the per-LOD table, the voxels' PNG (reference mode)
and one PNG per LOD with its PSNR against it."""

import json
import os
import subprocess
import sys

from conftest import ROOT


def test_demo_imports_every_lod_and_renders(tmp_path):
    out = tmp_path / "demo"
    # the suite's extensions folder: the demo reuses the suite's Blender set-up (and, through
    # GAUSSVDB_CACHE_DIR, the kernels it compiled)
    env = dict(os.environ, GAUSSVDB_BLENDER_EXTENSIONS=os.environ["BLENDER_USER_EXTENSIONS"])
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "cli.py"), "demo", "--json",
                           "--size", "32x24", "--out", str(out)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout[proc.stdout.index("{"):])
    density = {r["lod"]: r for r in result["rows"] if r["grid"] == "density"}
    assert list(density) == ["low", "medium", "high", "variance", "merged"]
    assert density["low"]["gaussians"] < density["medium"]["gaussians"] < density["high"]["gaussians"]
    assert 0 < density["high"]["nrmse"] < density["low"]["nrmse"] < 1
    assert "density:" in result["message"] and "field NRMSE" in result["message"]
    pngs = sorted(p.name for p in out.glob("density_*.png"))
    assert pngs == sorted(f"density_{lod}.png" for lod in [*density, "reference"])
    assert "the voxels, reference mode" in result["renders"][0]  # the first image
    db = result["image_psnr"]
    assert list(db) == list(density) and all(15.0 < v < 60.0 for v in db.values()), db
    assert db["high"] > db["low"]  # a finer LOD draws the voxels more closely
