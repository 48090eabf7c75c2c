"""Values at the edge of float32, not a number, or zero where a size belongs, through Blender, with Cycles as
the reference and a warning naming what was changed:

- Emission and Background strengths whose light exceeds MAX_LIGHT_RADIANCE (1e20 W/(sr m^2), the lights'
  limit) are clamped to it: past it Ember's float32 arithmetic and the denoiser overflow (Cycles drops
  such samples or sums them to inf; at 3.4e38 its emitter renders black).
- A strength that is not a number reads 0: black, as Cycles renders it.
- A camera with a focal length, sensor size or orthographic scale of 0 (or not a number), or an object scale
  of 0, sees nothing of the scene in Cycles; Ember renders the world along its view axis, as Cycles shows a constant world.
- A denoiser that turns a lit image black (pixels near the float32 limit from a node program) leaves the
  noisy image, with a warning.
- A negative emission strength (a surface that subtracts light) renders as in Cycles.
"""
import ctypes

import bpy
import numpy as np
import pytest

from bpy_helpers import (add_camera, compare_to_cycles, diffuse_material, emission_material, export_current,
                         mesh_object, new_scene, render_to_array, set_world)
from test_passes import render as record_render

from ember.engine.export.lights import MAX_LIGHT_RADIANCE


def _panel_scene(strength=1.0, world_strength=1.0):
    """A 16 x 12 frame: an emissive panel (material 'Hot') in front of a grey world, over a diffuse floor."""
    scene = new_scene(16, 12)
    add_camera(scene, (0, -6, 1.0), (0, 0, 1.0))
    mesh_object("Floor", [(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)], [(0, 1, 2, 3)], diffuse_material("Floor"))
    mesh_object("Panel", [(-1, 0, 0.5), (1, 0, 0.5), (1, 0, 1.5), (-1, 0, 1.5)], [(0, 1, 2, 3)],
                emission_material("Hot", strength=strength))
    set_world(scene, color=(0.3, 0.4, 0.5), strength=world_strength)
    return scene


def _panel(image):
    return image[5:7, 6:10, :3]   # pixels the panel covers whole


@pytest.mark.parametrize("where", ["Emission", "Background"])
def test_light_beyond_float32_is_clamped_with_a_warning_and_the_denoised_image_keeps_it(where):
    scene = _panel_scene(**({"strength": 3.4e38} if where == "Emission" else {"world_strength": 3.4e38}))
    warnings = export_current().warnings
    owner = "Material 'Hot': Emission 'Emission' Strength" if where == "Emission" else \
        "World 'World': Background Strength"
    assert any(w.startswith(owner) and "3.4e+38 is too bright" in w and "clamped to 1e+20" in w
               for w in warnings), warnings
    noisy = render_to_array(scene, "EMBER", 2, max_bounces=1)
    assert np.isfinite(noisy).all()
    if where == "Emission":
        np.testing.assert_allclose(_panel(noisy), MAX_LIGHT_RADIANCE, rtol=1e-6)
    else:
        np.testing.assert_allclose(noisy[0, 0, :3], np.array([0.3, 0.4, 0.5]) * MAX_LIGHT_RADIANCE / 0.5, rtol=1e-6)
    denoised = render_to_array(scene, "EMBER", 2, max_bounces=1, denoise=True)
    # The light the denoised image keeps: the panel, or the world seen around it.
    kept = _panel(denoised) if where == "Emission" else denoised[:2, :, :3]
    assert np.isfinite(denoised).all() and kept.min() > 1e18


@pytest.mark.parametrize("where", ["Emission", "Background"])
def test_a_strength_that_is_not_a_number_renders_black_as_in_cycles_with_a_warning(where):
    scene = _panel_scene(**({"strength": float("nan")} if where == "Emission" else {"world_strength": float("nan")}))
    warnings = export_current().warnings
    owner = "Material 'Hot': Emission 'Emission' Strength" if where == "Emission" else \
        "World 'World': Background Strength"
    assert any(w.startswith(owner) and "not a number, read as 0" in w for w in warnings), warnings
    ember = render_to_array(scene, "EMBER", 2, max_bounces=1)
    cycles = render_to_array(scene, "CYCLES", 2, max_bounces=1)
    black = _panel if where == "Emission" else (lambda image: image[0, :, :3])   # the top row sees the world
    assert not black(ember).any() and not black(cycles).any()


