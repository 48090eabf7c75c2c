"""World > Ray Visibility (Cycles' own setting, world.cycles_visibility) against Cycles: a world the camera does not
see lights the scene behind a black background (a product shot's usual set-up); a world diffuse rays do not see
lights only glossy and transmitting closures, both by its light samples and by the rays that escape to it. Before,
Ember ignored it: the HDRI showed behind the product."""
import bpy
import numpy as np
import pytest

from bpy_helpers import add_camera, compare_to_cycles, diffuse_material, hdri_world, new_scene, node_material, \
    quad_object, render_to_array


def product(off: tuple):
    """A diffuse floor, a glossy ball and a glass ball under an HDRI world with the Ray Visibility switches `off`
    turned off."""
    scene = new_scene(32, 24)
    add_camera(scene, (0, -4, 1.4), (0, 0, 0.5), lens=35)
    hdri_world(scene, "sunset.exr")
    for name in off:
        setattr(scene.world.cycles_visibility, name, False)
    quad_object("Floor", (-2, -2, 0), (4, 0, 0), (0, 4, 0), diffuse_material("Floor", (0.7, 0.7, 0.7)))
    for x, material in ((-0.6, node_material("Gloss", "ShaderNodeBsdfGlossy", Color=(0.9, 0.9, 0.9), Roughness=0.2)),
                        (0.6, node_material("Glass", "ShaderNodeBsdfGlass", Color=(1, 1, 1), Roughness=0.0))):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=(x, 0.2, 0.45), segments=24, ring_count=12)
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(material)
    return scene


@pytest.mark.parametrize("off", [("camera",), ("diffuse",), ("glossy", "transmission")],
                         ids=["camera", "diffuse", "glossy_transmission"])
def test_world_ray_visibility_matches_cycles(off):
    compare_to_cycles(product(off), samples=128, max_bounces=6, mean_z=4.0)


def test_a_world_hidden_from_the_camera_is_black_behind_a_lit_scene():
    image = render_to_array(product(("camera",)), "EMBER", 8)[..., :3]
    assert image[0].max() == 0.0 and image[-1].mean() > 0.05   # the sky black, the floor lit
