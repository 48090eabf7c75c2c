"""Geometry > Pointiness and Random Per Island, the Attribute node's Object, Instancer and View Layer types and
the Wireframe node: closed forms of what Blender's Cycles sync computes (engine/export/mesh_topology.py,
engine/export/rgba_attributes.py), the export's values, and parity with Cycles."""
import math

import bpy
import numpy as np
import pytest

from bpy_helpers import compare_to_cycles, export_current, mesh_object, new_scene, set_world

from ember.engine.export.mesh_topology import island_roots, pointiness, random_per_island, welded_vertices
from ember.kernels.programs import Op
from ember.kernels.shading.input_ops import wireframe

# ---------------------------------------------------------------- Pointiness: closed forms
CORNER = math.acos(-1 / math.sqrt(3)) / math.pi       # three perpendicular edges away from the normal
EDGE = math.acos(-1 / (2 * math.sqrt(2))) / math.pi   # an edge midpoint of a once-split cube
FLAT = 0.5                                            # every neighbour in the tangent plane

CUBE_VERTS = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
CUBE_EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8)
                       if np.abs(CUBE_VERTS[a] - CUBE_VERTS[b]).sum() == 2], np.int32)


def test_pointiness_of_a_cube_is_its_corner_angle():
    normals = CUBE_VERTS / np.sqrt(3)
    values = pointiness(CUBE_VERTS, normals, CUBE_EDGES)
    np.testing.assert_allclose(values, CORNER, rtol=1e-6)


def test_pointiness_of_a_flat_grid_is_one_half():
    xs, ys = np.meshgrid(np.arange(5), np.arange(4), indexing="ij")
    verts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1).astype(np.float32)
    index = np.arange(xs.size).reshape(xs.shape)
    edges = np.concatenate([np.stack([index[:-1].ravel(), index[1:].ravel()], 1),
                            np.stack([index[:, :-1].ravel(), index[:, 1:].ravel()], 1)])
    normals = np.tile(np.float32([0, 0, 1]), (xs.size, 1))
    np.testing.assert_allclose(pointiness(verts, normals, edges), FLAT, atol=1e-6)


def test_duplicate_vertices_are_welded_as_cycles_welds_them():
    """A cube whose faces are split apart (24 vertices, 24 edges) reads as the closed cube: welded vertices,
    their normals summed, each welded edge once."""
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    verts, normals, edges = [], [], []
    for face in faces:
        p = CUBE_VERTS[list(face)]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        first = len(verts)
        verts.extend(p)
        normals.extend([n / np.linalg.norm(n)] * 4)
        edges.extend((first + i, first + (i + 1) % 4) for i in range(4))
    verts = np.array(verts, np.float32)
    welded = welded_vertices(verts)
    assert len(np.unique(welded)) == 8
    np.testing.assert_array_equal(verts[welded], verts)
    np.testing.assert_allclose(pointiness(verts, np.array(normals, np.float32), np.array(edges)), CORNER, rtol=1e-6)


def test_pointiness_orders_corners_edges_and_faces_of_a_split_cube():
    """A cube split once (Simple subdivision): raw values CORNER, EDGE and FLAT, then Cycles' one blur step
    over the one-ring; read from Blender's evaluated mesh and through the export."""
    scene = new_scene(8, 8)
    bpy.ops.mesh.primitive_cube_add(size=2)
    ob = bpy.context.active_object
    mod = ob.modifiers.new("split", "SUBSURF")
    mod.subdivision_type, mod.levels, mod.render_levels = "SIMPLE", 1, 1
    ob.data.materials.append(_emission_of(lambda tree: tree.nodes.new("ShaderNodeNewGeometry").outputs["Pointiness"]))
    mesh = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    verts = np.array([v.co for v in mesh.vertices], np.float32)
    normals = np.array([v.normal for v in mesh.vertices], np.float32)
    edges = np.array([e.vertices[:] for e in mesh.edges])
    values = pointiness(verts, normals, edges)
    kind = np.count_nonzero(np.abs(np.abs(verts) - 1) < 1e-6, axis=1)   # 3 corner, 2 edge, 1 face centre
    expected = {3: (CORNER + 3 * EDGE) / 4, 2: (EDGE + 2 * CORNER + 2 * FLAT) / 5, 1: (FLAT + 4 * EDGE) / 5}
    for k, value in expected.items():
        np.testing.assert_allclose(values[kind == k], value, rtol=1e-5)
    assert expected[3] > expected[2] > expected[1]
    result = export_current()
    attributes = dict(result.scene.attributes)
    assert "Pointiness" not in " ".join(result.warnings)
    corner_values = attributes["geom:pointiness"][..., 0].ravel()
    nearest = np.abs(corner_values[:, None] - np.array(list(expected.values()))[None]).min(axis=1)
    assert nearest.max() < 1e-5 and scene.render.engine


