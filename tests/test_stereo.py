"""Stereoscopy (Output > Views, Stereo 3D): each view rendered through its own camera, as Blender places it
(RenderEngine.camera_model_matrix and camera_shift_x, which Cycles reads), into its own view of the result. Before,
Ember rendered the left view only: the right eye of every stereo frame was black."""
import os
import tempfile

import bpy
import numpy as np

from bpy_helpers import add_camera, configure_engine, diffuse_material, new_scene, quad_object, set_world


def render_views(engine: str) -> dict:
    scene = new_scene(48, 32)
    add_camera(scene, (0, -4, 1.4), (0, 0, 0.5))
    set_world(scene, (0.5, 0.5, 0.5))
    quad_object("Floor", (-2, -2, 0), (4, 0, 0), (0, 8, 0), diffuse_material("Floor", (0.7, 0.7, 0.7)))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.3, 3.0, 0.6))   # 7 m away, beyond the convergence
    bpy.context.active_object.data.materials.append(diffuse_material("Box", (0.9, 0.1, 0.1)))
    scene.render.use_multiview, scene.render.views_format = True, "STEREO_3D"
    configure_engine(scene, engine, 16)
    settings = scene.render.image_settings
    settings.file_format, settings.views_format = "OPEN_EXR", "INDIVIDUAL"
    out = {}
    with tempfile.TemporaryDirectory() as folder:
        scene.render.filepath = os.path.join(folder, "frame.exr")
        bpy.ops.render.render(write_still=True)
        for view in ("L", "R"):
            image = bpy.data.images.load(os.path.join(folder, f"frame_{view}.exr"))
            out[view] = np.array(image.pixels[:], np.float32).reshape(32, 48, 4)
            bpy.data.images.remove(image)
    return out


def box_columns(image) -> tuple:
    red = (image[..., 0] - image[..., 1]) > 0.2
    cols = np.flatnonzero(red.any(axis=0))
    return int(cols[0]), int(cols[-1])


def test_each_view_is_rendered_through_its_own_camera_as_in_cycles():
    cycles, ember = render_views("CYCLES"), render_views("EMBER")
    for view in ("L", "R"):
        assert box_columns(ember[view]) == box_columns(cycles[view]), view
        assert abs(ember[view][..., :3].mean() / cycles[view][..., :3].mean() - 1) < 0.02, view
    assert box_columns(ember["L"]) != box_columns(ember["R"])   # the views differ: the right one moved
