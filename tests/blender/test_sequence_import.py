"""Sequences of .vdb files: one object per grid following the timeline (real bpy, real files).

The frames are a blob that moves and grows, written with the bundled openvdb; each frame drawn
is compared with the same file imported alone (bit-identical Gaussians), renders with the
single-file renders (equal pixels)."""

import math
import os

import numpy as np
import pytest
from test_engine_helpers import add_camera, read_image, setup_render
from vdb_fixtures import write_grid

PKG = "bl_ext.user_default.gaussvdb"
FIELDS = ("group_origins", "group_start", "offsets", "sigmas", "values", "amplitudes", "voxels")


def blob(n):
    """Frame n: a ball of radius 2 + n voxels at x = 6 + 3n, values up to n / 4."""
    r = 2.0 + n
    x, y, z = np.mgrid[0:32, 0:16, 0:16].astype(np.float32)
    d = np.sqrt((x - 6 - 3 * n) ** 2 + (y - 8) ** 2 + (z - 8) ** 2)
    return np.where(d < r, (n / 4.0) * (1.0 - d / r) + 0.01, 0.0).astype(np.float32)


def write_frames(folder, numbers, heat_from=2, broken=()):
    """blob_NNNN.vdb with `density` and `heat` (heat empty before frame heat_from); `broken`
    frames are garbage bytes."""
    import bpy

    bpy.utils.expose_bundled_modules()
    import openvdb as ov

    os.makedirs(folder, exist_ok=True)
    for n in numbers:
        path = os.path.join(folder, f"blob_{n:04d}.vdb")
        if n in broken:
            with open(path, "wb") as f:
                f.write(b"not a vdb file" * 10)
            continue
        grids = []
        for name, arr in (("density", blob(n)), ("heat", blob(n) * 2 if n >= heat_from else None)):
            g = ov.FloatGrid()
            g.name = name
            if arr is not None:
                g.copyFromArray(arr)
            g.transform = ov.createLinearTransform(voxelSize=0.1)
            grids.append(g)
        ov.write(path, grids=grids)
    return os.path.join(folder, f"blob_{numbers[0]:04d}.vdb")


def _mods():
    import importlib

    return (importlib.import_module(f"{PKG}.gaussvdb_addon.io.importer"),
            importlib.import_module(f"{PKG}.gaussvdb_addon.engine.scene_sync"),
            importlib.import_module(f"{PKG}.gaussvdb_addon.engine.sequence_frames"))


def _drawn(bpy, scene, frame, viewport=False):
    """{object name: GaussianSet} the engine draws at ``frame``, and the SceneSync."""
    _, scene_sync, _ = _mods()
    scene.frame_set(frame)
    sync = scene_sync.SceneSync(viewport=viewport)
    rs = sync.sync(bpy.context.evaluated_depsgraph_get())
    return {o.name: o.gaussians for o in rs.objects}, sync


def _same(a, b):
    for k in FIELDS:
        x, y = np.asarray(getattr(a, k)), np.asarray(getattr(b, k))
        assert x.dtype == y.dtype and np.array_equal(x, y), k
    assert a.sigma_scale == b.sigma_scale and a.count == b.count


@pytest.fixture
def frames(tmp_path):
    return write_frames(str(tmp_path / "seq"), [1, 2, 3, 4])


@pytest.fixture
def references(bpy_module, scene, frames):
    """Each frame's file imported alone (into a collection outside the scene): name -> GaussianSet."""
    importer, _, _ = _mods()
    bpy = bpy_module
    coll = bpy.data.collections.new("refs")
    out = {}
    for n in (1, 2, 3, 4):
        path = frames.replace("0001", f"{n:04d}")
        for obj in importer.import_vdb(path, lods=("low",), collection=coll, compute_error=False):
            out[(n, obj.gaussvdb.grid_name)] = importer.gaussian_set_from_object(obj, "low")
    return out


def _import(bpy, path, **kw):
    importer, _, sf = _mods()
    sf.CACHE.clear()
    objs, message = importer.import_files(bpy.context, [path], lods=("low",), compute_error=False, **kw)
    return objs, message


