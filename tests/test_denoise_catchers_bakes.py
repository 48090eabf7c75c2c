"""What Cycles denoises besides a render's Combined, and Ember with it (engine/film_denoise.py, engine/bake.py):

- Shadow catchers (src/integrator/denoiser_oidn.cpp denoise_buffer): the Shadow Catcher pass, with a stand-in
  albedo, and the matte; the shadow of Combined (in a transparent film's alpha) is read from the denoised pass
  (kernel/film/read.h, film_calculate_shadow_catcher_matte_with_shadow).
- Bakes (blender/session.cpp bake_setup_pass keeps the denoiser for passes that support it, scene/pass.cpp):
  Combined and Shadow bakes are denoised when Denoise is on, the other bakes are not.

Denoised images are not bit-comparable across engines (each denoises its own noise), so what is compared is
what a denoiser promises: the denoised image is much closer to a converged one (Cycles' at REFERENCE_SPP) than
the noisy one, and the two engines' denoised images are much closer to each other than their noisy ones are
(measured figures beside each bound). The noisy passes stay exactly what a render without denoising gives, and
Combined's alpha follows Cycles' formula from the denoised pass to float precision.
"""
import os
import tempfile

import bpy
import numpy as np
import pytest

from bpy_helpers import configure_engine
from ember.engine import denoise as dn

pytestmark = pytest.mark.skipif(not dn.available()[0], reason="OpenImageDenoise is not available here")

LOW_SPP, REFERENCE_SPP = 4, 256
SEEDS = (1, 2)


def rmse(a, b) -> float:
    return float(np.sqrt(((np.asarray(a, np.float64) - b) ** 2).mean()))


# ---------------------------------------------------------------- shadow catchers
def _catcher_scene(transparent: bool, catcher_pass: bool):
    """test_shadow_catcher's ball on a catcher floor, under a wider sun (a soft, noisy shadow), with the
    Denoising Data passes (Noisy Image, Noisy Shadow Catcher)."""
    from test_shadow_catcher import _scene
    scene, _, _ = _scene(transparent, catcher_pass)
    bpy.data.objects["Sun"].data.angle = 0.6
    layer = scene.view_layers[0]
    layer.ember.denoising_store_passes = layer.cycles.denoising_store_passes = True
    return scene


def _render(scene, engine: str, samples: int, seed: int, denoise: bool) -> dict:
    """{pass name: (H, W, C) float32} of a render (Combined RGBA, the others RGB), row 0 at the top."""
    from exr import read_multilayer
    configure_engine(scene, engine, samples, seed, denoise=denoise)
    settings = scene.render.image_settings
    settings.media_type, settings.color_depth = "MULTI_LAYER_IMAGE", "32"
    with tempfile.TemporaryDirectory() as tmp:
        scene.render.filepath = os.path.join(tmp, "layers.exr")
        bpy.ops.render.render(write_still=True)
        parts, _ = read_multilayer(scene.render.filepath)
    return {name.split(".")[-1]: np.stack([planes[c] for c in "RGBA" if c in planes], axis=-1)
            for name, planes in parts.items() if any(c in planes for c in "RGBA")}


@pytest.fixture(scope="module")
def catcher_renders():
    """Renders of the catcher scene on a transparent film: {"reference": Cycles' converged render with the pass,
    "alpha reference": its converged Combined alpha without the pass, "plain": Ember's without denoising,
    (engine, pass on): [denoised renders, one per SEEDS]}."""
    scene = _catcher_scene(transparent=True, catcher_pass=True)
    out = {"reference": _render(scene, "CYCLES", REFERENCE_SPP, 7, denoise=False),
           "plain": _render(scene, "EMBER", LOW_SPP, SEEDS[0], denoise=False)}
    for engine in ("EMBER", "CYCLES"):
        out[engine, True] = [_render(scene, engine, LOW_SPP, seed, denoise=True) for seed in SEEDS]
    scene.view_layers[0].ember.use_pass_shadow_catcher = scene.view_layers[0].cycles.use_pass_shadow_catcher = False
    out["alpha reference"] = _render(scene, "CYCLES", REFERENCE_SPP, 7, denoise=False)["Combined"][..., 3]
    for engine in ("EMBER", "CYCLES"):
        out[engine, False] = [_render(scene, engine, LOW_SPP, seed, denoise=True) for seed in SEEDS]
    return out


