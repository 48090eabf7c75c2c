"""Object > Shading > Shadow Terminator > Shading Offset against Cycles: a coarse smooth-shaded sphere lit from
the side by a sun, whose terminator the offset softens (Cycles' shift_cos_in on each closure's eval toward
directions on its normal's side: kernels/bsdf/mixture_eval.py terminator_shift), on a diffuse, a glossy and a
mirror surface; before, the offset was ignored with a warning."""
import math

import bpy
import pytest

from bpy_helpers import add_camera, compare_to_cycles, diffuse_material, export_current, new_scene, set_world


def sphere_scene(material, offset):
    scene = new_scene(48, 48)
    add_camera(scene, (0, -4, 0.5), (0, 0, 0), lens=50)
    set_world(scene, color=(0.02, 0.02, 0.02))
    bpy.ops.mesh.primitive_ico_sphere_add(radius=1.0, subdivisions=1)
    ball = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    ball.shadow_terminator_shading_offset = offset
    ball.data.materials.append(material())
    sun = bpy.data.lights.new("Sun", "SUN")
    sun.energy, sun.angle = 3.0, 0.01
    lamp = bpy.data.objects.new("Sun", sun)
    lamp.rotation_euler = (0.0, math.radians(80), 0.0)
    scene.collection.objects.link(lamp)
    return scene


def principled(roughness, metallic):
    def make():
        material = bpy.data.materials.new("Shiny")
        bsdf = material.node_tree.nodes["Principled BSDF"]
        bsdf.inputs["Roughness"].default_value, bsdf.inputs["Metallic"].default_value = roughness, metallic
        return material
    return make


MATERIALS = {"diffuse": lambda: diffuse_material("Matte", (0.8, 0.8, 0.8)), "glossy": principled(0.4, 0.0),
             "mirror": principled(0.0, 1.0)}


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_shading_offset_matches_cycles(name):
    compare_to_cycles(sphere_scene(MATERIALS[name], 0.6), samples=128, max_bounces=2)


def test_shading_offset_is_read_without_a_warning():
    sphere_scene(MATERIALS["diffuse"], 0.6)
    exported = export_current()
    assert not [w for w in exported.warnings if "Terminator" in w], exported.warnings
    from ember.kernels.scene import OBJ_SHADING_OFFSET
    assert exported.scene.objects[:, OBJ_SHADING_OFFSET].max() == pytest.approx(0.6)
