"""Shared helpers of the engine tests (no tests here): tiny GaussVDB objects built directly, so
the engine tests do not depend on the importer."""

import math

import numpy as np

SIGMA = 0.6


def lattice(nx, ny, nz, origin=(0, 0, 0)):
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1)
    return g.reshape(-1, 3).astype(np.float64) + np.asarray(origin, np.float64)


def make_object(bpy, name, centres, values=None, *, sigma=SIGMA, grid_class="fog_volume",
                lod_index=None, lods="medium", matrix=None, link=True):
    """A mesh object of loose vertices carrying the GaussVDB point attributes (field weights)."""
    centres = np.asarray(centres, np.float64)
    m = len(centres)
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(m)
    mesh.vertices.foreach_set("co", centres.astype(np.float32).ravel())
    amp = 1.0 / ((2 * math.pi) ** 1.5 * sigma ** 3)
    attrs = {"gs_sigma": ("FLOAT_VECTOR", np.full((m, 3), sigma, np.float32), "vector"),
             "gs_value": ("FLOAT", np.ones(m, np.float32) if values is None
                          else np.asarray(values, np.float32), "value"),
             "gs_amplitude": ("FLOAT", np.full(m, amp, np.float32), "value"),
             "gs_voxels": ("INT", np.ones(m, np.int32), "value")}
    if lod_index is not None:
        attrs["gs_lod"] = ("INT8", np.asarray(lod_index, np.int8), "value")
    for key, (kind, arr, field) in attrs.items():
        a = mesh.attributes.new(key, kind, "POINT")
        a.data.foreach_set(field, np.ascontiguousarray(arr).ravel())
    ob = bpy.data.objects.new(name, mesh)
    if matrix is not None:
        ob.matrix_world = matrix
    s = ob.gaussvdb
    s.is_gaussvdb = True
    s.grid_class = grid_class
    s.lods = lods
    if link:
        bpy.context.scene.collection.objects.link(ob)
    return ob


def add_camera(bpy, scene, location, rotation, *, ortho_scale=None, lens=50.0):
    cam = bpy.data.cameras.new("Cam")
    if ortho_scale is not None:
        cam.type = "ORTHO"
        cam.ortho_scale = ortho_scale
    cam.lens = lens
    ob = bpy.data.objects.new("Cam", cam)
    ob.location = location
    ob.rotation_euler = rotation
    scene.collection.objects.link(ob)
    scene.camera = ob
    return ob


def read_image(bpy, path):
    """The pixels of an image file Blender reads: float32 (H, W, 4), row 0 = bottom."""
    img = bpy.data.images.load(str(path))
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)


def setup_render(scene, width, height, engine="GAUSSVDB"):
    scene.render.engine = engine
    scene.render.resolution_x = width
    scene.render.resolution_y = height
    scene.render.resolution_percentage = 100


class FakeEngine:
    """Stands in for a RenderEngine in final_render.render (records calls; test_break on demand)."""

    class _Pass:
        def __init__(self, n):
            self.data = np.zeros(n, np.float32)
            self.rect = self

        def foreach_set(self, arr):
            self.data[:] = arr

    class _Passes(dict):
        def find(self, name):
            return 0 if name in self else -1

    def __init__(self, break_after=None):
        self.break_after = break_after
        self.t_break = None
        self.errors = []
        self.reports = []  # (kind set, message) of every report
        self.stats = []
        self.progress = []
        self.result = None
        self.test_breaks = 0

    def begin_result(self, x, y, w, h, layer=None):
        class R:
            pass
        r = R()
        lay = R()
        lay.passes = self._Passes(Combined=self._Pass(w * h * 4), Depth=self._Pass(w * h),
                                  Value=self._Pass(w * h))
        r.layers = [lay]
        self.result = r
        self.size = (w, h)
        return r

    def end_result(self, result, cancel=False):
        pass

    def update_result(self, result):
        pass

    def add_pass(self, *a, **k):
        pass

    def test_break(self):
        import time

        self.test_breaks += 1
        if self.break_after is not None and self.test_breaks > self.break_after:
            if self.t_break is None:
                self.t_break = time.perf_counter()
            return True
        return False

    def update_progress(self, f):
        self.progress.append(f)

    def update_stats(self, a, b):
        self.stats.append(b)

    def report(self, kind, msg):
        self.reports.append((set(kind), msg))
        if "WARNING" not in kind and "INFO" not in kind:
            self.errors.append(msg)

    def error_set(self, msg):
        self.errors.append(msg)

    def image(self):
        w, h = self.size
        return self.result.layers[0].passes["Combined"].data.reshape(h, w, 4)
