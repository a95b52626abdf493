"""Phase 2 of an import: the Blender datablocks of converted grids (kernels.pipeline results),
all or nothing: when creating any of them fails, everything created is removed again.

One object per ConvertedGrid: a PointCloud laid out as schema.py says, the object's settings
(source, grid, LODs, figures, layout version) and its matrix, the grid's index-to-world.
"""

import os

from ...kernels.convert_options import DEFAULTS
from ..properties import lod_figures
from . import schema


def _new_pointcloud_object(name, arrays, collection):
    """A mesh of loose vertices with the attributes, converted to a POINTCLOUD object (5.0 has no
    Python API to add points to a point cloud)."""
    import bpy

    n = len(arrays["position"][1])
    mesh = bpy.data.meshes.new(name)
    created = [mesh]
    try:
        mesh.vertices.add(n)
        mesh.vertices.foreach_set("co", arrays["position"][1].ravel())
        schema.write_attributes(mesh, {k: v for k, v in arrays.items() if k != "position"})
        obj = bpy.data.objects.new(name, mesh)
        created.append(obj)
        collection.objects.link(obj)
    except BaseException:
        remove_ids(created)
        raise
    return obj, mesh


def remove_ids(ids):
    import bpy

    for idb in reversed(ids):
        try:
            if isinstance(idb, bpy.types.Object):
                bpy.data.objects.remove(idb)
            elif isinstance(idb, bpy.types.Mesh):
                bpy.data.meshes.remove(idb)
            elif isinstance(idb, bpy.types.PointCloud):
                bpy.data.pointclouds.remove(idb)
        except ReferenceError:
            pass


def _convert_to_pointclouds(objs):
    """object.convert(target='POINTCLOUD') on the given objects, each linked to the view layer."""
    import bpy

    scene = bpy.context.scene
    view_layer = bpy.context.view_layer
    temp_links = []
    in_scene = {scene.collection, *scene.collection.children_recursive}
    for obj in objs:
        if not any(c in in_scene for c in obj.users_collection):  # e.g. an unlinked collection
            scene.collection.objects.link(obj)
            temp_links.append(obj)
    try:
        override = dict(active_object=objs[0], object=objs[0], selected_objects=list(objs),
                        selected_editable_objects=list(objs), scene=scene, view_layer=view_layer)
        with bpy.context.temp_override(**override):
            result = bpy.ops.object.convert(target="POINTCLOUD", keep_original=False)
        if "FINISHED" not in result or any(o.type != "POINTCLOUD" for o in objs):
            raise schema.ConversionError("Blender could not convert the points to a point cloud")
    finally:
        for obj in temp_links:
            scene.collection.objects.unlink(obj)


def _settings_to_object(obj, cg, stats, options):
    st = obj.gaussvdb
    st.is_gaussvdb = True
    if cg.sequence:  # the first file, with Blender's Volume sequence settings
        from . import source_path

        st.source_volume = source_path.sequence_volume(cg.filepath, **cg.sequence["settings"])
    else:
        st.source_file = cg.filepath
    st.grid_name = cg.name
    st.color_grid = cg.color_grid
    st.grid_class = cg.grid_class
    st.value_type = cg.value_type
    st.lods = ",".join(cl.name for cl in cg.lods)
    st.weight_rule = options.weights
    st.level_set_band = bool(options.level_set_band)
    st.vector_magnitude = bool(options.vector_magnitude)
    st.index_to_world = schema.index_to_world_text(cg.index_to_world)
    st.leaf_box_min = [float(v) for v in cg.leaf_box[0]]
    st.leaf_box_max = [float(v) for v in cg.leaf_box[1]]
    st.layout_version = schema.LAYOUT_VERSION
    figures = {"lods": stats, "nonfinite_voxels": cg.nonfinite_voxels, "values": cg.values,
               "seconds_compile": cg.seconds_compile}
    if cg.color_grid:
        figures["color_values"] = cg.color_stats  # (the key files hold)
    if cg.sequence:
        figures["sequence"] = cg.sequence["figures"]
    lod_figures.store(st, figures)
    names = [cl.name for cl in cg.lods]
    if names:  # Like the Subdivision modifier: the viewport shows the coarsest LOD held, renders the finest.
        st.viewport_lod = names[0]
        st.render_lod = names[-1]


def build_objects(converted, collection=None, options=DEFAULTS) -> list:
    """Create one point-cloud object per ConvertedGrid (converted with the ConvertOptions
    ``options``, whose object settings each object keeps); on any failure remove everything
    created."""
    import bpy
    from mathutils import Matrix

    if collection is None:
        collection = bpy.context.view_layer.active_layer_collection.collection
    prepared = []
    for cg in converted:  # still no datablock: arrays first, so a precision error creates nothing
        arrays = schema.point_arrays(cg)
        prepared.append((cg, arrays, schema.lod_stats(cg, schema.bytes_per_point(arrays))))
    created = []
    try:
        objs = []
        for cg, arrays, _ in prepared:
            stem = os.path.splitext(os.path.basename(cg.filepath))[0]
            obj, mesh = _new_pointcloud_object(f"{stem}_{cg.name}", arrays, collection)
            created += [mesh, obj]
            objs.append(obj)
        _convert_to_pointclouds(objs)
        for (cg, _, stats), obj in zip(prepared, objs):
            created.append(obj.data)
            pc = obj.data
            pc.name = obj.name
            if ".select_vert" in pc.attributes:
                pc.attributes.remove(pc.attributes[".select_vert"])
            obj.matrix_world = Matrix(cg.index_to_world.tolist())
            _settings_to_object(obj, cg, stats, options)
        for idb in created:  # the meshes the conversion left without users
            if isinstance(idb, bpy.types.Mesh) and idb.users == 0:
                bpy.data.meshes.remove(idb)
        return objs
    except BaseException:
        remove_ids([c for c in created if _alive(c)])
        raise


def _alive(idb):
    try:
        idb.name  # noqa: B018
        return True
    except ReferenceError:
        return False
