"""A scene rendered by the GAUSSVDB engine into an image file: what the command line, the demo
and scripts call (``bpy.ops.render.render(write_still=True)``, as F12 then Save does).

    figures = render_scene_to_file(scene, "out.png")   # the render's figures, returned
"""

import os

from . import final_render


def set_exact_colors(scene):
    """Standard view transform, no look, exposure 0, gamma 1, no dither: colormaps come out
    exact in 8-bit files (AgX, the default, maps linear 1.0 to 0.859; the default dither adds
    +-1 noise to 8-bit output)."""
    scene.render.dither_intensity = 0.0
    vs = scene.view_settings
    scene.display_settings.display_device = "sRGB"
    vs.view_transform = "Standard"
    vs.look = "None"
    vs.exposure = 0.0
    vs.gamma = 1.0
    vs.use_curve_mapping = False


FORMATS = {".png": "PNG", ".exr": "OPEN_EXR", ".jpg": "JPEG", ".jpeg": "JPEG", ".tif": "TIFF",
           ".tiff": "TIFF"}


def render_scene_to_file(scene, path, *, exact_colors=True, color_depth=None):
    """Render ``scene`` with the GAUSSVDB engine and write ``path`` (format from the extension).
    Returns the render's figures; raises RuntimeError with the engine's message."""
    import bpy

    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise ValueError(f"unsupported image type {ext!r}; use one of {', '.join(sorted(FORMATS))}")
    scene.render.engine = "GAUSSVDB"
    img = scene.render.image_settings
    if hasattr(img, "media_type"):  # Blender 5.0: pick plain images before the file format
        img.media_type = "IMAGE"
    img.file_format = FORMATS[ext]
    img.color_mode = "RGBA" if FORMATS[ext] in ("PNG", "OPEN_EXR", "TIFF") else "RGB"
    if color_depth:
        img.color_depth = str(color_depth)
    elif FORMATS[ext] == "OPEN_EXR":
        img.color_depth = "32"
    if exact_colors:
        set_exact_colors(scene)
    scene.render.filepath = os.path.abspath(path)
    scene.render.use_file_extension = False
    final_render.LAST_STATS.clear()
    bpy.ops.render.render(write_still=True, scene=scene.name)
    stats = dict(final_render.LAST_STATS)
    if "error" in stats:
        raise RuntimeError(stats["error"])
    return stats
