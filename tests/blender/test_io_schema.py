"""The point-cloud schema (gaussvdb_addon/io/schema.py): what an import writes reads back as the
same GaussianSet bit for bit, through the reader the engine uses; files without a layout version
(layout 0) are upgraded in place when they load (io/versioning.py)."""

import importlib

import numpy as np
import pytest
from conftest import ADDON_MODULE, SAMPLE

FIELDS = ("group_origins", "group_start", "offsets", "sigmas", "values", "amplitudes", "voxels")


def _mod(name):
    return importlib.import_module(f"{ADDON_MODULE}.{name}")


def _same(a, b):
    for f in FIELDS:
        x, y = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), f
    assert (a.lod, a.grid_class, a.n_leaf_groups, a.sigma_scale) == \
        (b.lod, b.grid_class, b.n_leaf_groups, b.sigma_scale)


@pytest.mark.parametrize("lods", [("low", "medium", "high"), ("variance",)])
def test_write_then_read_is_the_kernels_set(scene, lods):
    pipeline, schema, datablocks = (_mod("kernels.pipeline"), _mod("gaussvdb_addon.io.schema"),
                                    _mod("gaussvdb_addon.io.datablocks"))
    cg = pipeline.convert_file(SAMPLE, ["density"], lods, compute_error=False)[0]
    obj = datablocks.build_objects([cg], scene.collection)[0]
    assert obj.gaussvdb.layout_version == schema.LAYOUT_VERSION
    for cl in cg.lods:
        back = _mod("gaussvdb_addon.engine.scene_sync").read_gaussians(obj, cl.name)  # the engine's reader
        _same(back, cl.gset)
        assert np.array_equal(back.index_to_world, cg.index_to_world)
    assert schema.lod_names(obj) == list(lods)


def _shuffle_without_origins(obj, schema):
    """Rewrite the object as a layout-0 point cloud: points in random order, no gs_origin, no
    gs_lod, no LOD named, no version."""
    a = schema.read_attributes(obj)
    order = np.random.default_rng(3).permutation(len(a["position"]))
    for name in ("gs_origin", "gs_lod"):
        obj.data.attributes.remove(obj.data.attributes[name])
    typed = {k: ("FLOAT_VECTOR" if v.ndim == 2 else obj.data.attributes[k].data_type, v[order], 1)
             for k, v in a.items() if k not in ("gs_origin", "gs_lod")}
    schema.write_attributes(obj.data, typed)
    obj.gaussvdb.lods = ""
    obj.gaussvdb.property_unset("layout_version")


def _rows(gs):
    """The Gaussians as sorted rows (centre, sigma, value, amplitude, voxels): order-free."""
    rows = np.column_stack([gs.centers(), gs.sigmas, gs.values, gs.amplitudes, gs.voxels])
    return rows[np.lexsort(rows.T[::-1])]


def test_layout_0_is_upgraded_on_load(scene, bpy_module, tmp_path):
    bpy = bpy_module
    imp, schema = _mod("gaussvdb_addon.io.importer"), _mod("gaussvdb_addon.io.schema")
    a, b = imp.import_vdb(SAMPLE, grids=["density", "temperature"], lods=("medium",),
                          compute_error=False, collection=scene.collection)
    before = {o.name: imp.gaussian_set_from_object(o, "medium") for o in (a, b)}
    names = a.name, b.name
    a.gaussvdb.property_unset("layout_version")  # as imported before the version was stored
    _shuffle_without_origins(b, schema)
    assert a.gaussvdb.layout_version == 0 and b.gaussvdb.layout_version == 0
    assert "gs_origin" not in b.data.attributes and b.gaussvdb.lods == ""
    path = str(tmp_path / "layout0.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=path)  # load_post: versioning.do_versions
    a, b = (bpy.data.objects[n] for n in names)
    for o in (a, b):
        assert o.gaussvdb.layout_version == schema.LAYOUT_VERSION
        assert o.gaussvdb.lods == "medium" and "gs_origin" in o.data.attributes
    _same(imp.gaussian_set_from_object(a, "medium"), before[a.name])  # only the number was missing
    back = imp.gaussian_set_from_object(b, "medium")
    assert np.array_equal(_rows(back), _rows(before[b.name]))
    starts = back.group_start[:-1]  # each leaf cell one contiguous group again
    assert len(np.unique(back.group_origins, axis=0)) == len(starts)


def test_newer_layout_is_refused(scene):
    imp, schema = _mod("gaussvdb_addon.io.importer"), _mod("gaussvdb_addon.io.schema")
    obj = imp.import_vdb(SAMPLE, grids=["density"], lods=("low",), compute_error=False,
                         collection=scene.collection)[0]
    obj.gaussvdb.layout_version = schema.LAYOUT_VERSION + 1
    with pytest.raises(ValueError, match="newer than this GaussVDB reads"):
        imp.gaussian_set_from_object(obj, "low")


def test_weight_rule_text_of_older_files_becomes_the_enum(scene, bpy_module, tmp_path):
    bpy = bpy_module
    imp = _mod("gaussvdb_addon.io.importer")
    obj = imp.import_vdb(SAMPLE, grids=["density"], lods=("low",), weights="paper",
                         compute_error=False, collection=scene.collection)[0]
    before = imp.gaussian_set_from_object(obj, "low")
    st = obj.gaussvdb
    st.property_unset("weight_rule")  # as stored before the enum: the rule as text only
    st.weights = "paper"
    assert st.weight_rule == "field" and st.weights_rule() == "paper"  # read right before the upgrade
    path = str(tmp_path / "weights_text.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=path)  # load_post: versioning.do_versions
    st = bpy.data.objects[0].gaussvdb
    assert st.weight_rule == "paper" and st.weights == ""
    _same(imp.gaussian_set_from_object(bpy.data.objects[0], "low"), before)
