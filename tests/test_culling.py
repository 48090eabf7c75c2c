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


def test_texture_limit_scales_images_down_as_cycles():
    """Simplify > Texture Limit (Cycles' own, read with Simplify on): an image larger than the limit is scaled down
    by a power of two, each pixel the mean of its block (util_image_resize_pixels). 1-pixel stripes of a 256-pixel
    image under a 128-pixel limit become a flat grey in both engines, seen close up with Closest interpolation.
    Before, Ember rendered the stripes."""
    from bpy_helpers import emission_material
    scene = new_scene(32, 32)
    add_camera(scene, (0, 0, 1.2), (0, 0, 0), lens=50)
    set_world(scene, color=(0.0, 0.0, 0.0))
    image = bpy.data.images.new("Stripes", 256, 256)
    stripes = np.zeros((256, 256, 4), np.float32)
    stripes[:, ::2, :3] = 1.0
    stripes[..., 3] = 1.0
    image.pixels.foreach_set(stripes.ravel())
    material = emission_material("Screen", (1, 1, 1), 1.0)
    tree = material.node_tree
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.image, texture.interpolation = image, "Closest"
    tree.links.new(texture.outputs["Color"], next(n for n in tree.nodes if n.type == "EMISSION").inputs["Color"])
    quad_object("Screen", (-0.5, -0.5, 0), (1, 0, 0), (0, 1, 0), material)
    scene.render.use_simplify, scene.cycles.texture_limit_render = True, "128"
    flat = render_to_array(scene, "EMBER", 4)[..., :3]
    assert flat.std() < 0.01 and 0.1 < flat.mean() < 0.9   # grey, not stripes
    compare_to_cycles(scene, samples=16, max_bounces=1)
    scene.render.use_simplify = False   # Cycles reads the limit only with Simplify on
    assert render_to_array(scene, "EMBER", 4)[..., :3].std() > 0.1


def test_limited_box_filter():
    """The scaling itself: a factor of 1/2^k, sides floored, plain block means rounded for 8-bit pixels."""
    from ember.engine.export.images import ImagePixels, limited
    pixels = ImagePixels(np.arange(8 * 6, dtype=np.uint8).reshape(6, 8, 1) * 5, srgb=True)
    out = limited(pixels, 3)            # 8 -> 2^floor(log2(3/8)) = 1/4: 2 x 1 blocks of 4 x 4
    assert out.array.shape == (1, 2, 1) and out.srgb
    block = pixels.array[:4, :4, 0].astype(float).mean()
    assert out.array[0, 0, 0] == int(np.floor(block + 0.5))
    assert limited(pixels, 8) is pixels and limited(pixels, 0) is pixels
