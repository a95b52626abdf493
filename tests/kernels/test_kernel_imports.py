"""The kernels' import graph: no bpy or gpu anywhere under kernels/, and no cycle between kernel
modules, counting imports inside functions too (a lazy import hides a cycle, it does not remove
it). Registration of the extension loads no numba."""
import subprocess
import sys
import textwrap

import import_graph
from conftest import ROOT


def _modules():
    return import_graph.modules(("kernels",))


def _imports(name, path, known):
    """Kernel modules (and any other top-level names) that module ``name`` imports."""
    return import_graph.imports(name, path, known)


def test_no_bpy_or_gpu_under_kernels():
    mods = _modules()
    bad = {n: sorted(i for i in _imports(n, p, mods) if i.split(".")[0] in ("bpy", "gpu", "bl_ui",
                                                                            "addon_utils"))
           for n, p in mods.items()}
    assert not {n: v for n, v in bad.items() if v}


def test_no_import_cycle_inside_kernels():
    cycles = import_graph.cycles(import_graph.graph(_modules()))
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_the_graph_is_read():
    """The parser sees the edges it must (so an empty graph cannot pass the test above)."""
    mods = _modules()
    lod = _imports("kernels.lod.build", mods["kernels.lod.build"], mods)
    assert "kernels.lod.schemes" in lod and "kernels.lod.gridprep" in lod
    assert "kernels.jit" in _imports("kernels.render.cpu.pixels", mods["kernels.render.cpu.pixels"], mods)


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
