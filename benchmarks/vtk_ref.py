"""VTK's CPU volume renderer (vtkFixedPointVolumeRayCastMapper, off-screen) matched to the GAUSSVDB
emission-absorption model, for the benchmark's error-vs-time front.

Run as a subprocess (VTK's OpenGL context and thread pool stay out of the benchmark's process):

    python benchmarks/vtk_ref.py JOB.json

JOB.json: {"volume" (.npy float32 (X, Y, Z), voxel (i, j, k) at index origin + (i, j, k)), "origin",
"spacing" (world position of voxel (0, 0, 0) and the voxel size per axis: the grid's axis-aligned
index-to-world), "width", "height", "position", "focal_point", "view_up", "fov_x" (radians, across the
larger image side), "lut" (K x 4 linear RGBA over vmin..vmax), "vmin", "vmax", "density" (extinction
per world unit at alpha 1), "steps" (sample distances in voxels), "voxel" (world length of one
voxel), "threads", "repeat", "out_dir"}.
Writes OUT_DIR/vtk_<i>.npy (float32 (H, W, 4), linear, premultiplied, row 0 = bottom, like the
GAUSSVDB 'Combined' pass) per step and OUT_DIR/vtk.json with the seconds per render. Exits 3 with
one line when `import vtk` fails (the benchmark then skips VTK).

How the models are matched (README "Choosing a LOD"):
- Opacity: VTK's scalar opacity is per ScalarOpacityUnitDistance u: a sample at distance d gets
  1 - (1 - a)^(d/u). With a(v) = 1 - exp(-density * alpha(v) * u) that is 1 - exp(-density * alpha(v) * d),
  our extinction over one step. Colour from our LUT (the same K entries, linear), composited
  premultiplied front to back as ours; shading off, trilinear, post-classification (the transfer
  function applied to the interpolated value), one component.
- Camera: our pinhole (position, focal point, up), view angle = our fov across the larger side
  (VTK's horizontal view angle when the image is wider than tall), clipping range from the bounds.
- Image: the window's 8-bit RGBA read back (no sRGB, no multisampling, black background), so
  quantisation alone bounds the PSNR near 59 dB; the mapper's own fixed-point arithmetic (15-bit
  opacities, quantised scalar tables) makes it slightly brighter at thin silhouettes.
"""
from __future__ import annotations

import json
import math
import os
import sys
import time

MISSING = 3  # exit status when VTK cannot be imported


def transfer(vtk, job, unit):
    """VTK colour and opacity functions sampled at our LUT's K entries."""
    lut, vmin, vmax = job["lut"], float(job["vmin"]), float(job["vmax"])
    k = len(lut)
    col, opa = vtk.vtkColorTransferFunction(), vtk.vtkPiecewiseFunction()
    col.SetColorSpaceToRGB()
    for i, (r, g, b, a) in enumerate(lut):
        v = vmin + (vmax - vmin) * i / (k - 1)
        col.AddRGBPoint(v, r, g, b)
        opa.AddPoint(v, 1.0 - math.exp(-float(job["density"]) * a * unit))
    col.ClampingOn()
    opa.ClampingOn()
    return col, opa


def build(vtk, job):
    import numpy as np
    from vtk.util import numpy_support

    vol = np.load(job["volume"])
    img = vtk.vtkImageData()
    img.SetDimensions(*vol.shape)
    img.SetOrigin(*job["origin"])
    img.SetSpacing(*job["spacing"])
    img.GetPointData().SetScalars(numpy_support.numpy_to_vtk(vol.ravel(order="F"), deep=True))

    unit = float(job["voxel"])
    col, opa = transfer(vtk, job, unit)
    prop = vtk.vtkVolumeProperty()
    prop.SetColor(col)
    prop.SetScalarOpacity(opa)
    prop.SetScalarOpacityUnitDistance(unit)
    prop.ShadeOff()
    prop.SetInterpolationTypeToLinear()
    prop.IndependentComponentsOn()

    mapper = vtk.vtkFixedPointVolumeRayCastMapper()
    mapper.SetInputData(img)
    mapper.SetBlendModeToComposite()
    mapper.AutoAdjustSampleDistancesOff()
    mapper.LockSampleDistanceToInputSpacingOff()
    mapper.SetImageSampleDistance(1.0)  # one ray per pixel
    mapper.SetNumberOfThreads(int(job["threads"]))
    volume = vtk.vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(prop)

    ren = vtk.vtkRenderer()
    ren.SetBackground(0.0, 0.0, 0.0)
    ren.AddVolume(volume)
    cam = ren.GetActiveCamera()
    cam.SetPosition(*job["position"])
    cam.SetFocalPoint(*job["focal_point"])
    cam.SetViewUp(*job["view_up"])
    w, h = int(job["width"]), int(job["height"])
    cam.SetUseHorizontalViewAngle(1 if w >= h else 0)
    cam.SetViewAngle(math.degrees(float(job["fov_x"])))
    ren.ResetCameraClippingRange()
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetMultiSamples(0)
    win.AddRenderer(ren)
    win.SetSize(w, h)
    return win, ren, mapper


def read_back(vtk, win, w, h):
    import numpy as np
    from vtk.util import numpy_support

    buf = vtk.vtkFloatArray()
    win.GetRGBAPixelData(0, 0, w - 1, h - 1, 0, buf, 0)  # the back buffer holds the last render
    return numpy_support.vtk_to_numpy(buf).reshape(h, w, 4).astype(np.float32)


def render_all(job) -> dict:
    try:
        import vtk
    except ImportError as err:
        print(f"VTK: not available ({err})", file=sys.stderr)
        sys.exit(MISSING)
    import numpy as np

    vtk.vtkMultiThreader.SetGlobalDefaultNumberOfThreads(int(job["threads"]))
    win, ren, mapper = build(vtk, job)
    w, h = int(job["width"]), int(job["height"])
    rows = []
    for i, step in enumerate(job["steps"]):
        mapper.SetSampleDistance(float(step) * float(job["voxel"]))
        ren.ResetCameraClippingRange()
        t0 = time.perf_counter()
        win.Render()  # warm-up: data upload, scalar tables, opacity tables for this distance
        warm = time.perf_counter() - t0
        times = []
        for _ in range(max(1, int(job["repeat"]))):
            t0 = time.perf_counter()
            win.Render()
            times.append(time.perf_counter() - t0)
        np.save(os.path.join(job["out_dir"], f"vtk_{i}.npy"), read_back(vtk, win, w, h))
        rows.append({"step": float(step), "seconds_render": float(np.median(times)),
                     "seconds_all": times, "seconds_warmup": warm})
        print(json.dumps(rows[-1]), flush=True)
    info = {"rows": rows, "vtk": vtk.vtkVersion.GetVTKVersion(), "window": win.GetClassName(),
            "threads": mapper.GetNumberOfThreads()}
    with open(os.path.join(job["out_dir"], "vtk.json"), "w") as f:
        json.dump(info, f, indent=1)
    return info


def main(argv):
    with open(argv[0]) as f:
        job = json.load(f)
    os.makedirs(job["out_dir"], exist_ok=True)
    render_all(job)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # off-screen, Mesa's EGL
    sys.exit(main(sys.argv[1:]))
