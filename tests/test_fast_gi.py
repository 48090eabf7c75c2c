"""Light Paths > Fast GI Approximation (Cycles' own settings, scene.cycles; the world's Ambient Occlusion Factor and
Distance) against Cycles. Replace: past the AO bounces a path's rays reach only as far as the AO distance, end at
the surface they meet (its emission still counts) and see the world times the factor where they meet nothing.
Add: every surface adds its diffuse weight times the factor times one AO ray. Before, Ember ignored the settings
(the corpus tool listed use_fast_gi as lacking): a room 10-60% off Cycles' image."""
import bpy
import pytest

from bpy_helpers import (add_camera, add_lamp, compare_to_cycles, diffuse_material, emission_material, new_scene,
                         quad_object, set_world)


def room(method: str, bounces: int, factor: float = 0.8, distance: float = 1.5):
    """Three walls and a floor around a box, an area lamp, an emissive strip far from the box and a blue-grey
    world, whose indirect light is a good part of the image."""
    scene = new_scene(32, 32)
    add_camera(scene, (0, -3.6, 1.3), (0, 0, 0.9), lens=26)
    set_world(scene, color=(0.35, 0.4, 0.5))
    light = scene.world.light_settings
    light.ao_factor, light.distance = factor, distance
    wall = diffuse_material("Wall", (0.75, 0.75, 0.75))
    quad_object("Floor", (-2, -2, 0), (4, 0, 0), (0, 4, 0), wall)
    quad_object("Back", (-2, 2, 0), (4, 0, 0), (0, 0, 2.5), wall)
    quad_object("Left", (-2, -2, 0), (0, 4, 0), (0, 0, 2.5), diffuse_material("Red", (0.8, 0.2, 0.1)))
    quad_object("Right", (2, -2, 0), (0, 0, 2.5), (0, 4, 0), diffuse_material("Green", (0.2, 0.7, 0.2)))
    quad_object("Strip", (-1.9, 1.9, 2.0), (1.2, 0, 0), (0, 0, 0.2), emission_material("Glow", (1, 0.8, 0.5), 6.0))
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(0.4, 0.5, 0.4), rotation=(0, 0, 0.4))
    bpy.context.active_object.data.materials.append(diffuse_material("Box", (0.7, 0.6, 0.3)))
    add_lamp(scene, "Key", "AREA", (0.6, -0.6, 2.4), (0.2, 0, 0), energy=120.0, size=0.6)
    c = scene.cycles
    c.use_fast_gi, c.fast_gi_method, c.ao_bounces_render = True, method, bounces
    return scene


@pytest.mark.parametrize("method, bounces, card", [("REPLACE", 1, False), ("REPLACE", 2, False), ("ADD", 0, False),
                                                   ("REPLACE", 1, True)],
                         ids=["replace_1", "replace_2", "add", "replace_1_card"])
def test_fast_gi_matches_cycles(method, bounces, card):
    """A constant world, which Cycles samples by BSDF rays alone: past the AO bounces a ray that meets nothing
    within the distance sees the world, whatever lies beyond, at full weight in both engines. (A world sampled as a
    light weighs those rays by MIS against its light samples, so what they add depends on the world's sampling
    distribution, Cycles' piecewise-constant map against Ember's bilinear one: docs/usage.md, Fast GI.)"""
    scene = room(method, bounces)
    if card:   # a half-transparent card whose Transparent Shadows is off: Cycles ends a replaced path there
        mat = bpy.data.materials.new("Card")
        mat.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.1
        mat.use_transparent_shadow = False
        quad_object("Card", (-1.2, -0.4, 0.0), (0, 1.6, 0), (0, 0, 2.0), mat)
    compare_to_cycles(scene, samples=128, max_bounces=6, mean_z=4.0)


def test_fast_gi_settings_are_read_as_cycles_reads_them():
    """Replace takes the render's AO Bounces (the viewport's in the viewport) and the world's AO Factor; Add takes
    the factor alone; a factor of 0, no bounces or no world turn it off (Cycles' sync and scene/integrator.cpp)."""
    from ember.engine.session import render_settings
    from ember.engine.viewport import viewport_settings
    scene = room("REPLACE", 2, factor=0.7)
    scene.cycles.ao_bounces = 1
    assert (render_settings(scene, None).ao_bounces, viewport_settings(scene).ao_bounces) == (2, 1)
    assert render_settings(scene, None).ao_factor == pytest.approx(0.7)
    scene.cycles.fast_gi_method = "ADD"
    got = render_settings(scene, None)
    assert (got.ao_bounces, got.ao_factor, got.ao_additive) == (0, 0.0, pytest.approx(0.7))
    scene.cycles.fast_gi_method = "REPLACE"
    scene.world.light_settings.ao_factor = 0.0
    assert render_settings(scene, None).ao_bounces == 0
    scene.world.light_settings.ao_factor = 0.7
    scene.world = None
    assert render_settings(scene, None).ao_bounces == 0


def test_an_object_s_own_ao_distance_is_named():
    """Cycles' Replace clips the rays leaving an object to that object's own AO Distance where it has one; Ember
    takes the world's and says so."""
    from bpy_helpers import export_current
    scene = room("REPLACE", 1)
    bpy.data.objects["Floor"].cycles.ao_distance = 0.5
    assert any("AO Distance of object Floor is not applied" in w for w in export_current().warnings)
