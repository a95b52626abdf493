"""The one declaration of the kernels' packed records (kernels/render/inputs/layout.py): the shaders
hold no copy of a value it declares, the packers fill records of its sizes where its names
say, and numba compiles a named offset as it compiles the literal."""
import glob
import os
import re

import numpy as np

from kernels.render import Camera, CPUDevice, RenderObject, RenderScene, TransferFunction
from kernels.render.gpu import assembly, tables_color, tables_gauss, tables_tiles
from kernels.render.gpu import tables as gpu_layout
from kernels.render.inputs import gauss_pack, layout
from kernels.render.inputs.packing import Scratch, pack_settings
from kernels.render.scene import lights
from kernels.render.scene.synthetic import gaussian_set

GLSL = sorted(glob.glob(os.path.join(assembly.GLSL_DIR, "*.glsl")))
NUMBER = re.compile(r"(?<![\w.])(\d+\.\d*(?:[eE][-+]?\d+)?|\d+[eE][-+]?\d+|\.\d+(?:[eE][-+]?\d+)?|\d+)u?(?![\w.])")


def glsl_code(path):
    """A shader's text without its comments."""
    with open(path, encoding="utf-8") as f:
        s = f.read()
    return re.sub(r"//[^\n]*", "", re.sub(r"/\*.*?\*/", "", s, flags=re.S))


def test_no_shader_defines_a_value_the_layout_holds():
    held = layout.glsl_defines()
    assert GLSL and {"CAM_W", "SET_K", "OBJ_LS", "LS_VOXEL", "LEAF", "BG_DEPTH", "KIND_SURFACE"} <= set(held)
    bad = [(os.path.basename(p), n) for p in GLSL
           for n in re.findall(r"^\s*#\s*define\s+(\w+)", glsl_code(p), re.M) if n in held]
    assert not bad, f"#defines the layout generates: {bad}"


def distinctive():
    """The layout's values that no shader has a reason to spell out: floats that are not
    small multiples of 1/8 and the larger integers."""
    out = {}
    for n in layout.GLSL_CONSTANTS:
        v = getattr(layout, n)
        if isinstance(v, float) and (abs(v) >= 1e6 or v * 8 != round(v * 8)):
            out[n] = v
        elif isinstance(v, int) and abs(v) >= 20 and n != "OBJ_TEXELS":
            out[n] = v
    return out


def test_no_shader_hard_codes_a_value_the_layout_holds():
    vals = distinctive()
    assert {"BG_DEPTH", "OVERFLOW_DEPTH", "SURFACE_LEVEL", "SQRT_HALF", "BRICK_HI", "ROW_TEXELS",
            "LUT_SIZE", "EXP_REBIAS", "MASK_BITS"} <= set(vals)
    bad = []
    for p in GLSL:
        for lit in NUMBER.findall(glsl_code(p)):
            x = np.float32(float(lit))
            bad += [(os.path.basename(p), lit, n) for n, v in vals.items() if x == np.float32(abs(v))]
    assert not bad, f"literals the layout holds: {bad}"
    # (the check itself sees such a literal)
    assert any(np.float32(float(m)) == np.float32(layout.SURFACE_LEVEL)
               for m in NUMBER.findall("float s = 0.13397460 * x;"))


def test_no_shader_reads_a_record_by_position():
    bad = []
    for p in GLSL:
        s = glsl_code(p)
        bad += re.findall(r"fr\(FR_\w+ \+ \d+\)|fr\(\d+\)|obj_texel\(\w+, \d+\)", s)
        bad += re.findall(r"\bkind\w* *[!=]= *\d", s)
    assert not bad, bad