def test_pointiness_is_read_only_for_meshes_that_ask():
    new_scene(8, 8)
    mesh_object("Plain", [(0, 0, 0), (1, 0, 0), (1, 1, 0)], [(0, 1, 2)])
    result = export_current()
    assert "geom:pointiness" not in dict(result.scene.attributes)


# ---------------------------------------------------------------- Random Per Island
def _lookup3_hash_uint(k: int) -> int:
    """Jenkins' lookup3 of one word, as Cycles' hash_uint (util/hash.h), written out independently."""
    m = 0xFFFFFFFF

    def rot(x, r):
        return ((x << r) | (x >> (32 - r))) & m
    a = b = c = (0xDEADBEEF + (1 << 2) + 13) & m
    a = (a + k) & m
    c ^= b; c = (c - rot(b, 14)) & m   # noqa: E702
    a ^= c; a = (a - rot(c, 11)) & m   # noqa: E702
    b ^= a; b = (b - rot(a, 25)) & m   # noqa: E702
    c ^= b; c = (c - rot(b, 16)) & m   # noqa: E702
    a ^= c; a = (a - rot(c, 4)) & m    # noqa: E702
    b ^= a; b = (b - rot(a, 14)) & m   # noqa: E702
    c ^= b; c = (c - rot(b, 24)) & m   # noqa: E702
    return c


def _hash_to_float(k: int) -> float:
    return float(np.float32(_lookup3_hash_uint(k)) * np.float32(1.0 / 0xFFFFFFFF))


def test_random_per_island_hashes_each_islands_root():
    """Two chains: DisjointSet joins (0, 1) under 0, then 2 and 3 under the higher-ranked 0; (4..7) under 4."""
    edges = np.array([(0, 1), (1, 2), (2, 3), (4, 5), (5, 6), (6, 7)])
    np.testing.assert_array_equal(island_roots(8, edges), [0, 0, 0, 0, 4, 4, 4, 4])
    values = random_per_island(8, edges, np.array([0, 3, 5, 7]))
    assert values[0] == values[1] == np.float32(_hash_to_float(0))
    assert values[2] == values[3] == np.float32(_hash_to_float(4))
    assert values[0] != values[2] and 0 <= values.min() and values.max() <= 1


def test_random_per_island_through_the_export():
    """Three cubes joined into one mesh: every triangle of a cube the same value, the cubes different."""
    new_scene(8, 8)
    _joined_cubes(3)
    bpy.context.active_object.data.materials.append(
        _emission_of(lambda tree: tree.nodes.new("ShaderNodeNewGeometry").outputs["Random Per Island"]))
    result = export_current()
    values = dict(result.scene.attributes)["geom:random_per_island"][..., 0]     # (T, 3)
    assert (values == values[:, :1]).all()
    centres = result.scene.bvh_vertices[result.scene.bvh_indices].mean(axis=1)
    island = np.round(centres[:, 0] / 3).astype(int)
    per_island = [np.unique(values[island == i]) for i in np.unique(island)]
    assert all(len(v) == 1 for v in per_island)
    assert len({float(v[0]) for v in per_island}) == 3


def _joined_cubes(count: int):
    for i in range(count):
        bpy.ops.mesh.primitive_cube_add(size=1.2, location=(3 * i - 3, 0, 1))
    for ob in bpy.context.scene.objects:
        ob.select_set(ob.type == "MESH")
    bpy.context.view_layer.objects.active = next(ob for ob in bpy.context.scene.objects if ob.type == "MESH")
    bpy.ops.object.join()
    return bpy.context.active_object


# ---------------------------------------------------------------- Object, Instancer and View Layer attributes
def _attribute(tree, kind: str, name: str, output: str = "Color"):
    node = tree.nodes.new("ShaderNodeAttribute")
    node.attribute_type, node.attribute_name = kind, name
    return node.outputs[output]


