"""Normal maps and tangents: the export of MikkTSpace tangents and Normal Map / Tangent nodes, the kernel's
normal-map evaluation against its closed form (Cycles' svm_node_normal_map), the specular-reflection
correction and the scene validation of tangents. Cycles parity is in test_parity_materials."""
import math

import bpy
import numpy as np
import pytest

from bpy_helpers import camera_only_scene, export_current
from ember.kernels.scene import Closure, Materials, NormalMap, Param, SceneArrays, Shader, Tangent
from ember.kernels.shading import normals

RNG_SEED = 7


# ---- Export -----------------------------------------------------------------------------------------

@pytest.fixture(autouse=True)
def empty_scene():
    """Every test starts from an empty factory scene with a camera."""
    return camera_only_scene()


export = export_current


def normal_mapped_material(name="Bumpy", space="TANGENT", uv_map="", shader="ShaderNodeBsdfDiffuse"):
    """A material whose shader's Normal comes from a Normal Map node fed by a Non-Color image."""
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    node = tree.nodes.new(shader)
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    image = bpy.data.images.new("Normals", 4, 4, float_buffer=True)
    image.colorspace_settings.name = "Non-Color"
    image.pixels.foreach_set(np.tile([0.6, 0.4, 0.9, 1.0], 16).astype(np.float32))
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    normal_map = tree.nodes.new("ShaderNodeNormalMap")
    normal_map.space = space
    normal_map.uv_map = uv_map
    normal_map.inputs["Strength"].default_value = 0.7
    tree.links.new(tex.outputs["Color"], normal_map.inputs["Color"])
    tree.links.new(normal_map.outputs["Normal"], node.inputs["Normal"])
    return mat, node


def quad(name="Quad", uvs=((0, 0), (1, 0), (1, 1), (0, 1)), material=None, size=(2.0, 1.0)):
    """A quad in the z = 0 plane, size[0] x size[1], with the given corner UVs."""
    w, h = size
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(0, 0, 0), (w, 0, 0), (w, h, 0), (0, h, 0)], [], [(0, 1, 2, 3)])
    layer = mesh.uv_layers.new(name="UVMap")
    layer.uv.foreach_set("vector", np.asarray(uvs, np.float32).ravel())
    if material is not None:
        mesh.materials.append(material)
    ob = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def test_no_normal_map_exports_no_tangents():
    quad()
    assert export().scene.tangents is None


@pytest.mark.parametrize("uvs, tangent, sign", [
    (((0, 0), (1, 0), (1, 1), (0, 1)), (1, 0, 0), 1.0),     # u along x, v along y
    (((0, 1), (1, 1), (1, 0), (0, 0)), (1, 0, 0), -1.0),    # v flipped: a mirrored bitangent
    (((0, 0), (0, 1), (-1, 1), (-1, 0)), (0, -1, 0), 1.0),  # UVs turned a quarter: u along -y
])
def test_quad_tangents_follow_its_uvs(uvs, tangent, sign):
    mat, _ = normal_mapped_material()
    quad(uvs=uvs, material=mat)
    result = export()
    t = result.scene.tangents
    assert t.shape == (2, 3, 4) and t.dtype == np.float32
    np.testing.assert_allclose(t[..., :3].reshape(-1, 3), np.tile(tangent, (6, 1)), atol=1e-6)
    np.testing.assert_array_equal(t[..., 3], sign)
    assert not [w for w in result.warnings if "Bumpy" in w or "Quad" in w]
    (closure,) = result.scene.materials.shaders[1].closures
    spec = closure.input("Normal")
    assert isinstance(spec, NormalMap) and spec.space == "TANGENT"
    assert spec.color.texture == 0 and spec.strength.value == pytest.approx((0.7,))
    result.scene.validate()


@pytest.mark.parametrize("scale, flips", [((2.0, 0.5, 1.0), False), ((-1.5, 1.0, 1.0), True)])
def test_tangents_transform_with_the_instance_matrix(scale, flips):
    """Tangents are directions on the surface: M T (made unit again), the sign flipped by a mirror."""
    mat, _ = normal_mapped_material()
    uvs = ((0, 0), (0.7, 0.7), (0, 1.4), (-0.7, 0.7))  # u along the quad's diagonal x = -y
    ob = quad(uvs=uvs, material=mat, size=(1.0, 1.0))
    ob.rotation_euler = (0.3, -0.2, 0.9)
    ob.scale = scale
    ob.location = (1, 2, 3)
    bpy.context.view_layer.update()
    t = export().scene.tangents
    linear = np.array(ob.matrix_world)[:3, :3]
    expected = linear @ (np.array([1.0, -1.0, 0.0]) / math.sqrt(2))
    expected /= np.linalg.norm(expected)
    np.testing.assert_allclose(t[..., :3].reshape(-1, 3), np.tile(expected, (6, 1)), atol=1e-5)
    np.testing.assert_array_equal(t[..., 3], -1.0 if flips else 1.0)


