"""A grid imported alone (``lods=()``): an object without Gaussians, drawn by the reference mode
from its voxels, as `./gaussvdb render --mode reference` imports a file."""

import importlib
import math

import numpy as np
import pytest
from conftest import SAMPLE
from test_engine_helpers import add_camera, read_image, setup_render

ADDON = "bl_ext.user_default.gaussvdb.gaussvdb_addon"


def _modules():
    return (importlib.import_module(f"{ADDON}.io.importer"), importlib.import_module(f"{ADDON}.io.schema"),
            importlib.import_module(f"{ADDON}.engine.image_file"))


def _camera_on(bpy, scene, obj):
    """An orthographic camera looking along +Y at the object's leaf box."""
    st = obj.gaussvdb
    m = np.array(obj.matrix_world, np.float64)
    lo = m[:3, :3] @ np.array(st.leaf_box_min) + m[:3, 3]
    hi = m[:3, :3] @ np.array(st.leaf_box_max) + m[:3, 3]
    c = 0.5 * (lo + hi)
    add_camera(bpy, scene, (c[0], lo[1] - 2.0 * (hi[1] - lo[1]), c[2]), (math.pi / 2, 0.0, 0.0),
               ortho_scale=1.2 * float(max(hi[0] - lo[0], hi[2] - lo[2])))


def test_a_grid_alone_holds_no_gaussians_and_draws_as_with_a_lod(bpy_module, scene, tmp_path):
    bpy = bpy_module
    importer, schema, image_file = _modules()
    alone = importer.import_vdb(SAMPLE, ["density"], lods=(), collection=scene.collection)[0]
    assert alone.type == "POINTCLOUD" and len(alone.data.points) == 0
    assert schema.lod_names(alone) == [] and schema.active_lod(alone) == ""
    assert importer.gaussian_set_from_object(alone) is None
    assert alone.gaussvdb.voxel_stats()["max"] > 0  # the automatic range still has the voxels' figures
    held = importer.import_vdb(SAMPLE, ["density"], lods=("low",), collection=scene.collection)[0]
    _camera_on(bpy, scene, held)
    setup_render(scene, 48, 40)
    scene.render.film_transparent = True
    scene.gaussvdb.mode = "REFERENCE"
    # per world unit: "Per Object Size" is relative to the box of what an object holds (a LOD's
    # Gaussians, a grid's leaves), which differ
    scene.gaussvdb.density_unit, scene.gaussvdb.density = "WORLD", 2.0
    img = {}
    for shown, hidden in ((alone, held), (held, alone)):
        shown.hide_render, hidden.hide_render = False, True
        path = str(tmp_path / f"{shown.name}.png")
        stats = image_file.render_scene_to_file(scene, path)
        assert stats["gaussians"] == (0 if shown is alone else len(held.data.points))
        img[shown.name] = read_image(bpy, path)
    assert img[alone.name][..., 3].max() > 0.5  # the smoke is in the picture
    np.testing.assert_array_equal(img[alone.name], img[held.name])

    # a mode that draws Gaussians leaves it out, and says why
    scene.gaussvdb.mode = "PARTICLES"
    held.hide_render, alone.hide_render = True, False
    stats = image_file.render_scene_to_file(scene, str(tmp_path / "particles.png"))
    assert any(alone.name in w and "Reference mode only" in w for w in stats["warnings"])
    assert read_image(bpy, str(tmp_path / "particles.png"))[..., 3].max() == 0.0


def test_a_grid_alone_reloads_alone(bpy_module, scene):
    importer, schema, _ = _modules()
    obj = importer.import_vdb(SAMPLE, ["density"], lods=(), collection=scene.collection)[0]
    importer.reload_object(obj)
    assert schema.lod_names(obj) == [] and len(obj.data.points) == 0
    assert obj.gaussvdb.grid_name == "density"


def test_the_import_dialog_and_a_sequence_still_need_a_lod(bpy_module, scene, tmp_path):
    importer, _, _ = _modules()
    before = set(bpy_module.data.objects)
    with pytest.raises(RuntimeError, match="choose at least one LOD preset"):
        bpy_module.ops.gaussvdb.import_vdb(filepath=SAMPLE, lods=set())
    frames = []
    for n in (1, 2):
        frames.append(tmp_path / f"m_{n:04d}.vdb")
        frames[-1].write_bytes(open(SAMPLE, "rb").read())
    sequence_import = importlib.import_module(f"{ADDON}.io.sequence_import")
    with pytest.raises(importer.VDBImportError, match="a sequence needs a LOD preset"):
        sequence_import.import_sequence(str(frames[0]), lods=(), collection=scene.collection)
    assert set(bpy_module.data.objects) == before
