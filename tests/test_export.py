"""engine.export against the real bpy: scenes are built in code, exported and compared with what Blender
itself reports (and, for the world's Mapping rotation, with what Cycles renders)."""
import math
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
import mathutils  # noqa: E402  (only importable once bpy is)

from bpy_helpers import camera_only_scene, export_current  # noqa: E402
from ember.engine.export import DEFAULT_ALBEDO, ExportError, export_scene, render_region  # noqa: E402
from ember.kernels.environment import direction_to_equirect  # noqa: E402
from ember.kernels.textures import srgb_to_linear  # noqa: E402


# ---- Helpers ----------------------------------------------------------------------------------------

@pytest.fixture(autouse=True)
def empty_scene():
    """Every test starts from an empty factory scene with a camera."""
    return camera_only_scene()


export = export_current


def add_cube(location=(0, 0, 0), rotation=(0, 0, 0), scale=(1, 1, 1)):
    """A 2 m cube whose transform is on the object (the operator's own scale would go into the mesh)."""
    bpy.ops.mesh.primitive_cube_add(location=location, rotation=rotation)
    ob = bpy.context.object
    ob.scale = scale
    return ob


def triangles_near(result, ob, array):
    """The rows of a per-triangle array that belong to `ob`, told apart by position: test objects stand
    10 m apart along x, and the depsgraph's object order is not the creation order."""
    centre_x = result.scene.positions[:, :, 0].mean(axis=1)
    return array[np.abs(centre_x - ob.matrix_world.translation.x) < 5.0]