def test_tangent_node_and_normal_map_spaces():
    mat, bsdf = normal_mapped_material("Brushed", space="WORLD", shader="ShaderNodeBsdfPrincipled")
    tree = mat.node_tree
    tangent = tree.nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tree.links.new(tangent.outputs["Tangent"], bsdf.inputs["Tangent"])
    bsdf.inputs["Anisotropic"].default_value = 0.5
    quad(material=mat)
    result = export()
    (closure,) = result.scene.materials.shaders[1].closures
    assert closure.input("Normal").space == "WORLD" and isinstance(closure.input("Tangent"), Tangent)
    assert result.scene.tangents is not None  # for the Tangent node
    assert not [w for w in result.warnings if "Brushed" in w]


def test_object_space_normal_map_bump_and_radial_tangent_link():
    mat, bsdf = normal_mapped_material("Odd", space="OBJECT", shader="ShaderNodeBsdfPrincipled")
    tree = mat.node_tree
    bump = tree.nodes.new("ShaderNodeBump")
    tree.links.new(bump.outputs["Normal"], bsdf.inputs["Coat Normal"])
    radial = tree.nodes.new("ShaderNodeTangent")
    tree.links.new(radial.outputs["Tangent"], bsdf.inputs["Tangent"])
    quad(material=mat)
    result = export()
    (closure,) = result.scene.materials.shaders[1].closures
    assert closure.input("Normal").link is not None          # the Object-space Normal Map's program
    assert closure.input("Coat Normal").link is not None     # the Bump node's program
    assert closure.input("Tangent").link is not None       # the radial Tangent node's program
    assert result.scene.tangents is None
    assert not [w for w in result.warnings if "'Odd'" in w]


def test_constant_normal_and_tangent_programs_are_kept_and_zero_ones_warned():
    """A Normal or Tangent fed by a program that folds to a constant is that direction (Cycles loads constant-folded
    inputs as linked ones); a zero vector is none: the shading normal or default tangent, with a warning."""
    mat = bpy.data.materials.new("Constant")
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    for socket, value in (("Normal", (0.0, 0.6, 0.8)), ("Coat Normal", (0.0, 0.0, 0.0)), ("Tangent", (1.0, 0.0, 0.0))):
        combine = tree.nodes.new("ShaderNodeCombineXYZ")
        combine.name = socket
        for k, v in enumerate(value):
            combine.inputs[k].default_value = v
        tree.links.new(combine.outputs["Vector"], bsdf.inputs[socket])
    quad(material=mat)
    result = export()
    (closure,) = result.scene.materials.shaders[1].closures
    normal, tangent = closure.input("Normal"), closure.input("Tangent")
    assert normal.link is None and np.allclose(normal.value, (0.0, 0.6, 0.8))
    assert tangent.link is None and np.allclose(tangent.value, (1.0, 0.0, 0.0))
    assert closure.input("Coat Normal") is None
    assert any("Coat Normal is linked to a zero vector: the shading normal is used" in w for w in result.warnings), \
        result.warnings


