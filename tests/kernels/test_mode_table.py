"""The table of render modes (kernels/render/devices/modes.py): every mode has an entry, a derived mode
is its drawn mode over other data, the surface rule, the kernels' id tuples, the GPU's tables for
every mode the table puts on the GPU, and no source file of the product compares modes by their
order."""
import dataclasses
import os
import re

import numpy as np

from kernels import mode_names
from kernels.mode_names import Mode
from kernels.render import CPUDevice, RenderObject, RenderScene
from kernels.render.devices import modes
from kernels.render.scene.synthetic import gaussian_set, grid_from_dense

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PRODUCT = ("kernels", "gaussvdb_addon", "operators", "tools", "benchmarks", "__init__.py")


def test_every_mode_has_an_entry():
    assert set(modes.SPECS) == set(Mode)
    for m in Mode:
        s = modes.spec(m)
        assert s.mode == m and modes.spec(int(m)) is s and modes.spec(m.name.lower()) is s
        assert s.draws in (modes.GAUSSIANS, modes.VOXELS)
        assert s.lights in (None, modes.CENTRES, modes.SAMPLES)
        assert s.color in (modes.GAUSSIANS, modes.FIELD, modes.VOXELS)
        assert s.with_surfaces is None or modes.spec(s.with_surfaces).surfaces
    assert set(mode_names.NAMES) == {m.name.lower() for m in modes.SPECS}


def test_a_derived_mode_is_its_drawn_mode():
    derived = [s for s in modes.SPECS.values() if s.drawn_as is not None]
    assert [s.mode for s in derived] == [Mode.SPLAT]
    for s in derived:
        drawn = modes.spec(s.drawn_as)
        assert drawn.drawn_as is None and s.mode not in modes.drawn_modes()
        assert dataclasses.replace(s, mode=drawn.mode, drawn_as=None) == drawn


def test_the_surface_rule():
    assert modes.frame_mode(Mode.PARTICLES, surfaces=True) == Mode.FIELD
    for m in modes.drawn_modes():
        assert modes.frame_mode(m, surfaces=False) == m
        if m != Mode.PARTICLES:
            assert modes.frame_mode(m, surfaces=True) == m


def test_particles_with_a_surface_draw_as_field():
    """The rule as the CPU device applies it: the frame's mode and image are the field's."""
    from test_render_surface import TF, camera

    from kernels.lod import build_lod

    g = np.arange(24)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    phi = np.sqrt((X - 11.5) ** 2 + (Y - 11.5) ** 2 + (Z - 11.5) ** 2) - 7.0
    grid = grid_from_dense(np.clip(phi, -3, 3), active=np.abs(phi) < 3, background=3.0, grid_class="level_set")
    sphere = RenderObject(build_lod(grid, "low"), grid=grid, is_level_set=True, surface=True)
    cam, dev = camera(24), CPUDevice()
    assert dev.begin_frame(RenderScene([sphere], mode="particles"), cam, TF).mode == Mode.FIELD
    a = dev.render(RenderScene([sphere], mode="particles"), cam, TF)["Combined"]
    b = CPUDevice().render(RenderScene([sphere], mode="field"), cam, TF)["Combined"]
    assert a[..., 3].max() > 0.5
    np.testing.assert_array_equal(a, b)
    vol = RenderObject(gaussian_set([[11.5, 11.5, 11.5]], [2.0], [1.0], [1.0]))
    assert dev.begin_frame(RenderScene([vol], mode="particles"), cam, TF).mode == Mode.PARTICLES


def test_the_kernels_id_tuples_are_the_columns():
    drawn = modes.drawn_modes()
    assert modes.SCREEN_TILE_MODES == tuple(int(m) for m in drawn if modes.spec(m).screen_tiles)
    assert modes.PIECE_MODES == tuple(int(m) for m in drawn if modes.spec(m).pieces)
    assert modes.LEAF_TILE_MODES == tuple(int(m) for m in drawn if modes.spec(m).leaf_tiles)
    assert all(type(i) is int for i in modes.SCREEN_TILE_MODES + modes.PIECE_MODES + modes.LEAF_TILE_MODES)


def test_every_gpu_mode_has_its_tables_and_shader_files():
    from kernels.render.gpu import tables as gpu_layout  # noqa: F401  (registers its modes' tables)

    on_gpu = {m.name.lower() for m in modes.drawn_modes() if modes.spec(m).gpu is not None}
    assert set(gpu_layout.MODE_TABLES) == on_gpu
    assert set(modes.gpu_modes()) == on_gpu | {"splat"}
    glsl = os.path.join(ROOT, "kernels", "render", "gpu", "glsl")
    for m in modes.drawn_modes():
        shader = modes.spec(m).gpu
        assert shader is None or all(os.path.isfile(os.path.join(glsl, f)) for f in shader.glsl)


ORDER = re.compile(r"(\bmode\w*\)?\s*[<>]=?\s*(Mode\.|\d))|([<>]=?\s*Mode\.[A-Z])|(Mode\.[A-Z]+\s*[<>])")


def product_sources():
    for top in PRODUCT:
        path = os.path.join(ROOT, top)
        if os.path.isfile(path):
            yield path
        for folder, dirs, files in os.walk(path):
            dirs[:] = [d for d in dirs if not d.startswith((".", "__pycache__"))]
            yield from (os.path.join(folder, f) for f in files if f.endswith((".py", ".glsl")))


def test_no_source_compares_modes_by_order():
    bad = []
    for path in product_sources():
        with open(path, encoding="utf-8") as fh:
            for n, line in enumerate(fh, 1):
                if ORDER.search(line):
                    bad.append(f"{os.path.relpath(path, ROOT)}:{n}: {line.strip()}")
    assert not bad, "modes compared by their order (ask kernels/render/devices/modes.py):\n" + "\n".join(bad)


def test_the_order_pattern_finds_what_it_should():
    for line in ("if mode <= Mode.FIELD:", "int(frame.mode) <= Mode.PAPER", "x = mode >= 2",
                 "if Mode.PAPER > mode:", "m < Mode.SPLAT"):
        assert ORDER.search(line), line
    for line in ("if mode == Mode.FIELD:", "mode in PIECE_MODES", "def f(mode) -> Mode:"):
        assert not ORDER.search(line), line