def pooled(pairs) -> float:
    """The RMSE over several (image, reference) pairs."""
    return float(np.sqrt(np.mean([rmse(a, b) ** 2 for a, b in pairs])))


def test_shadow_catcher_pass_is_denoised_as_cycles(catcher_renders):
    """The Shadow Catcher pass is denoised: closer to the converged pass than the noisy one (by 0.65-0.75 of the
    error over three seeds, bpy 5.0 and 5.3; Cycles' 0.56-0.83: the pass is mostly 1, its error mostly at the
    ball's outline, which neither denoiser can resolve at LOW_SPP), and much closer to Cycles' denoised pass than
    the two noisy ones are to each other (0.50-0.62); its mean as Cycles' (differences up to 0.0013). (The
    engines' noisy passes differ in noise, Cycles 5.0's less than 5.3's, so their denoised errors are not
    compared with each other.) The Noisy Shadow Catcher pass is the pass of a render without denoising,
    exactly."""
    r = catcher_renders
    reference = r["reference"]["Shadow Catcher"]
    ember, cycles = r["EMBER", True], r["CYCLES", True]
    assert {"Shadow Catcher", "Noisy Shadow Catcher"} <= set(ember[0])
    np.testing.assert_array_equal(ember[0]["Noisy Shadow Catcher"], r["plain"]["Shadow Catcher"])
    denoised = pooled((e["Shadow Catcher"], reference) for e in ember)
    noisy = pooled((e["Noisy Shadow Catcher"], reference) for e in ember)
    assert denoised < 0.85 * noisy, (denoised, noisy)
    apart = pooled((e["Noisy Shadow Catcher"], c["Noisy Shadow Catcher"]) for e, c in zip(ember, cycles))
    close = pooled((e["Shadow Catcher"], c["Shadow Catcher"]) for e, c in zip(ember, cycles))
    assert close < 0.75 * apart, (close, apart)
    for e, c in zip(ember, cycles):
        np.testing.assert_allclose(e["Shadow Catcher"].mean(axis=(0, 1)), c["Shadow Catcher"].mean(axis=(0, 1)),
                                   atol=0.003)


def test_transparent_film_alpha_takes_the_denoised_shadow(catcher_renders):
    """On a transparent film Combined's alpha is Cycles' (1 - a)(1 - clamp(mean(denoised pass))) + a, a the
    matte's alpha as rendered (what Combined's alpha is with the pass on), to float precision; its colour is the
    denoised matte either way. The alpha is closer to the converged one than the noisy alpha (0.63-0.78 of the
    error over three seeds, Cycles' 0.61-0.79), and closer to Cycles' denoised alpha than the noisy alphas are to
    each other (0.63-0.75)."""
    r = catcher_renders
    for split, ember in zip(r["EMBER", True], r["EMBER", False]):
        a = split["Combined"][..., 3]
        shadow = np.clip(split["Shadow Catcher"].mean(axis=-1), 0.0, 1.0)
        np.testing.assert_allclose(ember["Combined"][..., 3], (1 - a) * (1 - shadow) + a, atol=1e-6)
        np.testing.assert_allclose(ember["Combined"][..., :3], split["Combined"][..., :3], atol=1e-6)
    reference = r["alpha reference"]
    ember, cycles = r["EMBER", False], r["CYCLES", False]
    denoised = pooled((e["Combined"][..., 3], reference) for e in ember)
    noisy = pooled((e["Noisy Image"][..., 3], reference) for e in ember)
    assert denoised < 0.85 * noisy, (denoised, noisy)
    apart = pooled((e["Noisy Image"][..., 3], c["Noisy Image"][..., 3]) for e, c in zip(ember, cycles))
    close = pooled((e["Combined"][..., 3], c["Combined"][..., 3]) for e, c in zip(ember, cycles))
    assert close < 0.85 * apart, (close, apart)


