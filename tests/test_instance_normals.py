"""Smooth normals of non-uniformly scaled objects as Cycles interpolates them. Cycles applies an object's transform
to its mesh for a final render only when the mesh has one user (and no subsurface, true displacement, adaptive
subdivision or motion blur: scene/object.cpp apply_static_transforms); then each corner's normal is turned into
world space and made unit (Mesh::apply_transform). Otherwise it interpolates the object-space normals and turns
the result (triangle_smooth_normal, object_normal_transform). Under a non-uniform scale the two differ inside the
faces, by degrees: a public lotus of five geometry-nodes instances of a squashed metal icosphere read 1.6% bright
at its highlights, its normals 1.3 degrees off on average and up to 100 at the rims. Before, Ember made every
corner unit in world space."""

import bpy
import numpy as np
import pytest

from bpy_helpers import (add_camera, add_lamp, compare_to_cycles, configure_cycles, diffuse_material, hdri_world,
                         new_scene, set_world)
from exr import render_multilayer


def squashed_spheres(persistent: bool, linked: bool = True):
    """A coarse smooth icosphere squashed 1 x 0.5 x 0.25 and turned, shown twice as linked duplicates (one mesh,
    two users: Cycles keeps its transforms) and a copy of it with a mesh of its own (applied), side by side."""
    scene = new_scene(96, 60)
    scene.render.use_persistent_data = persistent   # every mesh an Embree instance; else copies in world space
    add_camera(scene, (0, -6, 2.5), (0, 0, 0), lens=40)
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, radius=1.0)
    first = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    first.data.materials.append(diffuse_material("Clay", (0.8, 0.8, 0.8)))
    placements = [((-2.2, 0, 0), (0.3, -0.4, 0.5)), ((0, 0, 0), (-0.6, 0.2, 1.1)), ((2.2, 0, 0), (0.2, 0.5, -0.7))]
    for i, (location, rotation) in enumerate(placements):
        shared = linked and i == 1
        ob = first if i == 0 else bpy.data.objects.new(f"Ball {i}", first.data if shared else first.data.copy())
        if ob is not first:
            scene.collection.objects.link(ob)
        ob.location, ob.rotation_euler, ob.scale = location, rotation, (1.0, 0.5, 0.25)
    return scene


def normal_pass(scene, engine):
    """The Normal pass through each pixel's centre (one sample, a tiny box filter)."""
    layer = scene.view_layers[0]
    layer.use_pass_normal = True
    scene.render.engine = engine
    if engine == "CYCLES":
        configure_cycles(scene, 1, 0, 1)
        scene.cycles.filter_width = 0.01
    else:
        e = scene.ember
        e.samples, e.seed, e.max_bounces = 1, 0, 1
        e.use_adaptive_sampling = e.use_denoising = False
        e.pixel_filter_type, e.filter_width = "BOX", 0.01
    parts, _ = render_multilayer(scene)
    planes = parts[f"{layer.name}.Normal"]
    return np.stack([planes[c] for c in "XYZ"], axis=-1)


def angles(a, b):
    """Degrees between the normals of pixels both engines hit."""
    hit = (np.abs(a).sum(-1) > 0) & (np.abs(b).sum(-1) > 0)
    a, b = a[hit].astype(np.float64), b[hit].astype(np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1))), hit


@pytest.mark.parametrize("persistent", [False, True], ids=["copies", "instances"])
def test_normals_of_a_shared_squashed_mesh_match_cycles(persistent):
    """Both ways Ember stores the duplicates (copies in world space; Embree instances, as under Persistent Data)
    give Cycles' normals at every pixel, the linked duplicates and the single-user copy alike; before, the
    duplicates' normals were off by a median of 1 degree, 5 at the 99th percentile, while the single user matched."""
    cycles = normal_pass(squashed_spheres(persistent), "CYCLES")
    ember = normal_pass(squashed_spheres(persistent), "EMBER")
    degrees, hit = angles(cycles, ember)
    assert hit.sum() > 600
    # The same rays through the same triangles: the normals agree to what Cycles' packed normals and float32 keep
    # (a median of 0.005 degrees, 0.06 at the 99th percentile); a pixel on a silhouette may see another triangle.
    assert np.median(degrees) < 0.02 and np.percentile(degrees, 99) < 0.25, \
        (np.percentile(degrees, [50, 90, 99]), degrees.max())


def subsurface(scene):
    material = bpy.data.materials.new("Wax")
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Subsurface Weight"].default_value = 1.0
    for ob in scene.objects:
        if ob.type == "MESH":
            ob.data.materials[0] = material
    return scene


