"""`./gaussvdb test [pytest args]`: the whole suite, in real Blender (the bpy module)."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main(argv: list[str]) -> int:
    cmd = [sys.executable, "-m", "pytest", *argv]
    return subprocess.call(cmd, cwd=ROOT)