def test_mesh_without_uvs_gets_spherical_tangents_with_a_warning():
    mat, _ = normal_mapped_material()
    ob = quad(material=mat)
    ob.data.uv_layers.remove(ob.data.uv_layers[0])
    result = export()
    t = result.scene.tangents
    np.testing.assert_allclose(np.linalg.norm(t[..., :3], axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(t[..., 2], 0.0, atol=1e-6)  # in the quad's plane
    assert any("no UV map" in w and "spherical" in w for w in result.warnings)


def test_missing_named_uv_map_leaves_the_normal_unperturbed():
    mat, _ = normal_mapped_material(uv_map="Detail")
    quad(material=mat)
    result = export()
    np.testing.assert_array_equal(result.scene.tangents, 0.0)
    assert any("no UV map 'Detail'" in w for w in result.warnings)


def test_ngon_tangents_by_mikktspace_on_its_triangles():
    """Blender's calc_tangents refuses n-gons; Cycles runs MikkTSpace on its triangles, and so does Ember (the
    object's to_mesh() copy with its n-gons split), without the per-triangle approximation or its warning."""
    mat, _ = normal_mapped_material()
    mesh = bpy.data.meshes.new("Hexagon")
    angles = np.arange(6) * np.pi / 3
    verts = [(math.cos(a), math.sin(a), 0.0) for a in angles]
    mesh.from_pydata(verts, [], [tuple(range(6))])
    layer = mesh.uv_layers.new(name="UVMap")
    layer.uv.foreach_set("vector", np.array([(x * 0.5 + 0.5, y * 0.5 + 0.5) for x, y, _ in verts],
                                            np.float32).ravel())
    mesh.materials.append(mat)
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("Hexagon", mesh))
    result = export()
    np.testing.assert_allclose(result.scene.tangents[..., :3].reshape(-1, 3), np.tile([1, 0, 0], (12, 1)),
                               atol=1e-5)
    np.testing.assert_array_equal(result.scene.tangents[..., 3], 1.0)
    assert not any("n-gons" in w for w in result.warnings), result.warnings


# ---- Kernel: the normal map against its closed form -------------------------------------------------

def _closed_form(color, strength, t, sign, n, backfacing):
    """Cycles' tangent-space normal map, written out in float64 for one hit."""
    c = 2.0 * (np.asarray(color, float) - 0.5)
    c[:2] *= strength
    c[2] = 1.0 + (c[2] - 1.0) * min(max(strength, 0.0), 1.0)
    b = sign * np.cross(n, t)
    out = c[0] * np.asarray(t) + c[1] * b + c[2] * np.asarray(n)
    out /= np.linalg.norm(out)
    return -out if backfacing else out


def _columns(rows):
    return tuple(np.ascontiguousarray(np.asarray(rows, np.float32)[:, k]) for k in range(3))


def test_tangent_space_normal_map_matches_the_closed_form():
    rng = np.random.default_rng(RNG_SEED)
    n_hits = 200
    normal = rng.normal(size=(n_hits, 3))
    normal *= rng.uniform(0.8, 1.0, (n_hits, 1)) / np.linalg.norm(normal, axis=1, keepdims=True)
    tangent = np.cross(normal, rng.normal(size=(n_hits, 3)))
    tangent *= rng.uniform(0.7, 1.1, (n_hits, 1)) / np.linalg.norm(tangent, axis=1, keepdims=True)
    sign = rng.choice([-1.0, 1.0], n_hits) * rng.uniform(0.5, 1.0, n_hits)  # interpolated across a seam
    color = rng.uniform(0.0, 1.0, (n_hits, 3))
    color[:, 2] = rng.uniform(0.5, 1.0, n_hits)
    strength = rng.uniform(-0.5, 2.0, n_hits)
    backfacing = rng.random(n_hits) < 0.3
    ns = normal / np.linalg.norm(normal, axis=1, keepdims=True) * np.where(backfacing, -1, 1)[:, None]
    frame = (_columns(tangent), sign.astype(np.float32), _columns(normal))
    got = np.stack(normals.normal_map(color.T.astype(np.float32), strength.astype(np.float32), "TANGENT",
                                      _columns(ns), backfacing, frame), axis=1)
    expected = np.stack([_closed_form(color[i], strength[i], tangent[i], sign[i], normal[i], backfacing[i])
                         for i in range(n_hits)])
    np.testing.assert_allclose(got, expected, atol=2e-5)


def test_world_space_normal_maps_and_strength():
    ns = _columns([[0, 0, 1], [0, 0, 1], [0, 0, -1]])
    color = np.array([[0.5, 1.0, 0.5], [1.0, 0.5, 0.5], [0.5, 1.0, 0.5]], np.float32).T  # +y, +x, +y
    backfacing = np.array([False, False, True])
    got = np.stack(normals.normal_map(color, np.ones(3, np.float32), "WORLD", ns, backfacing, None), axis=1)
    np.testing.assert_allclose(got, [[0, 1, 0], [1, 0, 0], [0, -1, 0]], atol=1e-6)
    blender = np.stack(normals.normal_map(color, np.ones(3, np.float32), "BLENDER_WORLD", ns, backfacing, None), 1)
    np.testing.assert_allclose(blender, [[0, -1, 0], [1, 0, 0], [0, 1, 0]], atol=1e-6)
    half = np.stack(normals.normal_map(color, np.full(3, 0.5, np.float32), "WORLD", ns, backfacing, None), 1)
    np.testing.assert_allclose(half[0], np.array([0, 0.5, 0.5]) / math.sqrt(0.5), atol=1e-6)
    # Strength 0 in tangent space, or no tangents at all: the shading normal.
    assert normals.normal_map(color, np.zeros(3, np.float32), "TANGENT", ns, backfacing, None) is ns


def test_specular_normal_keeps_the_mirror_direction_above_the_surface():
    rng = np.random.default_rng(RNG_SEED)
    n_hits = 500
    ng = np.tile([0.0, 0.0, 1.0], (n_hits, 1))
    wo = rng.normal(size=(n_hits, 3))
    wo[:, 2] = np.abs(wo[:, 2]) * 0.3
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    n = rng.normal(size=(n_hits, 3)) * [1.0, 1.0, 0.4]
    n[:, 2] = np.abs(n[:, 2]) + 0.05
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    got = np.stack(normals.valid_specular_normal(_columns(ng), _columns(wo), _columns(n)), axis=1)
    iz = wo[:, 2]
    threshold = np.minimum(0.9 * iz, 0.01)
    r_before = 2 * np.sum(wo * n, 1)[:, None] * n - wo
    r_after = 2 * np.sum(wo * got, 1)[:, None] * got - wo
    low = r_before[:, 2] < threshold
    assert 50 < low.sum() < n_hits
    np.testing.assert_allclose(got[~low], n[~low], atol=0)               # valid normals are kept
    np.testing.assert_allclose(r_after[low, 2], threshold[low], atol=5e-4)  # the others just clear it
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-5)
    # Tilted toward ng within the plane of n and ng.
    np.testing.assert_allclose(np.sum(np.cross(n[low], ng[low]) * got[low], 1), 0.0, atol=1e-5)


