"""Persistent Data (Render Properties > Performance): the frames of an animation reuse the scene built for
the frame before. Only transforms, materials, lights or the camera changed: the kept renderer is updated in
place; a mesh changed: a new one is built, keeping the BVHs of the meshes that did not change. Either way
the frame is the one a fresh render with the same settings makes, bit for bit."""
from __future__ import annotations

import bpy
import numpy as np
import pytest

import os
import tempfile

from bpy_helpers import diffuse_material, load_exr, new_scene, quad_object, render_to_array, set_world

import ember.engine.persistent as persistent


def _animated_scene():
    scene = new_scene(40, 30)
    set_world(scene, color=(0.15, 0.17, 0.2))
    quad_object("Floor", (-5, -5, 0), (10, 0, 0), (0, 10, 0), diffuse_material("Floor"))
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=3, radius=0.7, location=(-1.2, 0, 0.7))
    bpy.context.object.data.materials.append(diffuse_material("Ball", (0.8, 0.3, 0.2)))
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(1.0, 0, 0.4))
    cube = bpy.context.object
    cube.data.materials.append(diffuse_material("Cube", (0.2, 0.4, 0.8)))
    cube.keyframe_insert("location", frame=1)
    cube.location = (1.6, 0.5, 0.4)
    cube.keyframe_insert("location", frame=2)
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.location = (0, -2, 3)
    lamp.data.energy = 300
    lamp.data.keyframe_insert("energy", frame=1)
    lamp.data.energy = 600
    lamp.data.keyframe_insert("energy", frame=2)
    scene.collection.objects.link(lamp)
    scene.render.use_persistent_data = True
    return scene


@pytest.fixture(autouse=True)
def _fresh_kept_scene():
    persistent.drop_kept_scene()
    persistent.kept.updated = persistent.kept.built = 0
    yield
    persistent.drop_kept_scene()


def _frame(scene, frame):
    """Frame `frame` rendered with the settings render_to_array makes; after the first call the settings
    are left alone, as in an animation render (setting them again, even to the same values, makes Blender
    evaluate the render depsgraph anew, and its updates then name everything)."""
    scene.frame_set(frame)
    if scene.render.engine != "EMBER":
        return render_to_array(scene, "EMBER", 8, seed=2)
    with tempfile.TemporaryDirectory() as tmp:
        scene.render.filepath = os.path.join(tmp, "frame.exr")
        bpy.ops.render.render(write_still=True)
        return load_exr(scene.render.filepath)


def test_moved_object_and_edited_light_update_the_kept_scene():
    scene = _animated_scene()
    _frame(scene, 1)
    assert persistent.kept.built == 1 and persistent.kept.renderer is not None
    assert persistent.kept.meshes.reads == 3                              # floor, ball, cube
    second = _frame(scene, 2)
    assert persistent.kept.built == 1 and persistent.kept.updated == 1      # updated, not built again
    # Blender kept the render depsgraph, whose updates name only the cube's transform and the lamp: the
    # export reuses the meshes it read for frame 1.
    assert persistent.kept.meshes.reads == 0
    persistent.drop_kept_scene()
    fresh = _frame(scene, 2)
    assert persistent.kept.built == 2
    np.testing.assert_array_equal(second, fresh)
    assert not np.array_equal(second, _frame(scene, 1))               # the frames do differ


def test_a_deformed_mesh_rebuilds_and_the_others_keep_their_bvh():
    scene = _animated_scene()
    ball = bpy.data.objects["Icosphere"]
    ball.shape_key_add(name="Basis")
    key = ball.shape_key_add(name="Squash")
    for point in key.data:
        point.co.z *= 0.6
    key.value = 0.0
    key.keyframe_insert("value", frame=1)
    key.value = 1.0
    key.keyframe_insert("value", frame=2)
    _frame(scene, 1)
    second = _frame(scene, 2)
    assert persistent.kept.built == 2 and persistent.kept.updated == 0
    assert persistent.kept.meshes.reads == 1                   # the ball alone is read again
    accel = persistent.kept.renderer.accel
    assert accel.meshes_reused == len(accel.meshes) - 1       # all but the deformed ball's
    persistent.drop_kept_scene()
    np.testing.assert_array_equal(second, _frame(scene, 2))


def test_without_persistent_data_nothing_is_kept():
    scene = _animated_scene()
    scene.render.use_persistent_data = False
    _frame(scene, 1)
    assert persistent.kept.renderer is None and persistent.kept.built == 0
