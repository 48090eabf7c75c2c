"""Simplify > Culling (Cycles' own settings: the scene's Camera and Distance Culling and their margins, each
object's switches) against Cycles: culled objects are left out of the render, so they cast no shadow and show in
no reflection. Before, Ember ignored them: a wall behind the camera shadowed the floor that Cycles lights."""
import math

import bpy
import numpy as np
import pytest

from bpy_helpers import (add_camera, add_lamp, compare_to_cycles, diffuse_material, new_scene, quad_object,
                         render_to_array, set_world)


def scene_with_culling(camera_cull=True, distance_cull=False, both_flags=False):
    """A floor and a box in view, lit by a low sun from behind the camera; a wall behind the camera (out of view)
    that shadows the floor, and a pillar 12 m away in view. Simplify on."""
    scene = new_scene(32, 24)
    add_camera(scene, (0, -4, 1.5), (0, 0, 0.4), lens=35)
    set_world(scene, color=(0.1, 0.1, 0.12))
    quad_object("Floor", (-4, -4, 0), (8, 0, 0), (0, 30, 0), diffuse_material("Floor", (0.7, 0.7, 0.7)))
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(0.3, 0.3, 0.4))
    bpy.context.active_object.data.materials.append(diffuse_material("Box", (0.8, 0.3, 0.2)))
    wall = quad_object("Wall", (-6, -6, 0), (12, 0, 0), (0, 0, 4), diffuse_material("Wall", (0.5, 0.5, 0.5)))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(1.5, 8.5, 1.0))
    pillar = bpy.context.active_object
    pillar.scale = (0.5, 0.5, 2.0)
    pillar.data.materials.append(diffuse_material("Pillar", (0.2, 0.3, 0.8)))
    add_lamp(scene, "Sun", "SUN", (0, -8, 5), (math.radians(70), 0, 0), energy=3.0)
    scene.render.use_simplify = True
    c = scene.cycles
    c.use_camera_cull, c.camera_cull_margin = camera_cull, 0.1
    c.use_distance_cull, c.distance_cull_margin = distance_cull, 6.0
    wall.cycles.use_camera_cull = True
    pillar.cycles.use_distance_cull = True
    if both_flags:
        pillar.cycles.use_camera_cull = True
    return scene


@pytest.mark.parametrize("camera_cull, distance_cull, both_flags", [(True, False, False), (False, True, False),
                                                                    (True, True, True)],
                         ids=["camera", "distance", "both_on_the_pillar"])
def test_culling_matches_cycles(camera_cull, distance_cull, both_flags):
    scene = scene_with_culling(camera_cull, distance_cull, both_flags)
    compare_to_cycles(scene, samples=32, max_bounces=3, mean_z=4.0)


def test_culling_changes_the_image_and_needs_simplify():
    """The wall's shadow goes with Camera Culling and comes back without Simplify (the test can fail)."""
    culled = render_to_array(scene_with_culling(), "EMBER", 8)[..., :3].mean()
    scene = scene_with_culling()
    scene.render.use_simplify = False
    assert culled > 1.3 * render_to_array(scene, "EMBER", 8)[..., :3].mean()


def test_texture_limit_is_named():
    from bpy_helpers import export_current
    scene = scene_with_culling()
    scene.cycles.texture_limit_render = "256"
    assert any("Texture Limit 256 is not applied" in w for w in export_current().warnings)
    scene.render.use_simplify = False   # Cycles reads it only with Simplify on
    assert not any("Texture Limit" in w for w in export_current().warnings)