def test_object_and_instancer_attributes_are_read_per_instance():
    new_scene(8, 8)
    mat = _emission_of(lambda tree: _sum(tree, _attribute(tree, "OBJECT", "tint"),
                                         _attribute(tree, "INSTANCER", "glow")))
    a = mesh_object("A", [(0, 0, 0), (1, 0, 0), (1, 1, 0)], [(0, 1, 2)], mat)
    b = mesh_object("B", [(0, 0, 1), (1, 0, 1), (1, 1, 1)], [(0, 1, 2)], mat)
    a["tint"] = (0.25, 0.5, 0.75)
    b.data["tint"] = 2                       # not on the object: on its mesh, an int
    b["glow"] = True
    result = export_current()
    table = dict(result.scene.object_attributes)
    rows = {k[0]: r for r, k in enumerate(result.index.instance_keys)}
    np.testing.assert_allclose(table["object:tint"][rows["A"]], (0.25, 0.5, 0.75, 1.0))
    np.testing.assert_allclose(table["object:tint"][rows["B"]], (2, 2, 2, 1))
    np.testing.assert_allclose(table["instancer:glow"][rows["A"]], (0, 0, 0, 0))   # found nowhere
    np.testing.assert_allclose(table["instancer:glow"][rows["B"]], (1, 1, 1, 1))   # not an instance: its own
    assert not [w for w in result.warnings if "attribute" in w.lower()]


def test_view_layer_attributes_fold_into_constants():
    scene = new_scene(8, 8)
    scene["haze"] = (0.1, 0.2, 0.6, 0.5)
    mat = _emission_of(lambda tree: _attribute(tree, "VIEW_LAYER", "haze"))
    mesh_object("A", [(0, 0, 0), (1, 0, 0), (1, 1, 0)], [(0, 1, 2)], mat)
    bpy.context.view_layer["haze"] = 0.3     # the view layer comes before the scene
    result = export_current()
    (shader,) = [s for s in result.scene.materials.shaders if s.name == mat.name]
    (closure,) = shader.closures
    np.testing.assert_allclose(closure.input("Color").value, (0.3, 0.3, 0.3))
    assert not [w for w in result.warnings if "attribute" in w.lower()]


# ---------------------------------------------------------------- Wireframe
class _Corners:
    def __init__(self, corners):
        self._corners = corners

    def corners(self, idx):
        return tuple(np.repeat(c[None], len(idx), axis=0) for c in self._corners)


class _Hits:
    def __init__(self, points, corners):
        self.P = np.asarray(points, np.float32)
        self.n = len(self.P)
        self.idx = np.arange(self.n)
        self.hit = _Corners([np.asarray(c, np.float32) for c in corners])