def test_the_header_is_one_define_per_name():
    h = layout.glsl_header(max_obj=4)
    lines = h.splitlines()
    names = [ln.split()[1] for ln in lines]
    assert len(names) == len(set(names)) and all(ln.startswith("#define ") for ln in lines)
    d = layout.glsl_defines(4)
    assert d["MAX_OBJ"] == "4" and d["OVERFLOW_DEPTH"].startswith("(-") and d["LEAF"] == "8"
    assert np.float32(float(d["SURFACE_LEVEL"])) == np.float32(layout.SURFACE_LEVEL)
    assert d["KIND_SURFACE"] == str(int(layout.Kind.SURFACE)) and d["OBJ_TEXELS"] == "12"


def test_records_are_consecutive_and_the_texel_reads_aligned():
    for r in layout.RECORDS:
        off = 0
        for name, width in r.fields:
            assert r.offset[name] == (4 * -(-off // 4) if name in r.texels else off)
            off = r.offset[name] + width
        assert off <= r.size < off + 4 and (r.size == off or r.texels)
    for f in ("W2I", "NODE_MIN", "NODE_DIMS", "REF", "SH_GRID"):  # read as whole texels
        assert layout.OBJ.offset[f] % 4 == 0
    # one more ls field moves the object row's texel reads along, aligned
    ls = layout.Record("LS", "CONST PLANE:4 RANGE:2 VOXEL COLOR:3 NEW")
    obj = layout.Record("OBJ", [(n, ls.size if n == "LS" else w) for n, w in layout.OBJ.fields],
                        texels=layout.OBJ.texels)
    assert obj.offset["NODE_MIN"] == layout.OBJ_NODE_MIN + 4 and obj.size == layout.OBJ_SIZE + 4
    assert layout.SHG_DIMS % 4 == 0 and layout.FR_SET >= layout.CAM_SIZE
    assert layout.OBJ.width("LS") == layout.LS_SIZE and layout.OBJ.width("SH_GRID") == layout.SHG_SIZE
    assert layout.GREC_SIZE == 8 and layout.TENT_SIZE == 4 and layout.TLG_SIZE == 8  # two / one texel(s)
    assert layout.NF >= layout.NF_PARTICLES and layout.NF == layout.NF_FIELD


def frame(mode="particles"):
    rng = np.random.default_rng(2)
    objs = [RenderObject(gaussian_set(rng.uniform(0, 9, (60, 3)), 0.8, rng.uniform(0, 1, 60), 1.0),
                         clip=np.array([[1.0, 0.0, 0.0, -2.0]]))]
    cam = Camera.frame_box([0] * 3, [9] * 3, 20, 12)
    return CPUDevice().begin_frame(RenderScene(objs, mode=mode), cam, TransferFunction.from_colormap("viridis", 0, 1))


def test_the_packers_fill_the_declared_records():
    cam = Camera.frame_box([0] * 3, [4] * 3, 30, 20, kind="ortho")
    c = cam.packed()
    assert c.shape == (layout.CAM_SIZE,) and (c[layout.CAM_W], c[layout.CAM_H], c[layout.CAM_KIND]) == (30, 20, 1)
    np.testing.assert_array_equal(c[layout.CAM_POS:layout.CAM_POS + 3], cam.cam_to_world[:3, 3])
    assert c[layout.CAM_CLIP + 1] == np.inf
    tf = TransferFunction.from_colormap("viridis", 0.25, 3.0, log_scale=True, density=7.0)
    p = tf.packed()
    assert p.shape == (layout.PAR_SIZE,)
    assert (p[layout.PAR_VMIN], p[layout.PAR_VMAX], p[layout.PAR_LOG], p[layout.PAR_DENSITY]) == (0.25, 3.0, 1, 7)
    pts = [lights.Light("point", (1.0, 2.0, 3.0))]
    for ls in ([], pts):
        assert lights.pack(ls).shape[1] == layout.LIGHT_SIZE
    assert lights.pack(pts)[0, layout.LIGHT_KIND] == layout.LightKind.POINT
    assert lights.pack([])[0, layout.LIGHT_KIND] == layout.LightKind.HEADLIGHT
    assert gauss_pack.test_records(np.ones((3, 3)), np.ones((3, 3))).shape == (3, layout.REC_SIZE)
    fr = frame()
    s = pack_settings(RenderScene([], support_k=2.5))
    assert s.shape == (layout.SET_SIZE,) and s[layout.SET_K] == 2.5
    assert fr.transfer.settings.shape == (layout.SET_SIZE,) and fr.cam.shape == (layout.CAM_SIZE,)
    assert fr.objects.ls.shape[1] == layout.LS_SIZE and fr.objects.sh_grid.shape[1] == layout.SHG_SIZE
    assert fr.gauss.rec.shape[1] == layout.REC_SIZE
    np.testing.assert_array_equal(fr.gauss.rec[:, layout.REC_W], fr.gauss.w)
    assert list(fr.objects.kind) == [layout.Kind.FOG]
    # the GPU tables, read back where the shaders read them
    objs, per = gpu_layout.object_rows(fr)
    assert per == layout.OBJ_TEXELS + 1
    row = objs.reshape(-1)[:per * 4]
    assert row[layout.OBJ_NCLIP] == 1 and row[layout.OBJ_KIND] == layout.Kind.FOG
    assert row[layout.OBJ_STEP] == np.float32(fr.objects.step[0])
    np.testing.assert_array_equal(row[layout.OBJ_LS:layout.OBJ_LS + layout.LS_SIZE],
                                  fr.objects.ls[0].astype(np.float32))
    table = gpu_layout.frame_table(fr).reshape(-1)
    np.testing.assert_array_equal(table[layout.FR_CAM:layout.FR_CAM + layout.CAM_SIZE], fr.cam.astype(np.float32))
    assert table[layout.FR_SET + layout.SET_K] == np.float32(fr.transfer.settings[layout.SET_K])
    g = tables_gauss.gauss_tables(fr.mode, fr.gauss)["g_rec"].reshape(-1, layout.GREC_SIZE)
    m = fr.gauss.mu.shape[0]
    np.testing.assert_array_equal(g[:m, layout.GREC_W], fr.gauss.w.astype(np.float32))
    ti = tables_tiles.tile_inputs(fr)
    tl = ti["tl_g"].reshape(-1, layout.TLG_SIZE)
    np.testing.assert_array_equal(tl[:m, layout.TLG_OBJ], 0)
    tp = ti["tl_par"].reshape(-1)
    assert (tp[layout.TLP_W], tp[layout.TLP_H]) == (20, 12)
    assert tables_gauss.tile_tables(*tables_gauss.frame_tiles(fr))["t_ent"].reshape(-1)[
        layout.TENT_ID] >= 0
    assert tables_color.frame_tables(fr) == {}


def test_scratch_fields_are_all_allocated_by_name():
    import inspect

    from kernels.render.cpu import pixels

    src = inspect.getsource(pixels.new_scratch.py_func)
    assert set(re.findall(r"(\w+)=np\.empty", src)) == set(Scratch._fields)


def test_named_offsets_compile_as_the_literals():
    """numba folds module constants (and IntEnum members): the same machine code."""
    import numba

    @numba.njit
    def named(c, k):
        return c[layout.CAM_ROT + 4] * c[layout.CAM_W] + (k[0] == layout.Kind.SURFACE)

    @numba.njit
    def literal(c, k):
        return c[11] * c[1] + (k[0] == 2)

    c, k = np.arange(21.0), np.array([2], np.int32)
    assert named(c, k) == literal(c, k) == 12.0

    def code(f):
        asm = next(iter(f.inspect_asm().values()))
        asm = re.sub(r"_ZN\S*|\.const\.\w+|<locals>\.\w+", "NAME", asm)  # the functions' own names
        return [ln for ln in asm.splitlines() if ln.strip() and not ln.lstrip().startswith((".", "#", ";"))]

    assert code(named) == code(literal)
