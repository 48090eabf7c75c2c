"""Motion blur (issue 12) through Blender: object transform motion and camera motion against Cycles, and
what must not change (a still scene, the scene's frame)."""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from bpy_helpers import (compare_to_cycles, diffuse_material, emission_material, new_scene, quad_object,
                         render_to_array, set_world)


def _linear(ob):
    action = ob.animation_data.action
    curves = getattr(action, "fcurves", None)
    if curves is None:  # Blender 5.0 layered actions
        curves = [c for layer in action.layers for strip in layer.strips
                  for bag in strip.channelbags for c in bag.fcurves]
    for curve in curves:
        for key in curve.keyframe_points:
            key.interpolation = "LINEAR"


def motion_scene(position="CENTER", emissive=False, camera_moves=False, steps=1):
    """A spinning cube and a translating sphere (and optionally a moving camera or a moving lamp
    object made of emissive triangles) over a floor, keyed on frames 1 and 2, rendered at frame 1 with a
    one-frame shutter."""
    scene = new_scene(48, 48)
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = 1.0
    scene.render.motion_blur_position = position
    quad_object("Floor", (-4, -4, 0), (8, 0, 0), (0, 8, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(-1.0, 0, 1.0))
    cube = bpy.context.object
    cube.data.materials.append(diffuse_material("Red", (0.8, 0.1, 0.1)))
    cube.cycles.motion_steps = steps
    cube.keyframe_insert("rotation_euler", frame=1)
    cube.rotation_euler = (0, 0, math.radians(90))
    cube.keyframe_insert("rotation_euler", frame=2)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.4, location=(0.6, 0, 1.0))
    ball = bpy.context.object
    ball.data.materials.append(emission_material("Glow", (1.0, 0.6, 0.2), 4.0) if emissive
                               else diffuse_material("Blue", (0.1, 0.2, 0.8)))
    ball.keyframe_insert("location", frame=1)
    ball.location = (1.6, 0.3, 1.4)
    ball.keyframe_insert("location", frame=2)
    animated = [cube, ball]
    if camera_moves:
        cam = scene.camera
        cam.keyframe_insert("location", frame=1)
        cam.location = (cam.location.x + 0.8, cam.location.y, cam.location.z + 0.3)
        cam.keyframe_insert("location", frame=2)
        animated.append(cam)
    for ob in animated:
        _linear(ob)
    scene.frame_set(1)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.5, 0.3, 0.0)
    scene.collection.objects.link(sun)
    set_world(scene, (0.2, 0.25, 0.3), 1.0)
    return scene


@pytest.mark.parametrize("position,emissive,camera_moves,steps", [
    ("CENTER", False, False, 1), ("START", True, False, 2), ("END", False, True, 1)])
def test_motion_blur_matches_cycles(position, emissive, camera_moves, steps):
    compare_to_cycles(motion_scene(position, emissive, camera_moves, steps), samples=64, blocks=6, max_bounces=2)


def test_motion_blur_blurs_and_keeps_the_frame():
    scene = motion_scene()
    blurred = render_to_array(scene, "EMBER", 16, max_bounces=1)
    assert scene.frame_current == 1 and scene.frame_subframe == 0.0
    scene.render.use_motion_blur = False
    sharp = render_to_array(scene, "EMBER", 16, max_bounces=1)
    assert np.abs(blurred - sharp).max() > 0.2  # the moving objects smear


def test_still_scene_is_unchanged_by_motion_blur():
    """Nothing moves: the same paths, bit for bit (no time is drawn, no scene is split)."""
    scene = new_scene(24, 24)
    quad_object("Floor", (-4, -4, 0), (8, 0, 0), (0, 8, 0), diffuse_material("Floor"))
    set_world(scene, (0.5, 0.5, 0.5), 1.0)
    off = render_to_array(scene, "EMBER", 8)
    scene.render.use_motion_blur = True
    np.testing.assert_array_equal(render_to_array(scene, "EMBER", 8), off)


def test_object_motion_blur_off_per_object():
    """Cycles' Object > Motion Blur toggle: an object with it off renders sharp at the frame."""
    scene = motion_scene()
    for ob in scene.objects:
        ob.cycles.use_motion_blur = False
    blurred_off = render_to_array(scene, "EMBER", 8, max_bounces=1)
    scene.render.use_motion_blur = False
    np.testing.assert_array_equal(render_to_array(scene, "EMBER", 8, max_bounces=1), blurred_off)


@pytest.mark.parametrize("duration", [0.0, 0.3])
def test_rolling_shutter_matches_cycles(duration):
    """Cycles' Rolling Shutter (Top) with its Duration: rows from the top to the bottom take later times,
    so a moving object leans; as Cycles renders it."""
    scene = motion_scene(camera_moves=True)
    scene.cycles.rolling_shutter_type, scene.cycles.rolling_shutter_duration = "TOP", duration
    compare_to_cycles(scene, samples=64, blocks=6, max_bounces=2)


def test_zooming_lens_matches_cycles():
    """A camera zooming from 35 mm to 60 mm over frames 1 to 3, rendered at frame 2 with a one-frame
    shutter: Cycles lerps the view plane between the shutter's start, the frame's and its end lens."""
    scene = motion_scene()
    cam = scene.camera.data
    cam.lens = 35.0
    cam.keyframe_insert("lens", frame=1)
    cam.lens = 60.0
    cam.keyframe_insert("lens", frame=3)
    for curve in (getattr(cam.animation_data.action, "fcurves", None) or
                  [c for layer in cam.animation_data.action.layers for strip in layer.strips
                   for bag in strip.channelbags for c in bag.fcurves]):
        for key in curve.keyframe_points:
            key.interpolation = "LINEAR"
    scene.frame_set(2)
    compare_to_cycles(scene, samples=64, blocks=6, max_bounces=2)
