"""True displacement (Cycles' Displacement Only and Displacement and Bump) and bump from displacement:
closed forms on the exported vertices, the normals, and parity with Cycles (a displaced plane's silhouette, the
bump of Displacement and Bump on the undisplaced surface, back faces)."""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from bpy_helpers import add_camera, compare_to_cycles, export_current, mesh_object, new_scene, set_world


def grid_object(name, n=8, size=2.0, material=None, location=(0, 0, 0), smooth=True):
    """An n x n grid of quads over [-size/2, size/2]^2 in z = 0, with a UV map."""
    xs = np.linspace(-size / 2, size / 2, n + 1)
    verts = [(x, y, 0.0) for y in xs for x in xs]
    faces = [(j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)
             for j in range(n) for i in range(n)]
    ob = mesh_object(name, verts, faces, material, smooth=smooth)
    ob.data.uv_layers.new(name="UVMap")
    ob.location = location
    return ob


def displaced_material(name, method="DISPLACEMENT", node="ShaderNodeDisplacement", noise=None, **inputs):
    """A diffuse material whose Displacement output is a Displacement (or Vector Displacement) node with the
    given inputs (and opt_ options), its Height (or Vector) fed by a Noise texture of `noise` settings."""
    mat = bpy.data.materials.new(name)
    mat.displacement_method = method
    tree = mat.node_tree
    out = tree.nodes["Material Output"]
    d = tree.nodes.new(node)
    for key, value in inputs.items():
        if key.startswith("opt_"):
            setattr(d, key[4:], value)
        else:
            d.inputs[key].default_value = value
    if noise is not None:
        tex = tree.nodes.new("ShaderNodeTexNoise")
        for key, value in noise.items():
            tex.inputs[key].default_value = value
        tree.links.new(tex.outputs["Fac" if node == "ShaderNodeDisplacement" else "Color"], d.inputs[0])
    tree.links.new(d.outputs[0], out.inputs["Displacement"])
    tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.25, 0.25, 0.25, 1.0)
    return mat


def vertex_positions(result):
    """(T*3, 3) world-space triangle corners of an export."""
    return np.asarray(result.scene.positions).reshape(-1, 3)


# ---------------------------------------------------------------- closed forms
@pytest.mark.parametrize("space", ["OBJECT", "WORLD"])
def test_constant_height_moves_plane_along_its_normal(space):
    """Height h, midlevel m, scale s: every vertex moves by (h - m) s along the normal. The object is scaled
    by 2: in object space the offset is in object units (doubled in the world), in world space not."""
    new_scene()
    mat = displaced_material("D", Height=0.9, Midlevel=0.25, Scale=0.4, opt_space=space)
    ob = grid_object("P", n=2, material=mat)
    ob.scale = (2.0, 2.0, 2.0)
    result = export_current()
    z = vertex_positions(result)[:, 2]
    expected = (0.9 - 0.25) * 0.4 * (2.0 if space == "OBJECT" else 1.0)
    np.testing.assert_allclose(z, expected, rtol=1e-5)
    assert not any("Displacement" in w for w in result.warnings), result.warnings


def test_bump_method_leaves_vertices():
    new_scene()
    ob = grid_object("P", n=2, material=displaced_material("D", method="BUMP", Height=1.0))
    np.testing.assert_allclose(vertex_positions(export_current())[:, 2], 0.0)


def test_vector_displacement_object_space_moves_by_the_vector():
    new_scene()
    mat = displaced_material("V", node="ShaderNodeVectorDisplacement", opt_space="OBJECT",
                             Vector=(0.7, 0.3, 0.9, 1.0), Midlevel=0.5, Scale=2.0)
    ob = grid_object("P", n=2, material=mat)
    ob.rotation_euler = (0.0, 0.0, math.pi / 2)
    p = vertex_positions(export_current())
    before = np.array([ob.matrix_world @ v.co for v in ob.data.vertices])
    offset = np.array(ob.matrix_world.to_3x3()) @ ((np.array([0.7, 0.3, 0.9]) - 0.5) * 2.0)
    expected = before + offset
    distance = np.linalg.norm(p[:, None, :] - expected[None, :, :], axis=2)
    assert distance.min(axis=1).max() < 1e-5 and distance.min(axis=0).max() < 1e-5