def test_one_object_per_grid_with_blender_sequence_settings(bpy_module, scene, frames):
    bpy = bpy_module
    objs, message = _import(bpy, frames)
    assert sorted(o.name for o in objs) == ["blob_density", "blob_heat"]
    vols = {o.gaussvdb.source_volume for o in objs}
    assert len(vols) == 1
    vol = vols.pop()
    assert vol.is_sequence and (vol.frame_start, vol.frame_offset, vol.frame_duration) == (1, 0, 4)
    assert vol.sequence_mode == "REPEAT" and os.path.basename(vol.filepath) == "blob_0001.vdb"
    heat = bpy.data.objects["blob_heat"].gaussvdb.stats()["sequence"]
    assert heat["shown"] == 2  # heat is empty in frame 1: the object holds frame 2
    # the range over all frames is the union of each frame's figures
    dens = bpy.data.objects["blob_density"].gaussvdb
    per = dens.stats()["sequence"]["values"]
    assert sorted(per) == ["1", "2", "3", "4"]
    assert dens.voxel_stats()["max"] == max(v["max"] for v in per.values())
    # with the option off, the file imports alone (its heat grid is empty: density only)
    objs, _ = _import(bpy, frames, sequence=False)
    assert [o.name for o in objs] == ["blob_0001_density"]
    assert not objs[0].gaussvdb.source_volume.is_sequence


@pytest.mark.parametrize("mode,start,offset", [("REPEAT", 1, 0), ("CLIP", 3, 0), ("EXTEND", 2, 1),
                                               ("PING_PONG", 1, 0)])
def test_frame_set_draws_that_frames_gaussians(bpy_module, scene, frames, references, mode, start,
                                               offset):
    from kernels.sequence import map_frame

    bpy = bpy_module
    objs, _ = _import(bpy, frames)
    vol = objs[0].gaussvdb.source_volume
    vol.sequence_mode, vol.frame_start, vol.frame_offset = mode, start, offset
    vol.frame_duration = 4 - offset
    for f in range(-1, 9):
        drawn, sync = _drawn(bpy, scene, f)
        n = map_frame(f, start, offset, 4 - offset, mode)
        if n is None:
            assert drawn == {}, f
            continue
        assert "blob_density" in drawn, f
        _same(drawn["blob_density"], references[(n, "density")])
        if n >= 2:
            _same(drawn["blob_heat"], references[(n, "heat")])
        else:  # heat has no voxels in frame 1: nothing drawn, no error
            assert "blob_heat" not in drawn and not sync.errors


def test_viewport_lod_and_memory_budget(bpy_module, scene, frames):
    importer, _, sf = _mods()
    bpy = bpy_module
    sf.CACHE.clear()
    objs, _ = importer.import_files(bpy.context, [frames], lods=("low", "high"), compute_error=False)
    obj = bpy.data.objects["blob_density"]
    assert (obj.gaussvdb.viewport_lod, obj.gaussvdb.render_lod) == ("low", "high")
    low, _ = _drawn(bpy, scene, 2, viewport=True)
    high, _ = _drawn(bpy, scene, 2, viewport=False)
    assert low["blob_density"].lod == "low" and high["blob_density"].lod == "high"
    assert high["blob_density"].count > low["blob_density"].count
    scene.gaussvdb.sequence_memory = 0.0  # keep only the frame on screen
    sf.CACHE.clear()
    ev = sf.CACHE.evictions
    for f in (1, 2, 3):
        _drawn(bpy, scene, f, viewport=True)
    assert len(sf.CACHE) == 1 and sf.CACHE.evictions - ev == 2 * 3 - 1  # 2 grids x 3 frames
    scene.gaussvdb.sequence_memory = 64.0
    for f in (1, 2, 3):
        _drawn(bpy, scene, f, viewport=True)
    assert len(sf.CACHE) == 6
    held = sf.CACHE.nbytes
    assert held > 0 and all(n > 0 for _, n in sf.CACHE.items.values())
    hits = sf.CACHE.hits
    _drawn(bpy, scene, 2, viewport=True)  # a second visit converts nothing
    assert sf.CACHE.hits == hits + 2 and sf.CACHE.nbytes == held


