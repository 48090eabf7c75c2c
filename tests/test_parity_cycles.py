"""Ember against Cycles (CPU, no clamping, box filter) on scenes built in code.

Each scene is rendered four times per engine with different seeds (the samples split between them):
their mean is the image, their spread measures its noise. The whole-image mean must agree within 2%, and every block of an 8x8
grid within 4.5 standard errors of the difference (64 blocks: a false alarm about once in 2,000 runs).
"""
import math

import bpy
import numpy as np
import pytest

from bpy_helpers import (add_camera, add_lamp, compare_to_cycles, diffuse_material, emission_material, hdri_world,
                         mesh_object, node_material, new_scene, quad_object, set_world, veil_material)

BOX = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), (-1, -1, 2), (1, -1, 2), (1, 1, 2), (-1, 1, 2)]


def test_diffuse_and_emission_in_a_box():
    scene = new_scene(64, 64)
    white = diffuse_material("White", (0.7, 0.7, 0.7))
    red = diffuse_material("Red", (0.7, 0.1, 0.1), principled=True)
    mesh_object("Box", BOX, [(0, 1, 2, 3), (4, 7, 6, 5), (3, 2, 6, 7), (0, 3, 7, 4)], white)
    mesh_object("Red Wall", BOX, [(1, 5, 6, 2)], red)
    quad_object("Lamp", (-0.4, -0.4, 1.98), (0, 0.8, 0), (0.8, 0, 0), emission_material("Lamp", strength=8.0))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.4, location=(0.3, 0.2, 0.4))
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(diffuse_material("Ball", (0.2, 0.5, 0.8)))
    add_camera(scene, (0, -3.5, 1), (0, 0, 1), lens=30)
    set_world(scene, color=(0, 0, 0))
    compare_to_cycles(scene, samples=128, max_bounces=4)


def test_diffuse_objects_under_a_rotated_hdri():
    scene = new_scene(64, 48)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(-0.6, 0, 0.8))
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(diffuse_material("Ball", (0.8, 0.8, 0.8)))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(1.0, 0.5, 0.5), rotation=(0, 0, 0.5))
    bpy.context.active_object.data.materials.append(diffuse_material("Cube", (0.6, 0.3, 0.2), principled=True))
    mesh_object("Ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)],
                diffuse_material("Ground", (0.5, 0.5, 0.5)))
    add_camera(scene, (0.5, -5, 2.0), (0, 0, 0.9), lens=35)
    # Rotation about all three axes: any mistake in the Mapping convention shows in the sky and the shading.
    hdri_world(scene, "courtyard.exr", strength=1.0, rotation=(0.3, -0.2, 1.9))
    compare_to_cycles(scene, samples=256, max_bounces=3)


