"""The engine reads Blender's own settings: threads (Render > Performance), passes (View Layer >
Passes), the background (the World); Blender's panels it opts in to; tooltips and units; old
files' settings migrated on load."""

import importlib
import math

import numpy as np
import pytest
from conftest import ADDON_MODULE
from test_engine_helpers import add_camera, lattice, make_object, read_image, setup_render

W, H = 32, 24


def _mod(name):
    return importlib.import_module(f"{ADDON_MODULE}.{name}")


def _cloud(bpy, scene):
    """An 8^3 cloud in the middle of the frame, corners empty."""
    make_object(bpy, "Cloud", lattice(8, 8, 8), values=np.linspace(0, 1, 512))
    add_camera(bpy, scene, (3.5, -40.0, 3.5), (math.pi / 2, 0.0, 0.0))
    setup_render(scene, W, H)
    scene.gaussvdb.density_unit = "WORLD"
    scene.gaussvdb.density = 5.0
    scene.render.film_transparent = True


def _sync(bpy, scene):
    ss = _mod("gaussvdb_addon.engine.scene_sync").SceneSync(viewport=False)
    return ss.sync(bpy.context.evaluated_depsgraph_get())


def _exr_channels(bpy, path):
    """Every channel of a multilayer EXR, by name (all parts: Blender may write one per pass)."""
    bpy.utils.expose_bundled_modules()
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    out = {}
    try:
        sub = 0
        while inp.seek_subimage(sub, 0):
            spec = inp.spec()
            names = list(spec.channelnames)
            data = np.asarray(inp.read_image(sub, 0, 0, len(names), "float")).reshape(
                spec.height, spec.width, len(names))
            out.update({n: data[..., i][::-1] for i, n in enumerate(names)})  # row 0 = bottom
            sub += 1
    finally:
        inp.close()
    return out


# -- threads --------------------------------------------------------------------------------------
def test_threads_from_render_performance(bpy_module, scene, tmp_path):
    bpy = bpy_module
    fi = _mod("gaussvdb_addon.engine.image_file")
    _cloud(bpy, scene)
    r = scene.render
    r.threads_mode = "AUTO"
    assert _sync(bpy, scene).threads is None  # all cores
    r.threads_mode, r.threads = "FIXED", 1
    assert _sync(bpy, scene).threads == 1
    assert not hasattr(scene.gaussvdb, "threads")  # no copy of Blender's setting
    stats = fi.render_scene_to_file(scene, str(tmp_path / "t.png"))
    assert stats["threads"] == 1


# -- passes ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("depth,value", [(True, False), (False, True), (True, True)])
def test_passes_from_the_view_layer(bpy_module, scene, tmp_path, depth, value):
    bpy = bpy_module
    fi = _mod("gaussvdb_addon.engine.image_file")
    _cloud(bpy, scene)
    layer = scene.view_layers[0]
    layer.use_pass_z = depth
    layer.gaussvdb.use_pass_value = value
    assert set(_sync(bpy, scene).passes) == {p for p, on in (("Depth", depth), ("Value", value)) if on}
    img = scene.render.image_settings
    if hasattr(img, "media_type"):  # Blender 5.0 picks multilayer files by media type
        img.media_type = "MULTI_LAYER_IMAGE"
    img.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.image_settings.color_depth = "32"
    path = str(tmp_path / "passes.exr")
    scene.render.filepath = path
    scene.render.use_file_extension = False
    fi.set_exact_colors(scene)
    bpy.ops.render.render(write_still=True)
    ch = _exr_channels(bpy, path)
    prefix = f"{layer.name}."
    assert (prefix + "Depth.Z" in ch) == depth, sorted(ch)
    assert (prefix + "Value.X" in ch) == value, sorted(ch)
    alpha = ch[prefix + "Combined.A"]
    inside = alpha > 0.5
    assert inside.any() and (alpha[0, 0] < 1e-6)
    if depth:
        z = ch[prefix + "Depth.Z"]
        # the cloud spans y = 0..7 (40..47 units ahead, rays at the edges longer); misses: 1e10
        assert np.all((z[inside] > 38.0) & (z[inside] < 52.0)), z[inside].max()
        assert z[0, 0] > 1e9
    if value:
        v = ch[prefix + "Value.X"]
        assert np.all((v[inside] >= 0.0) & (v[inside] <= 1.0)) and v[inside].max() > 0.1