def blender_corners(ob):
    """(T, 3, 3) world-space triangle corners and (T, 3, 3) unit corner normals, read one by one through
    Blender's own per-item API and mathutils: an independent path from the export's bulk reads."""
    dg = bpy.context.evaluated_depsgraph_get()
    ob_eval = ob.evaluated_get(dg)
    mesh = ob_eval.data
    m = ob_eval.matrix_world
    normal_matrix = m.to_3x3().inverted_safe().transposed()
    positions, normals = [], []
    for tri in mesh.loop_triangles:
        positions.append([tuple(m @ mesh.vertices[v].co) for v in tri.vertices])
        normals.append([tuple((normal_matrix @ mesh.corner_normals[c].vector).normalized())
                        for c in tri.loops])
    return np.array(positions), np.array(normals)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def new_material(name, shader="ShaderNodeBsdfPrincipled"):
    """A material whose Surface is fed by a single new node of type `shader`; returns (material, node)."""
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    for node in [n for n in tree.nodes if n.bl_idname != "ShaderNodeOutputMaterial"]:
        tree.nodes.remove(node)
    node = tree.nodes.new(shader)
    tree.links.new(node.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    return mat, node


def material_row(result, index=1):
    """(albedo, albedo texture, emission, emission texture) of a material made of one Diffuse or
    Principled BSDF and/or an Emission shader (black albedo and emission where there is none)."""
    albedo, albedo_tex, emission, emission_tex = np.zeros(3), -1, np.zeros(3), -1
    for closure in result.scene.materials.shaders[index].closures:
        if closure.kind in ("DIFFUSE", "PRINCIPLED"):
            p = closure.input("Color" if closure.kind == "DIFFUSE" else "Base Color")
            albedo, albedo_tex = np.asarray(p.value), p.texture
        if closure.kind in ("EMISSION", "PRINCIPLED"):
            color, strength = (closure.input(n) for n in (("Color", "Strength") if closure.kind == "EMISSION"
                                                          else ("Emission Color", "Emission Strength")))
            if color is not None and strength is not None:
                emission, emission_tex = np.asarray(color.value) * strength.value[0], color.texture
    return albedo, albedo_tex, emission, emission_tex


def new_image(name, rgba, float_buffer=False, colorspace=None):
    """A generated image holding an (H, W, 4) array, row 0 at the bottom."""
    h, w, _ = rgba.shape
    image = bpy.data.images.new(name, w, h, float_buffer=float_buffer)
    if colorspace is not None:  # before the pixels: changing it regenerates a generated image
        image.colorspace_settings.name = colorspace
    image.pixels.foreach_set(np.asarray(rgba, np.float32).ravel())
    return image


def textured_material(name, image):
    mat, diffuse = new_material(name, "ShaderNodeBsdfDiffuse")
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    mat.node_tree.links.new(tex.outputs["Color"], diffuse.inputs["Color"])
    return mat, tex


# ---- Geometry ---------------------------------------------------------------------------------------

def test_transformed_cube_world_positions():
    ob = add_cube(location=(1, 2, 3), rotation=(0.3, 0.2, 0.1), scale=(1, 2, 3))
    result = export()
    assert result.triangle_count == 12 and result.instance_count == 1
    expected, _ = blender_corners(ob)
    np.testing.assert_allclose(result.scene.positions, expected, atol=1e-5)
    assert result.scene.positions.dtype == np.float32
    assert result.scene.validate().dropped_triangles == 0


def test_subdivision_modifier_is_applied():
    ob = add_cube()
    mod = ob.modifiers.new("subsurf", "SUBSURF")
    mod.levels = 2
    assert export().triangle_count == 6 * 16 * 2


def test_a_mesh_in_edit_mode_exports_as_in_object_mode():
    # A file saved in Edit Mode opens with the object still in it (an F12 from Edit Mode is the same): its
    # mesh then lists BMesh's layers as attributes, without 'position', '.corner_vert' or 'material_index'.
    ob = add_cube()
    ob.modifiers.new("subsurf", "SUBSURF").levels = 1
    for name in ("A", "B"):
        ob.data.materials.append(new_material(name)[0])
    ob.data.polygons.foreach_set("material_index", np.array([0, 1, 0, 0, 1, 1], np.int32))
    ob.data.update()
    object_mode = export()
    bpy.ops.object.mode_set(mode="EDIT")
    assert ob.data.is_editmode
    edit_mode = export()
    np.testing.assert_array_equal(edit_mode.scene.positions, object_mode.scene.positions)
    np.testing.assert_array_equal(edit_mode.scene.material_ids, object_mode.scene.material_ids)
    np.testing.assert_array_equal(edit_mode.scene.uvs, object_mode.scene.uvs)
    assert len(np.unique(edit_mode.scene.material_ids)) == 2 and np.ptp(edit_mode.scene.uvs) > 0.5


def test_collection_instances_with_rotation_and_scale():
    source = bpy.data.collections.new("Source")  # not linked to the scene: renders only as instances
    bpy.ops.mesh.primitive_cube_add(size=1)
    cube = bpy.context.object
    bpy.context.scene.collection.objects.unlink(cube)
    source.objects.link(cube)
    placements = [((5, 0, 0), (0, 0, 0), 1.0), ((-5, 0, 0), (0, 0, math.pi / 4), 2.0)]
    for location, rotation, scale in placements:
        empty = bpy.data.objects.new("Inst", None)
        empty.instance_type = "COLLECTION"
        empty.instance_collection = source
        empty.location, empty.rotation_euler, empty.scale = location, rotation, (scale,) * 3
        bpy.context.scene.collection.objects.link(empty)
    result = export()
    assert result.triangle_count == 24 and result.instance_count == 2
    for i, (location, rotation, scale) in enumerate(placements):
        m = np.array(mathutils.Matrix.LocRotScale(location, mathutils.Euler(rotation), (scale,) * 3))
        cube_corners = np.array(list(np.ndindex(2, 2, 2))) - 0.5
        expected = cube_corners @ m[:3, :3].T + m[:3, 3]
        corners = result.scene.positions[12 * i:12 * (i + 1)].reshape(-1, 3)
        distance = np.linalg.norm(corners[:, None] - expected[None], axis=2)
        assert distance.min(axis=0).max() < 1e-5 and distance.min(axis=1).max() < 1e-5


def test_particle_and_geometry_nodes_instances():
    source = add_cube(location=(0, 0, 50))
    source.hide_render = True  # hiding the instanced object still renders its particles, as in Cycles
    bpy.ops.mesh.primitive_plane_add(location=(20, 0, 0))
    emitter = bpy.context.object
    emitter.modifiers.new("particles", "PARTICLE_SYSTEM")
    settings = emitter.particle_systems[0].settings
    settings.count, settings.frame_end = 5, 1
    settings.render_type, settings.instance_object = "OBJECT", source
    bpy.ops.mesh.primitive_plane_add(location=(-20, 0, 0))
    points = bpy.context.object
    tree = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    on_points = tree.nodes.new("GeometryNodeInstanceOnPoints")
    cone = tree.nodes.new("GeometryNodeMeshCone")
    tree.links.new(tree.nodes.new("NodeGroupInput").outputs[0], on_points.inputs["Points"])
    tree.links.new(cone.outputs["Mesh"], on_points.inputs["Instance"])
    tree.links.new(on_points.outputs[0], tree.nodes.new("NodeGroupOutput").inputs[0])
    points.modifiers.new("scatter", "NODES").node_group = tree
    bpy.context.scene.frame_set(1)
    result = export()
    cone_triangles = 32 + 30  # the default cone: 32 side triangles and a 32-gon base
    positions = result.scene.positions
    assert np.count_nonzero(positions[:, 0, 0] > 10) == 2 + 5 * 12  # emitter and its particles
    assert result.instance_count == 1 + 5 + 4
    assert np.count_nonzero(positions[:, 0, 0] < -10) == 4 * cone_triangles  # one cone per plane corner


def test_unsupported_object_settings_warn():
    # An empty Curves object renders nothing and says nothing (curves render: test_curves_points.py).
    hair = bpy.data.objects.new("Hair", bpy.data.hair_curves.new("Hair"))
    bpy.context.scene.collection.objects.link(hair)
    cube = add_cube()
    cube.visible_shadow = False
    cube.is_shadow_catcher = True
    result = export()
    assert result.triangle_count == 12
    assert not any("'Hair'" in w for w in result.warnings) and not result.scene.has_shapes
    # Ray visibility and the shadow catcher are rendered (test_visibility.py, test_shadow_catcher.py): no warning.
    assert not any("visibility" in w.lower() or "Shadow Catcher" in w for w in result.warnings)
    assert result.scene.object_visibility.tolist() == [63 - 32 + 64]


def test_light_and_shadow_linking_export_without_warnings():
    """Light Linking and Shadow Linking collections, on an emitting object and on a light, are rendered
    (test_light_linking.py): nothing warns, and a scene where none is set has no linking at all."""
    cube = add_cube()
    result = export()
    assert result.scene.light_links is None and result.scene.lights.light_sets is None
    receivers = bpy.data.collections.new("Receivers")
    cube.light_linking.receiver_collection = receivers
    lamp = bpy.data.objects.new("Key", bpy.data.lights.new("Key", "POINT"))
    bpy.context.scene.collection.objects.link(lamp)
    lamp.light_linking.blocker_collection = receivers
    assert not any("Linking" in w for w in export().warnings)


def test_hidden_objects_and_non_geometry_are_skipped():
    add_cube(location=(3, 0, 0)).hide_render = True
    bpy.ops.object.text_add()
    bpy.context.object.hide_render = True
    bpy.ops.object.light_add(type="POINT")
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("NoFaces", bpy.data.meshes.new("NoFaces")))
    bpy.ops.object.empty_add()
    add_cube()
    assert export().triangle_count == 12


@pytest.mark.parametrize("add", [
    lambda: bpy.ops.object.text_add(),
    lambda: (bpy.ops.curve.primitive_bezier_circle_add(),
             setattr(bpy.context.object.data, "bevel_depth", 0.1)),
    lambda: bpy.ops.surface.primitive_nurbs_surface_sphere_add(),
    lambda: bpy.ops.object.metaball_add(type="BALL"),
])
def test_curve_text_surface_metaball_export_their_mesh_once(add):
    add()
    ob = bpy.context.object
    ob_eval = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = ob_eval.to_mesh()
    mesh.calc_loop_triangles()
    expected = len(mesh.loop_triangles)
    ob_eval.to_mesh_clear()
    assert expected > 0
    assert export().triangle_count == expected