@pytest.mark.parametrize("float_image", [False, True])
def test_image_textured_plane(float_image):
    scene = new_scene(64, 64)
    size = 16
    yy, xx = np.mgrid[0:size, 0:size]
    rgb = np.stack([(xx + 0.5) / size, (yy + 0.5) / size, ((xx // 4 + yy // 4) % 2) * 0.8 + 0.1], -1)
    image = bpy.data.images.new("Pattern", size, size, alpha=True, float_buffer=float_image)
    if not float_image:
        image.colorspace_settings.name = "sRGB"
    image.pixels.foreach_set(np.concatenate([rgb, np.ones((size, size, 1))], -1).astype(np.float32).ravel())
    image.pack()
    plane = quad_object("Plane", (-1, 0, 0), (2, 0, 0), (0, 0, 2),
                        diffuse_material("Textured", image=image, principled=True))
    assert plane.data.uv_layers.active is not None
    add_camera(scene, (0, -3.2, 1.0), (0, 0, 1.0), lens=40)
    set_world(scene, color=(1.0, 1.0, 1.0))
    compare_to_cycles(scene, samples=128, max_bounces=1)


def test_collection_instances_with_rotation_and_scale():
    scene = new_scene(64, 64)
    source = bpy.data.collections.new("Source")
    bpy.ops.mesh.primitive_cube_add(size=0.5, location=(0, 0, 0.25))
    cube = bpy.context.active_object
    cube.data.materials.append(diffuse_material("Orange", (0.8, 0.4, 0.1)))
    bpy.ops.mesh.primitive_cone_add(radius1=0.25, depth=0.6, location=(0.5, 0, 0.3))
    cone = bpy.context.active_object
    cone.data.materials.append(diffuse_material("Teal", (0.1, 0.6, 0.6)))
    for ob in (cube, cone):
        for c in ob.users_collection:
            c.objects.unlink(ob)
        source.objects.link(ob)
    for i, (loc, rot, scale) in enumerate([((-1.2, 0, 0), (0, 0, 0.4), 1.0), ((0.3, 0.5, 0), (0, 0, 2.0), 1.6),
                                           ((1.3, -0.6, 0.2), (0.5, 0.3, 0), 0.7)]):
        empty = bpy.data.objects.new(f"Instance {i}", None)
        empty.instance_type = "COLLECTION"
        empty.instance_collection = source
        empty.location, empty.rotation_euler, empty.scale = loc, rot, (scale, scale * 1.3, scale)
        scene.collection.objects.link(empty)
    mesh_object("Ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)],
                diffuse_material("Ground", (0.6, 0.6, 0.6)))
    quad_object("Lamp", (-1.5, -1.0, 3.0), (0, 2.0, 0), (3.0, 0, 0), emission_material("Lamp", strength=3.0))
    add_camera(scene, (0, -5, 3), (0, 0, 0.4), lens=35)
    set_world(scene, color=(0.15, 0.18, 0.25))
    compare_to_cycles(scene, samples=128, max_bounces=3)


def test_flat_smooth_and_sharp_edged_normals():
    scene = new_scene(72, 48)
    mat = diffuse_material("Clay", (0.75, 0.7, 0.65))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(-1.4, 0, 0.6), segments=12, ring_count=6)
    bpy.context.active_object.data.materials.append(mat)                 # flat
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0, 0, 0.6), segments=12, ring_count=6)
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(mat)                 # smooth
    bpy.ops.mesh.primitive_cylinder_add(radius=0.5, depth=1.2, location=(1.4, 0, 0.6), vertices=10)
    bpy.ops.object.shade_smooth_by_angle(angle=math.radians(40))
    bpy.context.active_object.data.materials.append(mat)                 # smooth sides, sharp rims
    mesh_object("Ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)], mat)
    add_camera(scene, (0, -4.5, 1.6), (0, 0, 0.6), lens=35)
    # A gradient sky makes the shading follow the normals closely.
    hdri_world(scene, "courtyard.exr", strength=1.0)
    compare_to_cycles(scene, samples=128, max_bounces=2)


@pytest.mark.parametrize("geometry_offset", [0.1, 0.0, 0.6])
def test_shadow_terminator_of_a_low_poly_smooth_sphere(geometry_offset):
    """An 8 x 5 smooth sphere lit by a low sun: near the terminator Cycles starts shadow rays from the smooth
    surface the normals describe (Object > Shading > Shadow Terminator > Geometry Offset, 0.1 by default); at 0
    it does not. Without the lift Ember's terminator blocks read 5% dark at the default."""
    scene = new_scene(48, 48)
    add_camera(scene, (0, -4, 0.8), (0, 0, 0.6))
    quad_object("Floor", (-4, -4, 0), (8, 0, 0), (0, 8, 0), diffuse_material("Floor", (0.5, 0.5, 0.5)))
    bpy.ops.mesh.primitive_uv_sphere_add(segments=8, ring_count=5, radius=0.6, location=(0, 0, 0.6))
    bpy.ops.object.shade_smooth()
    ball = bpy.context.object
    ball.data.materials.append(diffuse_material("Ball", (0.8, 0.8, 0.8)))
    ball.shadow_terminator_geometry_offset = geometry_offset
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy, sun.data.angle = 3.0, 0.0
    sun.rotation_euler = (0.0, 1.2, 0.3)
    scene.collection.objects.link(sun)
    set_world(scene, (0.0, 0.0, 0.0))
    compare_to_cycles(scene, samples=64, max_bounces=1)


@pytest.mark.parametrize("geometry_offset", [0.1, 0.5])
def test_shadow_terminator_lift_toward_a_near_lamp(geometry_offset):
    """A smooth-shaded bevelled slab (its side faces' corner normals lean 55 degrees off them, as in a public
    file) in black gloss, lit at a grazing angle by a large two-sided emitting quad close by. A shadow ray lifted
    off the smooth surface aims from the lifted origin at the point sampled on the lamp, as Cycles'
    shadow_ray_setup does; Ember aimed at that point moved by the lift, behind the lamp's plane, and the lamp
    shadowed itself: 2% dark (a block 7%) at the default offset, 28% (blocks black) at 0.5."""
    scene = new_scene(48, 32)
    add_camera(scene, (0.4, -6, 0.6), (0.4, 0, -0.2), lens=50)
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    slab = bpy.context.active_object
    slab.scale = (1.6, 1.6, 0.5)
    bpy.ops.object.transform_apply(scale=True)
    bevel = slab.modifiers.new("Bevel", "BEVEL")
    bevel.width, bevel.segments = 0.2, 3
    bpy.ops.object.shade_smooth()
    slab.shadow_terminator_geometry_offset = geometry_offset
    slab.data.materials.append(node_material("Plate", "ShaderNodeBsdfPrincipled", Base_Color=(0, 0, 0, 1),
                                             Roughness=0.5))
    lamp = emission_material("Lamp", strength=6.0)
    lamp.cycles.emission_sampling = "FRONT_BACK"
    quad_object("Lamp", (3.0, -4.0, -2.0), (2.0, 2.5, 0), (0, 0, 4.0), lamp)
    set_world(scene, (0.0, 0.0, 0.0))
    compare_to_cycles(scene, samples=128, max_bounces=0)


@pytest.mark.parametrize("limits", [(4, 4, 12), (1, 2, 2), (12, 0, 1)])
def test_per_type_bounce_limits_match_cycles(limits):
    """Cycles' Diffuse, Glossy and Transmission bounce limits under a Total of 12 (its defaults, 4 4 12, first):
    a white room lit through its ceiling, with a mirror-like metal ball and a glass ball. A path past a limit
    only takes the light of what it meets next. Without the limits, the room read 36% bright in the corpus."""
    diffuse, glossy, transmission = limits
    scene = new_scene(48, 48)
    white = diffuse_material("White", (0.8, 0.8, 0.8))
    mesh_object("Box", BOX, [(0, 1, 2, 3), (4, 7, 6, 5), (3, 2, 6, 7), (0, 3, 7, 4), (1, 5, 6, 2)], white)
    quad_object("Lamp", (-0.4, -0.4, 1.98), (0, 0.8, 0), (0.8, 0, 0), emission_material("Lamp", strength=8.0))
    for x, shader, inputs in ((-0.45, "ShaderNodeBsdfAnisotropic", dict(Roughness=0.1)),
                              (0.45, "ShaderNodeBsdfGlass", dict(Roughness=0.0, IOR=1.5))):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(x, 0.2, 0.35))
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(node_material(shader, shader, **inputs))
    add_camera(scene, (0, -3.5, 1), (0, 0, 0.8), lens=30)
    set_world(scene, color=(0, 0, 0))
    compare_to_cycles(scene, samples=128, max_bounces=12, type_bounces=limits)


@pytest.mark.parametrize("limit", [0, 1, 2])
def test_the_transparent_bounce_limit_ends_paths_as_cycles_does(limit):
    """Two veils (60% transparent) before a wall, a glowing strip and, on the left, the sky. Cycles lets a path pass
    Transparent Max Bounces transparent surfaces and then takes only the emission of the surface it meets next (and
    the sky, if it meets none): the last layer it reaches is dark but for its glow (path_state_next:
    PATH_RAY_TERMINATE_ON_NEXT_SURFACE); a limit of 0 ends paths as 1 does. Before, Ember shaded that last surface
    too: with a limit of 1 or 2 the scene read 11% bright (a room behind one veil, 44%)."""
    scene = new_scene(24, 24)
    add_camera(scene, (0, -4, 1), (0, 0, 1))
    set_world(scene, color=(0.8, 0.9, 1.0))
    quad_object("Wall", (-0.5, 2, -2), (3.5, 0, 0), (0, 0, 6), diffuse_material("Wall", (0.8, 0.8, 0.8)))
    quad_object("Glow", (0.2, 1.9, 0.6), (0.6, 0, 0), (0, 0, 0.8), emission_material("Glow", strength=3.0))
    for k, y in enumerate((0.0, 0.8)):
        quad_object(f"Veil{k}", (-3, y, -2), (6, 0, 0), (0, 0, 6), veil_material(f"Veil{k}"))
    compare_to_cycles(scene, samples=64, max_bounces=limit, mean_z=4.0)


def test_shadow_rays_pass_what_transparent_bounces_their_path_has_left_as_cycles():
    """Cycles' shadow rays pass as many transparent surfaces as their path has left of its Transparent Max Bounces
    (integrate_shadow_max_transparent_hits: the limit less the path's transparent bounces); one more blocks them. A
    wall lit from the side through two veils, the left half seen through a third, limit 2: the wall behind the third
    veil gets no light (its paths have one bounce left, the shadow rays meet two veils), the rest gets it through
    both. Before, every shadow ray had the whole limit: the wall behind the third veil lit (the image 20% bright)."""
    scene = new_scene(24, 24)
    add_camera(scene, (0, -4, 1), (0, 0, 1))
    set_world(scene, color=(0.0, 0.0, 0.0))
    quad_object("Wall", (-3, 2, -2), (6, 0, 0), (0, 0, 6), diffuse_material("Wall", (0.8, 0.8, 0.8)))
    quad_object("Front", (-3, 0, -2), (3, 0, 0), (0, 0, 6), veil_material("Front"))
    for k, x in enumerate((5.0, 5.5)):
        quad_object(f"Side{k}", (x, -2, -2), (0, 5, 0), (0, 0, 6), veil_material(f"Side{k}"))
    lamp = add_lamp(scene, "Lamp", "POINT", (8.0, 0.5, 1.5))
    lamp.data.energy, lamp.data.shadow_soft_size = 3000.0, 0.2
    compare_to_cycles(scene, samples=64, max_bounces=2, mean_z=4.0)


def test_shadow_rays_count_their_transparent_depth_as_cycles():
    """In a shadow ray the Light Path node's Transparent Depth is its path's transparent bounces plus the surfaces
    the ray has passed (Cycles' shadow_path.transparent_bounce, one more after each surface it evaluates). Veils
    transparent only at depth 0, between a wall and its lamp: a shadow ray passes the first and stops at the second.
    Before, Ember read 0 in every shadow ray: the wall was lit through both (the image 0.180 against Cycles' 0.039)."""
    scene = new_scene(24, 24)
    add_camera(scene, (0, -4, 1), (0, 0, 1))
    set_world(scene, color=(0.05, 0.05, 0.05))   # something to see where the lamp is blocked
    quad_object("Wall", (-3, 2, -2), (6, 0, 0), (0, 0, 6), diffuse_material("Wall", (0.8, 0.8, 0.8)))
    for k, x in enumerate((5.0, 5.5)):
        veil = veil_material(f"Side{k}")
        tree = veil.node_tree
        path, first = tree.nodes.new("ShaderNodeLightPath"), tree.nodes.new("ShaderNodeMath")
        first.operation, first.inputs[1].default_value = "LESS_THAN", 0.5
        scale = tree.nodes.new("ShaderNodeMath")
        scale.operation, scale.inputs[1].default_value = "MULTIPLY", 0.6
        tree.links.new(path.outputs["Transparent Depth"], first.inputs[0])
        tree.links.new(first.outputs[0], scale.inputs[0])
        tree.links.new(scale.outputs[0], tree.nodes["Mix Shader"].inputs["Fac"])
        quad_object(f"Side{k}", (x, -2, -2), (0, 5, 0), (0, 0, 6), veil)
    lamp = add_lamp(scene, "Lamp", "POINT", (8.0, 0.5, 1.5))
    lamp.data.energy, lamp.data.shadow_soft_size = 3000.0, 0.2
    compare_to_cycles(scene, samples=64, max_bounces=4, mean_z=4.0)