def test_auto_range_all_frames_or_each_frame(bpy_module, scene, frames):
    bpy = bpy_module
    objs, _ = _import(bpy, frames, grids="density")
    obj = objs[0]
    per = obj.gaussvdb.stats()["sequence"]["values"]
    ranges = {f: _drawn(bpy, scene, f)[1].value_range for f in (1, 2, 3, 4)}
    assert len(set(ranges.values())) == 1  # steady while playing
    assert ranges[1][1] == pytest.approx(max(v["max"] for v in per.values()))
    obj.gaussvdb.sequence_range = "FRAME"
    for f in (1, 3):
        lo, hi = _drawn(bpy, scene, f)[1].value_range
        assert hi == pytest.approx(per[str(f)]["max"]) and lo == pytest.approx(per[str(f)]["min"])


def test_missing_empty_and_unreadable_frames(bpy_module, scene, tmp_path, references):
    _, _, sf = _mods()
    bpy = bpy_module
    folder = str(tmp_path / "gappy")
    first = write_frames(folder, [1, 2, 4, 5], broken=(5,))
    sf._WARNED.clear()
    objs, message = _import(bpy, first)
    assert "cannot read blob_0005.vdb" in message  # said at import, left out of the range
    vol = objs[0].gaussvdb.source_volume
    assert vol.frame_duration == 5
    drawn, sync = _drawn(bpy, scene, 3)  # blob_0003 is missing: frame 2 is held, one warning
    _same(drawn["blob_density"], references[(2, "density")])
    assert any("blob_0003.vdb" in w and "held" in w for w in sync.warnings)
    assert not sync.errors
    _, sync = _drawn(bpy, scene, 3)
    assert not any("blob_0003" in w for w in sync.warnings)  # once
    drawn, sync = _drawn(bpy, scene, 5)  # unreadable: an error naming the frame, nothing drawn
    assert drawn == {} and len(sync.errors) == 2
    assert all("frame 5" in e and "blob_0005.vdb" in e for e in sync.errors)
    drawn, sync = _drawn(bpy, scene, 4)  # and the next frame draws again
    _same(drawn["blob_density"], references[(4, "density")])
    assert not sync.errors


def _camera_scene(bpy, scene):
    add_camera(bpy, scene, (1.6, -3.0, 0.8), (math.pi / 2, 0.0, 0.0), lens=35.0)
    setup_render(scene, 40, 24)
    s = scene.gaussvdb
    s.auto_range, s.value_min, s.value_max = False, 0.0, 1.0  # the same colours for every file
    s.density_unit, s.density = "WORLD", 20.0
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import image_file

    image_file.set_exact_colors(scene)
    scene.render.image_settings.file_format = "PNG"
    scene.render.use_file_extension = True


def _png(bpy, path):
    return read_image(bpy, path).reshape(-1)


