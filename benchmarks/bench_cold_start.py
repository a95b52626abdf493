"""Cold start: the seconds to a first import and a first frame with no compiled kernels, and again
with the kernels cached.

    ./gaussvdb bench cold_start [--only kernels,blender,cli,demo,compat] [--modes reference,particles,...]
                                [--lods low,medium,high,adaptive] [--cli-modes reference,particles]
                                [--size 256x256] [--timeout 900] [--json FILE]
    ./gaussvdb bench cold_start --only cpu [--modes particles,field,reference] [--size 512x512]
    ./gaussvdb bench cold_start --only stamps

Every case runs in a fresh process on a fresh, empty cache folder (GAUSSVDB_CACHE_DIR), then in a
second fresh process on the same folder (warm). On the bundled sample
(samples/mantaflow_smoke_r128_f040.vdb), three ways:

- kernels: plain kernels in Python: the first import per LOD (read_vdb + build_lod), the first frame
  per mode (read + Medium, then CPUDevice().render at --size);
- blender: the add-on in the bpy module: the import operator (gaussvdb.import_vdb) per LOD, and an
  F12 (render.render(write_still=True), GAUSSVDB engine) per mode after a Medium import; the
  add-on's kernels load under its own module name, so they have their own cache entries;
- cli: the whole process of `./gaussvdb render SAMPLE --mode M --out X.png` (--cli-modes), and
  `./gaussvdb demo` up to its first image (demo);
- compat (only when asked: --only compat): the blender cases in the oldest supported Blender (the
  compat environment's bpy module, `GAUSSVDB_COMPAT_VENV` or .venv-compat), from this platform's
  zip installed into a fresh user folder, as a user has it (the zip's own numba wheels).

Per case: the seconds of the step, numba's compile seconds in it (the "numba:compile" events,
nested compiles counted once) and the functions compiled (every compile event, nested ones too),
the whole process's seconds, and the issue's target beside it. Steps before the measured one
(starting Blender, the import before an F12) are in --json.

--only cpu: the cache compiled for a generic CPU of this architecture (NUMBA_CPU_NAME=generic,
portable across CPUs) against the host-tuned one: compile seconds cold, then warm the Medium
import's seconds and ms per frame (best of --repeat) per mode, host and generic alternating.

--only stamps: the first import at Medium from a copy of kernels/: cold, warm, after every file
is rewritten with a new mtime (a reinstall), with numba's stamp as installed and with numba < 0.68's
(mtime, size) stamp for locators that take numba's, then after one file of vdb/ and of lod/ changes.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

try:
    import resource
except ImportError:  # Windows
    resource = None

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for _p in (ROOT, os.path.join(ROOT, "tools")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import cli_errors  # noqa: E402  (after the sys.path set-up above)

SAMPLE = os.path.join(ROOT, "samples", "mantaflow_smoke_r128_f040.vdb")
WAYS = ("kernels", "blender", "cli", "demo")
ALL_MODES = ("reference", "splat", "particles", "field", "paper")
ALL_LODS = ("low", "medium", "high", "adaptive")

# The targets, seconds: (way, what, mode or LOD or None for all) -> (cold, warm)
TARGETS = {
    ("blender", "f12", "reference"): (10.0, 1.0),
    ("blender", "f12", "particles"): (20.0, 1.0),
    ("blender", "f12", None): (None, 1.0),
    ("blender", "import", "medium"): (15.0, 1.5),
    ("blender", "import", None): (None, 1.5),
    ("cli", "render", "reference"): (15.0, None),
    ("cli", "render", "particles"): (25.0, 8.0),
    ("demo", "first image", None): (20.0, None),
}


def target(way, what, which):
    way = "blender" if way == "compat" else way  # the same targets in every Blender
    return TARGETS.get((way, what, which)) or TARGETS.get((way, what, None)) or (None, None)


def compat_zip(python, folder):
    """This platform's zip for ``python``'s Blender (its wheels' Python tag), built into folder."""
    import cmd_build
    import cmd_compat

    tag = subprocess.run([python, "-c", "import sys; print(f'cp{sys.version_info[0]}{sys.version_info[1]}')"],
                         capture_output=True, text=True, check=True).stdout.strip()
    return cmd_build.build([cmd_compat.this_platform()], [tag], folder)[0]


# -- the parent: one subprocess per measurement -------------------------------------------------

def run_child(kind, args, cache, timeout, env=None, watch=None, python=None):
    """Run one child on ``cache`` (in ``python``, default this one); returns its figures, with
    ``process`` (whole process seconds) and, with ``watch`` (a folder), ``first_image``: seconds
    until a PNG other than warmup.png appears there."""
    fd, result = tempfile.mkstemp(suffix=".json", prefix="gaussvdb-cold-")
    os.close(fd)
    os.unlink(result)
    e = dict(os.environ, GAUSSVDB_CACHE_DIR=cache, **(env or {}))
    e.pop("NUMBA_CACHE_DIR", None)
    cmd = [python or sys.executable, os.path.join(os.path.dirname(os.path.abspath(__file__)), "cold_start_child.py"),
           kind, *args, "--result", result]
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN) if resource else None
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=e, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    first = None
    out = ""
    try:
        if watch:
            while proc.poll() is None and time.perf_counter() - t0 < timeout:
                if first is None and os.path.isdir(watch) and any(
                        f.endswith(".png") and f != "warmup.png" for f in os.listdir(watch)):
                    first = time.perf_counter() - t0
                time.sleep(0.05)
        out = proc.communicate(timeout=max(1.0, timeout - (time.perf_counter() - t0)))[0]
    except subprocess.TimeoutExpired:
        proc.kill()
        out = proc.communicate()[0]
        return dict(error=f"timed out after {timeout:.0f} s", process=time.perf_counter() - t0)
    process = time.perf_counter() - t0
    cpu = None
    if resource:  # the child's CPU seconds: what a loaded machine does not inflate
        ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    if proc.returncode != 0 or not os.path.isfile(result):
        tail = " | ".join(out.strip().splitlines()[-3:])
        return dict(error=f"exit {proc.returncode}: {tail}", process=process)
    with open(result) as fh:
        fig = json.load(fh)
    os.unlink(result)
    fig["process"], fig["process_cpu"] = process, cpu
    fig["load_average"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    if watch:
        fig["first_image"] = first
    return fig


def cases(a, tmp):
    """(way, what, which, kind, args, headline step, watch folder) of every case asked for."""
    size = f"{a.size[0]}x{a.size[1]}"
    out = []
    if "kernels" in a.only:
        out += [("kernels", "import", lod, "kernels-import", [lod], "import", None) for lod in a.lods]
        out += [("kernels", "frame", m, "kernels-frame", [m, size], "frame", None) for m in a.modes]
    if "blender" in a.only:
        out += [("blender", "import", lod, "blender-import", [lod], "import", None) for lod in a.lods]
        out += [("blender", "f12", m, "blender-f12", [m, size, os.path.join(tmp, f"f12_{m}.png")],
                 "f12", None) for m in a.modes]
    if "cli" in a.only:
        out += [("cli", "render", m, "cli",
                 ["render", SAMPLE, "--mode", m, "--size", size, "--out",
                  os.path.join(tmp, f"cli_{m}.png")], "process", None) for m in a.cli_modes]
    if "demo" in a.only:
        demo_out = os.path.join(tmp, "demo")
        out.append(("demo", "first image", None, "cli", ["demo", "--out", demo_out, "--json"],
                    "first_image", demo_out))
    if "compat" in a.only:
        z = compat_zip(a.compat_python, tmp)
        out += [("compat", "import", lod, "compat-import", [lod, z], "import", None) for lod in a.lods]
        out += [("compat", "f12", m, "compat-f12", [m, size, os.path.join(tmp, f"compat_{m}.png"), z],
                 "f12", None) for m in a.modes]
    return out


def headline(fig, step):
    """(seconds, compile seconds, functions) of the case's measured step."""
    if "error" in fig:
        return None, None, None
    if step in ("process", "first_image"):
        return fig.get(step), fig["compile_seconds"], fig["functions"]
    s = fig["steps"][step]
    return s["seconds"], s["compile_seconds"], s["functions"]


def _f(x, fmt="{:.2f}"):
    return "-" if x is None else fmt.format(x)


def _verdict(x, limit):
    if limit is None:
        return "-"
    return f"<= {limit:g} s " + ("(yes)" if x is not None and x <= limit else "(NO)")


def cold_warm(a):
    rows = []
    tmp = tempfile.mkdtemp(prefix="gaussvdb-coldstart-")
    try:
        for way, what, which, kind, args, step, watch in cases(a, tmp):
            cache = os.path.join(tmp, f"cache-{len(rows)}")
            os.makedirs(cache)
            row = dict(way=way, what=what, which=which)
            for state in ("cold", "warm"):
                if watch:
                    shutil.rmtree(watch, ignore_errors=True)
                fig = run_child(kind, args, cache, a.timeout, watch=watch,
                                python=a.compat_python if way == "compat" else None)
                row[state] = fig
                sec, comp, fns = headline(fig, step)
                row[f"{state}_seconds"], row[f"{state}_compile"], row[f"{state}_functions"] = sec, comp, fns
                print(f"{way} {what} {which or ''} {state}: "
                      + (fig["error"] if "error" in fig else
                         f"{_f(sec)} s (compile {_f(comp)} s, {fns} functions; "
                         f"process {_f(fig['process'])} s, CPU {_f(fig['process_cpu'], '{:.1f}')} s)"),
                      flush=True)
            row["target_cold"], row["target_warm"] = target(way, what, which)
            rows.append(row)
            shutil.rmtree(cache, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows


def table(rows, size) -> str:
    load = f", load average {os.getloadavg()[0]:.1f} at the end" if hasattr(os, "getloadavg") else ""
    lines = [f"Cold start on {os.path.basename(SAMPLE)}, frames at {size[0]}x{size[1]} "
             f"({os.cpu_count()} CPUs{load}); seconds, compile seconds and functions compiled",
             "",
             "| way | case | cold s | compile s | compiled | process s (CPU s) | warm s | compile s | "
             "compiled | process s (CPU s) | target cold | target warm |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        case = f"{r['what']} {r['which'] or ''}".strip()
        cells = [r["way"], case]
        for state in ("cold", "warm"):
            fig = r[state]
            if "error" in fig:
                cells += [fig["error"], "-", "-", _f(fig.get("process"))]
                continue
            cells += [_f(r[f"{state}_seconds"]), _f(r[f"{state}_compile"]),
                      str(r[f"{state}_functions"]),
                      f"{_f(fig.get('process'))} ({_f(fig.get('process_cpu'), '{:.1f}')})"]
        cells += [_verdict(r["cold_seconds"], r["target_cold"]),
                  _verdict(r["warm_seconds"], r["target_warm"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def cpu_compare(a):
    """Host-tuned against generic: cold compile, then warm speed, alternating (--rounds)."""
    size = f"{a.size[0]}x{a.size[1]}"
    tmp = tempfile.mkdtemp(prefix="gaussvdb-cpuname-")
    targets = {"host": {}, "generic": {"NUMBA_CPU_NAME": "generic"}}
    out = {name: dict(warm=[]) for name in targets}
    try:
        args = [",".join(a.modes), size, str(a.repeat)]
        for name, env in targets.items():
            cache = os.path.join(tmp, name)
            os.makedirs(cache)
            out[name]["cold"] = fig = run_child("speed", args, cache, a.timeout, env=env)
            print(f"{name} cold: " + (fig.get("error") or
                  f"compile {fig['compile_seconds']:.1f} s, {fig['functions']} functions, "
                  f"process {fig['process']:.1f} s"), flush=True)
        for _ in range(a.rounds):
            for name, env in targets.items():
                fig = run_child("speed", args, os.path.join(tmp, name), a.timeout, env=env)
                out[name]["warm"].append(fig)
                print(f"{name} warm: " + (fig.get("error") or
                      f"compiles {fig['functions']}, import {fig['steps']['import']['seconds']:.2f} s, "
                      + ", ".join(f"{m} {v:.1f} ms" for m, v in fig["ms_per_frame"].items())),
                      flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def cpu_table(out, a) -> str:
    lines = [f"Host-tuned (NUMBA_CPU_NAME unset) against generic (NUMBA_CPU_NAME=generic) kernels, "
             f"Medium LOD, {a.size[0]}x{a.size[1]}, best of {a.repeat} x {a.rounds} rounds",
             "",
             "| cache | cold compile s | compiled | cold process CPU s | first import warm s | "
             "import again ms | "
             + " | ".join(f"{m} ms" for m in a.modes) + " |",
             "|---|---|---|---|---|---|" + "---|" * len(a.modes)]
    for name, d in out.items():
        cold = d["cold"]
        warm = [w for w in d["warm"] if "error" not in w]
        if "error" in cold or not warm:
            lines.append(f"| {name} | {cold.get('error', 'no warm run')} |")
            continue
        imp = min(w["steps"]["import"]["seconds"] for w in warm)
        again = min(w["steps"]["import again"]["seconds"] for w in warm)
        ms = [min(w["ms_per_frame"][m] for w in warm) for m in a.modes]
        lines.append(f"| {name} | {cold['compile_seconds']:.1f} | {cold['functions']} | "
                     f"{_f(cold.get('process_cpu'), '{:.1f}')} | {imp:.2f} | {1e3 * again:.1f} | "
                     + " | ".join(f"{v:.1f}" for v in ms) + " |")
    return "\n".join(lines)


def touch_all(folder, ahead):
    """Every file of ``folder`` written again (same bytes, a new mtime ``ahead`` seconds on): a
    reinstall of the same extension."""
    for here, _, names in os.walk(folder):
        for name in names:
            path = os.path.join(here, name)
            with open(path, "rb") as fh:
                data = fh.read()
            with open(path, "wb") as fh:
                fh.write(data)
            t = time.time() + ahead
            os.utime(path, (t, t))


def stamps(a):
    """The first import at Medium from a copy of kernels/: cold, warm, after every file is touched
    (numba's stamp as installed, and numba < 0.68's (mtime, size)), then after one file of a
    subpackage changes (vdb/leaves.py, lod/fit.py): what that change costs to compile again."""
    tmp = tempfile.mkdtemp(prefix="gaussvdb-stamps-")
    rows = []
    try:
        for chain, env in (("numba's own stamp", {}), ("(mtime, size) stamp", {"GAUSSVDB_BENCH_MTIME_STAMP": "1"})):
            src = os.path.join(tmp, f"src-{len(rows)}")
            shutil.copytree(os.path.join(ROOT, "kernels"), os.path.join(src, "kernels"),
                            ignore=shutil.ignore_patterns("__pycache__"))
            cache = os.path.join(tmp, f"cache-{len(rows)}")
            env = dict(env, GAUSSVDB_BENCH_SOURCES=src)

            def measure(label, chain=chain, cache=cache, env=env):
                fig = run_child("kernels-import", ["medium"], cache, a.timeout, env=env)
                sec, comp, fns = headline(fig, "import")
                rows.append(dict(chain=chain, step=label, seconds=sec, compile_seconds=comp,
                                 functions=fns, error=fig.get("error")))
                print(f"{chain}, {label}: " + (fig.get("error") or
                      f"{sec:.2f} s, compile {comp:.2f} s, {fns} functions"), flush=True)

            measure("cold")
            measure("warm")
            touch_all(os.path.join(src, "kernels"), 1000.0)
            measure("every file touched")
            if env.get("GAUSSVDB_BENCH_MTIME_STAMP"):
                continue
            for rel in ("vdb/leaves.py", "lod/fit.py"):
                with open(os.path.join(src, "kernels", *rel.split("/")), "a") as fh:
                    fh.write("\n# changed\n")
                measure(f"{rel} changed")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    lines = ["First import at Medium from a copy of kernels/ (cache stamps)", "",
             "| stamp | step | s | compile s | compiled |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['chain']} | {r['step']} | " + (r["error"] or
                     f"{r['seconds']:.2f} | {r['compile_seconds']:.2f} | {r['functions']}") + " |")
    return rows, "\n".join(lines)


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    from kernels.mode_names import NAMES as MODES

    ap = cli_errors.ArgumentParser(prog="gaussvdb bench cold_start", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default=list(WAYS), type=cli_errors.names(WAYS + ("compat", "cpu", "stamps")),
                    help="ways to measure: kernels, blender, cli, demo (default all), compat (the "
                         "installed zip in the oldest supported Blender); cpu: the generic-CPU "
                         "comparison instead; stamps: the cache stamps")
    venv = os.environ.get("GAUSSVDB_COMPAT_VENV", os.path.join(ROOT, ".venv-compat"))
    ap.add_argument("--compat-python", default=os.path.join(venv, "bin", "python"),
                    help="--only compat: the Python with that Blender's bpy module")
    ap.add_argument("--modes", default=None, type=cli_errors.names(MODES),
                    help="render modes of the frames (default all; --only cpu: particles,field,reference)")
    ap.add_argument("--lods", default=list(ALL_LODS), type=cli_errors.names(ALL_LODS))
    ap.add_argument("--cli-modes", default=["reference", "particles"], type=cli_errors.names(MODES))
    ap.add_argument("--size", default=None, type=cli_errors.size,
                    help="frame size WxH (default 256x256; --only cpu: 512x512)")
    ap.add_argument("--repeat", type=cli_errors.positive_int, default=3, help="--only cpu: frames per best")
    ap.add_argument("--rounds", type=cli_errors.positive_int, default=2, help="--only cpu: warm processes each")
    ap.add_argument("--timeout", type=cli_errors.positive_int, default=900, help="seconds per process")
    ap.add_argument("--json", default=None, help="write every figure to this file")
    a = ap.parse_args(argv)
    if "compat" in a.only and not os.path.exists(a.compat_python):
        raise cli_errors.InputError(f"{a.compat_python}: no such Python (./gaussvdb compat sets up "
                                    "the compat environment)")
    if "stamps" in a.only:
        out, text = stamps(a)
        print()
        print(text)
    elif "cpu" in a.only:
        a.modes = a.modes or ["particles", "field", "reference"]
        a.size = a.size or (512, 512)
        out = cpu_compare(a)
        print()
        print(cpu_table(out, a))
    else:
        a.modes = a.modes or list(ALL_MODES)
        a.size = a.size or (256, 256)
        out = cold_warm(a)
        print()
        print(table(out, a.size))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
