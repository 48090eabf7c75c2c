"""The Vector pass (motion vectors) against Cycles' on the same animated scene (issue 13)."""
from __future__ import annotations


import bpy
import numpy as np
import pytest

from bpy_helpers import configure_cycles, diffuse_material, new_scene, quad_object, set_world
from exr import render_multilayer
from test_motion_blur import _linear


def vector_scene(camera_moves: bool):
    """A sphere moving right and up and a static floor, keyed on frames 1 to 3, rendered at frame 2;
    optionally the camera moving sideways too."""
    scene = new_scene(40, 30)
    quad_object("Floor", (-4, -4, 0), (8, 0, 0), (0, 8, 0), diffuse_material("Floor"))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(-0.4, 0, 0.8))
    ball = bpy.context.object
    ball.data.materials.append(diffuse_material("Ball", (0.2, 0.3, 0.8)))
    ball.keyframe_insert("location", frame=1)
    ball.location = (0.4, 0.0, 1.2)
    ball.keyframe_insert("location", frame=3)
    animated = [ball]
    if camera_moves:
        cam = scene.camera
        cam.keyframe_insert("location", frame=1)
        cam.location = (cam.location.x + 0.6, cam.location.y, cam.location.z)
        cam.keyframe_insert("location", frame=3)
        animated.append(cam)
    for ob in animated:
        _linear(ob)
    scene.frame_set(2)
    set_world(scene, (0.5, 0.5, 0.5), 1.0)
    scene.view_layers[0].use_pass_vector = True
    return scene


def render(engine, camera_moves):
    scene = vector_scene(camera_moves)
    scene.render.engine = engine
    if engine == "CYCLES":
        configure_cycles(scene, 16, 0, 1)
    else:
        e = scene.ember
        e.samples, e.max_bounces, e.use_adaptive_sampling, e.use_denoising, e.pixel_filter_type = 16, 1, False, False, "BOX"
    parts, _ = render_multilayer(scene)
    assert scene.frame_current == 2
    planes = parts[f"{scene.view_layers[0].name}.Vector"]
    return np.stack([planes[c] for c in "XYZW"], axis=-1)


@pytest.mark.parametrize("camera_moves", [False, True])
def test_vector_pass_matches_cycles(camera_moves):
    """Away from silhouettes (pixels whose vectors are uniform with their neighbours in both renders) the
    vectors agree to 0.05 pixel; the moving sphere's are not zero."""
    cycles, ember = render("CYCLES", camera_moves), render("EMBER", camera_moves)
    assert np.abs(cycles).max() > 1.0  # something moves by more than a pixel
    smooth = np.ones(cycles.shape[:2], bool)
    for image in (cycles, ember):
        for axis in (0, 1):
            jump = np.abs(np.diff(image, axis=axis)).max(axis=2) > 0.2
            if axis == 0:
                smooth[:-1] &= ~jump
                smooth[1:] &= ~jump
            else:
                smooth[:, :-1] &= ~jump
                smooth[:, 1:] &= ~jump
    assert smooth.mean() > 0.5
    moving = smooth & (np.abs(cycles).max(axis=2) > 0.5)
    assert moving.sum() >= 10  # the comparison covers moving pixels, not only the still floor
    np.testing.assert_allclose(ember[smooth], cycles[smooth], atol=0.05)
