"""The Ambient Occlusion and Bevel nodes against Cycles (CPU, no clamping, box filter), as
test_parity_materials compares: a rock in a corner darkened by AO through a Color Ramp, AO's Only Local and
Inside options, and a metal cube whose edges a Bevel normal rounds."""
import math

import bpy
import numpy as np
from mathutils import Vector

from bpy_helpers import compare_to_cycles, diffuse_material, export_current, mesh_object, new_scene, set_world


def corner_room():
    """A grey floor and two walls meeting in a corner behind the origin, a sun from the front left."""
    grey = diffuse_material("Room", (0.5, 0.5, 0.5))
    mesh_object("Floor", [(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)], [(0, 1, 2, 3)], grey)
    mesh_object("Back", [(-3, 1, 0), (3, 1, 0), (3, 1, 3), (-3, 1, 3)], [(0, 1, 2, 3)], grey)
    mesh_object("Side", [(1, -3, 0), (1, 3, 0), (1, 3, 3), (1, -3, 3)], [(0, 1, 2, 3)], grey)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 2.0
    sun.rotation_euler = (math.radians(40), math.radians(-25), math.radians(20))
    bpy.context.scene.collection.objects.link(sun)


def rock(material, location=(0.2, 0.3, 0.45)):
    """A lumpy icosphere (vertices pushed in and out by a fixed random draw), smooth shaded."""
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=0.55, location=location)
    ob = bpy.context.active_object
    rng = np.random.default_rng(4)
    for v in ob.data.vertices:
        v.co *= float(rng.uniform(0.8, 1.15))
    ob.data.shade_smooth()
    ob.data.materials.append(material)
    return ob


