"""Deformation motion blur of meshes through Blender, against Cycles: shape keys, a modifier animated over the
frames, a mesh that also moves; what gets no deformation (a mesh changing its vertex count, Deformation off, a
modifier that does not deform over the shutter)."""
from __future__ import annotations

import bpy
import numpy as np
import pytest

from bpy_helpers import compare_to_cycles, diffuse_material, quad_object, render_to_array, set_world
from motion_helpers import node_modifier, slide_along_x, store_velocity, time_driven, x_from_height
from test_motion_blur import _linear
from test_shape_motion_blur import blurred_scene, export_blurred


def lit(scene):
    """A floor, a sun and a sky."""
    quad_object("Floor", (-4, -4, 0), (8, 0, 0), (0, 8, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.5, 0.3, 0.0)
    scene.collection.objects.link(sun)
    set_world(scene, (0.2, 0.25, 0.3), 1.0)


def stretching_cube(scene, moves=False, mirrored=False):
    """A cube whose shape key lifts and shears its top over frames 0 to 2 (keyed linearly; rendered at frame 1, a
    one-frame shutter spans 0.5 to 1.5); moves: it slides along x too; mirrored: its object scale is -1 in x."""
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(-0.3, 0, 0.8))
    cube = bpy.context.object
    if mirrored:
        cube.scale.x = -1.0
    cube.data.materials.append(diffuse_material("Red", (0.8, 0.1, 0.1)))
    cube.shape_key_add(name="Basis")
    key = cube.shape_key_add(name="Stretch")
    for point in key.data:
        if point.co.z > 0:
            point.co.z += 1.2
            point.co.x += 1.0
    key.value = 0.0
    key.keyframe_insert("value", frame=0)
    key.value = 1.0
    key.keyframe_insert("value", frame=2)
    _linear(cube.data.shape_keys)
    if moves:
        slide_along_x(cube, 1.6)
    scene.frame_set(1)
    return cube


def waving_grid(scene):
    """A grid rippled by a Wave modifier, whose waves travel with the frame."""
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=24, y_subdivisions=24, size=3.0, location=(0, 0, 0.6),
                                    rotation=(1.1, 0, 0))
    grid = bpy.context.object
    grid.data.materials.append(diffuse_material("Grid", (0.7, 0.7, 0.2)))
    wave = grid.modifiers.new("Wave", "WAVE")
    wave.height, wave.width, wave.narrowness, wave.speed = 0.5, 0.8, 1.0, 1.5
    wave.use_normal = False
    bpy.ops.object.shade_smooth()
    scene.frame_set(1)
    return grid


@pytest.mark.parametrize("moves,mirrored", [(False, False), (True, False), (False, True)])
def test_shape_keys_deforming_a_cube_match_cycles(moves, mirrored):
    """A cube stretched by an animated shape key (sliding along x too: its deformation in its moving object's
    space; mirrored: its faces' fronts kept) smears over the shutter as in Cycles; without deformation blur its top
    would stand sharp (blocks 9.0 and 16.3 standard errors off, still and moving)."""
    scene = blurred_scene()
    lit(scene)
    cube = stretching_cube(scene, moves, mirrored)
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    arrays = exported.scene
    assert arrays.deform_ids is not None and (arrays.deform_ids >= 0).sum() == 12
    assert arrays.deform_positions.shape == (3, 12, 3, 3)
    compare_to_cycles(scene, samples=64, blocks=6, max_bounces=2)
    assert cube.data.shape_keys is not None


def test_a_wave_modifier_matches_cycles():
    """A grid rippled by a Wave modifier travelling with the frame: its positions and smooth normals at each motion
    step (two steps: five), as Cycles reads them (without deformation blur: a block 43 standard errors off)."""
    scene = blurred_scene()
    lit(scene)
    grid = waving_grid(scene)
    grid.cycles.motion_steps = 2
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    assert exported.scene.deform_positions.shape[0] == 5
    compare_to_cycles(scene, samples=64, blocks=6, max_bounces=2)


def bending_arm(scene, axis=2):
    """A cylinder skinned to a two-bone armature whose upper bone turns 120 degrees about its own axis `axis` over
    frames 0 to 2 (2: it bends sideways; 1, the bone's length: it twists the cylinder's sides)."""
    armature = bpy.data.armatures.new("Rig")
    rig = bpy.data.objects.new("Rig", armature)
    scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    root = armature.edit_bones.new("Root")
    root.head, root.tail = (0, 0, 0), (0, 0, 1)
    tip = armature.edit_bones.new("Tip")
    tip.head, tip.tail, tip.parent = (0, 0, 1), (0, 0, 2), root
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.ops.mesh.primitive_cylinder_add(vertices=16, radius=0.4, depth=2.0, location=(0, 0, 1))
    arm = bpy.context.object
    bpy.ops.object.transform_apply(location=True)
    arm.data.materials.append(diffuse_material("Arm", (0.9, 0.9, 0.9)))
    low, high = arm.vertex_groups.new(name="Root"), arm.vertex_groups.new(name="Tip")
    for v in arm.data.vertices:
        (high if v.co.z > 1.0 else low).add([v.index], 1.0, "REPLACE")
    arm.modifiers.new("Skin", "ARMATURE").object = rig
    bone = rig.pose.bones["Tip"]
    bone.rotation_mode = "XYZ"
    bone.keyframe_insert("rotation_euler", frame=0)
    bone.rotation_euler[axis] = np.radians(120)
    bone.keyframe_insert("rotation_euler", frame=2)
    _linear(rig)
    scene.frame_set(1)
    return arm


