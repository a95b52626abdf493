"""Every packed record the render kernels read, declared once, and the constants the numba kernels
and the GLSL shaders share.

A record is an ordered table of fields, ``"NAME"`` (one float) or ``"NAME:width"``; its fields'
offsets become module constants ``PREFIX_NAME`` and its width ``PREFIX_SIZE`` (``Record``). The
numba kernels import them by name: numba reads module globals as compile-time constants, so
``cam[CAM_W]`` compiles to the same code as ``cam[1]`` (tests/kernels/test_layout.py). The GLSL
shaders get the same names, and the shared constants, as ``#define`` lines (``glsl_defines``,
injected by the shader build); no .glsl file defines or hard-codes one of them (the test checks).

Adding a per-object setting: a field of ``LS`` (or of ``OBJ``, for what only the GPU reads), its
value in ``packing.pack_objects``; the kernels read it by its name in both languages.
"""
from __future__ import annotations

import math
from enum import IntEnum

from ...lod.levelset import SURFACE_LEVEL  # noqa: F401  (one of GLSL_CONSTANTS)


class Record:
    """Fields at consecutive offsets: ``fields`` a string of ``NAME`` / ``NAME:width`` words or
    (name, width) pairs. ``prefix`` names the constants (None: the bare field names, for the
    CPU kernels' scratch columns); ``glsl``: whether the shaders get them too; ``texels``: the
    fields a shader reads as whole texels, which start at a multiple of 4 (padding before them,
    and the size rounded up to whole texels)."""

    def __init__(self, prefix, fields, glsl=True, size_name=None, texels=()):
        if isinstance(fields, str):
            fields = [(w.split(":")[0], int(w.split(":")[1]) if ":" in w else 1) for w in fields.split()]
        self.prefix, self.glsl = prefix, glsl
        self.fields = tuple((n, int(w)) for n, w in fields)
        self.offset, off = {}, 0
        for name, width in self.fields:
            if name in self.offset or width < 1:
                raise ValueError(f"record {prefix}: field {name!r} repeated or of width {width}")
            if name in texels:
                off = 4 * -(-off // 4)
            self.offset[name] = off
            off += width
        self.size = 4 * -(-off // 4) if texels else off
        self.texels = tuple(texels)
        self.size_name = size_name or f"{prefix}_SIZE"
        if any((f"{prefix}_{n}" if prefix else n) == self.size_name for n in self.offset):
            raise ValueError(f"record {prefix}: a field named as its size {self.size_name}")

    def width(self, name):
        return dict(self.fields)[name]

    def constants(self) -> dict:
        """{constant name: offset}, and the size."""
        p = "" if self.prefix is None else self.prefix + "_"
        out = {p + n: o for n, o in self.offset.items()}
        out[self.size_name] = self.size
        return out


def texels(n):
    """RGBA texels that n floats take."""
    return -(-int(n) // 4)


# -- shared constants ---------------------------------------------------------------------------
LEAF = 8  # voxels per VDB leaf axis: a leaf cell
NODE_LEAVES = 16  # leaf cells per node axis (the walk's upper level)
NODE = LEAF * NODE_LEAVES
BRICK = LEAF + 2  # a reference-mode voxel brick's side: the leaf and a one-voxel apron
BRICK_HI = 8.999999  # a brick coordinate's upper clamp: its last trilinear cell, 8..9, kept open
TILE = 8  # screen tiles: TILE x TILE pixels, one 64-bit pixel mask
LUT_SIZE = 256  # entries of a transfer function's table (one GPU texture row)
BG_DEPTH = 1e10  # a pixel's Depth where nothing reached its median transmittance
OVERFLOW_DEPTH = -2e10  # the GPU's Depth for a pixel whose ray it could not finish (drawn on the CPU)
MAX_OBJ = 16  # objects one GPU frame draws (more: the device says so)
ROW_TEXELS = 4096  # GPU tables: texels per texture row
SQRT_HALF = math.sqrt(0.5)
SQRT_HALF_PI = math.sqrt(0.5 * math.pi)
TWO_OVER_SQRT_PI = 2.0 / math.sqrt(math.pi)
# Field-mode surfaces (cpu.surface): the occupancy above which a signed-distance mixture is
# trusted, the variance (voxels^2) of the blur under an occupancy surface's normal, and how far
# (voxels) around the hit the normal's Gaussians are gathered. SURFACE_LEVEL: lod.levelset's.
SDF_OCCUPANCY = 0.25
NORMAL_BLUR = 1.0
NORMAL_REACH = 4.0
# GPU Gaussian records (gpu.tables_gauss): 1/sigma as 18-bit floats (mantissa bits dropped,
# exponent bias), the pixel masks in pieces of MASK_BITS bits
MANT_DROP, EXP_REBIAS = 10, 112
MASK_BITS = 22


class Kind(IntEnum):
    """What an object is (Objects.kind)."""
    FOG = 0  # a volume: its values through its transfer function
    SHELL = 1  # a level set drawn as a shell of uniform opacity (paper mode, or surface off)
    SURFACE = 2  # a level set drawn as a lit opaque surface


class Shading(IntEnum):
    """How a volume is shaded (Objects.lit)."""
    EMISSION = 0
    LIT = 1
    LIT_SHADOWS = 2


class LightKind(IntEnum):
    """A light's kind (lights.pack)."""
    SUN = 0
    POINT = 1
    HEADLIGHT = 2  # the default light, shining along each ray


# -- the kernels' inputs ------------------------------------------------------------------------
# camera.Camera.packed: orthographic flag, image size, the image rectangle on the plane z = -1
# (persp) or the camera plane (ortho): extent, offset; rotation (rows, camera x y z in world
# columns), position, clip start and end
CAM = Record("CAM", "KIND W H EX EY OX OY ROT:9 POS:3 CLIP:2")
# packing.pack_settings: T_min, tau_max, support k, background rgba, paper steps and depth,
# Blinn-Phong (ambient, diffuse, specular, shininess), lit volumes' gradient threshold
SET = Record("SET", "TMIN TAU_MAX K BG:4 PAPER_STEPS PAPER_DEPTH SHADING:4 LIT_THRESHOLD")
# packing.pack_objects' ls row, a level set's colouring: 1 for a constant colour (COLOR), else a
# colormap over the world coordinate PLANE . (x, y, z, 1) of index points across RANGE; the
# voxel's world size
LS = Record("LS", "CONST PLANE:4 RANGE:2 VOXEL COLOR:3")
# transfer.TransferFunction.packed: value range, log scale flag, density
PAR = Record("PAR", "VMIN VMAX LOG DENSITY")
# packing.Gaussians.rec (gauss_pack.test_records): the per-ray test's row: centre, 1/sigma, this
# frame's extinction weight, the tile lists' entry bound
REC = Record("REC", "MU:3 INV:3 W LB", glsl=False)
# lights.pack
LIGHT_ROW = Record("LIGHT", "KIND VEC:3 RGB:3 PAD")
# packing.Objects.sh_grid: a lit volume's shadow grid, [origin xyz, spacing, dims xyz, offset in sh_tau]
SHG = Record("SHG", "ORIGIN:3 SPACING DIMS:3 OFFSET")

# -- the GPU tables (gpu_layout*) ---------------------------------------------------------------
# frame: the camera (padded to whole texels), then the settings
FR = Record("FR", [("CAM", 4 * texels(CAM.size)), ("SET", SET.size)])
# objs: per object, floats (texel-aligned where a shader reads 3 or 4 at once), then its clip
# half-spaces, one texel each: w2i rows 0-2, kind, transfer row, step, shading, ls, clip count,
# node grid (min, table offset, dims, walk scale), bounding spheres' reference point, a
# signed-distance surface's single-layer level (0: none), shadow grid
OBJ = Record("OBJ", [("W2I", 12), ("KIND", 1), ("TF", 1), ("STEP", 1), ("LIT", 1), ("LS", LS.size),
                     ("NCLIP", 1), ("NODE_MIN", 3), ("NODE_OFF", 1), ("NODE_DIMS", 3),
                     ("WALK_SCALE", 1), ("REF", 3), ("LEVEL", 1), ("SH_GRID", SHG.size)],
             texels=("W2I", "NODE_MIN", "NODE_DIMS", "REF", "SH_GRID"))
OBJ_TEXELS = texels(OBJ.size)
# obj_color (gpu.tables_color): colour map row (-1: none), colour grid's background
OCOL = Record("OCOL", "CTF CBG PAD:2")
# g_rec (gpu.tables_gauss): centre, entry bound (paper: w x volfac), 1/sigma words (size_words), w, value
GREC = Record("GREC", "MU:3 BOUND WORDS:2 W VAL")
# t_ent: Gaussian id, pixel mask in three pieces of MASK_BITS
TENT = Record("TENT", "ID MASK:3")
# tl_g, tl_par (gpu.tables_tiles): a Gaussian; the camera and k, then per object its camera
# matrix (3 x 4) and spectral norm
TLG = Record("TLG", "MU:3 INV:3 W OBJ")
TLP = Record("TLP", "W H EX EY OX OY ORTHO K")
TLO = Record("TLO", "CMAT:12 NORM PAD:3")

# -- the CPU kernels' per-ray columns (numba only) ----------------------------------------------
# The ray state st: transmittance TR, radiance RAD (rgb), the median depth DEPTH, the value sum
# VSUM and its weight VWT, segments SEGS, the surface flag HIT (HIT_FOUND, or HIT_NORMAL: found,
# its normal still to take from the Gaussians), the early-termination threshold TMIN, the paper's
# continuations PDEPTH and where the last one left PCUR; a surface hit: its t HIT_T, index-space
# gradient HIT_G, object HIT_OB and albedo HIT_C.
ST = Record(None, "TR RAD:3 DEPTH VSUM VWT SEGS HIT TMIN PDEPTH PCUR HIT_T HIT_G:3 HIT_OB HIT_C:3",
            glsl=False, size_name="NST")
HIT_FOUND, HIT_NORMAL = 1.0, 2.0
# A hit record (cpu.chords): chord [S, E], closest approach TS, sqrt(a/2) SA, C = peak x
# sqrt(pi / 2a), Q/2 HQ, a/2 HA, peak PK; then particles: erf at the member's last boundary FA
# (and a running one, FB), colour, value (0 when NaN) and value weight (0 when NaN); field: value
# V, ratios R, RC, exit EX, for lit volumes the gradient's terms GA + t GB and, for volumes
# coloured by a second grid, its mixture's term CV.
_CHORD = "S E TS SA C HQ HA PK "
HIT_PARTICLES = Record(None, _CHORD + "FA FB CR CG CB VAL VW", glsl=False, size_name="NF_PARTICLES")
HIT_FIELD = Record(None, _CHORD + "V R RC EX GA:3 GB:3 CV", glsl=False, size_name="NF_FIELD")
NF = max(HIT_PARTICLES.size, HIT_FIELD.size)  # a hit record's columns
# The sweep state (cpu.chords): qs (int64): the queue's end NQ, active NACT, members NM, hits
# NH, field sample ISAMP, queue head QH; fs: IA, LAST, RHO, HSTEP, CEND
QS = Record(None, "NQ NACT NM NH ISAMP QH", glsl=False, size_name="NQS")
FS = Record(None, "IA LAST RHO HSTEP CEND", glsl=False, size_name="NFS")

RECORDS = (CAM, SET, LS, PAR, REC, LIGHT_ROW, SHG, FR, OBJ, OCOL, GREC, TENT, TLG, TLP, TLO, ST,
           HIT_PARTICLES, HIT_FIELD, QS, FS)
ENUMS = ((Kind, "KIND"), (Shading, "SHADING"), (LightKind, "LIGHT"))  # (enum, GLSL prefix)
# the scalar constants the shaders get (by name, from this module)
GLSL_CONSTANTS = ("LEAF", "NODE_LEAVES", "NODE", "BRICK", "BRICK_HI", "TILE", "LUT_SIZE", "BG_DEPTH",
                  "OVERFLOW_DEPTH", "ROW_TEXELS", "SQRT_HALF", "SQRT_HALF_PI", "TWO_OVER_SQRT_PI",
                  "SDF_OCCUPANCY", "NORMAL_BLUR", "NORMAL_REACH", "SURFACE_LEVEL", "MANT_DROP",
                  "EXP_REBIAS", "MASK_BITS", "OBJ_TEXELS")


def _export():
    """The records' constants as module globals (one value per name, checked)."""
    g = globals()
    seen = {}
    for r in RECORDS:
        for name, v in r.constants().items():
            if seen.get(name, v) != v or (name not in seen and name in g):
                raise ValueError(f"layout: {name} declared twice with different values")
            seen[name] = v
            g[name] = v


_export()


def _glsl_value(v) -> str:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise TypeError(f"layout: no GLSL form for {v!r}")
    s = str(int(v)) if isinstance(v, int) else repr(float(v))
    return f"({s})" if s.startswith("-") else s


def glsl_defines(max_obj=MAX_OBJ) -> dict:
    """{name: value} for the shaders' ``#define`` lines: the shared constants, every GLSL record's
    offsets and size, the enums as KIND_FOG ..., and MAX_OBJ (a shader's per-object array size,
    max_obj <= MAX_OBJ)."""
    g = globals()
    out = {n: _glsl_value(g[n]) for n in GLSL_CONSTANTS}
    for r in RECORDS:
        if r.glsl:
            out.update((n, _glsl_value(v)) for n, v in r.constants().items())
    for e, prefix in ENUMS:
        out.update((f"{prefix}_{m.name}", str(int(m))) for m in e)
    out["MAX_OBJ"] = str(int(max_obj))
    return out


def glsl_header(max_obj=MAX_OBJ) -> str:
    """glsl_defines as ``#define NAME value`` lines."""
    return "".join(f"#define {n} {v}\n" for n, v in glsl_defines(max_obj).items())