def test_flat_and_mirrored_normals():
    flat = add_cube(location=(-10, 0, 0), rotation=(0.2, 0.4, 0.1), scale=(1, 2, 3))
    mirrored = add_cube(location=(10, 0, 0), scale=(-1, 1, 2))
    result = export()
    normals = unit(result.scene.normals.astype(np.float64))
    for ob in (flat, mirrored):
        expected_p, expected_n = blender_corners(ob)
        n = triangles_near(result, ob, normals)
        np.testing.assert_allclose(n, expected_n, atol=1e-5)
        # Shading normals point out of the (scaled or mirrored) box, whatever the winding does.
        centre = np.array(ob.location)
        outward = expected_p.mean(axis=1) - centre
        assert np.all(np.einsum("tci,ti->tc", n, outward) > 0)
        # Flat faces: every corner normal is the face's normal.
        p = triangles_near(result, ob, result.scene.positions).astype(np.float64)
        geometric = unit(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))
        np.testing.assert_allclose(np.abs(np.einsum("tci,ti->tc", n, geometric)), 1.0, atol=1e-5)


def test_flat_faces_are_shaded_by_each_triangles_own_normal():
    # Cycles shades the faces of a mesh of flat faces only by the normal of the triangle hit: a quad that is
    # not planar (a sculpted or displaced terrain) shows its two triangles' normals, where Blender's corner
    # normals give both the face's. In a mesh with corner normals (a smooth face and a sharp edge beside the
    # flat one) Cycles shades the flat face by those corner normals: the face's.
    folded = [(0, 0, 0), (2, 0, 0), (2, 2, 0.8), (0, 2, 0)]
    objects = {}
    for name, x, scale, corner_domain in (("Flat", -10, (1, 2, 1), False), ("Mirrored", 0, (-1, 1, 1), False),
                                          ("Corner", 10, (1, 1, 1), True)):
        mesh = bpy.data.meshes.new(name)
        if corner_domain:
            mesh.from_pydata(folded + [(0, 4, 0), (2, 4, 0.3)], [], [(0, 1, 2, 3), (3, 2, 5, 4)])
            mesh.polygons[1].use_smooth = True
            sharp = mesh.attributes.new("sharp_edge", "BOOLEAN", "EDGE")
            sharp.data[next(e.index for e in mesh.edges if set(e.vertices) == {4, 5})].value = True
        else:
            mesh.from_pydata(folded, [], [(0, 1, 2, 3)])
        ob = bpy.data.objects.new(name, mesh)
        ob.location, ob.scale, ob.rotation_euler = (x, 0, 0), scale, (0.3, 0.2, 0.1)
        bpy.context.scene.collection.objects.link(ob)
        objects[name] = ob
    dg = bpy.context.evaluated_depsgraph_get()
    result = export()
    normals = unit(result.scene.normals.astype(np.float64))
    for name, ob in objects.items():
        ob_eval = ob.evaluated_get(dg)
        mesh = ob_eval.data
        assert mesh.normals_domain == ("CORNER" if name == "Corner" else "FACE")
        normal_matrix = ob_eval.matrix_world.to_3x3().inverted_safe().transposed()
        own = np.array([(normal_matrix @ tri.normal).normalized()[:] for tri in mesh.loop_triangles[:2]])
        face = np.array((normal_matrix @ mesh.polygons[0].normal).normalized()[:])
        assert np.abs(own[0] @ own[1]) < 0.99   # the folded quad's triangles differ
        expected = np.array([face, face]) if name == "Corner" else own
        np.testing.assert_allclose(triangles_near(result, ob, normals)[:2], np.repeat(expected[:, None], 3, axis=1),
                                   atol=1e-5)


def test_smooth_sharp_and_custom_normals():
    smooth = add_cube(location=(-10, 0, 0))
    smooth.data.shade_smooth()
    sharp = add_cube(location=(0, 0, 0))
    sharp.data.shade_smooth()
    top_edges = {tuple(sorted(e.vertices)) for p in sharp.data.polygons if p.normal.z > 0.5
                 for e in sharp.data.edges if set(e.vertices) <= set(p.vertices)}
    sharp_edge = sharp.data.attributes.new("sharp_edge", "BOOLEAN", "EDGE")
    sharp_edge.data.foreach_set("value", [tuple(sorted(e.vertices)) in top_edges for e in sharp.data.edges])
    custom = add_cube(location=(10, 0, 0))
    custom.data.normals_split_custom_set_from_vertices([(0.0, 0.0, 1.0)] * 8)
    sharp.data.update()
    result = export()
    objects = (smooth, sharp, custom)
    normals = [triangles_near(result, ob, unit(result.scene.normals.astype(np.float64))) for ob in objects]
    positions = [triangles_near(result, ob, result.scene.positions) for ob in objects]
    for n, ob in zip(normals, objects):
        np.testing.assert_allclose(n, blender_corners(ob)[1], atol=1e-5)
    # Smooth cube: each corner normal is the diagonal through its vertex.
    np.testing.assert_allclose(normals[0], unit(positions[0] - np.array([-10.0, 0, 0])), atol=1e-5)
    # Sharp top edges: the top face is flat, the sides stay smooth around the vertical edges.
    top = np.all(positions[1][:, :, 2] > 0.5, axis=1)
    np.testing.assert_allclose(normals[1][top].reshape(-1, 3) - [0, 0, 1.0], 0.0, atol=1e-5)
    side_top_corners = normals[1][~top][positions[1][~top][:, :, 2] > 0.5]
    np.testing.assert_allclose(side_top_corners[:, 2], 0.0, atol=1e-5)
    # Blender stores custom normals compressed, to about 5e-5.
    np.testing.assert_allclose(normals[2].reshape(-1, 3), np.tile([0, 0, 1.0], (36, 1)), atol=1e-4)