@pytest.mark.parametrize("kind", ["applied", "subsurface"])
def test_single_users_as_cycles_treats_them(kind):
    """The same three balls, each with a mesh of its own. Cycles applies each transform (each corner made unit in
    world space), but not to a mesh with subsurface scattering, whose normals it interpolates in object space; the
    two conventions differ here by degrees, so a swap would show."""
    make = (lambda: squashed_spheres(False, linked=False)) if kind == "applied" else \
        (lambda: subsurface(squashed_spheres(False, linked=False)))
    cycles = normal_pass(make(), "CYCLES")
    ember = normal_pass(make(), "EMBER")
    degrees, _ = angles(cycles, ember)
    assert np.median(degrees) < 0.02 and np.percentile(degrees, 99) < 0.25, \
        (np.percentile(degrees, [50, 90, 99]), degrees.max())


def test_squashed_metal_duplicates_shade_as_in_cycles():
    """The shading the normals make: the linked duplicates in rough metal under a sky, against Cycles (a block
    14% off before)."""
    scene = squashed_spheres(False)
    metal = bpy.data.materials.new("Metal")
    bsdf = metal.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Metallic"].default_value, bsdf.inputs["Roughness"].default_value = 1.0, 0.25
    bpy.data.objects["Icosphere"].data.materials[0] = metal
    hdri_world(scene, "courtyard.exr", strength=1.0)
    compare_to_cycles(scene, samples=64, max_bounces=2)


def test_shadow_terminator_of_squashed_duplicates_matches_cycles():
    """Shadow rays lifted off the smooth surface of objects whose transform Cycles keeps: coarse squashed linked
    duplicates lit by a grazing sun, the Geometry Offset at its largest. Cycles lifts them in object space
    (shadow_ray_smooth_surface_offset, then the object's matrix); Ember lifts them in world space from the unit
    corner normals, which agrees with it within noise here."""
    scene = squashed_spheres(False)
    for ob in scene.objects:
        if ob.type == "MESH":
            ob.shadow_terminator_geometry_offset = 1.0
    add_lamp(scene, "Sun", "SUN", (0, 0, 0), (0.0, 1.45, 0.6), energy=3.0, angle=0.0)
    set_world(scene, (0.0, 0.0, 0.0))
    compare_to_cycles(scene, samples=64, max_bounces=1)


@pytest.mark.parametrize("users", [1, 3])
def test_a_mesh_flattened_to_zero_scale_renders_as_in_cycles(users):
    """A cube scaled to zero height on a lit floor. Shown by several objects (a public city of geometry-nodes
    buildings had 445 of 678 flattened so), Cycles places the mesh by its transform and rays taken into object space by
    the inverse of a singular matrix meet nothing: the image is the floor's alone, in both engines now (Ember
    drew the flat boxes black: the city read -18%); Ember names the object in a warning. Shown once, Cycles applies
    the transform and the flat box is drawn, as Ember draws it."""
    from bpy_helpers import export_current, mesh_object, render_to_array, set_world
    scene = new_scene(48, 32)
    add_camera(scene, (0, -6, 4), (0, 0, 0), lens=35)
    set_world(scene, color=(0.3, 0.3, 0.3))
    mesh_object("Ground", [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [(0, 1, 2, 3)],
                diffuse_material("Green", (0.1, 0.6, 0.1)))
    add_lamp(scene, "Sun", "SUN", (0, 0, 5), rotation=(0.4, 0.2, 0), energy=3.0)
    floor_only = {engine: render_to_array(scene, engine, 8, seed=1)[..., :3] for engine in ("CYCLES", "EMBER")}
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, 0.0))
    cube = bpy.context.active_object
    cube.data.materials.append(diffuse_material("Grey", (0.8, 0.8, 0.8)))
    cube.scale = (1.0, 1.0, 0.0)
    for x in (-2.5, 2.5)[:users - 1]:
        copy = cube.copy()
        copy.location = (x, 0.0, 0.0)
        scene.collection.objects.link(copy)
    warned = [w for w in export_current().warnings if "zero scale" in w]
    assert bool(warned) == (users > 1), warned
    for engine in ("CYCLES", "EMBER"):
        image = render_to_array(scene, engine, 8, seed=1)[..., :3]
        if users > 1:
            np.testing.assert_array_equal(image, floor_only[engine], err_msg=engine)
        else:
            assert image.min() < 0.5 * floor_only[engine].min(), engine    # the flat box, dark where it lies
