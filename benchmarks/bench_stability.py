"""Issue 8 numerical-stability sweeps: larger versions of tests/kernels/test_stability_kernels.py's cases.
Prints one row per case: worst error found, the reference it was measured against, the tolerance
and PASS/FAIL (FAIL rows are known bugs, see the xfail marks in the tests).

  ./gaussvdb bench stability [--quick]
  ./gaussvdb bench stability
"""
from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for p in (ROOT, os.path.join(ROOT, "tests"), os.path.join(ROOT, "tools")):
    if p not in sys.path:
        sys.path.insert(0, p)

import cli_errors  # noqa: E402  (after the sys.path set-up above)


def _nan_inf_row():
    """Reader + LOD on a file with NaN, +Inf, -Inf voxels: non-finite Gaussian values that reach the
    renderer (0 = sanitized or refused)."""
    import numpy as np
    from vdb_fixtures import write_nan_inf

    from kernels.lod import build_lod
    from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
    from kernels.vdb import read_vdb

    tmp = tempfile.mkdtemp(prefix="gaussvdb-bench-")
    atexit.register(shutil.rmtree, tmp, True)
    path = write_nan_inf(os.path.join(tmp, "naninf.vdb"))
    grid = read_vdb(path).grids[0]
    bad = 0
    value_bad = 0
    for p in ("low", "medium", "high"):
        gs = build_lod(grid, p)
        bad += int((~np.isfinite(gs.values)).sum())
        out = CPUDevice().render(RenderScene([RenderObject(gs)]), Camera.frame_box([0] * 3, [8] * 3, 12, 12),
                                 TransferFunction.from_colormap("viridis", 0, 1))
        value_bad += int((~np.isfinite(out["Value"])).sum())
    return bad + value_bad, f"{bad} non-finite Gaussian values, {value_bad} non-finite Value pixels"


def main(argv=None) -> int:
    ap = cli_errors.ArgumentParser(prog="gaussvdb bench stability", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the test-suite sizes only")
    a = ap.parse_args(argv or [])
    import numpy as np
    import test_stability_kernels as K

    big = not a.quick
    rows = []

    def row(case, worst, ref, tol, ok=None):
        ok = (worst <= tol) if ok is None else ok
        rows.append((case, worst, ref, tol, "PASS" if ok else "FAIL"))
        print(f"{case:<52} {worst:>11.3e}  {ref:<44} {tol:>8.1e}  {'PASS' if ok else 'FAIL'}", flush=True)

    t0 = time.perf_counter()
    print(f"{'case':<52} {'worst err':>11}  {'reference':<44} {'tol':>8}  result")
    w, ref, tol, _ = K.case_line_integrals(n_random=400 if big else 10)
    row("line integral: tiny sigma, aniso 1e3-1e4, t*=0, tails", w, "mpmath 50 digits (erfc form)", tol)
    w, _, _, _ = K.case_line_integrals(n_random=0, short_h=(1e-15, 1e-12, 1e-10, 1e-8), stiff=False)
    row("line integral: ulp-scale segments h=1e-15..1e-8", w, "mpmath 50 digits (erfc form)", 1e-5)
    rng = np.random.default_rng(1)
    import mpmath
    worst = 0.0
    for _ in range(3000 if big else 200):
        u0 = rng.uniform(-25, 25)
        u1 = u0 + 10 ** rng.uniform(-6, 1.5)
        ref_ = K.mp_erf_diff(u0, u1)
        worst = max(worst, K.rel_err(K._k().erf_diff(u0, u1), ref_))
    row("erf_diff |u| <= 25, h >= 1e-6", worst, "mpmath 50 digits (erfc form)", 1e-5)
    worst = 0.0
    for _ in range(500 if big else 50):
        taus = list(10 ** rng.uniform(-14, 7, rng.integers(1, 40)))
        cols = [tuple(c) for c in rng.uniform(0, 1, (len(taus), 3))]
        T, L = K.case_composite(taus, cols)
        refL = np.zeros(3)
        Tr = 1.0
        for tau, c in zip(taus, cols):
            refL += Tr * float(-mpmath.expm1(-mpmath.mpf(tau))) * np.asarray(c)
            Tr *= np.exp(-tau)
        mono = np.all(np.diff(T) <= 0) and T.min() >= 0 and T.max() <= 1
        worst = max(worst, float(np.max(np.abs(L - refL) / np.maximum(refL, 1e-300))), 0.0 if mono else 1.0)
    row("composite: tau 1e-14..1e7, T in [0,1] monotone", worst, "float64 sum with mpmath expm1", 1e-12)
    for mode in ("particles", "field"):
        jump, err, _ = K.case_faces(n_shift=(0.0, 1e-6, -1e-6, 1e-9) if big else (0.0, 1e-6),
                                    size=24, mode=mode)
        row(f"{mode}: rays on voxel/leaf/node faces vs +-1e-6", jump, "same scene, perturbed rays", 1e-4)
        if mode == "particles":
            row("particles: rays on faces vs closed form", err, "numpy float64 closed form", 1e-6)
    err, same, _ = K.case_ties(n=8 if big else 6)
    row("exact ties: ortho along axis of a lattice", err, "numpy float64 closed form", 1e-6)
    row("exact ties: 1 vs 2 threads (0 = bitwise equal)", 0.0 if same else 1.0, "bitwise", 0.0)
    for kind in ("persp", "ortho"):
        row(f"camera inside a Gaussian / the volume ({kind})", K.case_inside(kind), "numpy float64 closed form", 1e-6)
    for d in ((1e5, 1e6, 1e7) if big else (1e5, 1e7)):
        for mode in ("particles", "field"):
            row(f"{mode}: translate scene+camera by {d:.0e} voxels", K.case_translation(d, mode),
                "same scene at the origin", 1e-4)
    for s in ((1e-3, 0.1, 10.0, 100.0) if big else (0.1, 10.0)):  # 1e3: see the report (accel OOM)
        for mode, tol in (("particles", 5e-5), ("field", 1e-3), ("paper", None)):
            err, _ = K.case_scale(s, mode)
            if mode == "paper":
                row(f"paper: world x{s:g}, density /{s:g} (must fail)", err, "same scene at scale 1", 1e-4,
                    ok=err > 0.05)
            else:
                row(f"{mode}: world x{s:g}, density /{s:g}", err, "same scene at scale 1", tol)
    errs, order, _ = K.case_field_convergence(steps=(1.0, 0.5, 0.25, 0.125, 0.0625) if big else (1.0, 0.5, 0.25))
    row(f"field dt->0: err(dt={0.0625 if big else 0.25}), order {order:.2f}", errs[-1],
        "fine quadrature (4e5 steps)", 1e-3, ok=order > 1.5)
    errs, order, _ = K.case_particles_convergence(
        tau_maxes=(0.8, 0.4, 0.2, 0.1, 0.05, 0.025, 0.0125) if big else (0.8, 0.4, 0.2))
    row(f"particles tau_max->0: order {order:.2f}", errs[-1], "fine quadrature (4e5 steps)", 2e-3,
        ok=order > 1.2)
    try:
        bad, text = _nan_inf_row()
        row("NaN/+-Inf voxels: non-finite after LOD/render", float(bad), text, 0.0)
    except Exception as err:  # noqa: BLE001 (no bpy/openvdb: skip the row)
        print(f"NaN/Inf row skipped: {err}")
    fails = [r for r in rows if r[4] == "FAIL"]
    print(f"\n{len(rows)} cases, {len(fails)} FAIL, {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(cli_errors.run("gaussvdb bench stability", main, sys.argv[1:]))