def test_normals_recomputed_for_displacement_only_kept_for_both():
    """A ramp z = x (Height from the object-space x, World space): Displacement Only shades by the tilted
    faces' normal, (-1, 0, 1)/sqrt 2 inside the grid; Displacement and Bump keeps the flat plane's (0, 0, 1)."""
    for method, expected in (("DISPLACEMENT", np.array([-1.0, 0.0, 1.0]) / math.sqrt(2.0)), ("BOTH", np.array([0, 0, 1.0]))):
        new_scene()
        mat = displaced_material("D" + method, method=method, Midlevel=0.0, Scale=1.0, opt_space="WORLD")
        tree = mat.node_tree
        coords, split = tree.nodes.new("ShaderNodeTexCoord"), tree.nodes.new("ShaderNodeSeparateXYZ")
        tree.links.new(coords.outputs["Object"], split.inputs[0])
        tree.links.new(split.outputs["X"], tree.nodes["Displacement"].inputs["Height"])
        grid_object("P", n=4, material=mat)
        result = export_current()
        p = vertex_positions(result)
        np.testing.assert_allclose(p[:, 2], p[:, 0], atol=1e-6)
        n = np.asarray(result.scene.normals).reshape(-1, 3)
        np.testing.assert_allclose(n, np.broadcast_to(expected, n.shape), atol=1e-5)


def test_instances_share_one_displacement():
    """Two objects showing one mesh: displaced once, in object space, each placed by its transform."""
    new_scene()
    mat = displaced_material("D", Height=1.0, Midlevel=0.0, Scale=0.25)
    a = grid_object("A", n=2, material=mat)
    b = bpy.data.objects.new("B", a.data)
    bpy.context.scene.collection.objects.link(b)
    b.location = (0.0, 0.0, 3.0)
    z = np.sort(np.unique(np.round(vertex_positions(export_current())[:, 2], 5)))
    np.testing.assert_allclose(z, [0.25, 3.25], atol=1e-5)


# ---------------------------------------------------------------- parity with Cycles
def _grazing_scene(make_material):
    """A 32 x 32 grid displaced by make_material(), seen at a grazing angle against a bright world, so that its
    silhouette (the displaced far edge and ridges) covers a good part of the image."""
    scene = new_scene(48, 48)
    set_world(scene, color=(1.0, 1.0, 1.0), strength=1.0)
    grid_object("P", n=32, size=3.0, material=make_material())
    add_camera(scene, (0.0, -2.4, 0.75), (0.0, 0.6, 0.0), lens=30.0)
    return scene


NOISE = {"Scale": 2.5, "Detail": 1.0}


def test_noise_displacement_matches_cycles():
    scene = _grazing_scene(lambda: displaced_material("D", noise=NOISE, Midlevel=0.5, Scale=0.8))
    print(compare_to_cycles(scene, samples=64))


def test_displacement_and_bump_silhouette_matches_cycles():
    """Displacement and Bump on an emission surface (no normal to bump): the displaced silhouette alone."""
    def emitting():
        mat = displaced_material("D", method="BOTH", noise=NOISE, Midlevel=0.5, Scale=0.8)
        tree = mat.node_tree
        emission = tree.nodes.new("ShaderNodeEmission")
        emission.inputs["Strength"].default_value = 0.2
        tree.links.new(emission.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
        return mat
    print(compare_to_cycles(_grazing_scene(emitting), samples=16))


def test_displacement_and_bump_shading_matches_cycles():
    """Displacement and Bump under a BSDF. The bump's normal becomes the shading normal (Cycles' SetNormal), so
    the closures on it take no bump shadowing term: with the term, as before, blocks were 11% dark (z 19)."""
    print(compare_to_cycles(_grazing_scene(lambda: displaced_material("D", method="BOTH", noise=NOISE, Midlevel=0.5,
                                                                      Scale=0.8)), samples=64))


def _object_noise(method, scale, noise_scale, detail=1.0):
    """displaced_material of method with its noise read at Object coordinates (3D: it changes along the
    displacement too)."""
    mat = displaced_material("D", method=method, noise={"Scale": noise_scale, "Detail": detail}, Midlevel=0.5,
                             Scale=scale)
    tree = mat.node_tree
    tree.links.new(tree.nodes.new("ShaderNodeTexCoord").outputs["Object"], tree.nodes["Noise Texture"].inputs["Vector"])
    return mat


def _sunlit(scene, camera, rotation):
    """A dim world and a low sun, so that the shading follows the bumped normal closely; the camera at camera."""
    set_world(scene, color=(0.05, 0.05, 0.05))
    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy = 3.0
    ob = bpy.data.objects.new("sun", sun)
    scene.collection.objects.link(ob)
    ob.rotation_euler = rotation
    add_camera(scene, camera, (0.0, 0.6, 0.0), lens=30.0)
    return scene


def test_displacement_and_bump_bumps_the_undisplaced_surface():
    """Cycles evaluates the bump of Displacement and Bump at the undisplaced position and normal
    (svm_node_enter_bump_eval): a noise read at Object coordinates, whose value changes with the height the
    vertices moved to, lit by a low sun. Bumped at the displaced surface instead, blocks were 9% off (z 20)."""
    def make():
        mat = _object_noise("BOTH", 0.6, 1.5, detail=0.0)
        mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.6, 0.6, 0.6, 1.0)
        return mat
    print(compare_to_cycles(_sunlit(_grazing_scene(make), (0.0, -2.5, 2.0), (1.1, 0.0, 0.8)), samples=64))


