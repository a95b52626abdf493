"""The GPU device's shaders outside Blender: plain OpenGL 4.3 compute on moderngl (a headless EGL
context), drawing a saved frame (kernels/render/gpu/case.py's ``.npz``) exactly as the GPU device
(gaussvdb_addon/gpu) does: the same tables uploaded as the same textures, the screen-tile lists'
three passes and the counts' readback where the device builds them on the GPU, one dispatch of the
mode's shader over the frame, the passes read back. The shaders come from glsl_assembly, which
Blender's create-info takes too. Needs numpy and moderngl only (no Blender, no numba).

    python benchmarks/gl_backend.py CASE.npz ... [--view 512x512] [--out FOLDER]

writes per case FOLDER/CASE.npz: the Combined pass and Depth/Value (rgba, dv: (H, W, 4) float32,
row 0 = bottom), and prints a JSON line: the renderer, the image's shape and the overflow tiles
(tiles the device would draw on the CPU)."""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_ASM = os.path.join(ROOT, "kernels", "render", "gpu", "assembly.py")


def assembly():
    """kernels/render/gpu/assembly.py loaded by path (the package's __init__ imports numba)."""
    mod = sys.modules.get("glsl_assembly")
    if mod is None:
        spec = importlib.util.spec_from_file_location("glsl_assembly", _ASM)
        mod = importlib.util.module_from_spec(spec)
        sys.modules["glsl_assembly"] = mod
        spec.loader.exec_module(mod)
    return mod


class TooMany(Exception):
    """The screen-tile lists pass what this GPU's textures hold: the device takes the CPU's."""


class Case:
    """A saved frame (gpu_case.save): its tables per view, ints, programs, CPU images."""

    def __init__(self, path):
        self.path = path
        self.z = np.load(path, allow_pickle=False)
        self.info = json.loads(str(self.z["case.json"]))
        self.views = {v["name"]: v for v in self.info["views"]}
        asm = assembly()
        self.program = asm.from_json(self.info["program"]) if "program" in self.info else None
        self.tile_programs = {s: asm.from_json(p) for s, p in self.info.get("tile_programs", {}).items()}
        self._read = {}
        self.files = set(self.z.files)

    def array(self, key):
        """An array of the file, decompressed once (the views share most tables)."""
        if key not in self._read:
            self._read[key] = self.z[key]
        return self._read[key]

    def tables(self, view):
        """{name: array} the mode's shader samples for this view."""
        out = {}
        for key in sorted(self.files):
            if key.startswith("t."):
                name = key[2:]
                own = f"{view}.t.{name}"
                out[name] = self.array(own if own in self.files else key)
        return out

    def tile_inputs(self, view):
        return {"tl_g": self.array("tiles.tl_g"), "tl_par": self.array(f"{view}.tiles.tl_par")}

    def cpu(self, view):
        """The CPU device's Combined pass of a view, (H, W, 4) float32 (case.pack_image's planes
        unpacked: the values rounded as saved; cpu_floor_db says by how much)."""
        a = self.z[f"{view}.cpu"]
        if a.dtype == np.float32:  # (saved before the images were packed)
            return a
        v = self.views[view]
        return np.ascontiguousarray(a.T).view(np.float32).reshape(v["height"], v["width"], 4)

    def define(self, name):
        return dict(self.program.defines)[name]


