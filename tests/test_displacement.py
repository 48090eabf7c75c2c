"""True displacement (Cycles' Displacement Only and Displacement and Bump) and bump from displacement:
closed forms on the exported vertices, the normals, and parity with Cycles (a displaced plane's silhouette)."""
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
    found = {tuple(np.round(q, 4)) for q in p}
    assert found == {tuple(np.round(q + offset, 4)) for q in before}