def test_smooth_meshes_read_their_vertex_normals_as_blender_gives_its_corner_normals():
    """A mesh smooth all over (normals_domain POINT) is read by its vertex normals, a quarter of the rows of
    its corner normals, and its triangles' normals are Blender's corner normals bit for bit; a mesh flat all
    over (FACE) has a row per triangle, its own normal (the face's, to float precision, on planar faces)."""
    from ember.engine.export.mesh import read_mesh
    smooth = add_cube(location=(-10, 0, 0))
    smooth.data.shade_smooth()
    flat = add_cube(location=(10, 0, 0))
    dg = bpy.context.evaluated_depsgraph_get()
    for ob, domain in ((smooth, "POINT"), (flat, "FACE")):
        mesh = ob.evaluated_get(dg).data
        assert mesh.normals_domain == domain
        local = read_mesh(mesh)
        assert len(local.normal_rows) == (len(mesh.vertices) if domain == "POINT" else len(mesh.loop_triangles))
        corner = np.array([c.vector[:] for c in mesh.corner_normals], np.float32)
        loops = np.array([tri.loops[:] for tri in mesh.loop_triangles]).reshape(-1)
        if domain == "POINT":
            np.testing.assert_array_equal(local.normals, corner[loops])
        else:
            np.testing.assert_allclose(local.normals, corner[loops], atol=1e-6)


def test_plain_normals_are_rows_gathered_by_index_for_every_copy():
    """The export keeps the plain triangles' normals as CornerRows: each mesh's normals moved once per
    copy (here one smooth mesh shown by two objects, mirrored and rotated, and a flat cube), each corner
    reading its copy's row; they are Blender's corner normals either way (the flat cube's are its triangles'
    normals, its faces' as its faces are planar)."""
    from ember.kernels.scene import CornerRows
    first = add_cube(location=(-10, 0, 0), rotation=(0.3, 0.1, 0.7), scale=(1, 2, 0.5))
    first.data.shade_smooth()
    second = bpy.data.objects.new("Linked", first.data)
    bpy.context.scene.collection.objects.link(second)
    second.location, second.scale = (10, 0, 0), (-1, 1, 1)
    flat = add_cube(location=(0, 0, 0))
    result = export()
    normals = result.scene.normals
    assert isinstance(normals, CornerRows)
    # The corners are the BVH's own vertices and indices, not a copy.
    positions = result.scene.positions
    assert isinstance(positions, CornerRows)
    assert positions.rows is result.scene.bvh_vertices and positions.index is result.scene.bvh_indices
    for ob in (first, second, flat):
        np.testing.assert_allclose(triangles_near(result, ob, np.asarray(positions)), blender_corners(ob)[0],
                                   atol=1e-5)
    assert len(normals.rows) == 2 * 8 + 12      # the smooth mesh's 8 vertices twice, the flat cube's 12 triangles
    dense = unit(np.asarray(normals).astype(np.float64))
    for ob in (first, second, flat):
        np.testing.assert_allclose(triangles_near(result, ob, dense), blender_corners(ob)[1], atol=1e-5)


def test_uvs_come_from_the_render_uv_map():
    ob = add_cube()
    render_map = ob.data.uv_layers.new(name="RenderMap")
    render_map.uv.foreach_set("vector", np.tile([0.25, 0.75], len(ob.data.loops)).astype(np.float32))
    render_map.active_render = True
    ob.data.uv_layers.active = ob.data.uv_layers[0]  # the map shown in the editor is not the render one
    uvs = export().scene.uvs
    assert uvs.shape == (12, 3, 2) and uvs.dtype == np.float32
    np.testing.assert_allclose(uvs.reshape(-1, 2), np.tile([0.25, 0.75], (36, 1)))


def test_no_uv_map_gives_zero_uvs():
    ob = add_cube()
    ob.data.uv_layers.remove(ob.data.uv_layers[0])
    ob.data.update()
    uvs = export().scene.uvs
    np.testing.assert_array_equal(uvs, 0.0)
    # One row of zeros seen by every corner: a big mesh without UVs holds no 24 bytes per triangle of them.
    assert uvs.shape == (12, 3, 2) and uvs.strides[:2] == (0, 0)


def test_material_slots_per_face():
    colors = {"Red": (1.0, 0.0, 0.0), "Blue": (0.0, 0.0, 1.0), "Green": (0.0, 1.0, 0.0),
              None: (DEFAULT_ALBEDO,) * 3}
    mats = {}
    for name in ("Red", "Blue", "Green"):
        mats[name], bsdf = new_material(name)
        bsdf.inputs["Base Color"].default_value = colors[name] + (1.0,)
    ob = add_cube()
    for name in ("Red", "Blue", None):  # an empty slot renders the default surface
        ob.data.materials.append(mats.get(name))
    face_slots = np.array([0, 1, 0, 0, 1, 2], np.int32)
    ob.data.polygons.foreach_set("material_index", face_slots)
    ob.data.update()
    # A second cube sharing the mesh, with slot 0 linked to the object: same triangles, other material.
    other = bpy.data.objects.new("Other", ob.data)
    other.location.x = 10
    bpy.context.scene.collection.objects.link(other)
    other.material_slots[0].link = "OBJECT"
    other.material_slots[0].material = mats["Green"]
    result = export()
    assert result.scene.material_ids.dtype == np.int32 and result.scene.materials.count == 4
    albedo = np.array([material_row(result, m)[0] for m in range(4)])[result.scene.material_ids]
    dg = bpy.context.evaluated_depsgraph_get()
    tri_slots = face_slots[[t.polygon_index for t in ob.evaluated_get(dg).data.loop_triangles]]
    for cube, slot_names in ((ob, ("Red", "Blue", None)), (other, ("Green", "Blue", None))):
        expected = [colors[slot_names[slot]] for slot in tri_slots]
        np.testing.assert_allclose(triangles_near(result, cube, albedo), expected)