def test_wireframe_is_one_near_an_edge_and_zero_inside():
    """Size 0.1 in world units: 1 within 0.05 of any of the triangle's three edges (Cycles' svm_node_wireframe)."""
    hits = _Hits([(1 / 3, 1 / 3, 0), (0.5, 0.02, 0), (0.5, 0.06, 0), (0.01, 0.5, 0), (0.48, 0.48, 0)],
                 [(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    fac = wireframe(hits, {"Size": 0.1}, Op("ShaderNodeWireframe", (), (("use_pixel_size", False),)))["Fac"]
    np.testing.assert_array_equal(fac, [0, 1, 0, 1, 1])


# ---------------------------------------------------------------- parity with Cycles
def _emission_of(build, strength=None):
    mat = bpy.data.materials.new("Shown")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    em = tree.nodes.new("ShaderNodeEmission")
    tree.links.new(build(tree), em.inputs["Color"])
    if strength is not None:
        tree.links.new(strength(tree), em.inputs["Strength"])
    tree.links.new(em.outputs[0], out.inputs["Surface"])
    return mat


def _sum(tree, a, b):
    node = tree.nodes.new("ShaderNodeVectorMath")
    tree.links.new(a, node.inputs[0])
    tree.links.new(b, node.inputs[1])
    return node.outputs[0]


def _ramp(tree, value, stops):
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    elements = ramp.color_ramp.elements
    elements[0].position, elements[0].color = stops[0][0], (*stops[0][1], 1)
    elements[1].position, elements[1].color = stops[-1][0], (*stops[-1][1], 1)
    for position, color in stops[1:-1]:
        element = elements.new(position)
        element.color = (*color, 1)
    tree.links.new(value, ramp.inputs["Fac"])
    return ramp.outputs["Color"]


def test_pointiness_through_a_color_ramp_against_cycles():
    scene = new_scene(48, 48)
    set_world(scene, color=(0, 0, 0))
    bpy.ops.mesh.primitive_monkey_add(size=2.2, location=(0, 0, 1.1), rotation=(0, 0, math.radians(20)))
    ob = bpy.context.active_object
    mod = ob.modifiers.new("smooth", "SUBSURF")
    mod.levels = mod.render_levels = 1
    ob.data.materials.append(_emission_of(lambda tree: _ramp(
        tree, tree.nodes.new("ShaderNodeNewGeometry").outputs["Pointiness"],
        [(0.40, (0.05, 0.05, 0.3)), (0.5, (0.5, 0.5, 0.5)), (0.58, (1.0, 0.6, 0.1))])))
    compare_to_cycles(scene, samples=64, max_bounces=0)


def test_random_per_island_against_cycles():
    scene = new_scene(48, 48)
    set_world(scene, color=(0, 0, 0))
    ob = _joined_cubes(3)
    ob.rotation_euler = (0.3, 0.2, 0.5)

    def build(tree):
        # The value itself, not hashed further: Cycles 5.0 stores exactly hash_uint_to_float(root), Cycles 5.3
        # one float32 step above it (seen on these islands), which a White Noise of it would magnify.
        geometry = tree.nodes.new("ShaderNodeNewGeometry")
        square = tree.nodes.new("ShaderNodeMath")
        square.operation = "MULTIPLY"
        tree.links.new(geometry.outputs["Random Per Island"], square.inputs[0])
        tree.links.new(geometry.outputs["Random Per Island"], square.inputs[1])
        comb = tree.nodes.new("ShaderNodeCombineXYZ")
        tree.links.new(geometry.outputs["Random Per Island"], comb.inputs[0])
        tree.links.new(square.outputs[0], comb.inputs[1])
        comb.inputs[2].default_value = 0.2
        return comb.outputs[0]

    ob.data.materials.append(_emission_of(build))
    compare_to_cycles(scene, samples=64, max_bounces=0)


def test_object_instancer_and_view_layer_attributes_against_cycles():
    scene = new_scene(48, 48)
    set_world(scene, color=(0, 0, 0))
    scene["exposure_boost"] = 1.5
    mat = _emission_of(lambda tree: _sum(tree, _attribute(tree, "OBJECT", "tint"),
                                         _attribute(tree, "INSTANCER", "shift")),
                       strength=lambda tree: _attribute(tree, "VIEW_LAYER", "exposure_boost", "Fac"))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-1.2, 0, 1.0))
    left = bpy.context.active_object
    left["tint"] = (0.8, 0.2, 0.1)
    left.data.materials.append(mat)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0, 0, 0), segments=16, ring_count=8)
    sphere = bpy.context.active_object
    sphere.data["tint"] = (0.1, 0.3, 0.7)      # on the mesh: every instance of it reads it
    sphere.data.materials.append(mat)
    group = bpy.data.collections.new("Group")
    scene.collection.children.link(group)
    scene.collection.objects.unlink(sphere)
    group.objects.link(sphere)
    group.hide_render = False
    bpy.context.view_layer.layer_collection.children["Group"].exclude = True
    for i, x in enumerate((0.4, 1.6)):
        empty = bpy.data.objects.new(f"Instancer{i}", None)
        empty.instance_type, empty.instance_collection = "COLLECTION", group
        empty.location = (x, 0, 1.0 + 0.4 * i)
        empty["shift"] = (0.0, 0.5 * i, 0.2)
        scene.collection.objects.link(empty)
    compare_to_cycles(scene, samples=64, max_bounces=0)