# -- background -----------------------------------------------------------------------------------
def _background_pixel(bpy, scene, tmp_path, name):
    fi = _mod("gaussvdb_addon.engine.image_file")
    path = str(tmp_path / f"{name}.exr")
    fi.render_scene_to_file(scene, path)
    return read_image(bpy, path)[0, 0]


def test_background_from_the_world(bpy_module, scene, tmp_path):
    bpy = bpy_module
    bs = _mod("gaussvdb_addon.engine.blender_settings")
    _cloud(bpy, scene)
    scene.render.film_transparent = False
    # no World: the render settings' colour
    scene.world = None
    scene.gaussvdb.background = (0.1, 0.2, 0.3)
    px = _background_pixel(bpy, scene, tmp_path, "noworld")
    np.testing.assert_allclose(px, [0.1, 0.2, 0.3, 1.0], atol=1e-5)
    # a World: its Background node's colour times strength (the scene colour is ignored)
    world = bpy.data.worlds.new("W")
    scene.world = world
    node = bs.surface_background_node(world)
    assert node is not None
    node.inputs["Color"].default_value = (0.4, 0.25, 0.05, 1.0)
    node.inputs["Strength"].default_value = 0.5
    px = _background_pixel(bpy, scene, tmp_path, "world")
    np.testing.assert_allclose(px, [0.2, 0.125, 0.025, 1.0], atol=1e-5)
    # the surface is not a plain Background node: the World's own colour
    tree = world.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld")
    tree.links.remove(out.inputs["Surface"].links[0])
    world.color = (0.3, 0.0, 0.6)
    assert bs.background(scene) == pytest.approx((0.3, 0.0, 0.6, 1.0))
    scene.render.film_transparent = True
    assert bs.background(scene) == (0.0, 0.0, 0.0, 0.0)