# ---- Materials --------------------------------------------------------------------------------------

def test_principled_base_color_and_emission():
    mat, bsdf = new_material("P")
    bsdf.inputs["Base Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    bsdf.inputs["Emission Color"].default_value = (1.0, 0.5, 0.0, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 3.0
    add_cube().data.materials.append(mat)
    result = export()
    albedo, albedo_tex, emission, emission_tex = material_row(result)
    np.testing.assert_allclose(albedo, [0.2, 0.4, 0.6], rtol=1e-6)
    np.testing.assert_allclose(emission, [3.0, 1.5, 0.0], rtol=1e-6)
    assert albedo_tex == -1 and emission_tex == -1
    assert result.warnings == []  # the default Principled settings need no warning
    assert np.all(result.scene.material_ids == 1)


def test_diffuse_and_emission_shaders():
    diffuse_mat, diffuse = new_material("D", "ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.1, 0.2, 0.3, 1.0)
    emit_mat, emit = new_material("E", "ShaderNodeEmission")
    emit.inputs["Color"].default_value = (1.0, 0.9, 0.8, 1.0)
    emit.inputs["Strength"].default_value = 10.0
    ob = add_cube()
    ob.data.materials.append(diffuse_mat)
    ob.data.materials.append(emit_mat)
    result = export()
    albedo, _, emission, _ = material_row(result, 1)
    np.testing.assert_allclose(albedo, [0.1, 0.2, 0.3], rtol=1e-6)
    np.testing.assert_array_equal(emission, 0.0)
    albedo, _, emission, _ = material_row(result, 2)
    np.testing.assert_array_equal(albedo, 0.0)  # an Emission surface is black apart from its light
    np.testing.assert_allclose(emission, [10.0, 9.0, 8.0], rtol=1e-6)


def test_unsupported_nodes_render_grey_with_one_warning_per_material():
    mat = bpy.data.materials.new("Odd")
    tree = mat.node_tree
    mix = tree.nodes.new("ShaderNodeMixShader")
    tree.links.new(mix.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    tree.links.new(tree.nodes.new("ShaderNodeEeveeSpecular").outputs[0], mix.inputs[1])
    tree.links.new(tree.nodes.new("ShaderNodeEeveeSpecular").outputs[0], mix.inputs[2])
    metal, bsdf = new_material("Metal")
    bsdf.inputs["Metallic"].default_value = 1.0
    bsdf.inputs["Base Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    stroke = metal.node_tree.nodes.new("ShaderNodeUVAlongStroke")
    metal.node_tree.links.new(stroke.outputs["UV"], bsdf.inputs["Roughness"])
    ob = add_cube()
    ob.data.materials.append(mat)
    ob.data.materials.append(metal)
    result = export()
    odd = result.scene.materials.shaders[1].closures
    assert [c.kind for c in odd] == ["DIFFUSE", "DIFFUSE"]
    np.testing.assert_allclose(odd[0].input("Color").value, DEFAULT_ALBEDO)
    assert [(p.value, second) for p, second in odd[0].factors] == [((0.5,), False)]
    warned = [w for w in result.warnings if "'Odd'" in w]
    assert len(warned) == 1 and "'Specular BSDF'" in warned[0] and "'Specular BSDF.001'" in warned[0]
    (principled,) = result.scene.materials.shaders[2].closures
    assert principled.kind == "PRINCIPLED" and principled.input("Metallic").value == (1.0,)
    assert principled.input("Roughness").value == (0.5,)  # the socket's own value
    metallic = [w for w in result.warnings if "'Metal'" in w]
    assert len(metallic) == 1 and "UV Along Stroke node" in metallic[0] and "feeding Roughness" in metallic[0]


def test_mix_and_add_shaders_keep_their_factors():
    mat = bpy.data.materials.new("Mixed")
    tree = mat.node_tree
    tree.nodes.remove(tree.nodes["Principled BSDF"])
    mix, add = tree.nodes.new("ShaderNodeMixShader"), tree.nodes.new("ShaderNodeAddShader")
    mix.inputs[0].default_value = 0.25
    glossy, glass = tree.nodes.new("ShaderNodeBsdfAnisotropic"), tree.nodes.new("ShaderNodeBsdfGlass")
    emit, transparent = tree.nodes.new("ShaderNodeEmission"), tree.nodes.new("ShaderNodeBsdfTransparent")
    tree.links.new(glossy.outputs[0], mix.inputs[1])
    tree.links.new(add.outputs[0], mix.inputs[2])
    tree.links.new(glass.outputs[0], add.inputs[0])
    tree.links.new(emit.outputs[0], add.inputs[1])
    tree.links.new(mix.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    unused = tree.nodes.new("ShaderNodeMixShader")  # a Mix at factor 0 drops its second input
    unused.inputs[0].default_value = 0.0
    tree.links.new(transparent.outputs[0], unused.inputs[2])
    add_cube().data.materials.append(mat)
    result = export()
    closures = result.scene.materials.shaders[1].closures
    assert [c.kind for c in closures] == ["GLOSSY", "GLASS", "EMISSION"]
    assert [[(p.value, s) for p, s in c.factors] for c in closures] == \
        [[((0.25,), False)], [((0.25,), True)], [((0.25,), True)]]
    assert dict(closures[0].options)["distribution"] == "MULTI_GGX"
    assert result.warnings == []


def test_beckmann_and_ashikhmin_shirley_distributions_export_without_warnings():
    mat = bpy.data.materials.new("Distributions")
    tree = mat.node_tree
    tree.nodes.remove(tree.nodes["Principled BSDF"])
    add = [tree.nodes.new("ShaderNodeAddShader") for _ in range(2)]
    glossy, refraction = tree.nodes.new("ShaderNodeBsdfAnisotropic"), tree.nodes.new("ShaderNodeBsdfRefraction")
    metal = tree.nodes.new("ShaderNodeBsdfMetallic")
    glossy.distribution, metal.distribution = "ASHIKHMIN_SHIRLEY", "BECKMANN"
    refraction.inputs["Roughness"].default_value = 0.3  # Beckmann is the Refraction BSDF's default
    tree.links.new(glossy.outputs[0], add[0].inputs[0])
    tree.links.new(refraction.outputs[0], add[0].inputs[1])
    tree.links.new(add[0].outputs[0], add[1].inputs[0])
    tree.links.new(metal.outputs[0], add[1].inputs[1])
    tree.links.new(add[1].outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    add_cube().data.materials.append(mat)
    result = export()
    closures = result.scene.materials.shaders[1].closures
    assert [(c.kind, dict(c.options)["distribution"]) for c in closures] == \
        [("GLOSSY", "ASHIKHMIN_SHIRLEY"), ("REFRACTION", "BECKMANN"), ("METALLIC", "BECKMANN")]
    assert result.warnings == []


def test_unlinked_surface_renders_black():
    mat = bpy.data.materials.new("Empty")
    tree = mat.node_tree
    tree.links.remove(tree.nodes["Material Output"].inputs["Surface"].links[0])
    add_cube().data.materials.append(mat)
    albedo, _, emission, _ = material_row(export())
    np.testing.assert_array_equal(albedo, 0.0)
    np.testing.assert_array_equal(emission, 0.0)


def test_groups_reroutes_and_muted_nodes_are_seen_through():
    group = bpy.data.node_groups.new("Shade", "ShaderNodeTree")
    group.interface.new_socket("Tint", in_out="INPUT", socket_type="NodeSocketColor")
    group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    g_in, g_out = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    diffuse = group.nodes.new("ShaderNodeBsdfDiffuse")
    group.links.new(g_in.outputs["Tint"], diffuse.inputs["Color"])
    group.links.new(diffuse.outputs[0], g_out.inputs["Shader"])

    mat = bpy.data.materials.new("Grouped")
    tree = mat.node_tree
    tree.nodes.remove(tree.nodes["Principled BSDF"])
    group_node = tree.nodes.new("ShaderNodeGroup")
    group_node.node_tree = group
    rgb = tree.nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (0.3, 0.2, 0.1, 1.0)
    reroute = tree.nodes.new("NodeReroute")
    tree.links.new(rgb.outputs[0], reroute.inputs[0])
    tree.links.new(reroute.outputs[0], group_node.inputs["Tint"])
    add = tree.nodes.new("ShaderNodeAddShader")
    add.mute = True  # a muted Add Shader passes its first input through
    tree.links.new(group_node.outputs["Shader"], add.inputs[0])
    tree.links.new(add.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    add_cube().data.materials.append(mat)
    result = export()
    np.testing.assert_allclose(material_row(result)[0], [0.3, 0.2, 0.1], rtol=1e-6)
    assert result.warnings == []


def test_image_textures_srgb_float_and_non_color():
    # Whole byte values k / 255, so the byte image stores them exactly.
    rows = np.array([[[0, 51, 102, 255], [153, 204, 255, 255]],   # bottom row
                     [[128, 128, 128, 255], [25, 77, 230, 255]]], np.float32) / 255
    srgb = new_image("SRGB", rows)
    data = new_image("Data", rows, colorspace="Non-Color")
    hdr = new_image("HDR", rows * 4, float_buffer=True)
    srgb.pack()  # packed images read the same
    ob = add_cube()
    mats = [textured_material(name, image)[0] for name, image in
            (("A", srgb), ("B", data), ("C", hdr), ("Again", srgb))]
    for mat in mats:
        ob.data.materials.append(mat)
    bsdf_mat, bsdf = new_material("Glow")
    tex = bsdf_mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = hdr
    bsdf_mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Emission Color"])
    bsdf.inputs["Emission Strength"].default_value = 2.0
    ob.data.materials.append(bsdf_mat)
    result = export()
    textures = result.scene.textures
    assert len(textures) == 3  # one per image, shared by the materials that use it
    # 8-bit sRGB stays encoded and flagged: the kernel decodes after filtering, as Cycles does.
    assert result.scene.texture_srgb == (True, False, False)
    assert textures[0].dtype == textures[1].dtype == np.uint8  # 8-bit images stay bytes: k stands for k / 255
    np.testing.assert_allclose(textures[0] / 255, rows[..., :3], atol=1e-6)
    np.testing.assert_allclose(textures[1] / 255, rows[..., :3], atol=1e-6)
    np.testing.assert_allclose(textures[2], rows[..., :3] * 4, atol=1e-6)
    rows = [material_row(result, m) for m in range(1, 6)]
    assert [r[1] for r in rows] == [0, 1, 2, 0, -1]
    np.testing.assert_array_equal(rows[0][0], 1.0)  # the kernel multiplies constant x texture
    assert rows[4][3] == 2
    np.testing.assert_allclose(rows[4][2], 2.0)
    assert result.warnings == []
    result.scene.validate()


def test_missing_image_renders_magenta_with_a_warning(tmp_path):
    path = str(tmp_path / "gone.png")
    image = new_image("Gone", np.ones((2, 2, 4), np.float32))
    image.filepath_raw = path
    image.file_format = "PNG"
    image.save()
    image = bpy.data.images.load(path)
    os.remove(path)
    mat, _ = textured_material("Missing", image)
    add_cube().data.materials.append(mat)
    result = export()
    albedo, albedo_tex, _, _ = material_row(result)
    np.testing.assert_array_equal(albedo, [1.0, 0.0, 1.0])
    assert albedo_tex == -1 and result.scene.textures == ()
    assert any(f"'{image.name}'" in w and "magenta" in w for w in result.warnings)


def test_non_uv_texture_coordinates_go_through_the_node_program():
    image = new_image("Tex", np.ones((1, 1, 4), np.float32))
    mat, tex = textured_material("Generated", image)
    coords = mat.node_tree.nodes.new("ShaderNodeTexCoord")
    mat.node_tree.links.new(coords.outputs["Generated"], tex.inputs["Vector"])
    add_cube().data.materials.append(mat)
    result = export()
    shader = result.scene.materials.shaders[1]
    assert [op.kind for op in shader.program.ops] == ["ShaderNodeTexCoord", "ShaderNodeTexImage"]
    assert shader.closures[0].input("Color").link is not None
    assert not [w for w in result.warnings if "'Generated'" in w]


# ---- World ------------------------------------------------------------------------------------------

def test_no_world_is_black_and_constant_world(empty_scene):
    world = export().scene.world
    np.testing.assert_array_equal(world.color, 0.0)
    assert world.hdri is None
    empty_scene.world = bpy.data.worlds.new("W")
    background = empty_scene.world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (0.1, 0.2, 0.3, 1.0)
    background.inputs["Strength"].default_value = 2.0
    world = export().scene.world
    np.testing.assert_allclose(world.color, [0.1, 0.2, 0.3], rtol=1e-6)
    assert world.strength == 2.0 and world.hdri is None


def test_8_bit_srgb_environment_is_kept_as_bytes_and_decoded_after_filtering(empty_scene):
    """An 8-bit sRGB environment stays bytes, 3 a texel, marked sRGB (decoded after filtering, as Cycles'), with its
    node's interpolation; its strength is limited by its brightest decoded value."""
    rows = np.array([[[0, 51, 102, 255], [153, 204, 255, 255]]], np.float32) / 255
    hdri_world(empty_scene, new_image("Sky", rows))
    empty_scene.world.node_tree.nodes["Environment Texture"].interpolation = "Closest"
    world = export().scene.world
    assert world.hdri.dtype == np.uint8 and world.hdri_srgb and world.hdri_interpolation == "Closest"
    np.testing.assert_array_equal(world.hdri, np.rint(rows[..., :3] * 255).astype(np.uint8))


def test_unsupported_world_nodes_warn_once(empty_scene):
    """A shader node Ember cannot read as the world's surface (EEVEE's Specular BSDF) renders grey, and a BSDF
    black without a word (Cycles reads a world's emission only); an unsupported node feeding the Background's
    Color leaves the Color's own value; each world warns in one line naming the node."""
    empty_scene.world = bpy.data.worlds.new("Odd")
    tree = empty_scene.world.node_tree
    specular = tree.nodes.new("ShaderNodeEeveeSpecular")
    tree.links.new(specular.outputs[0], tree.nodes["World Output"].inputs["Surface"])
    result = export()
    np.testing.assert_allclose(result.scene.world.color, 0.05)
    (line,) = [w for w in result.warnings if "'Odd'" in w]
    assert "Specular" in line
    tree.links.new(tree.nodes.new("ShaderNodeBsdfDiffuse").outputs[0], tree.nodes["World Output"].inputs["Surface"])
    result = export()
    np.testing.assert_allclose(result.scene.world.color, 0.0)
    assert not [w for w in result.warnings if "'Odd'" in w]
    empty_scene.world = bpy.data.worlds.new("Fallen")
    tree = empty_scene.world.node_tree
    background = tree.nodes["Background"]
    background.inputs["Color"].default_value = (0.2, 0.3, 0.4, 1.0)
    tree.links.new(tree.nodes.new("ShaderNodeUVAlongStroke").outputs["UV"], background.inputs["Color"])
    result = export()
    np.testing.assert_allclose(result.scene.world.color, (0.2, 0.3, 0.4), rtol=1e-6)
    (line,) = [w for w in result.warnings if "'Fallen'" in w]
    assert "UV Along Stroke" in line and "Color" in line


def test_ambient_occlusion_in_a_world_is_one(empty_scene):
    """Cycles traces no rays for a world (its background node mask has no RAYTRACE): AO is 1 and the Color
    passes, folded to a constant world, without a warning; the world's AO distance is exported."""
    empty_scene.world = bpy.data.worlds.new("Occluded")
    tree = empty_scene.world.node_tree
    background = tree.nodes["Background"]
    ao = tree.nodes.new("ShaderNodeAmbientOcclusion")
    ao.inputs["Color"].default_value = (0.2, 0.3, 0.4, 1.0)
    tree.links.new(ao.outputs["Color"], background.inputs["Color"])
    empty_scene.world.light_settings.distance = 3.5
    result = export()
    np.testing.assert_allclose(result.scene.world.color, (0.2, 0.3, 0.4), rtol=1e-6)
    assert result.scene.world.program is None
    assert not [w for w in result.warnings if "'Occluded'" in w]
    assert result.scene.world.ao_distance == pytest.approx(3.5)


def hdri_world(scene, image, vector_type=None, rotation=(0.0, 0.0, 0.0)):
    scene.world = bpy.data.worlds.new("HDRI")
    tree = scene.world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = image
    tree.links.new(env.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    if vector_type is not None:
        mapping = tree.nodes.new("ShaderNodeMapping")
        mapping.vector_type = vector_type
        mapping.inputs["Rotation"].default_value = rotation
        coords = tree.nodes.new("ShaderNodeTexCoord")
        tree.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
        tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    return env


@pytest.mark.parametrize("vector_type", ["POINT", "TEXTURE"])
def test_hdri_world_with_mapping_rotation(empty_scene, vector_type):
    path = os.path.join(bpy.utils.system_resource("DATAFILES", path="studiolights/world"), "forest.exr")
    image = bpy.data.images.load(path)
    rotation = (0.3, 0.5, 1.0)
    hdri_world(empty_scene, image, vector_type, rotation)
    result = export()
    world = result.scene.world
    pixels = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(pixels)
    w, h = image.size
    np.testing.assert_array_equal(world.hdri, np.maximum(pixels.reshape(h, w, 4)[..., :3], 0))
    r = np.array(mathutils.Euler(rotation, "XYZ").to_matrix())
    np.testing.assert_allclose(world.env_from_world, r if vector_type == "POINT" else r.T, atol=1e-6)
    assert result.warnings == []
    result.scene.validate()


def test_mapping_rotation_matches_cycles(empty_scene):
    """Render one pixel of a UV-coded environment with Cycles and look it up the way the kernel does."""
    width, height = 64, 32
    uv = np.zeros((height, width, 4), np.float32)
    uv[..., 0] = ((np.arange(width) + 0.5) / width)[None, :]
    uv[..., 1] = ((np.arange(height) + 0.5) / height)[:, None]
    uv[..., 3] = 1.0   # opaque: from Blender 5.2 Cycles multiplies a Straight float image's colour by its alpha
    env = hdri_world(empty_scene, new_image("UV", uv, float_buffer=True), "POINT", (0.3, 0.5, 1.0))
    env.interpolation = "Closest"
    camera = empty_scene.camera
    camera.rotation_euler = (1.2, 0.0, 0.7)
    camera.data.lens = 2000  # one pixel sees one direction
    world = export().scene.world
    direction = -np.array(camera.matrix_world.to_3x3().col[2], np.float32)
    render = empty_scene.render
    render.filter_size = 0.01
    render.engine = "CYCLES"
    empty_scene.cycles.samples = 1
    empty_scene.cycles.use_denoising = False
    render.resolution_x = render.resolution_y = 1
    render.image_settings.file_format = "OPEN_EXR"
    render.filepath = os.path.join(bpy.app.tempdir or "/tmp", "ember_env_check.exr")
    bpy.ops.render.render(write_still=True)
    out = bpy.data.images.load(render.filepath)
    cycles_uv = np.array(out.pixels[:2])
    lookup = world.env_from_world @ direction
    u, v = direction_to_equirect(*[np.float32(c) for c in lookup])
    np.testing.assert_allclose([u, v], cycles_uv, atol=1.0 / height)


# ---- Camera -----------------------------------------------------------------------------------------

def test_perspective_camera_parameters(empty_scene):
    cam = empty_scene.camera
    cam.data.lens = 35.0
    cam.data.sensor_fit = "VERTICAL"
    cam.data.sensor_height = 24.0
    cam.data.shift_x, cam.data.shift_y = 0.1, -0.2
    cam.data.clip_start, cam.data.clip_end = 0.5, 50.0
    cam.scale = (2, 2, 2)
    render = empty_scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = 1920, 1080, 50
    render.pixel_aspect_x, render.pixel_aspect_y = 2.0, 1.0
    c = export().scene.camera
    assert (c.kind, c.sensor_fit, c.width, c.height) == ("PERSP", "VERTICAL", 960, 540)
    assert c.fov_rad == pytest.approx(2 * math.atan(24.0 / 70.0))
    assert (c.shift_x, c.shift_y, c.pixel_aspect) == pytest.approx((0.1, -0.2, 2.0))
    assert (c.clip_start, c.clip_end) == pytest.approx((0.5, 50.0))
    expected = np.array(cam.matrix_world.normalized())
    np.testing.assert_allclose(c.world_from_camera, expected, atol=1e-6)
    assert c.world_from_camera.dtype == np.float64
    c.validate()


def test_orthographic_camera_override_and_explicit_size(empty_scene):
    bpy.ops.object.camera_add()
    other = bpy.context.object
    other.data.type = "ORTHO"
    other.data.ortho_scale = 3.5
    other.data.sensor_fit = "AUTO"
    other.data.sensor_width = 30.0
    result = export_scene(bpy.context.evaluated_depsgraph_get(), other, width=64, height=48)
    c = result.scene.camera
    assert (c.kind, c.ortho_scale, c.width, c.height) == ("ORTHO", pytest.approx(3.5), 64, 48)
    assert c.fov_rad == pytest.approx(2 * math.atan(30.0 / 100.0))


def test_no_camera_raises_export_error(empty_scene):
    empty_scene.camera = None
    with pytest.raises(ExportError, match="no camera"):
        export()


def test_render_region_counts_rows_from_the_top(empty_scene):
    render = empty_scene.render
    assert render_region(empty_scene, 100, 50) is None
    render.use_border = True
    render.border_min_x, render.border_max_x = 0.123, 0.567
    render.border_min_y, render.border_max_y = 0.211, 0.789
    # Blender renders x 12..55 and, from the bottom, y 10..38 (a 44 x 29 render result).
    assert render_region(empty_scene, 100, 50) == (12, 11, 56, 40)


# ---- Bad input --------------------------------------------------------------------------------------

def test_empty_scene_exports_and_validates():
    result = export()
    assert result.triangle_count == 0 and result.scene.positions.shape == (0, 3, 3)
    result.scene.validate()


def test_nan_and_zero_area_faces_do_not_break_export():
    ob = add_cube()
    ob.data.vertices[0].co = (float("nan"), 0.0, 0.0)
    for v in ob.data.vertices[4:]:
        v.co = (0.0, 0.0, 0.0)  # collapses the faces that only use these vertices
    ob.data.update()
    result = export()
    assert result.triangle_count == 12
    validated = result.scene.validate()
    assert 0 < validated.dropped_triangles < 12


def test_world_fog_is_read_and_light_groups_are_exported():
    """A world's Volume output becomes the world's medium (no warning); a view layer's light groups need no
    warning either (the world joins its group: tests/test_light_groups.py)."""
    scene = camera_only_scene()
    world = bpy.data.worlds.new("Foggy")
    scene.world = world
    tree = world.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld")
    tree.links.new(tree.nodes.new("ShaderNodeVolumePrincipled").outputs[0], out.inputs["Volume"])
    bpy.context.view_layer.lightgroups.add(name="Key")
    world.lightgroup = "Key"
    result = export_current()
    warnings = result.warnings
    assert not any("Volume" in w for w in warnings), warnings
    assert result.scene.world.volume is not None
    assert [c.kind for c in result.scene.world.volume.volume] == ["PRINCIPLED_VOLUME"]
    assert not any("light group" in w for w in warnings), warnings
    assert result.scene.light_groups.world == 0