def test_uv_tangent_and_rotation():
    ns = _columns([[0, 0, 1], [0, 0, -1]])
    frame = (_columns([[2.0, 0.0, 0.5], [0.0, 3.0, 1.0]]), np.ones(2, np.float32), ns)
    t = np.stack(normals.uv_tangent(frame, ns), axis=1)
    np.testing.assert_allclose(t, [[1, 0, 0], [0, 1, 0]], atol=1e-6)
    turned = np.stack(normals.rotate_about(tuple(t.T), ns, np.full(2, np.pi / 2, np.float32)), axis=1)
    np.testing.assert_allclose(turned, [[0, 1, 0], [1, 0, 0]], atol=1e-6)


# ---- Kernel: the scene --------------------------------------------------------------------------------

def _scene(tangents, shader=None, positions=None):
    positions = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [1, 0, 0], [2, 0, 0]]], np.float32) \
        if positions is None else positions
    t = len(positions)
    normals_ = np.tile(np.float32([0, 0, 1]), (t, 3, 1))
    materials = Materials((shader,)) if shader is not None else Materials()
    return SceneArrays(positions=positions, normals=normals_, uvs=np.zeros((t, 3, 2), np.float32),
                       material_ids=np.zeros(t, np.int32), materials=materials, tangents=tangents)


def test_validate_checks_and_cleans_tangents():
    with pytest.raises(ValueError, match="tangents"):
        _scene(np.zeros((2, 3, 3), np.float32)).validate()
    with pytest.raises(ValueError, match="tangents"):
        _scene(np.zeros((2, 3, 4), np.float64)).validate()
    tangents = np.zeros((2, 3, 4), np.float32)
    tangents[0, 1, 0] = np.nan
    tangents[1] = 1.0
    cleaned = _scene(tangents).validate()
    assert cleaned.dropped_triangles == 1  # the second triangle has no area, its tangents go with it
    np.testing.assert_array_equal(cleaned.scene.tangents, np.zeros((1, 3, 4)))


def test_validate_checks_normal_map_inputs():
    good = NormalMap(Param.of((0.5, 0.5, 1.0)), Param.of(1.0), "TANGENT")
    ok = Shader((Closure("DIFFUSE", (("Normal", good),)),))
    _scene(None, ok).validate()
    for bad in (Closure("DIFFUSE", (("Color", good),)),
                Closure("DIFFUSE", (("Normal", NormalMap(Param.of((0.5, 0.5, 1.0)), Param.of(1.0), "OBJECT")),)),
                Closure("DIFFUSE", (("Normal", Tangent()),))):
        with pytest.raises(ValueError, match="DIFFUSE"):
            _scene(None, Shader((bad,))).validate()