def test_displacement_and_bump_on_folds_matches_cycles():
    """A strong displacement seen at a grazing angle folds over: on the back faces Cycles' saved differential of
    the undisplaced position runs backwards (dPdu, dPdv negated) while Object coordinates step forwards, which
    turns the bump's slope around. Bumped at the displaced surface, blocks there were 32% off (z 26); with the
    differential not reversed on back faces, 56% (z 48)."""
    print(compare_to_cycles(_grazing_scene(lambda: _object_noise("BOTH", 0.8, 2.5)), samples=64))


def test_bump_seen_from_behind_matches_cycles():
    """The Bump method on a plane seen from below (every hit a back face): Cycles' attribute differentials (the
    Generated coordinates here) run against the position's there. Stepped forwards, blocks were 32% off (z 720)."""
    scene = _grazing_scene(lambda: displaced_material("B", method="BUMP", noise={"Scale": 4.0, "Detail": 1.0},
                                                      Midlevel=0.5, Scale=0.3))
    print(compare_to_cycles(_sunlit(scene, (0.0, -2.5, -2.0), (math.pi - 1.1, 0.0, 0.8)), samples=64))


def test_vector_displacement_matches_cycles():
    scene = _grazing_scene(lambda: displaced_material("V", node="ShaderNodeVectorDisplacement", opt_space="OBJECT",
                                                      noise=NOISE, Midlevel=0.5, Scale=0.6))
    report = compare_to_cycles(scene, samples=64)
    print(report)


def test_bump_method_matches_cycles():
    scene = _grazing_scene(lambda: displaced_material("B", method="BUMP", noise={"Scale": 6.0, "Detail": 2.0},
                                                      Midlevel=0.5, Scale=0.3))
    scene.camera.location = (0.0, -2.5, 2.0)
    report = compare_to_cycles(scene, samples=64)
    print(report)


def test_adaptive_subdivision_dices_instead_of_warning():
    """A displaced mesh with adaptive subdivision is diced (test_adaptive_subdivision.py), not named in a
    warning: more triangles than the modifier's levels give."""
    scene = new_scene()
    scene.cycles.preview_dicing_rate = 1.0
    ob = grid_object("P", n=2, material=displaced_material("D", Height=1.0))
    modifier = ob.modifiers.new("Subdivision", "SUBSURF")
    modifier.use_adaptive_subdivision = True
    result = export_current()
    assert not any("adaptive" in w for w in result.warnings), result.warnings
    assert result.triangle_count > 2 * 4 * 4 ** modifier.levels


@pytest.mark.parametrize("method", ["DISPLACEMENT", "BOTH"])
def test_generated_coordinates_are_the_undisplaced_mesh_s_as_in_cycles(method):
    """Generated coordinates are an attribute of the mesh before true displacement moves it (Cycles'
    ATTR_STD_GENERATED): a surface coloured by its Generated z reads the flat grid's 0.5 wherever it was lifted.
    Before, "Displacement Only" read the displaced position: a real file's displaced terrain, its colour a 3D noise
    of Generated, rendered 16% darker than in Cycles."""
    def material():
        mat = displaced_material("D", method=method, noise=NOISE, Midlevel=0.0, Scale=0.8)
        tree = mat.node_tree
        coords, glow = tree.nodes.new("ShaderNodeTexCoord"), tree.nodes.new("ShaderNodeEmission")
        tree.links.new(coords.outputs["Generated"], glow.inputs["Color"])
        tree.links.new(glow.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
        return mat
    scene = _grazing_scene(material)
    set_world(scene, color=(0.0, 0.0, 0.0))
    compare_to_cycles(scene, samples=16, max_bounces=1)