def ao_material(name, distance=0.6, only_local=False, inside=False, ramp=True):
    """AO (its Color output when ramp is off, else AO through a dark-to-light Color Ramp) into a Principled
    Base Color."""
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.6
    ao = tree.nodes.new("ShaderNodeAmbientOcclusion")
    ao.inputs["Distance"].default_value = distance
    ao.inputs["Color"].default_value = (0.9, 0.7, 0.5, 1.0)
    ao.only_local, ao.inside = only_local, inside
    ao.samples = 8
    if ramp:
        ramp_node = tree.nodes.new("ShaderNodeValToRGB")
        ramp_node.color_ramp.elements[0].color = (0.05, 0.03, 0.02, 1.0)
        ramp_node.color_ramp.elements[1].position = 0.8
        ramp_node.color_ramp.elements[1].color = (0.8, 0.7, 0.55, 1.0)
        tree.links.new(ao.outputs["AO"], ramp_node.inputs["Fac"])
        tree.links.new(ramp_node.outputs["Color"], bsdf.inputs["Base Color"])
    else:
        tree.links.new(ao.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def test_rock_in_a_corner_darkened_by_ao_through_a_color_ramp():
    scene = new_scene(48, 48)
    scene.camera.location = (-1.6, -3.2, 1.6)
    corner_room()
    mat = ao_material("Rock")
    rock(mat)
    bpy.data.objects["Floor"].data.materials[0] = mat   # the floor darkens where the rock and walls are near
    set_world(scene, (0.4, 0.45, 0.5))
    exported = export_current()
    assert not [w for w in exported.warnings if "Ambient Occlusion" in w], exported.warnings
    compare_to_cycles(scene, samples=64, max_bounces=3)


def test_ao_only_local_in_a_room_with_a_rock():
    """The room (floor and two walls, one object) darkened by its own Only Local AO: its corner darkens, the
    rock's contact does not (another object)."""
    scene = new_scene(48, 48)
    scene.camera.location = (-1.6, -3.2, 1.6)
    mat = ao_material("Room", distance=1.0, only_local=True)
    mesh_object("Room", [(-3, -3, 0), (1, -3, 0), (1, 1, 0), (-3, 1, 0), (-3, 1, 3), (1, 1, 3), (1, -3, 3)],
                [(0, 1, 2, 3), (3, 2, 5, 4), (1, 6, 5, 2)], mat)
    rock(diffuse_material("Stone", (0.5, 0.5, 0.5)), location=(-0.6, -0.4, 0.45))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 2.0
    sun.rotation_euler = (math.radians(40), math.radians(-25), math.radians(20))
    scene.collection.objects.link(sun)
    set_world(scene, (0.4, 0.45, 0.5))
    compare_to_cycles(scene, samples=64, max_bounces=3)


def test_ao_inside_a_rock():
    """Inside: the rays go into the rock (its lumps occlude them), the Color output straight into Base Color."""
    scene = new_scene(48, 48)
    scene.camera.location = (-1.2, -2.6, 1.4)
    corner_room()
    rock(ao_material("Rock", distance=0.8, inside=True, ramp=False))
    set_world(scene, (0.4, 0.45, 0.5))
    compare_to_cycles(scene, samples=64, max_bounces=3)


def bevel_cube(material, radius=0.3):
    bpy.ops.mesh.primitive_cube_add(size=1.6, location=(0, 0, 0.8))
    bpy.context.active_object.data.materials.append(material)


def test_metal_cube_with_a_bevel_normal():
    """A metal cube whose Bevel (radius 0.3) rounds its edges: the sun glints on the rounded top-front edge,
    which a sharp cube does not show; a grey world and a dark floor."""
    scene = new_scene(48, 48)
    scene.camera.location = (2.6, -3.4, 2.8)
    mesh_object("Floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.1, 0.1, 0.1)))
    mat = bpy.data.materials.new("Metal")
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    bsdf.inputs["Metallic"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = 0.3
    bsdf.inputs["Base Color"].default_value = (0.9, 0.75, 0.5, 1.0)
    bevel = tree.nodes.new("ShaderNodeBevel")
    bevel.inputs["Radius"].default_value = 0.3
    bevel.samples = 8
    tree.links.new(bevel.outputs["Normal"], bsdf.inputs["Normal"])
    bevel_cube(mat)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 5.0
    sun.data.angle = math.radians(10)
    # Mirrored by the top-front edge's 45-degree normal into the camera.
    sun.rotation_euler = Vector((0.67, 0.31, -0.67)).to_track_quat("-Z", "Y").to_euler()
    scene.collection.objects.link(sun)
    set_world(scene, (0.2, 0.2, 0.2))
    exported = export_current()
    assert not [w for w in exported.warnings if "Bevel" in w], exported.warnings
    compare_to_cycles(scene, samples=128, max_bounces=3)


def test_bevel_normal_as_a_colour():
    """The Bevel normal itself (its Normal input fed by a Geometry normal, Radius by a Math node), emitted as
    0.5 + 0.5 N: every edge's blend of face colours against Cycles'."""
    scene = new_scene(48, 48)
    scene.camera.location = (2.6, -3.4, 2.8)
    mat = bpy.data.materials.new("Normals")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    emission = tree.nodes.new("ShaderNodeEmission")
    bevel = tree.nodes.new("ShaderNodeBevel")
    bevel.samples = 4
    radius = tree.nodes.new("ShaderNodeMath")
    radius.operation = "MULTIPLY"
    radius.inputs[0].default_value, radius.inputs[1].default_value = 0.5, 0.5
    geometry = tree.nodes.new("ShaderNodeNewGeometry")
    tree.links.new(radius.outputs[0], bevel.inputs["Radius"])
    tree.links.new(geometry.outputs["Normal"], bevel.inputs["Normal"])
    half = tree.nodes.new("ShaderNodeVectorMath")
    half.operation = "MULTIPLY_ADD"
    half.inputs[1].default_value = half.inputs[2].default_value = (0.5, 0.5, 0.5)
    tree.links.new(bevel.outputs["Normal"], half.inputs[0])
    tree.links.new(half.outputs["Vector"], emission.inputs["Color"])
    tree.links.new(emission.outputs[0], out.inputs["Surface"])
    bevel_cube(mat)
    set_world(scene, (0.0, 0.0, 0.0))
    compare_to_cycles(scene, samples=32, max_bounces=1)