def test_each_catcher_denoise_reads_what_cycles_reads(monkeypatch):
    """The two denoises of a film with shadow catchers and their guides: the Shadow Catcher pass with the normal
    and Cycles' stand-in albedo of 0.5, never prefiltered; then the matte with the albedo and normal passes."""
    from ember.engine import film_denoise
    calls = []

    def spy(read, height, width, write, **options):
        whole = (slice(0, height), slice(0, width))
        calls.append((read("color", *whole), read("albedo", *whole), options.get("noise_free", ())))
        return dn.denoise_image(read, height, width, write, **options)
    monkeypatch.setattr(film_denoise, "denoise_image", spy)
    scene = _catcher_scene(transparent=True, catcher_pass=True)
    ember = _render(scene, "EMBER", LOW_SPP, 1, denoise=True)
    assert len(calls) == 2
    (shadow, stand_in, free), (matte, albedo, none) = calls
    np.testing.assert_array_equal(shadow, ember["Noisy Shadow Catcher"])
    assert np.all(stand_in == 0.5) and free == ("albedo",)
    np.testing.assert_allclose(albedo, ember["Denoising Albedo"], atol=1e-6)
    assert none == () and not np.all(albedo == 0.5)
    assert matte.shape == shadow.shape


@pytest.mark.parametrize("transparent", [False, True])
def test_catcher_film_through_an_identity_denoiser_is_its_own_combined(monkeypatch, transparent):
    """With a denoiser that hands its input back, the film's denoised image (a final render's tiles, the
    viewport's and progressive previews) is the film's own Combined, on an opaque film (the matte over the world
    darkened by the shadow) and a transparent one (the shadow in alpha), adaptive sampling's per-pixel counts
    included: the denoised pieces are put together as the film puts the noisy ones."""
    from bpy_helpers import export_current
    from ember.engine import film_denoise
    from ember.kernels import Renderer, RenderSettings

    def identity(read, height, width, write, **options):
        whole = (slice(0, height), slice(0, width))
        write(*whole, read("color", *whole))
        return True
    monkeypatch.setattr(film_denoise, "denoise_image", identity)
    _catcher_scene(transparent, catcher_pass=False)
    settings = RenderSettings(samples=16, seed=3, transparent_background=transparent, adaptive_threshold=0.05,
                              adaptive_min_samples=4, passes=("denoising_albedo", "denoising_normal"))
    with Renderer(export_current().scene, threads=2) as renderer:
        film = renderer.render(settings).film
    assert film.catchers and film.pixel_samples.shape[1] > 1 and len(np.unique(film.pixel_samples)) > 1
    np.testing.assert_allclose(film_denoise.denoised_film(film, "HIGH", "ACCURATE", 1), film.resolve(), atol=1e-6)


# ---------------------------------------------------------------- bakes
BAKE_SIZE = 64


@pytest.fixture(scope="module")
def bake_scene():
    """A floor baked into a BAKE_SIZE image: checkered in 4 x 4 squares (texture for the albedo to keep), under a
    cube and a wide sun (a soft, noisy shadow) and a blue-grey sky. Returns (scene, floor, image)."""
    from bpy_helpers import new_scene, set_world
    from test_bake import _image_node_material
    scene = new_scene(32, 32)
    set_world(scene, color=(0.3, 0.4, 0.5), strength=1.0)
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    floor = bpy.context.active_object
    image = bpy.data.images.new("floor bake", BAKE_SIZE, BAKE_SIZE, float_buffer=True)
    floor.data.materials.append(_image_node_material("floor", image))
    tree = floor.data.materials[0].node_tree
    checker = tree.nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = 4.0
    checker.inputs["Color1"].default_value = (0.8, 0.3, 0.2, 1.0)
    checker.inputs["Color2"].default_value = (0.2, 0.6, 0.8, 1.0)
    tree.links.new(tree.nodes.new("ShaderNodeTexCoord").outputs["UV"], checker.inputs["Vector"])
    tree.links.new(checker.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.2, 0.1, 0.6))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy, sun.data.angle = 3.0, 0.5
    sun.rotation_euler = (0.5, 0.2, 0.3)
    scene.collection.objects.link(sun)
    return scene, floor, image