@pytest.mark.skipif(bpy.app.version < (5, 1, 0), reason="the Normal Map's convention switch is Blender 5.1's")
@pytest.mark.parametrize("space", ["WORLD", "BLENDER_WORLD"])
def test_directx_convention_matches_cycles(space):
    """Normal Map in the DirectX convention (green negated) through bpy: Ember's node program against this
    Blender's Cycles, one probe colour per pixel; OpenGL differs from both where green is not 0.5."""
    from tests.node_probe import probe_scene, render_probe, sweep

    colors = sweep(0.0, 1.0, 64, seed=3)

    def build(convention):
        def graph(tree, sockets):
            node = tree.nodes.new("ShaderNodeNormalMap")
            node.space, node.convention = space, convention
            tree.links.new(sockets["probe"], node.inputs["Color"])
            return node.outputs["Normal"]
        return graph

    scene, count = probe_scene(build("DIRECTX"), {"probe": colors})
    cycles = render_probe(scene, count, "CYCLES")
    ember = render_probe(scene, count, "EMBER")
    np.testing.assert_allclose(ember, cycles, atol=2e-6)
    scene, count = probe_scene(build("OPENGL"), {"probe": colors})
    opengl = render_probe(scene, count, "EMBER")
    assert np.abs(opengl - cycles).max() > 0.1


@pytest.mark.parametrize("space", ["OBJECT", "BLENDER_OBJECT"])
def test_object_space_normal_maps_match_cycles(space):
    """Object and Blender Object space: the map's normal taken to world space by the object's normal transform
    (Cycles' object_normal_transform: the inverse transpose, normalized), then flipped on back faces. The probe's
    quads turned half a turn about z and stretched 3x along it (they stay where they were, in the z = 0 plane):
    Ember's program against this Blender's Cycles, one probe colour per pixel. Before, Ember used the shading
    normal, with a warning; read as World space the values differ too (the transform matters)."""
    from tests.node_probe import probe_scene, render_probe, sweep

    colors = sweep(0.0, 1.0, 64, seed=5)

    def build(chosen):
        def graph(tree, sockets):
            node = tree.nodes.new("ShaderNodeNormalMap")
            node.space = chosen
            tree.links.new(sockets["probe"], node.inputs["Color"])
            return node.outputs["Normal"]
        return graph

    def rendered(chosen, engine):
        scene, count = probe_scene(build(chosen), {"probe": colors})
        probe = bpy.data.objects["Probe"]
        width, height = scene.render.resolution_x, scene.render.resolution_y
        probe.location, probe.rotation_euler, probe.scale = (width, height, 0.0), (0.0, 0.0, math.pi), (1.0, 1.0, 3.0)
        return render_probe(scene, count, engine)

    cycles = rendered(space, "CYCLES")
    np.testing.assert_allclose(rendered(space, "EMBER"), cycles, atol=2e-6)
    world = "BLENDER_WORLD" if space == "BLENDER_OBJECT" else "WORLD"
    assert np.abs(rendered(world, "EMBER") - cycles).max() > 0.1


def test_an_image_colour_in_the_normal_maps_strength_renders_as_in_cycles():
    """A public gravestone material links its normal texture's Color into the Normal Map's Strength (the Color input
    left at its default): Blender reads the colour there as its luminance. Ember refused the scene ("a normal map
    needs ... a strength of 1") and rendered nothing; now, a floor under such a map and a low sun against Cycles."""
    from bpy_helpers import add_camera, add_lamp, compare_to_cycles, new_scene, set_world
    scene = new_scene(32, 24)
    add_camera(scene, (1.0, -2.5, 2.0), (1.0, 0.5, 0.0))
    set_world(scene, color=(0.05, 0.05, 0.05))
    mat, _ = normal_mapped_material("Swapped", "TANGENT")
    tree = mat.node_tree
    normal_map = tree.nodes["Normal Map"]
    tree.links.remove(normal_map.inputs["Color"].links[0])
    normal_map.inputs["Color"].default_value = (0.7, 0.5, 0.8, 1.0)
    image = tree.nodes["Image Texture"].image
    image.pixels.foreach_set(np.tile([0.9, 0.3, 0.5, 1.0], 16).astype(np.float32))
    tree.links.new(tree.nodes["Image Texture"].outputs["Color"], normal_map.inputs["Strength"])
    quad("Floor", material=mat, size=(2.0, 2.0))
    add_lamp(scene, "Sun", "SUN", (0, 0, 3), rotation=(1.1, 0.0, 0.6), energy=3.0)
    assert export().scene.materials is not None   # (the export's validation passes)
    compare_to_cycles(scene, samples=16, max_bounces=1)