def _instancing_nodes(ob, material, distribute: bool, nested: bool = False):
    """Geometry nodes on ob: spheres instanced on a grid's points (or on points Distribute Points scatters, which
    carry an id), each instance given a random colour "tint" and a float "glow" on the instance domain; nested:
    that whole set instanced twice more, one level up."""
    tree = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = tree.nodes, tree.links
    out = nodes.new("NodeGroupOutput")
    grid = nodes.new("GeometryNodeMeshGrid")
    grid.inputs["Size X"].default_value = grid.inputs["Size Y"].default_value = 3.0
    grid.inputs["Vertices X"].default_value = grid.inputs["Vertices Y"].default_value = 4
    points = grid.outputs["Mesh"]
    if distribute:
        scatter = nodes.new("GeometryNodeDistributePointsOnFaces")
        scatter.inputs["Density"].default_value = 2.0
        links.new(points, scatter.inputs["Mesh"])
        points = scatter.outputs["Points"]
    ball = nodes.new("GeometryNodeMeshUVSphere")
    ball.inputs["Radius"].default_value = 0.3
    dressed = nodes.new("GeometryNodeSetMaterial")
    dressed.inputs["Material"].default_value = material
    links.new(ball.outputs["Mesh"], dressed.inputs["Geometry"])
    place = nodes.new("GeometryNodeInstanceOnPoints")
    links.new(points, place.inputs["Points"])
    links.new(dressed.outputs["Geometry"], place.inputs["Instance"])
    geometry = place.outputs["Instances"]
    for name, kind, socket in (("tint", "FLOAT_COLOR", "Value"), ("glow", "FLOAT", "Value")):
        random = nodes.new("FunctionNodeRandomValue")
        random.data_type = "FLOAT_VECTOR" if kind == "FLOAT_COLOR" else "FLOAT"
        store = nodes.new("GeometryNodeStoreNamedAttribute")
        store.data_type, store.domain = kind, "INSTANCE"
        store.inputs["Name"].default_value = name
        links.new(geometry, store.inputs["Geometry"])
        links.new(next(o for o in random.outputs if o.enabled), store.inputs[socket])   # one output per type before 5.1
        geometry = store.outputs["Geometry"]
    if nested:
        line = nodes.new("GeometryNodeMeshLine")
        line.inputs["Count"].default_value = 2
        line.inputs["Offset"].default_value = (0.0, 0.0, 1.2)
        outer = nodes.new("GeometryNodeInstanceOnPoints")
        links.new(line.outputs["Mesh"], outer.inputs["Points"])
        links.new(geometry, outer.inputs["Instance"])
        geometry = outer.outputs["Instances"]
    links.new(geometry, out.inputs["Geometry"])
    ob.modifiers.new("Scatter", "NODES").node_group = tree


def _instance_attribute_scene(distribute: bool, nested: bool = False):
    scene = new_scene(48, 48)
    set_world(scene, color=(0, 0, 0))
    mat = _emission_of(lambda tree: _attribute(tree, "INSTANCER", "tint"),
                       strength=lambda tree: _attribute(tree, "INSTANCER", "glow", "Fac"))
    host = mesh_object("Host", [(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0)], [(0, 1, 2)], mat)
    host.location, host.rotation_euler, host.scale = (0.2, -0.1, 0.0), (0.0, 0.0, 0.4), (1.0, 1.3, 1.0)
    _instancing_nodes(host, mat, distribute, nested)
    from bpy_helpers import add_camera
    add_camera(scene, (0, -5, 4), (0, 0, 0.4), lens=35)
    return scene


@pytest.mark.parametrize("distribute", [False, True], ids=["grid", "scattered"])
def test_geometry_nodes_instance_attributes_against_cycles(distribute):
    """Colours and strengths stored on geometry-nodes instances, read by an Attribute node of type Instancer (as
    Molecular Nodes colours its atoms); scattered points carry ids, which reorder nothing. Before, Ember read no
    instance attribute (black, no glow: a public molecule read 3.3% dark with its atoms black)."""
    scene = _instance_attribute_scene(distribute)
    result = export_current()
    assert not [w for w in result.warnings if "Instancer" in w], result.warnings
    compare_to_cycles(scene, samples=16, max_bounces=0)


def test_nested_geometry_nodes_instances_are_warned_about():
    """Instances of instances are not matched to their attributes: a warning says how many."""
    _instance_attribute_scene(False, nested=True)
    result = export_current()
    assert [w for w in result.warnings if "Instancer attributes: 32 geometry-nodes instances" in w], result.warnings


def test_instance_attributes_a_blender_cannot_reach_are_warned_about(monkeypatch):
    """Where Blender's Python has no Object.evaluated_geometry, geometry-nodes instance attributes cannot be read:
    a warning says so instead of reading nothing silently."""
    from ember.engine.export import rgba_attributes
    monkeypatch.setattr(rgba_attributes, "evaluated_geometry", lambda parent: None)
    _instance_attribute_scene(False)
    result = export_current()
    assert [w for w in result.warnings if "does not reach geometry-nodes instance attributes" in w], result.warnings