def test_animation_render_equals_single_file_renders_and_survives_reopen(bpy_module, scene, frames,
                                                                         tmp_path):
    importer, _, sf = _mods()
    bpy = bpy_module
    _camera_scene(bpy, scene)
    singles = {}
    for n in (1, 2, 3):  # each file alone, in a scene of its own
        for o in list(scene.objects):
            if o.type != "CAMERA":
                bpy.data.objects.remove(o)
        importer.import_vdb(frames.replace("0001", f"{n:04d}"), grids=["density"], lods=("low",),
                            collection=scene.collection, compute_error=False)
        scene.render.filepath = str(tmp_path / f"single_{n}.png")
        scene.render.use_file_extension = False
        bpy.ops.render.render(write_still=True)
        singles[n] = _png(bpy, str(tmp_path / f"single_{n}.png"))
    for o in list(scene.objects):
        if o.type != "CAMERA":
            bpy.data.objects.remove(o)
    sf.CACHE.clear()
    importer.import_files(bpy.context, [frames], grids="density", lods=("low",), compute_error=False)
    scene.frame_start, scene.frame_end = 1, 3
    scene.render.filepath = str(tmp_path / "anim_")
    scene.render.use_file_extension = True
    bpy.ops.render.render(animation=True)
    for n in (1, 2, 3):
        px = _png(bpy, str(tmp_path / f"anim_{n:04d}.png"))
        assert px.max() > 0.1
        assert np.array_equal(px, singles[n]), n
    assert not np.array_equal(singles[1], singles[3])
    # saved with a relative path and reopened: frame 3 renders the same
    blend = str(tmp_path / "seq.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend, relative_remap=True)
    bpy.ops.wm.open_mainfile(filepath=blend)
    sf.CACHE.clear()
    scene = bpy.context.scene
    vol = bpy.data.objects["blob_density"].gaussvdb.source_volume
    assert vol.filepath.startswith("//") and vol.is_sequence and vol.frame_duration == 4
    scene.frame_set(3)
    scene.render.filepath = str(tmp_path / "reopened.png")
    scene.render.use_file_extension = False
    bpy.ops.render.render(write_still=True)
    assert np.array_equal(_png(bpy, str(tmp_path / "reopened.png")), singles[3])


def test_disk_cache_next_to_blend_skips_conversion(bpy_module, scene, frames, references, tmp_path):
    _, _, sf = _mods()
    bpy = bpy_module
    objs, _ = _import(bpy, frames, grids="density")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "cache_test.blend"))
    scene = bpy.context.scene
    scene.gaussvdb.use_sequence_disk_cache = True
    sf.CACHE.clear()
    before = dict(sf.STATS)
    fresh = {f: _drawn(bpy, scene, f)[0]["blob_density"] for f in (1, 2)}
    folder = tmp_path / "gaussvdb_cache"
    assert sorted(os.listdir(folder)) == ["blob_0001.density.low.npz", "blob_0002.density.low.npz"]
    assert sf.STATS["disk_writes"] - before["disk_writes"] == 2
    _same(fresh[2], references[(2, "density")])  # converted: exact
    sf.CACHE.clear()  # a second session: read from disk, not converted
    converted = sf.STATS["converted"]
    again = {f: _drawn(bpy, scene, f)[0]["blob_density"] for f in (1, 2)}
    assert sf.STATS["converted"] == converted and sf.STATS["disk_hits"] - before["disk_hits"] == 2
    for f in (1, 2):
        a, b = again[f], fresh[f]
        assert np.array_equal(a.group_origins, b.group_origins) and np.array_equal(a.offsets, b.offsets)
        assert np.allclose(a.sigmas, b.sigmas, rtol=1e-6)
        value_range = b.params["value_max"] - b.params["value_min"]  # the encoding's float16 bound
        assert np.abs(a.values - b.values).max() <= 1e-3 * value_range
    # a re-baked frame is converted again
    write_grid(frames, blob(3), voxel_size=0.1)
    sf.CACHE.clear()
    _drawn(bpy, scene, 1)
    assert sf.STATS["converted"] == converted + 1


def test_animation_goes_on_past_an_unreadable_frame(bpy_module, scene, tmp_path):
    from bl_ext.user_default.gaussvdb.gaussvdb_addon.engine import final_render

    bpy = bpy_module
    first = write_frames(str(tmp_path / "seq"), [1, 2, 3], broken=(2,))
    _import(bpy, first, grids="density")
    _camera_scene(bpy, scene)
    scene.frame_start, scene.frame_end = 1, 3
    scene.render.filepath = str(tmp_path / "anim_")
    bpy.ops.render.render(animation=True)  # no exception: frame 2 is a warning naming the file
    assert sorted(p for p in os.listdir(tmp_path) if p.startswith("anim_")) == [
        "anim_0001.png", "anim_0002.png", "anim_0003.png"]
    assert final_render.LAST_STATS["frame"] == 3 and not final_render.LAST_STATS["errors"]
    assert _png(bpy, str(tmp_path / "anim_0002.png")).reshape(-1, 4)[:, :3].max() == 0.0  # empty
    scene.frame_set(2)
    scene.render.filepath = str(tmp_path / "two.png")
    scene.render.use_file_extension = False
    bpy.ops.render.render(write_still=True)
    assert "blob_0002.vdb" in final_render.LAST_STATS["errors"][0]


