"""Shadow catchers (kernels/shadow_catcher.py) against Cycles: a red ball on a catcher floor under a sun and a
sky-like gradient world, rendered by both engines with an opaque and a transparent film, with and without the
Shadow Catcher pass; a glossy catcher that reflects the ball, a light and an emitter (hidden from the camera)
that are no shadow catchers, a chrome ball that reflects the floor. Colour, alpha and the pass agree within
noise (replicate renders, tests/bpy_helpers.py). Kernel level: without a shadow catcher nothing is recorded;
worker processes record the planes bit for bit as threads do. (Viewport edits: test_viewport_updates.py.)"""
from __future__ import annotations

import math
import os
import tempfile

import numpy as np
import pytest

from bpy_helpers import REPLICATE_SEEDS, configure_engine, manual_world_map

SAMPLES = 64
SIZE = 48
# Rows and columns of the image left of the ball, where the sun casts its shadow on the floor.
SHADOW = (slice(24, 36), slice(0, 16))


def _gradient_world(scene):
    """A sky-like world without files: blue above, a bright warm horizon, a dim ground, varying with the
    direction's height (so that it is sampled as a light, as an HDRI is)."""
    import bpy
    world = bpy.data.worlds.new("Sky")
    scene.world = world
    # A small map for the world's light sampling (both engines read it): Cycles' default, 1024 wide, took most of
    # each of its renders here; the images' expectation does not depend on it.
    manual_world_map(world, 256)
    tree = world.node_tree
    tree.nodes.clear()
    coords = tree.nodes.new("ShaderNodeTexCoord")
    mapping = tree.nodes.new("ShaderNodeMapping")   # z in [-1, 1] -> x in [0, 1]
    mapping.inputs["Rotation"].default_value = (0.0, math.pi / 2, 0.0)
    mapping.inputs["Scale"].default_value = (0.5, 0.5, 0.5)
    mapping.inputs["Location"].default_value = (0.5, 0.0, 0.0)
    gradient = tree.nodes.new("ShaderNodeTexGradient")
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    elements = ramp.color_ramp.elements
    elements[0].position, elements[0].color = 0.3, (0.15, 0.12, 0.1, 1.0)
    elements[1].position, elements[1].color = 1.0, (0.2, 0.35, 0.8, 1.0)
    horizon = elements.new(0.52)
    horizon.color = (1.6, 1.3, 0.9, 1.0)
    background = tree.nodes.new("ShaderNodeBackground")
    out = tree.nodes.new("ShaderNodeOutputWorld")
    tree.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], gradient.inputs["Vector"])
    tree.links.new(gradient.outputs["Fac"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], background.inputs["Color"])
    tree.links.new(background.outputs["Background"], out.inputs["Surface"])


def _scene(transparent=False, catcher_pass=False, floor=None):
    """The ball on the catcher floor (floor: a function making its material, None for a grey diffuse one);
    returns (scene, floor, ball)."""
    import bpy
    from bpy_helpers import diffuse_material, new_scene, quad_object
    scene = new_scene(SIZE, SIZE)
    _gradient_world(scene)
    floor = quad_object("Floor", (-5, -4, 0), (10, 0, 0), (0, 10, 0),
                        floor() if floor else diffuse_material("Ground", (0.7, 0.7, 0.7)))
    floor.is_shadow_catcher = True
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=0.7, location=(-0.2, 0.3, 0.7))
    ball = bpy.context.object
    ball.name = "Ball"
    ball.data.materials.append(diffuse_material("Red", (0.8, 0.12, 0.08)))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy, sun.data.angle = 3.0, 0.1
    sun.rotation_euler = (1.0, 0.0, 0.8)
    scene.collection.objects.link(sun)
    scene.render.film_transparent = transparent
    layer = scene.view_layers[0]
    layer.cycles.use_pass_shadow_catcher = catcher_pass
    layer.ember.use_pass_shadow_catcher = catcher_pass
    return scene, floor, ball


def _render(scene, engine: str, samples: int, seed: int) -> dict:
    """{pass name: (H, W, C) float32} of one render, row 0 at the top (Combined RGBA, Shadow Catcher RGB)."""
    import bpy
    from exr import read_exr, read_multilayer
    configure_engine(scene, engine, samples, seed)
    settings = scene.render.image_settings
    settings.media_type, settings.color_depth = "MULTI_LAYER_IMAGE", "32"
    with tempfile.TemporaryDirectory() as tmp:
        scene.render.filepath = os.path.join(tmp, "layers.exr")
        bpy.ops.render.render(write_still=True)
        try:
            parts, _ = read_multilayer(scene.render.filepath)
        except AssertionError:   # Combined alone: a single-part file
            parts = {"Combined": {name.split(".")[-1]: plane for name, plane in
                                  read_exr(scene.render.filepath).items()}}
    return {name.split(".")[-1]: np.stack([planes[c] for c in "RGBA" if c in planes], axis=-1)
            for name, planes in parts.items()}


