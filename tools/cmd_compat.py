"""`./gaussvdb compat [--python PY] [--user DIR]`: the compatibility suite on the oldest supported
Blender (4.5 LTS, its own environment `.venv-compat` from requirements-compat.txt, set up by the
launcher): builds this platform's zip for that Python and runs tests/compat/run_compat.py there,
which installs the zip into a fresh user folder and checks import, F12 on both devices, a sequence
frame, save/reload, the import's rollback and Compile Now's worker processes.

`--python` runs it in another environment (e.g. the main one's `.venv/bin/python`); `--user DIR`
keeps the user folder, so a second run reuses the compiled kernels (the warm-cache figures)."""

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the sibling tools modules

import cli_errors  # noqa: E402
import cmd_build  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def this_platform() -> str:
    machine = platform.machine().lower()
    if sys.platform == "darwin":
        return "macos-arm64" if machine == "arm64" else "macos-x64"
    return ("windows-x64" if sys.platform == "win32" else "linux-x64")


def main(argv: list[str]) -> int:
    parser = cli_errors.ArgumentParser(prog="gaussvdb compat", description=__doc__,
                                       formatter_class=argparse.RawDescriptionHelpFormatter)
    venv = os.environ.get("GAUSSVDB_COMPAT_VENV", os.path.join(ROOT, ".venv-compat"))
    parser.add_argument("--python", default=os.path.join(venv, "bin", "python"),
                        help="the Python with the bpy module to test in (default: the compat environment's)")
    parser.add_argument("--user", help="user folder to install into and keep (default: a fresh one)")
    args = parser.parse_args(argv)
    if not os.path.exists(args.python):
        raise cli_errors.InputError(f"{args.python}: no such Python (the launcher sets up the compat environment)")
    tag = subprocess.run([args.python, "-c", "import sys; print(f'cp{sys.version_info[0]}{sys.version_info[1]}')"],
                         capture_output=True, text=True, check=True).stdout.strip()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="gaussvdb-compat-zip-") as out:
        zips = cmd_build.build([this_platform()], [tag], out)
        print(f"built {os.path.basename(zips[0])} ({tag}) in {time.perf_counter() - t0:.0f} s", flush=True)
        cmd = [args.python, os.path.join(ROOT, "tests", "compat", "run_compat.py"), zips[0]]
        if args.user:
            cmd += ["--user", args.user]
        env = {k: v for k, v in os.environ.items() if not k.startswith("BLENDER_USER_")}
        return subprocess.call(cmd, cwd=ROOT, env=env)
