"""No import cycle anywhere in the product (kernels/, gaussvdb_addon/, operators/, tools/, the
root __init__.py), counting imports inside functions: a lazy import hides a cycle, it does not
remove it. The graph is read from the source (tests/import_graph.py), nothing is imported."""
import import_graph


def test_no_import_cycle_in_the_product():
    mods = import_graph.modules()
    cycles = import_graph.cycles(import_graph.graph(mods))
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_the_whole_tree_graph_is_read():
    """The edges the test above must see: relative imports across packages, imports inside
    functions, the tools' bare sibling imports, the root package's (so an empty graph cannot pass)."""
    g = import_graph.graph(import_graph.modules())
    assert "kernels.pipeline" in g["gaussvdb_addon.io.conversion"]
    assert "gaussvdb_addon.engine.final_render" in g["gaussvdb_addon.engine.render_engine"]  # lazy
    assert "tools.render_sequence" in g["tools.cmd_render"]
    assert "tools.cli_errors" in g["tools.render_setup"]
    assert "gaussvdb_addon.registration" in g["__init__"]
    assert "kernels.lod_names" in g["operators.import_vdb"]
    assert len(g) > 100


def test_a_cycle_is_reported():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert import_graph.cycles(g) == [["a", "b", "c", "a"]]
    assert import_graph.cycles({"a": {"b"}, "b": set()}) == []
