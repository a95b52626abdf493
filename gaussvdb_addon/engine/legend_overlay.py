"""The colour legend of a scene (scene.gaussvdb.show_legend): composited into the Combined pass
of final renders, and drawn over the rendered viewport. The raster is kernels/render/scene/legend.py;
this module only picks the entries, the corner and the size, and draws it with ``gpu``."""

import numpy as np

from ...kernels.render.scene import legend


def patch(settings, sync, tf, image_height):
    """The legend raster for this render ((h, w, 4) premultiplied, row 0 at the top), or None
    when the legend is off or no volume is drawn."""
    if not settings.show_legend:
        return None
    entries = sync.legend_entries(tf, settings.legend_units.strip())
    if not entries:
        return None
    return legend.legend_patch(entries, settings.legend_size * image_height)


def composite(settings, sync, tf, combined):
    """Lay the legend over ``combined`` (H, W, 4), in place; True when one was drawn."""
    p = patch(settings, sync, tf, combined.shape[0])
    if p is None:
        return False
    legend.composite(combined, p, settings.legend_corner.lower())
    return True


def draw_viewport(settings, sync, tf, width, height, cache, engine=None, scene=None):
    """Draw the legend over the viewport region (called from view_draw, after the image;
    ``engine``'s display-space shader converts its linear colours like the image's). The texture
    is kept in ``cache`` (a dict) until the legend's inputs change."""
    import gpu
    from gpu_extras.presets import draw_texture_2d

    key = (settings.show_legend, settings.legend_corner, round(settings.legend_size, 4),
           settings.legend_units, height, tf.vmin, tf.vmax, tf.log_scale, tf.lut.tobytes(),
           tuple((n, None if t is None else (t.vmin, t.vmax, t.log_scale, t.lut.tobytes()))
                 for n, t in sync.tf_users))
    if cache.get("key") != key:
        p = patch(settings, sync, tf, height)
        cache["key"] = key
        cache["tex"] = None
        if p is not None:
            up = np.ascontiguousarray(p[::-1], np.float32)  # textures start at the bottom row
            h, w = up.shape[:2]
            buf = gpu.types.Buffer("FLOAT", w * h * 4, up.ravel())
            cache["tex"] = (gpu.types.GPUTexture((w, h), format="RGBA16F", data=buf), w, h)
    if cache.get("tex") is None:
        return
    tex, w, h = cache["tex"]
    x0, y0 = legend.corner_origin(width, height, (h, w), settings.legend_corner.lower())
    gpu.state.blend_set("ALPHA_PREMULT")
    if engine is not None:
        engine.bind_display_space_shader(scene)
    draw_texture_2d(tex, (x0, y0), w, h)
    if engine is not None:
        engine.unbind_display_space_shader()
    gpu.state.blend_set("NONE")