def _replicates(scene, engine: str, samples: int = SAMPLES) -> dict:
    """{pass: (mean, variance of the mean)} over renders with REPLICATE_SEEDS sharing `samples`."""
    renders = [_render(scene, engine, samples // len(REPLICATE_SEEDS), seed) for seed in REPLICATE_SEEDS]
    out = {}
    for name in renders[0]:
        stack = np.stack([r[name] for r in renders]).astype(np.float64)
        out[name] = (stack.mean(axis=0), stack.var(axis=0, ddof=1) / len(renders))
    return out


def _assert_parity(scene, names=("Combined",), block: int = 8, z_block: float = 4.5, z_whole: float = 4.0,
                   mean_tol: float = 0.02) -> dict:
    """Every pass of `names`, each channel: every block x block sum of Ember's mean within z_block standard
    errors of Cycles' (the noise of both, from their replicates; blocks without noise must be equal to float
    rounding), and the whole image's mean within z_whole standard errors or mean_tol of Cycles' (relative).
    Combined and the pass are read from ratios and clamps of the pixels' sums (Cycles' film/read.h), whose
    expectation at a finite sample count moves with the pixels' noise, which differs between the engines: the
    transparent film's mean alpha here is 1% above Cycles' at 16 samples a render, 0.4% at 64, -0.1% at 256;
    hence a relative margin for the whole image, as compare_to_cycles'. Returns {pass: (Cycles' mean, Ember's
    mean)}."""
    cycles, ember = _replicates(scene, "CYCLES"), _replicates(scene, "EMBER")
    out = {}
    for name in names:
        (c, var_c), (e, var_e) = cycles[name], ember[name]
        assert c.shape == e.shape, name
        h, w, k = c.shape

        def blocks(x):
            return x.reshape(h // block, block, w // block, block, k).sum(axis=(1, 3))
        diff, spread = blocks(e) - blocks(c), np.sqrt(blocks(var_c) + blocks(var_e))
        spread = np.maximum(spread, 1e-5 * np.maximum(np.abs(blocks(c)), 1.0))   # float rounding, not noise
        z = np.abs(diff) / spread
        assert z.max() < z_block, (name, z.max(), np.unravel_index(np.argmax(z), z.shape))
        mean_c, mean_e = c.mean(axis=(0, 1)), e.mean(axis=(0, 1))
        se = np.sqrt(var_c.sum(axis=(0, 1)) + var_e.sum(axis=(0, 1))) / (h * w)
        assert np.all(np.abs(mean_e - mean_c) <= np.maximum(z_whole * se, mean_tol * np.abs(mean_c)) + 1e-7), \
            (name, mean_c, mean_e, se)
        out[name] = (c, e)
    return out


def _see_through():
    """A floor material that lets 40% of the light through (a Transparent BSDF mixed in)."""
    import bpy
    mat = bpy.data.materials.new("Veil")
    tree = mat.node_tree
    tree.nodes.clear()
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.4
    tree.links.new(tree.nodes.new("ShaderNodeBsdfDiffuse").outputs[0], mix.inputs[1])
    tree.links.new(tree.nodes.new("ShaderNodeBsdfTransparent").outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    return mat


@pytest.mark.parametrize("transparent, see_through", [(False, False), (True, False), (False, True)])
def test_combined_shows_the_shadow_as_cycles(transparent, see_through):
    """Without the Shadow Catcher pass Combined is Cycles' approximate one: the ball over its shadow, and the
    floor gone. On an opaque film the shadow darkens the world behind the floor; on a transparent one the
    floor is transparent but for the shadow, which is black in alpha. A floor that lets light through: what
    the camera sees through it counts in the Environment pass the floor lies over as Cycles counts it."""
    scene, _, _ = _scene(transparent, floor=_see_through if see_through else None)
    e = _assert_parity(scene)["Combined"][1]
    if see_through:
        return
    bottom, shadow = e[-6:], e[SHADOW]   # the floor out of the shadow, and in it
    if transparent:
        assert bottom[..., 3].mean() < 0.05 and np.abs(bottom[..., :3]).max() < 1e-6
        assert e[..., 3].max() > 0.99 and shadow[..., 3].max() > 0.3   # the ball opaque, the shadow half
    else:
        assert np.all(e[..., 3] == 1.0)
        floor = shadow[..., :3].mean(axis=-1)
        assert (1.0 - floor.min(axis=1) / floor.max(axis=1)).max() > 0.3   # the world darkened by the shadow


def test_shadow_catcher_pass_and_matte():
    """With the Shadow Catcher pass Combined is the matte (the ball alone, the floor transparent and black) and
    the pass is the factor the ball puts on the floor: below 1 in its shadow, 1 on the world."""
    scene, _, _ = _scene(transparent=False, catcher_pass=True)
    passes = _assert_parity(scene, ("Combined", "Shadow Catcher"))
    combined, catcher = passes["Combined"][1], passes["Shadow Catcher"][1]
    assert combined[-6:, :, 3].max() < 1e-6 and np.abs(combined[-6:, :, :3]).max() < 1e-6
    assert catcher[SHADOW].min() < 0.6 and np.abs(catcher[:4] - 1.0).max() < 1e-6


def test_reflections_and_lights_that_are_no_catchers():
    """A glossy catcher reflects the ball (the pass tinted red there), a point light that is no shadow catcher
    and an emitting sphere that the camera does not see light the floor in the render but not in the catcher's
    own light (the pass above 1). A chrome ball shows the floor as an ordinary object (in the matte: only camera
    paths split at a catcher)."""
    import bpy
    from bpy_helpers import emission_material, node_material
    scene, _, _ = _scene(transparent=True, catcher_pass=True, floor=lambda: node_material(
        "Polished", "ShaderNodeBsdfPrincipled", Base_Color=(0.5, 0.5, 0.5), Roughness=0.25))
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.data.energy, lamp.data.shadow_soft_size = 150.0, 0.2
    lamp.location = (1.8, -1.0, 1.5)
    lamp.is_shadow_catcher = False
    scene.collection.objects.link(lamp)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8, radius=0.25, location=(-1.7, -1.2, 0.6))
    glow = bpy.context.object
    glow.data.materials.append(emission_material("Glow", (0.3, 1.0, 0.4), 8.0))
    glow.visible_camera = False
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=0.45, location=(1.2, 0.8, 0.45))
    bpy.context.object.data.materials.append(node_material("Chrome", "ShaderNodeBsdfPrincipled",
                                                           Base_Color=(0.9, 0.9, 0.9), Metallic=1.0, Roughness=0.15))
    catcher = _assert_parity(scene, ("Combined", "Shadow Catcher"))["Shadow Catcher"][1]
    assert catcher[..., 0].max() > 1.5   # the lamp's and the glow's light on the floor
    red = catcher[..., 0] - catcher[..., 1:].mean(axis=-1)
    assert red.max() > 0.2   # the ball's reflection


def test_object_visibility_panels_show_for_ember():
    """Object > Visibility > Mask (Shadow Catcher, Holdout) and Ray Visibility, for meshes and lights."""
    import bpy
    from types import SimpleNamespace
    _, floor, _ = _scene()
    lamp = bpy.data.objects["Sun"]
    for panel in (bpy.types.EMBER_OBJECT_PT_visibility_mask, bpy.types.EMBER_OBJECT_PT_visibility_rays):
        for ob in (floor, lamp):
            assert panel.poll(SimpleNamespace(engine="EMBER", object=ob))
        assert not panel.poll(SimpleNamespace(engine="CYCLES", object=floor))


# ---- Kernel level ---------------------------------------------------------------------------------------

def test_without_catchers_nothing_is_recorded():
    """No shadow catcher: the settings get no planes (the waves record nothing more), and the Shadow Catcher
    pass reads 1 everywhere, as Cycles'."""
    from ember.kernels import RenderSettings, shadow_catcher
    from ember.kernels.film import Film
    settings = RenderSettings(passes=("shadow_catcher",))
    assert shadow_catcher.with_planes(settings, None) is settings
    assert shadow_catcher.with_planes(settings, np.array([63, 63 | 128], np.uint8)) is settings
    planes = shadow_catcher.with_planes(RenderSettings(), np.array([63, 63 | 64], np.uint8)).passes
    assert planes == ("catcher", "catcher_matte", "catcher_samples", "environment")
    film = Film(4, 3, passes=settings.passes)
    assert film.aux == {} and np.all(film.resolve_pass("shadow_catcher") == 1.0)


def test_worker_processes_record_the_planes_as_threads():
    from bpy_helpers import export_current
    from ember.kernels import Renderer, RenderSettings
    _scene(transparent=True)
    scene = export_current().scene
    settings = RenderSettings(samples=8, seed=3, wave_size=512, transparent_background=True)
    images = []
    for processes in (False, True):
        with Renderer(scene, threads=2, processes=processes) as renderer:
            if processes:
                assert renderer.crew.wait_for_workers() == 1, renderer.crew.worker_failures
            result = renderer.render(settings)
            assert not processes or renderer.crew.remote_waves > 0
            images.append((result.image, {k: np.asarray(v) for k, v in result.film.aux.items()}))
    np.testing.assert_array_equal(images[0][0], images[1][0])
    assert images[0][1].keys() == images[1][1].keys() == {"catcher", "catcher_matte", "catcher_samples"}
    for key in images[0][1]:
        np.testing.assert_array_equal(images[0][1][key], images[1][1][key], err_msg=key)