class GL:
    """One headless OpenGL 4.3 context and the compiled programs (per Program, per process)."""

    def __init__(self, backend="egl"):
        import moderngl

        self.ctx = moderngl.create_context(standalone=True, backend=backend, require=430)
        self.renderer = self.ctx.info["GL_RENDERER"]
        self.max_texture = int(self.ctx.info["GL_MAX_TEXTURE_SIZE"])
        self._programs = {}
        self.asm = assembly()

    def program(self, program):
        program = self.asm.on_renderer(program, self.renderer)
        cs = self._programs.get(program)
        if cs is None:
            cs = self._programs[program] = (self.ctx.compute_shader(self.asm.glsl_430(program)), program)
        return cs

    def upload(self, arrays):
        """{name: float32 array} -> {name: texture}: as compute.upload (2-D RGBA32F, 3-D R32F)."""
        out = {}
        for name, a in arrays.items():
            a = np.ascontiguousarray(a, np.float32)
            if self.asm.texture_kind(a) == "FLOAT_3D":
                out[name] = self.ctx.texture3d((a.shape[2], a.shape[1], a.shape[0]), 1, a.tobytes(), dtype="f4")
            else:
                if max(a.shape[:2]) > self.max_texture:
                    raise TooMany(f"the scene's {name} table needs a {a.shape[1]}x{a.shape[0]} texture")
                out[name] = self.ctx.texture((a.shape[1], a.shape[0]), 4, a.tobytes(), dtype="f4")
        return out

    def image(self, w, h):
        return self.ctx.texture((w, h), 4, dtype="f4")

    def counter(self, w, h):
        return self.ctx.texture((w, h), 1, np.zeros(w * h, np.uint32).tobytes(), dtype="u4")

    def run(self, program, tex, ints, groups):
        """One dispatch: samplers and images bound at the program's slots, ints as uniforms, then
        a barrier (gpu.compute.dispatch ends with one too)."""
        cs, program = self.program(program)
        for slot, (name, _) in enumerate(program.samplers):
            tex[name].use(location=slot)
        for slot, (name, _, _, qual) in enumerate(program.images):
            tex[name].bind_to_image(slot, read="READ" in qual, write="WRITE" in qual)
        for name, v in ints.items():
            if name in cs:  # (a push constant the compiler dropped: compute.dispatch skips it too)
                cs[name] = int(v)
        cs.run(*groups)
        self.ctx.memory_barrier()

    def timed(self, fn):
        """fn() and its GPU time in ms (a GL_TIME_ELAPSED query)."""
        q = self.ctx.query(time=True)
        with q:
            fn()
        return q.elapsed / 1e6


def read(tex):
    return np.frombuffer(tex.read(), np.float32).reshape(tex.height, tex.width, 4).copy()


def nbytes(tex):
    """Texture bytes (float32 or uint32 components; a 3-D texture's size has three sides)."""
    return sum(int(np.prod(t.size)) * t.components * 4 for t in tex.values())


