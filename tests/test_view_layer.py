"""A view layer's Filter and Override settings, which multi-layer files use (a clay layer, a layer without the sky,
a layer of volumes alone), against Cycles: Override > Material and World, Filter > Environment and Surfaces, and
the layer's Samples. Before, Ember ignored all five without a word: a clay layer rendered in full colour."""
import bpy
import numpy as np
import pytest

from bpy_helpers import (add_camera, add_lamp, compare_to_cycles, diffuse_material, new_scene, quad_object,
                         render_to_array, set_world)


def stage():
    """A red box on a green floor under a blue world and an area lamp."""
    scene = new_scene(32, 24)
    add_camera(scene, (0, -4, 2.0), (0, 0, 0.4), lens=35)
    set_world(scene, color=(0.2, 0.3, 0.6))
    quad_object("Floor", (-2, -2, 0), (4, 0, 0), (0, 4, 0), diffuse_material("Floor", (0.1, 0.6, 0.1)))
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(0.2, 0.3, 0.4), rotation=(0, 0, 0.4))
    bpy.context.active_object.data.materials.append(diffuse_material("Box", (0.8, 0.1, 0.1)))
    add_lamp(scene, "Key", "AREA", (0.8, -1.0, 2.4), (0.4, 0, 0), energy=150.0, size=0.8)
    return scene


def test_material_override_matches_cycles():
    """Every slot takes the override (a clay render): the red box and green floor turn grey, as in Cycles."""
    scene = stage()
    scene.view_layers[0].material_override = diffuse_material("Clay", (0.6, 0.6, 0.6))
    image = render_to_array(scene, "EMBER", 16)[..., :3]
    assert np.abs(image[..., 0] - image[..., 1]).max() < 0.3 * image.max()   # no longer red and green
    compare_to_cycles(scene, samples=64, max_bounces=4, mean_z=4.0)


def test_world_override_matches_cycles():
    scene = stage()
    other = bpy.data.worlds.new("Dusk")
    other.color = (0.8, 0.4, 0.1)
    if other.node_tree is not None:
        other.node_tree.nodes["Background"].inputs["Color"].default_value = (0.8, 0.4, 0.1, 1.0)
    scene.view_layers[0].world_override = other
    image = render_to_array(scene, "EMBER", 4)[..., :3]
    assert image[0, :, 0].mean() > image[0, :, 2].mean()   # the sky is the override's orange, not the scene's blue
    compare_to_cycles(scene, samples=64, max_bounces=4, mean_z=4.0)


def test_environment_filter_off_matches_cycles():
    """Filter > Environment off: the world neither shows nor lights (Cycles' empty background shader)."""
    scene = stage()
    scene.view_layers[0].use_sky = False
    image = render_to_array(scene, "EMBER", 4)[..., :3]
    assert image[0].max() == 0.0
    compare_to_cycles(scene, samples=64, max_bounces=4, mean_z=4.0)


def test_surfaces_filter_off_leaves_meshes_out_as_in_cycles():
    """Filter > Surfaces off: no mesh renders (the world alone, unshadowed), as in Cycles."""
    scene = stage()
    scene.view_layers[0].use_solid = False
    image = render_to_array(scene, "EMBER", 4)[..., :3]
    np.testing.assert_allclose(image, np.broadcast_to(np.float32([0.2, 0.3, 0.6]), image.shape), rtol=1e-5)
    compare_to_cycles(scene, samples=16, max_bounces=4)


@pytest.mark.parametrize("mode, layer, expected", [("USE", 5, 5), ("USE", 0, 12), ("BOUNDED", 5, 5),
                                                   ("BOUNDED", 20, 12), ("IGNORE", 5, 12)])
def test_layer_samples_as_cycles_reads_them(mode, layer, expected):
    """The view layer's Samples replace the scene's as Cycles' Layer Samples says (scene 12 here)."""
    from ember.engine.session import render_settings
    scene = stage()
    scene.ember.samples = 12
    scene.cycles.use_layer_samples = mode
    scene.view_layers[0].samples = layer
    assert render_settings(scene, None, view_layer=scene.view_layers[0]).samples == expected
    assert render_settings(scene, None).samples == 12   # the viewport and bakes keep the scene's


def test_a_render_takes_the_layer_samples(capfd):
    scene = stage()
    scene.ember.samples = 8
    scene.view_layers[0].samples = 3
    render_to_array(scene, "EMBER", 8)
    assert "3/3 samples" in capfd.readouterr().out
