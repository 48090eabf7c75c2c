"""Film > Exposure (Cycles' own setting, scene.cycles.film_exposure, shown in Ember's Film panel) against Cycles.

Cycles multiplies what it reads out of the film by the exposure for the passes it marks use_exposure
(scene/pass.cpp: Combined's colour, the light passes, Emission, Environment, the light groups) and leaves the
rest (alpha, the colour and data passes, the Shadow Catcher pass, which is a ratio); bakes take it as their
pass does. Which passes scale, and by how much, is read from Cycles itself: the same seed rendered at exposure
1 and at EXPOSURE gives each pass's factor without noise. Before, Ember ignored the setting."""
import numpy as np
import bpy
import pytest

from bpy_helpers import (add_lamp, configure_engine, diffuse_material, emission_material, new_scene,
                         quad_object, set_world)
from exr import render_multilayer

EXPOSURE = 2.5
# Blender's pass names, with the light group's; the Noise pass is Ember's own (no Cycles counterpart).
PASSES = ("Combined", "Diffuse Direct", "Diffuse Indirect", "Diffuse Color", "Glossy Direct", "Glossy Color",
          "Emission", "Environment", "Depth", "Mist", "Shadow Catcher", "Combined_Key")


def exposure_scene(exposure: float):
    """A floor, a glossy ball, an emissive panel, a shadow catcher, an area lamp in light group Key and a grey
    world, on a transparent film."""
    scene = new_scene(24, 16)
    set_world(scene, (0.3, 0.3, 0.35), 1.0)
    quad_object("Floor", (-4, -4, 0), (8, 0, 0), (0, 8, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    catcher = quad_object("Catcher", (-1.8, -1.5, 0.01), (1.0, 0, 0), (0, 1.0, 0), diffuse_material("C"))
    catcher.is_shadow_catcher = True
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(-0.7, 0, 0.6), segments=16, ring_count=8)
    ball = bpy.data.materials.new("Gloss")
    ball.node_tree.nodes["Principled BSDF"].inputs["Metallic"].default_value = 1.0
    ball.node_tree.nodes["Principled BSDF"].inputs["Roughness"].default_value = 0.3
    bpy.context.object.data.materials.append(ball)
    quad_object("Panel", (0.5, 1.0, 0.2), (1.0, 0, 0), (0, 0.2, 0.8), emission_material("Glow", (1, 0.6, 0.3), 4.0))
    key = add_lamp(scene, "Key", "AREA", (0, -2.5, 3.5), (0.6, 0, 0), energy=200.0, size=1.0)
    layer = scene.view_layers[0]
    layer.lightgroups.add(name="Key")
    key.lightgroup = "Key"
    for name in ("use_pass_diffuse_direct", "use_pass_diffuse_indirect", "use_pass_diffuse_color",
                 "use_pass_glossy_direct", "use_pass_glossy_color", "use_pass_emit", "use_pass_environment",
                 "use_pass_z", "use_pass_mist"):
        setattr(layer, name, True)
    layer.cycles.use_pass_shadow_catcher = layer.ember.use_pass_shadow_catcher = True
    layer.ember.use_pass_noise = True
    scene.render.film_transparent = True
    scene.cycles.film_exposure = exposure
    return scene


def render(engine: str, exposure: float) -> dict:
    scene = exposure_scene(exposure)
    configure_engine(scene, engine, 4, seed=3)
    parts, _ = render_multilayer(scene)
    layer = scene.view_layers[0].name
    out = {}
    for name in PASSES + (("Noise",) if engine == "EMBER" else ()):
        planes = parts[f"{layer}.{name}"]
        out[name] = np.stack([planes[c] for c in sorted(planes, key="RGBAXYZ".find)], axis=-1).astype(np.float64)
    return out


@pytest.fixture(scope="module")
def renders():
    return {(engine, e): render(engine, e) for engine in ("CYCLES", "EMBER") for e in (1.0, EXPOSURE)}


def factors(plain: np.ndarray, exposed: np.ndarray) -> np.ndarray:
    """Per channel, the ratio exposed / plain over the pixels where plain is clearly nonzero (NaN if none)."""
    ratios = []
    for c in range(plain.shape[-1]):
        a, b = plain[..., c], exposed[..., c]
        ok = np.abs(a) > 1e-4
        ratios.append(np.median(b[ok] / a[ok]) if ok.any() else np.nan)
    return np.array(ratios)


@pytest.mark.parametrize("name", PASSES)
def test_pass_scales_as_in_cycles(renders, name):
    """Each channel's factor is Cycles' (EXPOSURE or 1, read off Cycles' two renders), and Ember's render at
    EXPOSURE is its render at 1 times that factor, pixel for pixel (same seed: the same samples)."""
    cycles = factors(renders["CYCLES", 1.0][name], renders["CYCLES", EXPOSURE][name])
    known = ~np.isnan(cycles)
    assert known.any(), f"{name}: Cycles rendered nothing to compare"
    assert np.all(np.isclose(cycles[known], EXPOSURE, rtol=1e-3) | np.isclose(cycles[known], 1.0, rtol=1e-3)), cycles
    expected = np.where(np.isclose(cycles, EXPOSURE, rtol=1e-3), EXPOSURE, 1.0)
    plain, exposed = renders["EMBER", 1.0][name], renders["EMBER", EXPOSURE][name]
    assert np.abs(plain).max() > 0, name
    np.testing.assert_allclose(exposed, plain * expected, rtol=1e-5, atol=1e-7, err_msg=name)


def test_combined_colour_scales_and_alpha_does_not(renders):
    """Cycles scales Combined's RGB, not its alpha (the film is transparent: the alpha varies), and so does Ember."""
    for engine in ("CYCLES", "EMBER"):
        plain = renders[engine, 1.0]["Combined"]
        assert plain[..., 3].min() < 0.5 < plain[..., 3].max(), engine
        np.testing.assert_allclose(factors(plain, renders[engine, EXPOSURE]["Combined"]), [EXPOSURE] * 3 + [1.0],
                                   rtol=1e-3, err_msg=engine)


def test_noise_pass_scales_as_the_variance(renders):
    """Ember's Noise pass estimates Combined's variance, which the exposure scales by its square."""
    plain, exposed = renders["EMBER", 1.0]["Noise"], renders["EMBER", EXPOSURE]["Noise"]
    assert plain.max() > 0
    np.testing.assert_allclose(exposed, plain * EXPOSURE ** 2, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("kind, pass_filter", [("EMIT", ()), ("COMBINED", ()), ("DIFFUSE", ("COLOR",)),
                                               ("DIFFUSE", ("DIRECT", "INDIRECT", "COLOR"))])
def test_bake_scales_as_in_cycles(kind, pass_filter):
    """A bake takes the exposure as its pass does in Cycles (checked: Cycles' Emit bake doubles at exposure 2):
    Combined, Emit and light, not a colour alone."""
    from bpy_helpers import configure_engine as configure
    results = {}
    for engine in ("CYCLES", "EMBER"):
        for exposure in (1.0, EXPOSURE):
            bpy.ops.wm.read_factory_settings(use_empty=True)
            scene = new_scene(8, 8)
            configure(scene, engine, 4, seed=1)
            set_world(scene, (0.5, 0.5, 0.5), 1.0)
            add_lamp(scene, "Lamp", "POINT", (0, 0, 2), energy=50.0)
            material = diffuse_material("Plane", (0.8, 0.5, 0.3))
            tree = material.node_tree
            glow = tree.nodes.new("ShaderNodeEmission")
            glow.inputs["Strength"].default_value = 0.5
            add = tree.nodes.new("ShaderNodeAddShader")
            output = tree.nodes["Material Output"]
            tree.links.new(output.inputs["Surface"].links[0].from_socket, add.inputs[0])
            tree.links.new(glow.outputs[0], add.inputs[1])
            tree.links.new(add.outputs[0], output.inputs["Surface"])
            plane = quad_object("Plane", (-1, -1, 0), (2, 0, 0), (0, 2, 0), material)
            image = bpy.data.images.new("Bake", 8, 8, float_buffer=True)
            texture = tree.nodes.new("ShaderNodeTexImage")
            texture.image = image
            tree.nodes.active = texture
            bpy.context.view_layer.objects.active = plane
            plane.select_set(True)
            scene.cycles.film_exposure = exposure
            scene.render.bake.use_pass_direct = "DIRECT" in pass_filter
            scene.render.bake.use_pass_indirect = "INDIRECT" in pass_filter
            scene.render.bake.use_pass_color = "COLOR" in pass_filter
            bpy.ops.object.bake(type=kind)
            results[engine, exposure] = np.array(image.pixels[:]).reshape(8, 8, 4)[2:6, 2:6, :3]
    cycles = results["CYCLES", EXPOSURE].mean() / results["CYCLES", 1.0].mean()
    assert np.isclose(cycles, EXPOSURE, rtol=1e-3) or np.isclose(cycles, 1.0, rtol=1e-3), cycles
    expected = EXPOSURE if np.isclose(cycles, EXPOSURE, rtol=1e-3) else 1.0
    np.testing.assert_allclose(results["EMBER", EXPOSURE], results["EMBER", 1.0] * expected, rtol=1e-5)


def test_viewport_settings_and_adaptive_sampling_take_the_exposure():
    """The viewport renders with the exposure (a change restarts it, as any change of its settings), and adaptive
    sampling judges the exposed image, as Cycles' convergence check (film/adaptive_sampling.h: exposure / samples)."""
    from ember.engine.viewport import viewport_settings
    from ember.kernels.film import Film
    scene = new_scene(8, 8)
    scene.cycles.film_exposure = 3.0
    assert viewport_settings(scene).exposure == 3.0
    rng = np.random.default_rng(5)
    sums = rng.uniform(0.0, 0.2, (8, 8, 4)) * 16
    half = (sums[..., :3] * rng.uniform(0.35, 0.65, (8, 8, 3))).astype(np.float32)
    verdicts = []
    for exposure, scale in ((1.0, 3.0), (3.0, 1.0)):
        film = Film(8, 8, adaptive=True, exposure=exposure)
        film.sums[:] = sums * scale
        film.half[:] = half * scale
        film.pixel_samples[:] = 16
        film.update_convergence(0.05)
        verdicts.append(film.converged.copy())
    np.testing.assert_array_equal(verdicts[0], verdicts[1])
    assert 0 < verdicts[0].sum() < 64   # the threshold decides somewhere: the check can fail