class Frame:
    """A case's view on a GL context: upload(), lists() (where the GPU builds them), draw()."""

    def __init__(self, gl, case, view):
        self.gl, self.case, self.view = gl, case, view
        v = case.views[view]
        self.w, self.h = v["width"], v["height"]
        self.tex = {}
        self.out = None
        self._arrays = self._tile_in = None

    def read_tables(self):
        """The view's tables and tile inputs read from the file once (decompressed: CPU work,
        kept out of the upload's and the lists' times)."""
        if self._arrays is None:
            self._arrays = self.case.tables(self.view)
            if self.case.info["on_gpu_tiles"]:
                self._tile_in = self.case.tile_inputs(self.view)
        return self._arrays

    def upload(self):
        self.tex = self.gl.upload(self.read_tables())
        self.gl.ctx.finish()

    def lists(self):
        """The screen-tile lists' three passes (gaussvdb_addon/gpu/tiles.build); TooMany where
        the device would take the CPU's lists."""
        gl, case = self.gl, self.case
        if not case.info["on_gpu_tiles"]:
            return 0
        row = int(case.define("ROW_TEXELS"))
        m = int(case.info["gaussians"])
        v = case.views[self.view]
        ntx, nty = v["ntx"], v["nty"]
        limit = gl.max_texture
        if max(ntx, nty) > limit or -(-m // row) > limit:
            raise TooMany(f"{ntx}x{nty} tiles, {m} Gaussians")
        self.read_tables()
        tex = gl.upload(self._tile_in)

        def table(n):
            return gl.image(row, max(1, -(-n // row)))

        tex.update(tl_box=table(m), t_lb=table(m), cnt=gl.counter(ntx, nty))
        self._pass("FOOT", m, tex, {"n_g": m})
        counts = np.frombuffer(tex["cnt"].read(), np.uint32).astype(np.int64)
        start = np.zeros(counts.size + 1, np.int64)  # gpu.tables_tiles.starts
        np.cumsum(counts, out=start[1:])
        total = int(start[-1])
        if total > (1 << 24) - 1 or -(-max(total, 1) // row) > limit:
            raise TooMany(f"{total} tile entries")
        folded = np.zeros(-(-max(1, -(-start.size // 4)) // row) * row * 4, np.float32)  # fold_scalars
        folded[:start.size] = start
        tex.update(gl.upload({"t_start": folded.reshape(-1, row, 4)}))
        n = max(total, 1)
        tex.update(t_raw=table(n), t_tile=table(n), t_ent=table(n), cnt=gl.counter(ntx, nty))
        self._pass("FILL", m, tex, {"n_g": m, "ntx": ntx})
        self._pass("SORT", total, tex, {"n_ent": total})
        self.tex.update({k: tex[k] for k in ("t_start", "t_ent", "t_lb")})
        self.list_bytes = nbytes({k: tex[k] for k in ("t_start", "t_ent", "t_lb")})
        return total

    def _pass(self, stage, n, tex, ints):
        groups = max(1, -(-n // self.gl.asm.TILES_GROUP))
        gx = min(groups, 65535)
        self.gl.run(self.case.tile_programs[stage], tex, ints, (gx, -(-groups // gx), 1))

    def draw(self):
        """One dispatch of the mode's shader over the whole frame (GPUDevice.render's one band)."""
        gl = self.gl
        if self.out is None:
            self.out = {"out_rgba": gl.image(self.w, self.h), "out_dv": gl.image(self.w, self.h)}
        _, program = gl.program(self.case.program)
        side = program.local_size[0]
        ints = dict(self.case.info["ints"], row0=0, col0=0, nrows=self.h, ncols=self.w)
        gl.run(self.case.program, dict(self.tex, **self.out), ints,
               (-(-self.w // side), -(-self.h // side), 1))

    def read(self):
        return read(self.out["out_rgba"]), read(self.out["out_dv"])

    def gpu_bytes(self):
        """The scene's textures (tables, atlas, tile lists) in bytes."""
        return nbytes(self.tex)


def overflow_tiles(case, dv):
    """Screen tiles with a pixel whose ray the shader could not finish (the device redraws them
    on the CPU device: gpu.tables_gauss.overflow_tiles)."""
    tile = int(case.define("TILE"))
    rows, cols = np.nonzero(dv[..., 0] == np.float32(float(case.define("OVERFLOW_DEPTH").strip("()"))))
    return sorted(set(zip((rows // tile).tolist(), (cols // tile).tolist())))


def draw_case(path, view=None, gl=None):
    """(rgba, dv, overflow tiles) of a case's view (default: its first)."""
    gl = gl or GL()
    case = Case(path)
    view = view or case.info["views"][0]["name"]
    f = Frame(gl, case, view)
    f.upload()
    f.lists()
    f.draw()
    rgba, dv = f.read()
    return rgba, dv, overflow_tiles(case, dv)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--view", default=None)
    ap.add_argument("--out", default=None, help="a folder: CASE.npz there per case (rgba, dv)")
    a = ap.parse_args(argv)
    gl = GL()
    if a.out:
        os.makedirs(a.out, exist_ok=True)
    for path in a.cases:
        t = time.perf_counter()
        rgba, dv, over = draw_case(path, a.view, gl)
        print(json.dumps({"case": os.path.basename(path), "renderer": gl.renderer,
                          "shape": list(rgba.shape), "overflow_tiles": len(over),
                          "seconds": round(time.perf_counter() - t, 3)}), flush=True)
        if a.out:
            np.savez(os.path.join(a.out, os.path.basename(path)), rgba=rgba, dv=dv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
