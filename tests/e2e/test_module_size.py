"""Small modules with one job: no module outside tests/ over 500 lines unless its docstring says
why it is one unit (the words "one unit")."""
import ast
import os
import subprocess

from conftest import ROOT

LIMIT = 500


def _tracked_python():
    out = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True)
    if out.returncode != 0:  # not a git checkout (an unpacked zip): walk the tree
        return [os.path.relpath(os.path.join(d, f), ROOT) for d, _, fs in os.walk(ROOT)
                for f in fs if f.endswith(".py") and ".venv" not in d]
    return out.stdout.split()


def test_no_module_over_the_limit_without_a_reason():
    long = []
    for rel in _tracked_python():
        if rel.startswith("tests/"):
            continue
        with open(os.path.join(ROOT, rel), encoding="utf-8") as f:
            text = f.read()
        if text.count("\n") > LIMIT and "one unit" not in (ast.get_docstring(ast.parse(text)) or ""):
            long.append(f"{rel} ({text.count(chr(10))} lines)")
    assert not long, "over 500 lines with no reason in the docstring: " + ", ".join(long)
