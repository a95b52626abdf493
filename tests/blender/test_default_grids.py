"""One default-grid rule (kernels.pipeline.default_grids) for the import, `convert` and `render`:
a Mantaflow-like cache whose first grid is the domain-wide `shadow` gives density everywhere."""

import importlib
import os
import sys

import pytest
from conftest import ADDON_MODULE, ROOT, run_cli
from vdb_fixtures import write_mantaflow_like


@pytest.fixture(scope="module")
def manta(tmp_path_factory):
    import bpy  # noqa: F401  (the bundled openvdb comes with bpy)

    return str(write_mantaflow_like(tmp_path_factory.mktemp("manta") / "fluid_data_0001.vdb"))


def test_the_rule(manta):
    pipeline = importlib.import_module(ADDON_MODULE + ".kernels.pipeline")
    vdb = importlib.import_module(ADDON_MODULE + ".kernels.vdb")
    names = [g.name for g in vdb.read_topology(manta).grids]
    assert names[0] == "shadow" and "density" in names
    wanted, left_out = pipeline.default_grids(names)
    assert wanted == ["density"] and {n for n, _ in left_out} == set(names) - {"density"}
    assert pipeline.default_grids(["surface"]) == (None, [])


def test_cli_choice_is_the_import_choice(manta, scene):
    sys.path.insert(0, os.path.join(ROOT, "tools"))
    import cli_grids

    imp = importlib.import_module(ADDON_MODULE + ".gaussvdb_addon.io.importer")
    objs = imp.import_vdb(manta, lods=("low",), compute_error=False, collection=scene.collection)
    assert [o.gaussvdb.grid_name for o in objs] == ["density"]
    assert cli_grids.choose_grid(manta) == "density"  # not shadow, the first grid with voxels
    assert cli_grids.choose_grid(manta, "shadow") == "shadow"  # a named grid is taken as named


def test_convert_takes_density(manta, tmp_path):
    import json

    r = run_cli(ROOT, "convert", manta, "--lod", "low", "--no-error", "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["grid"] == "density" and res["gaussians"] > 0