# -- files of older versions ----------------------------------------------------------------------
def test_old_scene_settings_migrate_on_load(bpy_module, scene, tmp_path):
    bpy = bpy_module
    # what a file saved by the previous version holds: plain ID properties under Scene.gaussvdb
    scene.gaussvdb["threads"] = 3
    scene.gaussvdb["use_pass_depth"] = True
    scene.gaussvdb["use_pass_value"] = True
    scene.gaussvdb.density = 7.0
    blend = str(tmp_path / "old.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=blend)
    sc = bpy.context.scene
    assert (sc.render.threads_mode, sc.render.threads) == ("FIXED", 3)
    assert sc.view_layers[0].use_pass_z and sc.view_layers[0].gaussvdb.use_pass_value
    assert sc.gaussvdb.density == pytest.approx(7.0)  # the rest is untouched
    for key in ("threads", "use_pass_depth", "use_pass_value"):
        assert key not in sc.gaussvdb.keys()


# -- panels ---------------------------------------------------------------------------------------
NEEDED = (
    "RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_output", "RENDER_PT_color_management",
    "RENDER_PT_post_processing", "RENDER_PT_stamp", "RENDER_PT_simplify",
    "DATA_PT_context_camera", "DATA_PT_lens", "DATA_PT_camera", "DATA_PT_camera_background_image",
    "DATA_PT_camera_safe_areas", "DATA_PT_context_mesh", "DATA_PT_vertex_groups",
    "DATA_PT_mesh_attributes", "DATA_PT_context_light", "DATA_PT_light",
    "DATA_PT_context_pointcloud", "DATA_PT_pointcloud_attributes",
    # the Mantaflow domain's settings
    "PHYSICS_PT_fluid", "PHYSICS_PT_settings", "PHYSICS_PT_borders", "PHYSICS_PT_smoke",
    "PHYSICS_PT_fire", "PHYSICS_PT_cache", "PHYSICS_PT_export", "PHYSICS_PT_adaptive_domain",
    "PHYSICS_PT_noise", "PHYSICS_PT_flow_source",
    "TEXTURE_PT_context", "TEXTURE_PT_colors_ramp", "WORLD_PT_context_world",
    "VIEWLAYER_PT_layer", "VIEWLAYER_PT_layer_passes", "OBJECT_PT_visibility",
)
NOT_IMPLEMENTED = ("DATA_PT_camera_dof", "DATA_PT_camera_dof_aperture", "RENDER_PT_freestyle",
                   "RENDER_PT_stereoscopy", "DATA_PT_preview", "RENDER_PT_eevee_sampling",
                   "VIEWLAYER_PT_freestyle", "DATA_PT_lightprobe")


def test_panel_lists_name_real_panels(bpy_module, addon):
    """Every panel named here and in engine.py exists in this Blender (a rename is noticed)."""
    bpy = bpy_module
    eng = _mod("gaussvdb_addon.engine.render_engine")
    for name in (*NEEDED, *NOT_IMPLEMENTED, *eng.HIDDEN_PANELS, *eng.EXTRA_PANELS):
        assert hasattr(bpy.types, name), f"{name} is not a Blender panel (renamed?)"
    for prefix in eng.HIDDEN_PREFIXES:
        assert any(n.startswith(prefix) for n in dir(bpy.types)), prefix


def test_engine_opts_in_to_the_panels_that_apply(bpy_module, addon):
    bpy = bpy_module
    for name in NEEDED:
        assert "GAUSSVDB" in getattr(bpy.types, name).COMPAT_ENGINES, f"{name} hidden for GaussVDB"
    for name in NOT_IMPLEMENTED:
        assert "GAUSSVDB" not in getattr(bpy.types, name).COMPAT_ENGINES, f"{name} shown for GaussVDB"
    # our own: the Value pass under View Layer > Passes, the World's colour, colormap presets
    assert bpy.types.GAUSSVDB_PT_passes_data.bl_parent_id == "VIEWLAYER_PT_layer_passes"
    assert bpy.types.GAUSSVDB_PT_world.bl_context == "world"
    presets = _mod("gaussvdb_addon.ui.presets")
    rp = _mod("gaussvdb_addon.ui.render_panel")
    assert hasattr(rp.GAUSSVDB_PT_transfer, "draw_header_preset")
    assert rp.GAUSSVDB_PT_colormap_presets.preset_subdir == presets.COLORMAP_PRESET_SUBDIR
    files = [f for d in bpy.utils.preset_paths(presets.COLORMAP_PRESET_SUBDIR) for f in _listdir(d)]
    assert "Viridis.py" in files


def _listdir(d):
    import os

    return os.listdir(d) if os.path.isdir(d) else []


# -- tooltips and units -----------------------------------------------------------------------------
def test_every_setting_has_a_tooltip_and_its_unit(bpy_module, addon):
    bpy = bpy_module
    rs = _mod("gaussvdb_addon.properties.render_settings")
    groups = (rs.GaussVDBRenderSettings.bl_rna, rs.GaussVDBViewLayerSettings.bl_rna,
              bpy.ops.gaussvdb.import_vdb.get_rna_type())
    for rna in groups:
        for prop in rna.properties:
            if prop.identifier in ("rna_type", "name") or prop.is_hidden:
                continue
            assert prop.description.strip(), f"{rna.identifier}.{prop.identifier} has no tooltip"
            if prop.type == "ENUM":
                for item in prop.enum_items:
                    assert item.description.strip(), f"{prop.identifier}: {item.identifier}"
    props = rs.GaussVDBRenderSettings.bl_rna.properties
    assert props["early_termination"].subtype == "FACTOR"
    units = {i.identifier: i.name for i in props["density_unit"].enum_items}
    assert units == {"OBJECT": "Per Object Size", "WORLD": "Per World Unit"}
    assert "per world unit" in props["density_unit"].enum_items["WORLD"].description.lower()