def _store(idblock, prop: str, value: float) -> None:
    """Put a float into the ID's own memory under RNA property `prop`, past the interface's limits (a
    file can hold such a value): the property is set to a marker, found in the struct, overwritten."""
    marker = np.float32(12.345678)
    setattr(idblock, prop, float(marker))
    address = idblock.as_pointer()
    floats = np.frombuffer((ctypes.c_float * 512).from_address(address), np.float32)
    where = np.flatnonzero(floats == marker)
    assert len(where) == 1, where
    ctypes.c_float.from_address(address + 4 * int(where[0])).value = value
    assert getattr(idblock, prop) == value or np.isnan(value)


@pytest.mark.parametrize("setting, value, told", [
    ("lens", 0.0, "focal length is 0 mm"),
    ("sensor_width", 0.0, "sensor width of 0 mm"),
    ("lens", float("nan"), "focal length is nan mm"),
    ("ortho_scale", 0.0, "orthographic scale is 0"),
    ("scale", 0.0, "scaled to nothing along an axis"),
])
def test_a_camera_of_zero_size_sees_the_world_as_in_cycles_with_a_warning(setting, value, told):
    """The camera object scaled to 0 (found in a public file: Ember refused to render it, its camera matrix
    singular) is as blind in Cycles."""
    scene = _panel_scene()
    camera = scene.camera.data
    if setting == "scale":
        scene.camera.scale = (1.0, 1.0, value)
    elif setting == "ortho_scale":
        camera.type = "ORTHO"
        camera.ortho_scale = value
    elif value == 0.0:
        _store(camera, setting, value)   # Blender's interface stops at 1 mm
    else:
        setattr(camera, setting, value)
    warnings = export_current().warnings
    assert any(w.startswith(f"Camera '{scene.camera.name}'") and told in w and "sees nothing" in w
               for w in warnings), warnings
    ember = render_to_array(scene, "EMBER", 2, max_bounces=1)
    cycles = render_to_array(scene, "CYCLES", 2, max_bounces=1)
    np.testing.assert_allclose(ember, cycles, rtol=1e-6)
    np.testing.assert_allclose(ember[..., :3], np.broadcast_to([0.3, 0.4, 0.5], ember[..., :3].shape), rtol=1e-6)


def test_a_denoiser_that_blacks_out_the_image_leaves_the_noisy_one_with_a_warning(capsys):
    """A node program drives the emission to 3.4e38 x height: nothing to clamp at export; the denoiser's
    float32 exposure estimate overflows and it returns zeros (Cycles' denoised image is black too)."""
    scene = _panel_scene()
    tree = bpy.data.materials["Hot"].node_tree
    emission = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeEmission")
    coords, split, scale = (tree.nodes.new(kind) for kind in ("ShaderNodeTexCoord", "ShaderNodeSeparateXYZ",
                                                               "ShaderNodeMath"))
    scale.operation = "MULTIPLY"
    scale.inputs[1].default_value = 3.4e38
    tree.links.new(coords.outputs["Generated"], split.inputs[0])
    tree.links.new(split.outputs["Z"], scale.inputs[0])
    tree.links.new(scale.outputs[0], emission.inputs["Strength"])
    capsys.readouterr()
    denoised = record_render(scene, samples=2, use_denoising=True, max_bounces=1).image("Combined")
    assert "denoising failed" in capsys.readouterr().out
    assert np.isfinite(denoised).all() and _panel(denoised).max() > 1e37


@pytest.mark.parametrize("linked", [False, True], ids=["constant", "folded"])
def test_negative_emission_subtracts_light_as_in_cycles(linked):
    """An Emission of Strength -0.5 (typed in, or from a Math node that folds to it) beside a glowing panel: Cycles
    renders the panel below zero and takes its light from the floor, light-sampling it by the size of its emission
    (scene/light_tree.cpp: fabs of the estimate). Before, Ember refused the whole frame ("must be non-negative")."""
    scene = _panel_scene(strength=4.0)
    dark = emission_material("Dark", strength=-0.5)
    if linked:
        tree = dark.node_tree
        times = tree.nodes.new("ShaderNodeMath")
        times.operation, times.inputs[0].default_value, times.inputs[1].default_value = "MULTIPLY", -1.0, 0.5
        node = next(n for n in tree.nodes if n.type == "EMISSION")
        tree.links.new(times.outputs[0], node.inputs["Strength"])
    mesh_object("Dark", [(1.2, 0, 0.5), (2.2, 0, 0.5), (2.2, 0, 1.5), (1.2, 0, 1.5)], [(0, 1, 2, 3)], dark)
    report = compare_to_cycles(scene, samples=64, max_bounces=3, mean_z=4.0)
    assert report["mean_ember"] > 0
