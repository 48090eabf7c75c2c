"""Ember in the Blender it runs in (docs/blender-versions.md): export hands bpy.app.version to the kernel
functions that follow one Cycles release or another, the version switches sit where Cycles changed, and a
render uses the current API (no DeprecationWarning from Ember's code)."""
from __future__ import annotations

import warnings

import bpy
import numpy as np
import pytest

from bpy_helpers import ensure_registered, export_current, render_to_array
from ember.engine import demo
from ember.kernels.shading import math_nodes
from ember.kernels.shading import perlin
from ember.kernels.shading import patterns as pt
from tests.node_probe import sweep


def test_demo_render_raises_no_deprecation_warning():
    """The demo scene (materials, world, lights, textures) exported and rendered with every
    DeprecationWarning an error (Material.use_nodes warns in Blender 5.x, for one)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        scene = demo.build_demo_scene()
        scene.render.resolution_x, scene.render.resolution_y = 32, 24
        image = render_to_array(scene, "EMBER", 2)
    assert np.isfinite(image).all() and image[..., :3].max() > 0


def test_texture_ops_carry_the_running_blenders_version():
    """A Noise, Wave and Magic texture in a material: their ops hold bpy.app.version, which the kernel's
    rounding and formulas follow."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    scene = bpy.context.scene
    mat = bpy.data.materials.new("Textures")
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    add = tree.nodes.new("ShaderNodeMath")
    for kind, socket in (("ShaderNodeTexNoise", 0), ("ShaderNodeTexMagic", 1)):
        tree.links.new(tree.nodes.new(kind).outputs["Fac"], add.inputs[socket])
    wave = tree.nodes.new("ShaderNodeTexWave")
    tree.links.new(wave.outputs["Color"], bsdf.inputs["Emission Color"])
    tree.links.new(add.outputs[0], bsdf.inputs["Roughness"])
    mesh = bpy.data.meshes.new("Quad")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    mesh.materials.append(mat)
    scene.collection.objects.link(bpy.data.objects.new("Quad", mesh))
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    scene.camera = camera
    shaders = export_current().scene.materials.shaders
    options = {op.kind: dict(op.options) for shader in shaders for op in shader.program.ops}
    for kind in ("ShaderNodeTexNoise", "ShaderNodeTexMagic", "ShaderNodeTexWave"):
        assert options[kind]["cycles_version"] == tuple(bpy.app.version), kind


def test_magic_follows_the_release_that_changed_it():
    """Blender 5.2 scales before wrapping to (-2pi, 2pi): the same sines up to rounding, which far from the
    origin (where the wrap drops the most digits) is a different colour."""
    p = sweep(-1e7, 1e7, 200, seed=1)
    old = pt.magic(p, scale=5.0, turbulence_depth=0, cycles_version=(5, 1, 0))["Color"]
    new = pt.magic(p, scale=5.0, turbulence_depth=0, cycles_version=(5, 2, 0))["Color"]
    assert np.abs(old - new).max() > 0.1
    np.testing.assert_array_equal(old, pt.magic(p, scale=5.0, turbulence_depth=0)["Color"])


def test_perlin_rounding_switches_at_5_3_and_stays_within_float_precision():
    p = sweep(-40, 40, 512, seed=2)
    coords = tuple(p[:, k] for k in range(3))
    with perlin.cycles_rounding((5, 2, 0)):
        old = perlin.snoise(coords)
    with perlin.cycles_rounding((5, 3, 0)):
        new = perlin.snoise(coords)
    assert (old != new).any()
    np.testing.assert_allclose(old, new, rtol=0, atol=2e-6)
    np.testing.assert_array_equal(old, perlin.snoise(coords))   # outside the context: 5.0's


@pytest.mark.parametrize("version,offered", [((5, 0, 1), False), ((5, 2, 0), True), ((5, 3, 0), True)])
def test_vector_math_round_exists_from_5_2(version, offered):
    assert ("ROUND" in math_nodes.operations_in(version, math_nodes.VECTOR_MATH_OPERATIONS)) == offered
    np.testing.assert_array_equal(math_nodes.vector_math((0.5, -0.5, 1.49), operation="ROUND")["Vector"],
                                  [[1.0, 0.0, 1.0]])


@pytest.mark.skipif(bpy.app.version < (5, 3, 0), reason="these nodes and inputs are Blender 5.3's")
def test_what_5_1_to_5_3_added_and_ember_does_not_render_warns_by_name():
    """Shadow Raycast, Scene Time, Principled Thin Wall, Glass anisotropy: each named in the material's warning (the
    Raycast node is rendered: tests/test_raycast.py)."""
    from bpy_helpers import camera_only_scene
    scene = camera_only_scene()
    mat = bpy.data.materials.new("New")
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    tree.links.new(tree.nodes.new("ShaderNodeShadowRaycast").outputs[0], bsdf.inputs["Roughness"])
    tree.links.new(tree.nodes.new("GeometryNodeInputSceneTime").outputs["Seconds"], bsdf.inputs["Metallic"])
    bsdf.inputs["Thin Wall"].default_value = True
    glass = tree.nodes.new("ShaderNodeBsdfGlass")
    glass.inputs["Anisotropy"].default_value = 0.5
    add = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(bsdf.outputs[0], add.inputs[0])
    tree.links.new(glass.outputs[0], add.inputs[1])
    tree.links.new(add.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    mesh = bpy.data.meshes.new("Quad")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    mesh.materials.append(mat)
    scene.collection.objects.link(bpy.data.objects.new("Quad", mesh))
    text = " ".join(export_current().warnings)
    for named in ("Shadow Raycast 'Shadow Raycast'", "Scene Time node", "Thin Wall is not supported",
                  "Glass BSDF 'Glass BSDF' Anisotropy is not supported"):
        assert named in text, (named, text)