@pytest.mark.parametrize("axis", [2, 1])
def test_an_armature_bending_a_cylinder_matches_cycles(axis):
    """A cylinder bent (twisted) by an armature over the shutter (the Armature modifier: Cycles' deform-modified
    object); without deformation blur the bend is a block 9.5 standard errors off. The twist makes the side quads
    non-planar, and Blender splits some along the other diagonal at some steps: the steps keep the frame's triangles,
    as Cycles (read as Blender triangulates each step: a block 16.4 standard errors off)."""
    scene = blurred_scene()
    lit(scene)
    arm = bending_arm(scene, axis)
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    assert exported.scene.deform_ids is not None
    compare_to_cycles(scene, samples=64, blocks=6, max_bounces=2)
    assert arm.modifiers[0].type == "ARMATURE"


def test_deformation_blurs_and_still_meshes_are_unchanged():
    """The stretching cube renders otherwise than with its Deformation off, where it renders as with motion blur
    off, bit for bit; a modifier that does not deform over the shutter (a Bevel) gives no steps."""
    scene = blurred_scene(24, 24)
    lit(scene)
    cube = stretching_cube(scene)
    blurred = render_to_array(scene, "EMBER", 8, seed=1, max_bounces=2)
    cube.cycles.use_deform_motion = False
    assert export_blurred().scene.deform_ids is None
    off = render_to_array(scene, "EMBER", 8, seed=1, max_bounces=2)
    scene.render.use_motion_blur = False
    sharp = render_to_array(scene, "EMBER", 8, seed=1, max_bounces=2)
    assert np.array_equal(off, sharp)
    assert np.abs(blurred - sharp).mean() > 1e-3
    cube.cycles.use_deform_motion = True
    scene.render.use_motion_blur = True
    cube.shape_key_clear()
    cube.modifiers.new("Bevel", "BEVEL")
    exported = export_blurred()
    assert exported.scene.deform_ids is None and not exported.warnings, exported.warnings


def test_a_mesh_changing_its_vertex_count_is_warned_by_name():
    """A grid whose vertex count follows the frame (geometry nodes) at every motion step: no deformation blur, as
    Cycles drops the motion of a mesh whose topology differs; a warning names the object."""
    scene = blurred_scene(16, 16)
    lit(scene)
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(0, 0, 1))
    ob = bpy.context.object
    tree, _, output = node_modifier(ob, "grow", "Growing", geometry_in=False)
    grid = tree.nodes.new("GeometryNodeMeshGrid")
    tree.links.new(time_driven(tree, 4.0, plus=3.0), grid.inputs["Vertices X"])
    tree.links.new(grid.outputs[0], output.inputs[0])
    scene.frame_set(1)
    exported = export_blurred()
    assert any(f"'{ob.name}'" in w and "vertex count" in w for w in exported.warnings), exported.warnings
    assert exported.scene.deform_ids is None


def streaking_mesh(ob, speed=20.0):
    """Geometry nodes storing a `velocity` attribute on the mesh's vertices (units per second): x speed times the
    vertex's height above -0.7 (object space); the mesh itself stays still."""
    tree, into, out = node_modifier(ob, "streak", "Streak")
    velocity = x_from_height(tree, "MULTIPLY_ADD", speed, 0.7 * speed)
    tree.links.new(store_velocity(tree, into.outputs[0], velocity), out.inputs[0])
    return ob


def test_a_mesh_with_a_velocity_attribute_matches_cycles():
    """A still mesh whose vertices carry a `velocity` attribute blurs along it, half the shutter's seconds each way
    of the frame (Cycles' attr_create_motion_from_velocity for meshes: three steps, not read at the subframes); its
    flat faces shade by the moved triangles' own normals (with the frame's normals kept: a block 8.1 standard errors
    off; without the velocity 49.6)."""
    scene = blurred_scene()
    lit(scene)
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=0.7, location=(0, 0, 1))
    ball = streaking_mesh(bpy.context.active_object, speed=60.0)
    ball.data.materials.append(diffuse_material("Orange", (0.9, 0.5, 0.1)))
    scene.frame_set(1)
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    arrays = exported.scene
    steps = arrays.deform_positions
    assert steps is not None and len(steps) == 3
    half = 0.5 / (scene.render.fps / scene.render.fps_base)   # half the one-frame shutter, in seconds
    z = steps[1, ..., 2] - 1.0   # the object sits at z = 1: its vertices' own heights
    assert np.allclose(steps[2, ..., 0] - steps[1, ..., 0], 60.0 * (z + 0.7) * half, atol=1e-4)
    assert np.allclose(steps[0, ..., 0] - steps[1, ..., 0], -60.0 * (z + 0.7) * half, atol=1e-4)
    compare_to_cycles(scene, samples=64, blocks=6, max_bounces=2)