def test_reload_keeps_the_sequence_and_its_timing(bpy_module, scene, frames):
    importer, _, _ = _mods()
    bpy = bpy_module
    objs, _ = _import(bpy, frames, grids="density")
    obj = objs[0]
    vol = obj.gaussvdb.source_volume
    vol.frame_start, vol.sequence_mode = 5, "PING_PONG"
    n_volumes = len(bpy.data.volumes)
    write_grid(frames.replace("0001", "0004"), blob(4) * 3, voxel_size=0.1)  # re-baked
    importer.reload_object(obj, compute_error=False)
    assert obj.gaussvdb.source_volume == vol and len(bpy.data.volumes) == n_volumes
    assert (vol.frame_start, vol.sequence_mode) == (5, "PING_PONG")
    figures = obj.gaussvdb.stats()["sequence"]
    assert figures["values"]["4"]["max"] == pytest.approx(3 * blob(4).max(), rel=1e-6)
    assert obj.gaussvdb.voxel_stats()["max"] == figures["values"]["4"]["max"]


def test_numbered_files_without_neighbours_are_no_sequence(bpy_module, scene, tmp_path):
    for n in (256, 512):  # 'bunny_ls_256.vdb' beside 'bunny_ls_512.vdb': two resolutions
        write_grid(tmp_path / f"bunny_{n}.vdb", blob(1), voxel_size=0.1)
    objs, _ = _import(bpy_module, str(tmp_path / "bunny_256.vdb"))
    assert [o.name for o in objs] == ["bunny_256_density"]
    assert not objs[0].gaussvdb.source_volume.is_sequence


def test_viewport_session_follows_the_timeline(bpy_module, scene, frames, references):
    import importlib

    bpy = bpy_module
    vp = importlib.import_module(f"{PKG}.gaussvdb_addon.engine.viewport")
    _import(bpy, frames, grids="density")

    class Eng:
        def tag_redraw(self):
            pass

    sess = vp.ViewportSession(Eng())
    for f in (1, 3, 2):
        scene.frame_set(f)
        dg = bpy.context.evaluated_depsgraph_get()
        assert sess.update(None, dg) is True
        (obj,) = sess.sync.scene.objects
        _same(obj.gaussians, references[(f, "density")])
    assert sess.update(None, bpy.context.evaluated_depsgraph_get()) is False  # same frame: nothing


def test_figures_read_elsewhere_are_taken_as_given(bpy_module, scene, tmp_path):
    """A cluster reads every frame's figures once (kernels.sequence.frame_figures) and hands
    them to each worker's import: the same object as an import that reads them itself, and
    frames whose figures are given are not read again (a changed one shows in the range)."""
    import importlib

    sequence_import = importlib.import_module(f"{PKG}.gaussvdb_addon.io.sequence_import")
    seq = importlib.import_module(f"{PKG}.kernels.sequence")
    first = write_frames(str(tmp_path / "fig"), [1, 2, 3, 4], broken=(4,))
    pat = seq.parse(first)
    known = {n: seq.frame_figures(pat.path(n), ["density"]) for n in (1, 2, 3, 4)}
    assert "error" in known[4] and set(known[2]["grids"]) == {"density"}
    own = sequence_import.convert_sequence(first, options=_options("density"))[0]
    given = sequence_import.convert_sequence(first, options=_options("density"), known=known)[0]
    assert given.sequence == own.sequence and given.values == own.values
    assert all(np.array_equal(a, b) for a, b in zip(given.leaf_box, own.leaf_box))
    known[3]["grids"]["density"]["values"] = dict(known[3]["grids"]["density"]["values"], max=99.0)
    taken = sequence_import.convert_sequence(first, options=_options("density"), known=known)[0]
    assert taken.values["max"] == 99.0 and taken.sequence["figures"]["values"]["3"]["max"] == 99.0


def _options(grid):
    import importlib

    co = importlib.import_module(f"{PKG}.kernels.convert_options")
    return co.ConvertOptions(grids=(grid,), lods=("low",), compute_error=False)
