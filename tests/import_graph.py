"""The import graph of the product's Python modules, read from their source (imports inside
functions count too: a lazy import hides a cycle, it does not remove it), and its cycles.

Modules are named from the repository root (``kernels.pipeline``, ``gaussvdb_addon.io.importer``,
``tools.cmd_render``; the root ``__init__.py`` is ``__init__``). The command-line tools import
their siblings by bare name (tools/ is on their path), so such a name resolves to ``tools.X``.
"""
import ast
import os

from conftest import ROOT

PRODUCT = ("kernels", "gaussvdb_addon", "operators", "tools", "__init__.py")


def modules(tops=PRODUCT) -> dict:
    """{module name: path} under the folders ``tops`` (and the root __init__.py when named)."""
    out = {}
    for top in tops:
        path = os.path.join(ROOT, top)
        if top.endswith(".py"):
            out[top[:-3]] = path
            continue
        for d, _dirs, files in os.walk(path):
            for f in files:
                if f.endswith(".py"):
                    p = os.path.join(d, f)
                    rel = os.path.relpath(p, ROOT)[:-3].replace(os.sep, ".")
                    out[rel[:-len(".__init__")] if rel.endswith(".__init__") else rel] = p
    return out


def _package(name, path):
    if name == "__init__":
        return ""
    return name if path.endswith("__init__.py") else name.rpartition(".")[0]


def imports(name, path, known) -> set:
    """Module names (known ones, and any other top-level names) that module ``name`` imports."""
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    pkg = _package(name, path)
    sibling = name.rpartition(".")[0]  # tools/: `import cli_errors` is tools.cli_errors

    def absolute(mod):
        if sibling == "tools" and f"tools.{mod.split('.')[0]}" in known:
            return f"tools.{mod}"
        return mod

    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {absolute(a.name) for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = [p for p in pkg.split(".") if p]
                parts = parts[:len(parts) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            else:
                base = absolute(node.module)
            found.add(base)
            found |= {f"{base}.{a.name}" if base else a.name for a in node.names
                      if (f"{base}.{a.name}" if base else a.name) in known}
    return found


def graph(mods) -> dict:
    """Edges between the known modules. A package importing its own submodules through its
    __init__ is by design; a submodule importing its own package's __init__ is a cycle to catch,
    so only __init__ -> child edges are dropped."""
    g = {n: {i for i in imports(n, p, mods) if i in mods and i != n} for n, p in mods.items()}
    for n in g:
        if os.path.basename(mods[n]) == "__init__.py" and n != "__init__":
            g[n] = {i for i in g[n] if not i.startswith(n + ".")}
    return g


def cycles(g) -> list:
    """The cycles a depth-first walk meets, each as [a, b, ..., a]."""
    found, state = [], {}

    def visit(n, stack):
        state[n] = 1
        stack.append(n)
        for m in sorted(g[n]):
            if state.get(m) == 1:
                found.append(stack[stack.index(m):] + [m])
            elif m not in state:
                visit(m, stack)
        stack.pop()
        state[n] = 2

    for n in sorted(g):
        if n not in state:
            visit(n, [])
    return found
