"""Run by test_transfer_objects in its own process: draws the viewport legend overlay
(legend_overlay.draw_viewport, the code view_draw calls) into a GPU offscreen inside a render
engine that asks for a GPU context (headless Blender gives one there), and saves the pixels.

    python tests/blender/legend_gpu_draw.py OUT.npz
"""
import math
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path[:0] = [os.path.join(ROOT, "tools"), os.path.join(ROOT, "tests", "blender")]

from blender_session import addon_module, start  # noqa: E402

W, H = 200, 120


def main(out):
    bpy = start()
    import numpy as np
    from test_engine_helpers import add_camera, lattice, make_object, setup_render

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    make_object(bpy, "Smoke", lattice(8, 8, 8), values=np.linspace(0.0, 3.0, 512))
    add_camera(bpy, scene, (3.5, -30.0, 3.5), (math.pi / 2, 0.0, 0.0), ortho_scale=16.0)
    s = scene.gaussvdb
    s.show_legend, s.legend_corner, s.legend_size, s.legend_units = True, "TOP_RIGHT", 0.8, "kg/m3"
    scene_sync = addon_module("gaussvdb_addon.engine.scene_sync")
    overlay = addon_module("gaussvdb_addon.engine.legend_overlay")
    sync = scene_sync.SceneSync(viewport=True)
    sync.sync(bpy.context.evaluated_depsgraph_get())
    tf = sync.transfer_function(s)
    got = {}

    class Probe(bpy.types.RenderEngine):
        bl_idname = "GAUSSVDB_LEGEND_PROBE"
        bl_label = "Legend probe"
        bl_use_gpu_context = True

        def render(self, depsgraph):
            import gpu
            from mathutils import Matrix

            off = gpu.types.GPUOffScreen(W, H, format="RGBA16F")
            with off.bind():
                fb = gpu.state.active_framebuffer_get()
                fb.clear(color=(0.0, 0.0, 0.0, 0.0))
                with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
                    gpu.matrix.load_identity()
                    proj = Matrix.Identity(4)  # region pixels -> clip space, as in view_draw
                    proj[0][0], proj[1][1], proj[0][3], proj[1][3] = 2.0 / W, 2.0 / H, -1.0, -1.0
                    gpu.matrix.load_projection_matrix(proj)
                    overlay.draw_viewport(s, sync, tf, W, H, {})
                linear = np.array(fb.read_color(0, 0, W, H, 4, 0, "FLOAT").to_list(), np.float32)
                fb.clear(color=(0.0, 0.0, 0.0, 0.0))
                with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
                    gpu.matrix.load_identity()
                    gpu.matrix.load_projection_matrix(proj)
                    # as view_draw: through the display-space shader (Standard: sRGB encoding)
                    overlay.draw_viewport(s, sync, tf, W, H, {}, self, depsgraph.scene)
                buf = fb.read_color(0, 0, W, H, 4, 0, "FLOAT")
            got["pixels"] = linear.reshape(H, W, 4)
            got["display"] = np.array(buf.to_list(), np.float32).reshape(H, W, 4)
            got["renderer"] = gpu.platform.renderer_get()
            off.free()

    bpy.utils.register_class(Probe)
    setup_render(scene, 8, 8, engine=Probe.bl_idname)
    addon_module("gaussvdb_addon.engine.image_file").set_exact_colors(scene)
    bpy.ops.render.render()
    patch = overlay.patch(s, sync, tf, H)
    np.savez(out, pixels=got["pixels"], display=got["display"], patch=patch, renderer=got["renderer"])


if __name__ == "__main__":
    main(sys.argv[1])
