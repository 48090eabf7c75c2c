"""Film > Transparent > Transparent Glass (Cycles' own setting, scene.cycles) against Cycles: the world seen through
glass whose transmission is smoother than the Roughness Threshold makes alpha, as the world seen straight from the
camera does (Cycles' LABEL_TRANSMIT_TRANSPARENT keeps PATH_RAY_TRANSPARENT_BACKGROUND); rougher glass, a glass
reflection and anything seen after a diffuse bounce stay opaque. Before, the option was not read: glass over a
transparent film was opaque."""
import math

import bpy
import pytest

from bpy_helpers import add_camera, compare_to_cycles, diffuse_material, new_scene, set_world


def glass(name, roughness, color=(1.0, 1.0, 1.0)):
    material = bpy.data.materials.new(name)
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Transmission Weight"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    return material


def glass_scene(threshold=0.1, enabled=True):
    """Three glass balls (smooth and tinted, just under the threshold, rougher than it) over a floor that ends
    halfway, under a bright sky, on a transparent film."""
    scene = new_scene(48, 32)
    add_camera(scene, (0, -6, 1.2), (0, 0, 0.6), lens=35)
    set_world(scene, color=(0.8, 0.9, 1.0))
    scene.render.film_transparent = True
    scene.cycles.film_transparent_glass = enabled
    scene.cycles.film_transparent_roughness = threshold
    bpy.ops.mesh.primitive_plane_add(size=4, location=(0, 1.5, 0))
    bpy.context.active_object.data.materials.append(diffuse_material("Floor", (0.6, 0.6, 0.6)))
    for x, material in ((-1.4, glass("Clear", 0.0, (0.9, 0.6, 0.4))), (0.0, glass("Fine", 0.08)),
                        (1.4, glass("Rough", 0.2))):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(x, 0, 0.6))
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(material)
    return scene


@pytest.mark.parametrize("alpha", [True, False], ids=["alpha", "rgb"])
def test_transparent_glass_matches_cycles(alpha):
    """Threshold 0.1: Cycles compares alpha_x alpha_y with its fourth power (scene/background.cpp), so Principled
    roughness 0.08 (alpha 0.0064) passes and 0.2 (alpha 0.04) does not."""
    compare_to_cycles(glass_scene(), samples=64, max_bounces=4, alpha=alpha, mean_z=4.0)


def test_transparent_glass_off_keeps_glass_opaque():
    compare_to_cycles(glass_scene(enabled=False), samples=32, max_bounces=4, alpha=True, mean_z=4.0)


def test_holdout_seen_through_glass_matches_cycles():
    """A holdout object behind the smooth glass ball takes alpha through it too (Cycles tests holdouts with the
    same PATH_RAY_TRANSPARENT_BACKGROUND)."""
    scene = glass_scene()
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(-1.4, 1.2, 0.6))
    cube = bpy.context.active_object
    cube.data.materials.append(diffuse_material("Held", (0.2, 0.8, 0.2)))
    cube.is_holdout = True
    compare_to_cycles(scene, samples=64, max_bounces=4, alpha=True, mean_z=4.0)
