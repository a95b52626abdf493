"""What the engine reads from Blender's own settings rather than from copies of them:
threads (Render > Performance), passes (View Layer > Passes), the background (the World), and
the object size that the default density unit is relative to."""

import numpy as np


def threads(scene):
    """CPU threads as Cycles reads them: None (all cores) for Auto-detect, else the Fixed count."""
    r = scene.render
    return int(r.threads) if r.threads_mode == "FIXED" else None


def passes(view_layer):
    """Extra passes enabled on a view layer: Depth (Blender's Z pass), Value (ours)."""
    out = []
    if view_layer is None:
        return out
    if view_layer.use_pass_z:
        out.append("Depth")
    s = getattr(view_layer, "gaussvdb", None)
    if s is not None and s.use_pass_value:
        out.append("Value")
    return out


def surface_background_node(world):
    tree = getattr(world, "node_tree", None)
    if tree is None:
        return None
    out = next((n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld"
                and getattr(n, "is_active_output", True)), None)
    if out is None or not out.inputs["Surface"].is_linked:
        return None
    node = out.inputs["Surface"].links[0].from_node
    return node if node.bl_idname == "ShaderNodeBackground" else None


def world_color(world):
    """Scene-linear RGB of a World: its Background node's colour times strength when the world
    uses nodes (and the colour is not driven by other nodes), else the World's viewport colour."""
    import bpy

    uses_nodes = True if bpy.app.version >= (5, 0) else world.use_nodes  # 5.0: always nodes
    node = surface_background_node(world) if uses_nodes else None
    if node is not None and not node.inputs["Color"].is_linked:
        strength = node.inputs["Strength"].default_value
        if node.inputs["Strength"].is_linked:
            strength = 1.0
        return tuple(float(c) * float(strength) for c in node.inputs["Color"].default_value[:3])
    return tuple(float(c) for c in world.color[:3])


def background(scene):
    """RGBA behind the volumes: transparent film, else the World's colour; the render settings'
    Background colour only when the scene has no World."""
    if scene.render.film_transparent:
        return (0.0, 0.0, 0.0, 0.0)
    if scene.world is not None:
        r, g, b = world_color(scene.world)
    else:
        r, g, b = (float(c) for c in scene.gaussvdb.background)
    return (r, g, b, 1.0)


def world_box_diagonal(obj, matrix_world):
    """Length of the diagonal of an object's bounding box in world space (as the CLI frames it);
    a grid imported alone (no points): its leaves' box."""
    from ..io import schema

    st = getattr(obj.original, "gaussvdb", None)
    if st is not None and st.is_gaussvdb and not schema.lod_names(obj.original):
        lo, hi = tuple(st.leaf_box_min), tuple(st.leaf_box_max)
        corners = np.array([(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])], np.float64)
    else:
        corners = np.array([tuple(c) for c in obj.bound_box], np.float64)
    mw = np.asarray(matrix_world, np.float64)
    wc = np.c_[corners, np.ones(8)] @ mw.T
    return float(np.linalg.norm(wc[:, :3].max(0) - wc[:, :3].min(0)))


def extinction(settings, size):
    """Extinction per world unit at alpha 1. "Per Object Size": density is the optical depth
    across the largest rendered object's box diagonal (density / diagonal: the same image at any
    scale, what the CLI always did); "Per World Unit": density as is."""
    if settings.density_unit == "WORLD" or not size or size <= 0:
        return float(settings.density)
    return float(settings.density) / size
