"""Blender's views as kernel Cameras: one home for the conversion F12 and the viewport both use.

``camera_from_object``/``scene_camera``: a camera object at an image size (Blender's view-plane
rules: sensor fit, shift, pixel aspect, clip range); ``camera_from_matrices``/``camera_from_region``:
a viewport's view and window matrices (camera view or not). Plain Python over the objects' data,
tested headless.
"""

import dataclasses
import math

import numpy as np

from ...kernels.render import Camera


# -- a camera object (F12) ------------------------------------------------------------------------
def camera_from_object(cam_obj, width, height, matrix_world=None, pixel_aspect=1.0):
    """Kernel Camera for a Blender camera object at an image size (Blender's view-plane rules:
    sensor fit AUTO spans the larger image side, HORIZONTAL the width, VERTICAL the height, sides
    measured with the pixel aspect (a pixel's height over its width); shifts are in units of the
    fitted side; clip start/end along the view axis)."""
    cam = cam_obj.data
    if cam.type not in ("PERSP", "ORTHO"):
        raise ValueError(f"camera type {cam.type} is not supported (perspective and orthographic are)")
    mw = np.array(matrix_world if matrix_world is not None else cam_obj.matrix_world, np.float64)
    tall = height * pixel_aspect
    big = max(width, tall)
    fit = cam.sensor_fit
    if fit == "AUTO":
        fitted = big
    elif fit == "HORIZONTAL":
        fitted = width
    else:
        fitted = tall
    scale = big / fitted  # fitted-side units -> larger-side units
    kw = dict(shift_x=cam.shift_x / scale, shift_y=cam.shift_y / scale, pixel_aspect=pixel_aspect,
              clip_start=max(0.0, cam.clip_start), clip_end=max(cam.clip_start, cam.clip_end, 0.0))
    if cam.type == "ORTHO":
        return Camera(mw, width, height, "ortho", ortho_scale=cam.ortho_scale * scale, **kw)
    sensor = cam.sensor_height if fit == "VERTICAL" else cam.sensor_width
    half = 0.5 * sensor / cam.lens * scale
    return Camera(mw, width, height, "persp", fov_x=2.0 * math.atan(half), **kw)


def scene_camera(scene, depsgraph, width, height):
    cam = scene.camera
    if cam is None:
        raise ValueError("the scene has no camera")
    ev = cam.evaluated_get(depsgraph) if depsgraph is not None else cam
    r = scene.render
    return camera_from_object(ev, width, height, pixel_aspect=r.pixel_aspect_y / r.pixel_aspect_x)


# -- a viewport region ----------------------------------------------------------------------------
def camera_from_matrices(view_matrix, window_matrix, width, height, is_perspective=None):
    """Kernel Camera equivalent to an OpenGL-style view (world -> view) and window (projection)
    matrix pair for a width x height image: what Blender's viewport draws, in camera view (zoom
    and offset included in the window matrix) or not. Orthographic cameras are placed on the
    near clip plane (Blender's ortho viewport clips symmetrically around the view centre)."""
    v = np.array(view_matrix, np.float64).reshape(4, 4)
    p = np.array(window_matrix, np.float64).reshape(4, 4)
    if is_perspective is None:
        is_perspective = abs(p[3, 3]) < 0.5
    cam_to_world = np.linalg.inv(v)
    big = max(width, height)
    ex = 2.0 / p[0, 0]  # image width on the plane z = -1 (perspective) or in view units (ortho)
    if is_perspective:
        cx, cy = p[0, 2] / p[0, 0], p[1, 2] / p[1, 1]  # image centre on that plane
    else:
        cx, cy = -p[0, 3] / p[0, 0], -p[1, 3] / p[1, 1]
    # the kernel's plane: larger side spans `bigext`, the other side the same per pixel
    bigext = ex * big / width  # (the height gives the same for square pixels)
    sx, sy = cx / bigext, cy / bigext
    if is_perspective:
        return Camera(cam_to_world, width, height, "persp", fov_x=2.0 * math.atan(0.5 * bigext),
                      shift_x=sx, shift_y=sy)
    near = (p[2, 3] + 1.0) / p[2, 2]  # view-space z of the near plane is -near
    m = cam_to_world.copy()
    m[:3, 3] = (cam_to_world @ np.array([0.0, 0.0, -near, 1.0]))[:3]
    return Camera(m, width, height, "ortho", ortho_scale=bigext, shift_x=sx, shift_y=sy)


def camera_from_region(region, region_data):
    return camera_from_matrices(region_data.view_matrix, region_data.window_matrix,
                                region.width, region.height, bool(region_data.is_perspective))


def camera_key(cam):
    return (cam.packed().round(12).tobytes(), cam.width, cam.height)


def scaled_camera(cam, factor):
    """The same view at 1/factor resolution (at least one pixel). The low-resolution image is
    stretched over the region; rounding moves its edges by less than one coarse pixel."""
    w = max(1, int(math.ceil(cam.width / factor)))
    h = max(1, int(math.ceil(cam.height / factor)))
    return dataclasses.replace(cam, width=w, height=h)  # clip range and pixel aspect kept
