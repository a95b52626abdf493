"""The kernels' import graph: no bpy or gpu anywhere under kernels/, and no cycle between kernel
modules, counting imports inside functions too (a lazy import hides a cycle, it does not remove
it). Registration of the extension loads no numba."""
import ast
import os
import subprocess
import sys
import textwrap

from conftest import ROOT

KERNELS = os.path.join(ROOT, "kernels")


def _modules():
    out = {}
    for d, _dirs, files in os.walk(KERNELS):
        for f in files:
            if f.endswith(".py"):
                path = os.path.join(d, f)
                rel = os.path.relpath(path, ROOT)[:-3].replace(os.sep, ".")
                out[rel[:-len(".__init__")] if rel.endswith(".__init__") else rel] = path
    return out


def _imports(name, path, known):
    """Kernel modules (and any other top-level names) that module ``name`` imports."""
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    pkg = name if path.endswith("__init__.py") else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = pkg.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
            found.add(base)
            found |= {f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in known}
    return found


def test_no_bpy_or_gpu_under_kernels():
    mods = _modules()
    bad = {n: sorted(i for i in _imports(n, p, mods) if i.split(".")[0] in ("bpy", "gpu", "bl_ui",
                                                                            "addon_utils"))
           for n, p in mods.items()}
    assert not {n: v for n, v in bad.items() if v}


def test_no_import_cycle_inside_kernels():
    mods = _modules()
    graph = {n: {i for i in _imports(n, p, mods) if i in mods and i != n} for n, p in mods.items()}
    # a package imports its submodules through __init__ by design; a submodule importing its own
    # package's __init__ is the cycle to catch, so only __init__ -> child edges are dropped
    for n in graph:
        if os.path.basename(mods[n]) == "__init__.py":
            graph[n] = {i for i in graph[n] if not i.startswith(n + ".")}
    cycles = []
    state = {}

    def visit(n, stack):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                cycles.append(stack[stack.index(m):] + [m])
            elif m not in state:
                visit(m, stack)
        stack.pop()
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n, [])
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_the_graph_is_read():
    """The parser sees the edges it must (so an empty graph cannot pass the test above)."""
    mods = _modules()
    lod = _imports("kernels.lod.build", mods["kernels.lod.build"], mods)
    assert "kernels.lod.schemes" in lod and "kernels.lod.gridprep" in lod
    assert "kernels.jit" in _imports("kernels.render._cpu", mods["kernels.render._cpu"], mods)


def test_registration_loads_no_numba(tmp_path):
    code = textwrap.dedent(f"""
        import os, sys
        base = {str(tmp_path)!r}
        for k, sub in (("EXTENSIONS", "ext"), ("CONFIG", "cfg"), ("SCRIPTS", "scr")):
            os.environ["BLENDER_USER_" + k] = os.path.join(base, sub)
        repo = os.path.join(base, "ext", "user_default")
        os.makedirs(repo)
        os.symlink({ROOT!r}, os.path.join(repo, "gaussvdb"))
        import bpy, addon_utils
        assert addon_utils.enable("bl_ext.user_default.gaussvdb", default_set=True, handle_error=None)
        print("NUMBA", "numba" in sys.modules)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "NUMBA False" in r.stdout
