"""The Vector pass of deforming meshes against Cycles': shape keys, a Wave modifier (with the Deformation switch
off too: Cycles' motion pass reads deformation whatever it says), a `velocity` attribute, a mesh whose modifier
does not deform."""
from __future__ import annotations

import bpy
import numpy as np
import pytest

from bpy_helpers import configure_cycles, new_scene
from exr import render_multilayer
from motion_helpers import slide_along_x
from test_deform_motion_blur import lit, streaking_mesh, stretching_cube, waving_grid
from test_shape_motion_blur import _FrameSetter


def vector_scene(build):
    scene = new_scene(40, 30)
    lit(scene)
    ob = build(scene)
    scene.view_layers[0].use_pass_vector = True
    return scene, ob


def render(scene, engine, samples=16):
    scene.render.engine = engine
    if engine == "CYCLES":
        configure_cycles(scene, samples, 0, 1)
    else:
        e = scene.ember
        e.samples, e.max_bounces, e.use_adaptive_sampling, e.use_denoising, e.pixel_filter_type = samples, 1, False, False, "BOX"
    frame = scene.frame_current
    parts, _ = render_multilayer(scene)
    assert scene.frame_current == frame
    planes = parts[f"{scene.view_layers[0].name}.Vector"]
    return np.stack([planes[c] for c in "XYZW"], axis=-1)


def export_vector():
    """The current scene exported as a final render with the Vector pass exports it."""
    from ember.engine.export import export_scene
    from ember.engine.export.motion import sample_vector_motion
    depsgraph = bpy.context.evaluated_depsgraph_get()
    scene = bpy.context.scene
    return export_scene(depsgraph, vector=sample_vector_motion(_FrameSetter(scene), depsgraph, scene.camera))


def smooth_pixels(cycles, ember):
    """Pixels whose vectors change linearly to their neighbours in both renders (a deforming face's vectors vary
    over it; a silhouette bends them): second differences below 0.2 pixel along both axes."""
    smooth = np.ones(cycles.shape[:2], bool)
    for image in (cycles, ember):
        smooth[1:-1] &= np.abs(image[2:] - 2 * image[1:-1] + image[:-2]).max(axis=2) < 0.2
        smooth[:, 1:-1] &= np.abs(image[:, 2:] - 2 * image[:, 1:-1] + image[:, :-2]).max(axis=2) < 0.2
    return smooth


def compare(scene, deforming: int, samples=16):
    """Ember's Vector pass against Cycles', over at least `deforming` pixels that move by more than half a pixel;
    away from silhouettes, to 0.05 pixel as tests/test_vector_pass.py (16 samples: the largest difference seen is
    0.025 pixel)."""
    cycles, ember = render(scene, "CYCLES", samples), render(scene, "EMBER", samples)
    smooth = smooth_pixels(cycles, ember)
    assert smooth.mean() > 0.5
    moving = smooth & (np.abs(cycles).max(axis=2) > 0.5)
    assert moving.sum() >= deforming, moving.sum()
    print("compared", smooth.sum(), "pixels,", moving.sum(), "moving; largest difference",
          np.abs(ember[smooth] - cycles[smooth]).max())
    np.testing.assert_allclose(ember[smooth], cycles[smooth], atol=0.05)
    return cycles, ember


@pytest.mark.parametrize("moves", [False, True])
def test_shape_keys_vectors_match_cycles(moves):
    """A cube stretched by an animated shape key (sliding along x too): its vectors follow its vertices at frames 0
    and 2, on the frame's triangles, moved by the object's matrices then."""
    scene, cube = vector_scene(lambda s: stretching_cube(s, moves))
    arrays = export_vector().scene
    assert arrays.vector_deform_ids is not None and (arrays.vector_deform_ids >= 0).sum() == 12
    assert arrays.vector_deform.shape == (2, 12, 3, 3)
    compare(scene, 20)


@pytest.mark.parametrize("deform_switch", [True, False])
def test_wave_modifier_vectors_match_cycles(deform_switch):
    """A grid rippled by a Wave modifier: vectors that vary over the grid as Cycles' (its Deformation switch off
    too: Cycles gives every object three motion steps for the pass, object.cpp sync_object_motion_init)."""
    scene, grid = vector_scene(waving_grid)
    grid.cycles.use_deform_motion = deform_switch
    compare(scene, 40)   # the grid stands still: only its deformation moves these pixels


def test_velocity_attribute_vectors_match_cycles():
    """A still mesh whose vertices carry a `velocity` attribute: its vectors are one frame's worth of it each way
    (Cycles' attr_create_motion_from_velocity with the pass's two-frame shutter), not read at the other frames.
    64 samples: its steep vectors vary within a pixel (largest difference 0.043 pixel at 16 samples, 0.018 at 64)."""
    def build(scene):
        bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=0.7, location=(0, 0, 1))
        ball = streaking_mesh(bpy.context.active_object, speed=20.0)
        scene.frame_set(1)
        return ball
    scene, _ = vector_scene(build)
    arrays = export_vector().scene
    fps = scene.render.fps / scene.render.fps_base
    z = arrays.positions[arrays.vector_deform_ids >= 0][..., 2] - 1.0   # the vertices' own heights
    after = arrays.vector_deform[1][..., 0] - arrays.positions[arrays.vector_deform_ids >= 0][..., 0]
    assert np.allclose(after, 20.0 * (z + 0.7) / fps, atol=1e-4)
    compare(scene, 20, samples=64)


def test_still_mesh_with_modifier_keeps_its_object_motion():
    """A cube with a Bevel modifier (deform-modified to Cycles) that only slides: nothing deforms, so no field is
    made and its vectors are its object's motion, as Cycles'."""
    def build(scene):
        bpy.ops.mesh.primitive_cube_add(size=0.8, location=(-0.3, 0, 0.8))
        cube = bpy.context.object
        cube.modifiers.new("Bevel", "BEVEL").width = 0.05
        slide_along_x(cube, 1.2)
        scene.frame_set(1)
        return cube
    scene, _ = vector_scene(build)
    arrays = export_vector().scene
    assert arrays.vector_deform_ids is None and arrays.vector_deform is None
    assert arrays.vector_motion is not None
    compare(scene, 10)
