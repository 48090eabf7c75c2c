"""Mirrored objects (a negative scale on one or three axes) render as Cycles renders them: their faces keep
Blender's front although the transform turns their winding over. Every combination of negative axes, as
plain meshes, as instances sharing one mesh and as motion-blurred objects, against Cycles; and glass, whose
inside and outside are told apart by that front.

Comparing an instanced scene with its flattened copy cannot catch this (both turn the same way), nor can a
check of the shading normals alone: only the geometric normal was wrong."""
from __future__ import annotations

import itertools

import bpy
import pytest

from bpy_helpers import compare_to_cycles, diffuse_material, new_scene, node_material, quad_object, set_world
from test_motion_blur import _linear

SIGNS = list(itertools.product((1, -1), repeat=3))   # (1, 1, 1) ... (-1, -1, -1)


def _facing_material() -> bpy.types.Material:
    """Principled BSDF, green on a face's front and red on its back (Geometry > Backfacing)."""
    mat = bpy.data.materials.new("Facing")
    tree = mat.node_tree
    shader = tree.nodes["Principled BSDF"]
    geometry = tree.nodes.new("ShaderNodeNewGeometry")
    mix = tree.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.inputs["A"].default_value = (0.2, 0.7, 0.2, 1.0)
    mix.inputs["B"].default_value = (0.8, 0.1, 0.1, 1.0)
    tree.links.new(geometry.outputs["Backfacing"], mix.inputs["Factor"])
    tree.links.new(mix.outputs["Result"], shader.inputs["Base Color"])
    return mat


def _monkey(material, subdivisions: int = 0) -> bpy.types.Object:
    bpy.ops.mesh.primitive_monkey_add(size=0.9)
    ob = bpy.context.object
    ob.data.shade_smooth()
    ob.data.materials.append(material)
    if subdivisions:
        mod = ob.modifiers.new("Subdivision", "SUBSURF")
        mod.levels = mod.render_levels = subdivisions
    return ob


def _grid_location(i: int) -> tuple:
    """Eight places in four columns and two rows, facing the camera."""
    return (-2.4 + 1.6 * (i % 4), 0.0, 0.6 + 1.5 * (i // 4))


def mirrored_scene(kind: str, material: str = "facing") -> bpy.types.Scene:
    """Eight Suzannes, one per combination of scale signs, in front of a wall, under an area light.
    kind: 'mesh' (each its own mesh), 'instance' (collection instances of one subdivided mesh, enough
    triangles that Ember stores it once) or 'motion' (each moving during the shutter)."""
    scene = new_scene(64, 64)
    scene.camera.location = (0.0, -7.5, 1.4)
    scene.camera.rotation_euler = (1.57, 0.0, 0.0)
    wall = diffuse_material("Wall", (0.5, 0.5, 0.5))
    quad_object("Wall", (-5, 1.5, -1), (10, 0, 0), (0, 0, 5), wall)
    quad_object("Floor", (-5, -5, -0.2), (10, 0, 0), (0, 6.5, 0), wall)
    mat = _facing_material() if material == "facing" else \
        node_material("Glass", "ShaderNodeBsdfGlass", Roughness=0.0, IOR=1.5)
    if kind == "instance":
        source = bpy.data.collections.new("Source")   # not linked to the scene: seen only through instances
        ob = _monkey(mat, subdivisions=1)
        for c in ob.users_collection:
            c.objects.unlink(ob)
        source.objects.link(ob)
    for i, signs in enumerate(SIGNS):
        if kind == "instance":
            holder = bpy.data.objects.new(f"Instance{i}", None)
            holder.instance_type = "COLLECTION"
            holder.instance_collection = source
            scene.collection.objects.link(holder)
        else:
            holder = _monkey(mat)
        holder.location = _grid_location(i)
        holder.rotation_euler = (0.0, 0.0, 0.35)   # so that a mirror across x shows a different side
        holder.scale = tuple(0.75 * s for s in signs)
        if kind == "motion":
            holder.keyframe_insert("location", frame=1)
            holder.location = (holder.location[0] + 0.25, 0.0, holder.location[2] + 0.1)
            holder.keyframe_insert("location", frame=2)
            _linear(holder)
    if kind == "motion":
        scene.render.use_motion_blur = True
        scene.render.motion_blur_shutter = 1.0
        scene.frame_set(1)
    lamp = bpy.data.objects.new("Key", bpy.data.lights.new("Key", "AREA"))
    lamp.data.energy, lamp.data.size = 600.0, 2.0
    lamp.location, lamp.rotation_euler = (1.5, -4.0, 4.0), (0.8, 0.0, 0.35)
    scene.collection.objects.link(lamp)
    set_world(scene, (0.05, 0.05, 0.06), 1.0)
    return scene


@pytest.mark.parametrize("kind", ["mesh", "instance", "motion"])
def test_mirrored_objects_match_cycles(kind):
    from ember.engine.export import export_scene
    scene = mirrored_scene(kind)
    arrays = export_scene(bpy.context.evaluated_depsgraph_get()).scene
    # The instanced kind is traced through instances (one stored mesh), the others as plain triangles.
    assert (arrays.instances is not None and arrays.instances.count == 8) == (kind == "instance")
    compare_to_cycles(scene, samples=64, blocks=8, max_bounces=3)


def test_mirrored_glass_matches_cycles():
    """Glass turns its IOR over by the side a ray enters from: a mirrored glass object seen from outside
    must refract as glass entered, not as glass left."""
    compare_to_cycles(mirrored_scene("mesh", material="glass"), samples=128, blocks=8, max_bounces=6)
