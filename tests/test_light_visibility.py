"""Lights' own Ray Visibility (kernels/lights/ray_visibility.py), against Cycles.

One small scene: a sphere lamp over a floor that is half diffuse, half rough glossy (a Mix Shader), seen through
a rough Refraction panel that covers the left of the frame, with a wall behind. Every kind of bounce takes light
from the lamp: the floor's diffuse and glossy closures by light samples and by BSDF rays, the panel's
transmission closure by light samples and by the rays it refracts toward the lamp. Each test turns one of the
lamp's bounce kinds off and compares the image with Cycles'. Kernel level: with every kind on, nothing is
exported and the sampler carries nothing.
"""
from __future__ import annotations

import numpy as np
import pytest

SAMPLES = 64


def _scene():
    import bpy
    from bpy_helpers import add_camera, diffuse_material, new_scene, node_material, quad_object, set_world
    scene = new_scene(40, 40)
    add_camera(scene, (0, -4.5, 1.3), (0, 1.0, 0.6))
    set_world(scene, color=(0.03, 0.03, 0.04))
    floor = bpy.data.materials.new("Floor")
    tree = floor.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.5
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.7, 0.7, 0.7, 1.0)
    glossy = tree.nodes.new("ShaderNodeBsdfAnisotropic")
    glossy.inputs["Color"].default_value = (0.9, 0.9, 0.9, 1.0)
    glossy.inputs["Roughness"].default_value = 0.2
    tree.links.new(diffuse.outputs[0], mix.inputs[1])
    tree.links.new(glossy.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    quad_object("Floor", (-5, -5, 0), (10, 0, 0), (0, 10, 0), floor)
    quad_object("Wall", (-5, 3, 0), (10, 0, 0), (0, 0, 5), diffuse_material("Wall", (0.6, 0.5, 0.4)))
    quad_object("Panel", (-2.0, -1.5, 0.0), (2.0, 0, 0), (0, 0, 2.5),
                node_material("Frosted", "ShaderNodeBsdfRefraction", Color=(1, 1, 1), Roughness=0.3, IOR=1.3))
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.data.energy, lamp.data.shadow_soft_size = 150.0, 0.3
    lamp.location = (-0.4, 0.8, 1.2)
    scene.collection.objects.link(lamp)
    return scene, lamp


@pytest.mark.parametrize("setting", ["visible_diffuse", "visible_glossy", "visible_transmission"])
def test_a_bounce_kind_off_matches_cycles(setting):
    from bpy_helpers import compare_to_cycles, export_current, render_to_array
    scene, lamp = _scene()
    plain = render_to_array(scene, "EMBER", 16, seed=3)
    setattr(lamp, setting, False)
    assert export_current().warnings == []
    # The setting changes the image (so the comparison below tests it), and Ember changes it as Cycles does.
    changed = render_to_array(scene, "EMBER", 16, seed=3)
    assert np.abs(changed[..., :3] - plain[..., :3]).max() > 0.1
    compare_to_cycles(scene, samples=SAMPLES)


def test_defaults_export_nothing_and_camera_is_no_bounce_kind():
    """Defaults export nothing; Camera on (rendered: test_light_camera.py) leaves the bounce kinds' table off."""
    from bpy_helpers import export_current
    scene, lamp = _scene()
    exported = export_current()
    assert exported.scene.lights.visibility is None and exported.scene.lights.camera is None
    assert exported.warnings == []
    lamp.visible_camera = True
    exported = export_current()
    assert exported.warnings == [] and exported.scene.lights.visibility is None
    assert exported.scene.lights.camera.tolist() == [True]


def test_volume_scatter_off_matches_cycles():
    """A fog box lit by a lamp that volume scattering does not see: only the world lights the fog, as in
    Cycles (its light samples in the fog are dropped, shade_volume.h)."""
    import bpy
    from bpy_helpers import (compare_to_cycles, diffuse_material, export_current, mesh_object, new_scene,
                             node_material, quad_object, render_to_array, set_world)
    scene = new_scene(32, 32)
    set_world(scene, color=(0.05, 0.05, 0.06))
    quad_object("Floor", (-5, -5, 0), (10, 0, 0), (0, 10, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    verts = [(x, y, z) for x in (-1.2, 1.2) for y in (-1.2, 1.2) for z in (0.05, 2.0)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh_object("Fog", verts, faces, node_material("Fog", "ShaderNodeVolumePrincipled", output="Volume", Density=0.4))
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.data.energy, lamp.data.shadow_soft_size = 200.0, 0.1
    lamp.location = (0.8, -0.5, 2.6)
    scene.collection.objects.link(lamp)
    plain = render_to_array(scene, "EMBER", 8, seed=3)
    lamp.visible_volume_scatter = False
    assert export_current().warnings == []
    changed = render_to_array(scene, "EMBER", 8, seed=3)
    assert np.abs(changed[..., :3] - plain[..., :3]).max() > 0.1
    compare_to_cycles(scene, samples=32)


def test_a_sun_that_glossy_rays_do_not_see_matches_cycles():
    """A wide sun over the rough glossy half of the floor: its light samples leave the glossy closure out and
    the glossy rays that look into its disc get nothing (shade_background.h)."""
    import bpy
    from bpy_helpers import compare_to_cycles, export_current
    from bpy_helpers import render_to_array
    scene, lamp = _scene()
    lamp.data.energy = 0.0
    bpy.data.objects.remove(bpy.data.objects["Wall"])
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy, sun.data.angle = 3.0, 0.3
    sun.rotation_euler = (-0.9, 0.0, 0.0)   # behind the floor's far end: its glare on the glossy floor
    scene.collection.objects.link(sun)
    plain = render_to_array(scene, "EMBER", 16, seed=3)
    sun.visible_glossy = False
    assert export_current().warnings == []
    changed = render_to_array(scene, "EMBER", 16, seed=3)
    assert np.abs(changed[..., :3] - plain[..., :3]).max() > 0.1
    compare_to_cycles(scene, samples=SAMPLES)