def _bake(scene, target, image, engine: str, kind: str, samples: int, seed: int, denoise: bool) -> np.ndarray:
    """test_bake's bake of `kind` into target's image, with each engine's Denoise on or off."""
    configure_engine(scene, engine, samples, seed=seed, max_bounces=3, denoise=denoise)
    view_layer = bpy.context.view_layer
    for ob in view_layer.objects:
        ob.select_set(ob == target)
    view_layer.objects.active = target
    bpy.ops.object.bake(type=kind, use_clear=True, margin=0)
    pixels = np.empty(image.size[0] * image.size[1] * 4, np.float32)
    image.pixels.foreach_get(pixels)
    return pixels.reshape(image.size[1], image.size[0], 4)


@pytest.mark.parametrize("kind", ["COMBINED", "SHADOW"])
def test_combined_and_shadow_bakes_are_denoised_as_cycles(bake_scene, kind):
    """With Denoise on, a Combined or Shadow bake is much closer to the converged bake than without (Combined
    0.37-0.39 of the error, Shadow 0.18-0.19, over two seeds), as close as Cycles' denoised bake is (0.99-1.06
    times its error), and much closer to Cycles' denoised bake than the two noisy bakes are to each other
    (0.12-0.18); alpha stays as baked."""
    scene, floor, image = bake_scene
    reference = _bake(scene, floor, image, "CYCLES", kind, REFERENCE_SPP, 7, False)[..., :3]
    off, on = (_bake(scene, floor, image, "EMBER", kind, LOW_SPP, 1, d) for d in (False, True))
    c_off, c_on = (_bake(scene, floor, image, "CYCLES", kind, LOW_SPP, 1, d) for d in (False, True))
    denoised, noisy = rmse(on[..., :3], reference), rmse(off[..., :3], reference)
    assert denoised < 0.5 * noisy, (denoised, noisy)
    cycles_denoised = rmse(c_on[..., :3], reference)
    assert denoised < 1.25 * cycles_denoised, (denoised, cycles_denoised)
    apart, close = rmse(off[..., :3], c_off[..., :3]), rmse(on[..., :3], c_on[..., :3])
    assert close < 0.35 * apart, (close, apart)
    np.testing.assert_array_equal(on[..., 3], off[..., 3])


@pytest.mark.parametrize("kind", ["DIFFUSE", "AO"])
def test_other_bakes_are_not_denoised(bake_scene, kind):
    """Cycles turns the denoiser off for bakes whose pass does not support it: Diffuse or AO, Denoise on or off,
    bake the same."""
    scene, floor, image = bake_scene
    off, on = (_bake(scene, floor, image, "EMBER", kind, LOW_SPP, 1, d) for d in (False, True))
    np.testing.assert_array_equal(on, off)


def test_command_line_bake_denoises_as_asked(bake_scene, tmp_path):
    """python -m ember bake --denoise / --no-denoise: the bake of the operator with Denoise on / off (to float
    rounding: the line's process sums its texels' samples in another order, 4e-5 apart)."""
    from ember.engine.cli import main
    scene, floor, image = bake_scene
    expected = {d: _bake(scene, floor, image, "EMBER", "COMBINED", LOW_SPP, 1, d) for d in (False, True)}
    name = floor.name   # (the line's main opens the file here: the fixture's objects are gone after; last test)
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    for denoise, flag in ((False, "--no-denoise"), (True, "--denoise")):
        out = tmp_path / f"{flag}.exr"
        assert main(["bake", str(blend), "--type", "combined", "--object", name, "-o", str(out), flag,
                     "--margin", "0", "--resolution", f"{BAKE_SIZE}x{BAKE_SIZE}", "--samples", str(LOW_SPP),
                     "--seed", "1", "--max-bounces", "3", "--threads", "2"]) == 0
        loaded = bpy.data.images.load(str(out), check_existing=False)
        pixels = np.empty(BAKE_SIZE * BAKE_SIZE * 4, np.float32)
        loaded.pixels.foreach_get(pixels)
        bpy.data.images.remove(loaded)
        np.testing.assert_allclose(pixels.reshape(BAKE_SIZE, BAKE_SIZE, 4), expected[denoise], rtol=1e-4, atol=1e-5)
