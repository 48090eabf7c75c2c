"""Render passes and denoising through Ember's final render (issue 13).

Blender headless cannot hand a render's passes back to Python, so the session runs here against a
recording stand-in of the RenderEngine (the same calls Blender answers: begin_result, end_result, report,
...), with the real depsgraph; one test renders through bpy.ops.render.render and checks that Blender
received the passes (they reach its multilayer EXR).
"""
from __future__ import annotations

import math
import os
import re
import tempfile

import bpy
import numpy as np
import pytest

from bpy_helpers import diffuse_material, emission_material, new_scene, quad_object, set_world
from ember.engine import passes as engine_passes
from ember.engine.session import FinalRender


class _Rect:
    def __init__(self, store, name, x, y, w, h, channels):
        self.store, self.name, self.box, self.channels = store, name, (x, y, w, h), channels
        self.values = None

    def foreach_set(self, values):
        x, y, w, h = self.box
        self.values = np.asarray(values, np.float32).reshape(h, w, self.channels).copy()

    def merge(self):
        """Blender merges every pass of a sub-result into the render, written or not (unwritten: blank,
        NaN here so that tests see it); a later write wins where rectangles overlap."""
        plane = self.store.setdefault(self.name, {})
        plane.pop(self.box, None)
        x, y, w, h = self.box
        plane[self.box] = self.values if self.values is not None else np.full((h, w, self.channels), np.nan,
                                                                              np.float32)


class _Pass:
    def __init__(self, rect):
        self.rect = rect


class _Result:
    def __init__(self, engine, x, y, w, h):
        self.resolution_x, self.resolution_y = w, h
        passes = {"Combined": 4}
        passes.update({p.name: p.channels for p in engine.registered})
        self.layers = [type("Layer", (), {})()]
        self.layers[0].passes = {name: _Pass(_Rect(engine.store, name, x, y, w, h, c)) for name, c in passes.items()}


class RecordingEngine:
    """What FinalRender calls on a RenderEngine, recorded: every pass's pixels by sub-rectangle."""

    def __init__(self, scene, view_layer):
        self.resolution_x = scene.render.resolution_x * scene.render.resolution_percentage // 100
        self.resolution_y = scene.render.resolution_y * scene.render.resolution_percentage // 100
        self.camera_override = None
        self.registered = engine_passes.enabled_passes(scene, view_layer)
        self.store, self.reports = {}, []

    def begin_result(self, x, y, w, h, layer=None, view=None):
        return _Result(self, x, y, w, h)

    def end_result(self, result, cancel=False):
        if not cancel:
            for p in result.layers[0].passes.values():
                p.rect.merge()

    def report(self, kind, message):
        self.reports.append((kind, message))

    def update_stats(self, *args):
        pass

    def update_progress(self, *args):
        pass

    def test_break(self):
        return False

    def get_result(self):
        return None  # Blender's whole result, which carries the metadata: not recorded here

    def frame_set(self, frame, subframe):
        bpy.context.scene.frame_set(frame, subframe=subframe)

    def image(self, name) -> np.ndarray:
        """(H, W, C) of a pass, row 0 at the top, the last write winning."""
        h, w = self.resolution_y, self.resolution_x
        pieces = self.store[name]
        c = next(iter(pieces.values())).shape[2]
        out = np.full((h, w, c), np.nan, np.float32)
        for (x, y, pw, ph), values in pieces.items():
            out[h - y - ph:h - y, x:x + pw] = values[::-1]
        return out


def render(scene, samples=4, **ember):
    return render_with(RecordingEngine, scene, samples, **ember)


def plane_scene(width=24, height=16, ortho=False):
    """A camera 5 m above a plane z = 0 (pass index 3, material pass index 7), looking straight down."""
    scene = new_scene(width, height)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0.3, -0.2, 5.0), (0.0, 0.0, 0.0)
    if ortho:
        cam.data.type, cam.data.ortho_scale = "ORTHO", 4.0
    material = diffuse_material("Floor", (0.5, 0.4, 0.3))
    material.pass_index = 7
    floor = quad_object("Floor", (-20, -20, 0), (40, 0, 0), (0, 40, 0), material)
    floor.pass_index = 3
    set_world(scene, (0.5, 0.5, 0.5), 1.0)
    layer = scene.view_layers[0]
    for toggle in ("use_pass_z", "use_pass_position", "use_pass_normal", "use_pass_uv", "use_pass_object_index",
                   "use_pass_material_index"):
        setattr(layer, toggle, True)
    return scene


@pytest.mark.parametrize("ortho", [False, True])
def test_data_passes_match_closed_forms(ortho):
    """Depth is the camera's 5 m height everywhere (distance along the view axis), the normal +Z, the
    position on the plane, the indices the pass indices; UV is the plane's (x + 20) / 40."""
    scene = plane_scene(ortho=ortho)
    engine = render(scene, use_denoising=False)
    depth = engine.image("Depth")
    np.testing.assert_allclose(depth, 5.0, rtol=1e-5)
    np.testing.assert_allclose(engine.image("Normal"), np.broadcast_to([0, 0, 1], depth.shape[:2] + (3,)), atol=1e-6)
    position = engine.image("Position")
    np.testing.assert_allclose(position[..., 2], 0.0, atol=1e-5)
    np.testing.assert_allclose(engine.image("UV")[..., 0], (position[..., 0] + 20) / 40, atol=2e-2)
    assert np.all(engine.image("Object Index") == 3) and np.all(engine.image("Material Index") == 7)
    # positions spread over the view: the camera's footprint, centred under it
    assert abs(position[..., 0].mean() - 0.3) < 0.05 and position[..., 0].std() > 0.1


def test_background_depth_and_indices():
    """Where the camera sees the world: Depth 1e10 (Cycles' value for nothing), indices 0."""
    scene = plane_scene()
    scene.camera.rotation_euler = (math.radians(180), 0, 0)  # looking up, away from the plane
    engine = render(scene, use_denoising=False)
    assert np.all(engine.image("Depth") == 1e10)
    assert np.all(engine.image("Object Index") == 0) and np.all(engine.image("Normal") == 0)


def test_denoising_passes_and_noisy_image():
    """Denoising data: the albedo of a flat grey floor is its colour, its normal in camera space (Cycles'
    x right, y up, z forward) faces the camera looking down on it: z = -1; the Noisy Image is the
    undenoised Combined. Orthographic: every ray meets the floor at the same length."""
    scene = plane_scene(ortho=True)
    scene.view_layers[0].ember.denoising_store_passes = True
    engine = render(scene, samples=2, use_denoising=True)
    albedo = engine.image("Denoising Albedo")
    np.testing.assert_allclose(albedo, np.broadcast_to([0.5, 0.4, 0.3], albedo.shape), atol=1e-6)
    np.testing.assert_allclose(engine.image("Denoising Normal")[..., 2], -1.0, atol=1e-6)
    # the camera rays' lengths to the floor, from the near clip plane as in Cycles (ray_length - tmin)
    np.testing.assert_allclose(engine.image("Denoising Depth"), 5.0 - scene.camera.data.clip_start, rtol=1e-5)
    assert "Noisy Image" in engine.store
    assert not [r for r in engine.reports if r[0] == {"ERROR"}]


@pytest.mark.parametrize("node", ["ShaderNodeBsdfSheen", "ShaderNodeBsdfPrincipled"])
def test_sheen_albedo_is_its_colour_times_its_directional_albedo(node):
    """Cycles' bsdf_sheen_setup scales the sheen closure's weight and sample weight by the lobe's albedo
    toward the viewer: the Denoising Albedo of a sheen floor seen straight down (mu = 1) is its colour times
    sheen_albedo(1, roughness) (with the Principled BSDF, plus the base layer under it and the specular
    layer's). Before, the sheen closure counted its whole colour: the albedo read white."""
    from ember.kernels.bsdf.sheen import sheen_albedo
    scene = plane_scene(ortho=True)
    mat = bpy.data.materials.new("Velvet")
    tree = mat.node_tree
    tree.nodes.clear()
    shader = tree.nodes.new(node)
    tree.links.new(shader.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    color = (0.8, 0.6, 0.4)
    if node == "ShaderNodeBsdfSheen":
        shader.inputs["Color"].default_value = (*color, 1.0)
        shader.inputs["Roughness"].default_value = 0.5
    else:
        shader.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        shader.inputs["Specular IOR Level"].default_value = 0.0
        shader.inputs["Sheen Weight"].default_value = 1.0
        shader.inputs["Sheen Tint"].default_value = (*color, 1.0)
        shader.inputs["Sheen Roughness"].default_value = 0.5
    bpy.data.objects["Floor"].data.materials[0] = mat
    scene.view_layers[0].ember.denoising_store_passes = True
    engine = render(scene, samples=2, use_denoising=True)
    albedo = engine.image("Denoising Albedo")
    expected = np.float32(color) * sheen_albedo(np.float32([1.0]), np.float32([0.5]))[0]
    assert 0 < expected.max() < 0.1   # a sheen reflects little straight back: far below its colour
    np.testing.assert_allclose(albedo, np.broadcast_to(expected, albedo.shape), rtol=1e-4, atol=1e-6)


def test_an_emitter_seen_by_the_camera_has_its_emission_as_albedo():
    """Cycles writes what emitters give paths still looking for their denoising features into the
    Denoising Albedo (film_write_emission_or_background_pass): a dim emissive floor reads its emission
    (Ember keeps albedo within [0, 1], what OpenImageDenoise reads)."""
    scene = plane_scene(ortho=True)
    bpy.data.objects["Floor"].data.materials[0] = emission_material("Glow", (0.8, 0.6, 0.4), 0.5)
    scene.view_layers[0].ember.denoising_store_passes = True
    engine = render(scene, samples=2, use_denoising=True)
    albedo = engine.image("Denoising Albedo")
    np.testing.assert_allclose(albedo, np.broadcast_to([0.4, 0.3, 0.2], albedo.shape), rtol=1e-5)


def test_passes_reach_blenders_output():
    """Through bpy.ops.render.render the passes Ember registers reach Blender's multilayer EXR."""
    scene = plane_scene()
    scene.render.engine = "EMBER"
    scene.ember.samples, scene.ember.use_denoising = 2, False
    settings = scene.render.image_settings
    settings.media_type, settings.color_depth = "MULTI_LAYER_IMAGE", "32"
    with tempfile.TemporaryDirectory() as tmp:
        scene.render.filepath = os.path.join(tmp, "passes.exr")
        bpy.ops.render.render(write_still=True)
        data = open(scene.render.filepath, "rb").read()
    for name in (b"Depth", b"Normal", b"Position", b"UV", b"Object Index", b"Material Index"):
        assert b"ViewLayer." + name in data, name


def test_denoising_features_look_through_a_mirror():
    """Cycles waits for the first hit that is not mostly specular: through a mirror the denoiser's albedo
    is the mirror's colour times what it reflects (a red wall), not the mirror's grey."""
    scene = new_scene(16, 16)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0.0, 0.0, 5.0), (0.0, 0.0, 0.0)
    mirror = bpy.data.materials.new("Mirror")
    bsdf = mirror.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Metallic"].default_value, bsdf.inputs["Roughness"].default_value = 1.0, 0.0
    bsdf.inputs["Base Color"].default_value = (0.9, 0.9, 0.9, 1.0)
    quad_object("Mirror", (-20, -20, 0), (40, 0, 0), (0, 40, 0), mirror)
    quad_object("Wall", (-20, -20, 10), (0, 40, 0), (40, 0, 0), diffuse_material("Red", (0.8, 0.1, 0.1)))
    set_world(scene, (0.5, 0.5, 0.5), 1.0)
    scene.view_layers[0].ember.denoising_store_passes = True
    engine = render(scene, samples=1, use_denoising=True)
    albedo = engine.image("Denoising Albedo")
    assert np.all(albedo[..., 0] > 0.5) and np.all(albedo[..., 1] < 0.15), albedo[8, 8]


def test_interactive_final_render_shows_denoised_previews(monkeypatch):
    """With a window (not background), the progressive display of a denoised final render shows denoised
    previews; the finished result still carries every pass and the denoised image."""
    import ember.engine.session as session
    monkeypatch.setattr(session, "_background", lambda: False)
    monkeypatch.setattr(session, "DISPLAY_INTERVAL_S", 0.0)
    monkeypatch.setattr(session, "PREVIEW_DENOISE_INTERVAL_S", 0.0)
    shown = []
    original = session.PreviewDenoiser.display

    def spy(self, film, now, *rest):
        image = original(self, film, now, *rest)
        shown.append(image is not None)
        return image
    monkeypatch.setattr(session.PreviewDenoiser, "display", spy)
    scene = plane_scene()
    engine = render(scene, samples=8, use_denoising=True)
    assert any(shown)
    assert np.isfinite(engine.image("Combined")).all() and np.all(engine.image("Depth") == pytest.approx(5.0))


def test_mist_follows_the_worlds_mist_settings():
    """An orthographic camera 5 m above the plane: every first hit is 5 m away; mist start 1, depth 10,
    linear: mist 0.4 everywhere; the world seen: 1."""
    scene = plane_scene(ortho=True)
    scene.view_layers[0].use_pass_mist = True
    mist = scene.world.mist_settings
    mist.start, mist.depth, mist.falloff = 1.0, 10.0, "LINEAR"
    engine = render(scene, use_denoising=False)
    np.testing.assert_allclose(engine.image("Mist"), 0.4, atol=1e-5)
    mist.falloff = "QUADRATIC"
    np.testing.assert_allclose(render(scene, use_denoising=False).image("Mist"), 0.16, atol=1e-5)
    scene.camera.rotation_euler = (math.radians(180), 0, 0)
    np.testing.assert_allclose(render(scene, use_denoising=False).image("Mist"), 1.0)


def test_emission_and_environment_add_up_to_combined():
    """A black card with an emitting square in front of a coloured world: nothing is lit, so Combined is
    exactly Emission + Environment, pixel by pixel, and each holds its own part."""
    scene = new_scene(24, 24)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0.0, 0.0, 5.0), (0.0, 0.0, 0.0)
    quad_object("Card", (-0.6, -0.6, 0), (1.2, 0, 0), (0, 1.2, 0),
                emission_material("Glow", (1.0, 0.5, 0.25), 3.0))
    set_world(scene, (0.1, 0.2, 0.3), 1.0)
    layer = scene.view_layers[0]
    layer.use_pass_emit = layer.use_pass_environment = True
    engine = render(scene, samples=4, use_denoising=False, max_bounces=0)
    combined, emit, env = engine.image("Combined")[..., :3], engine.image("Emission"), engine.image("Environment")
    np.testing.assert_allclose(emit + env, combined, atol=1e-5)
    np.testing.assert_allclose(emit[12, 12], (3.0, 1.5, 0.75), rtol=1e-5)
    np.testing.assert_allclose(env[0, 0], (0.1, 0.2, 0.3), rtol=1e-5)


@pytest.mark.parametrize("mode", ["COSINE", "NEE_MIS"])
def test_noise_pass_is_the_variance_of_the_mean(mode):
    """The Noise pass against the spread of four independent renders' pixel means, on a floor half shadowed
    from the sky by a floating cube, averaged over the image. With independent samples (COSINE) it is
    unbiased: within 4 standard errors (both estimates' own, from their spread over pixels). With the
    stratified first bounce of NEE_MIS the halves it compares are each less even than the whole, so it
    overstates the variance: it must not understate it."""
    scene = plane_scene()
    set_world(scene, hdri="forest.exr")   # a sky that varies, sampled by NEE as a light (one colour is not)
    scene.view_layers[0].ember.use_pass_noise = True
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0.3, -0.2, 1.5))
    images, noise = [], []
    for seed in (1, 2, 3, 4):
        engine = render(scene, samples=8, use_denoising=False, seed=seed, sampling_mode=mode)
        images.append(engine.image("Combined")[..., :3])
        noise.append(engine.image("Noise"))
    spread = np.var(np.stack(images), axis=0, ddof=1)          # per pixel and channel
    predicted = np.mean(np.stack(noise), axis=0)
    n = spread.size
    se = np.sqrt(spread.var() / n + predicted.var() / n)
    assert spread.mean() > 1e-4  # there is noise to measure
    if mode == "COSINE":
        assert abs(predicted.mean() - spread.mean()) < 4 * se, (predicted.mean(), spread.mean(), se)
    else:
        assert predicted.mean() > spread.mean() - 4 * se, (predicted.mean(), spread.mean(), se)
    assert np.all(np.stack(noise) >= 0)




def light_scene():
    """A grey floor, a glossy metal sphere, a glass sphere, a red diffuse wall, a sun and a grey world:
    every class of light pass gets something."""
    scene = new_scene(32, 24)
    quad_object("Floor", (-4, -4, 0), (8, 0, 0), (0, 8, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    quad_object("Wall", (-4, 2, 0), (8, 0, 0), (0, 0, 4), diffuse_material("Red", (0.7, 0.1, 0.1)))
    for name, location, inputs in (("Metal", (-0.7, 0, 0.6), {"Metallic": 1.0, "Roughness": 0.3}),
                                   ("Glass", (0.7, 0, 0.6), {"Transmission Weight": 1.0, "Roughness": 0.05})):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=location, segments=24, ring_count=12)
        material = bpy.data.materials.new(name)
        bsdf = material.node_tree.nodes["Principled BSDF"]
        for key, value in inputs.items():
            bsdf.inputs[key].default_value = value
        bpy.context.object.data.materials.append(material)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy, sun.rotation_euler = 3.0, (0.6, 0.2, 0.3)
    scene.collection.objects.link(sun)
    set_world(scene, (0.3, 0.3, 0.35), 1.0)
    layer = scene.view_layers[0]
    for name in ("diffuse", "glossy", "transmission"):
        for kind in ("direct", "indirect", "color"):
            setattr(layer, f"use_pass_{name}_{kind}", True)
    layer.use_pass_emit = layer.use_pass_environment = True
    return scene


def test_light_passes_add_up_to_combined():
    """Cycles' identity: Combined = Emit + Env + sum over Diffuse, Glossy and Transmission of
    (Direct + Indirect) x Color, pixel by pixel (float precision), and every class has light (Transmission
    Direct stays dark: light through a closed glass sphere has always bounced inside it first)."""
    engine = render(light_scene(), samples=4, use_denoising=False)
    total = engine.image("Emission") + engine.image("Environment")
    for c in ("Diffuse", "Glossy", "Transmission"):
        colour = engine.image(c + " Color")
        direct, indirect = engine.image(c + " Direct"), engine.image(c + " Indirect")
        assert indirect.max() > 0 and (c == "Transmission" or direct.max() > 0), c
        total += (direct + indirect) * colour
    combined = engine.image("Combined")[..., :3]
    np.testing.assert_allclose(total, combined, rtol=1e-4, atol=1e-5)


def test_diffuse_direct_of_a_sunlit_plane_is_the_irradiance_over_pi():
    """A white-ish diffuse plane under a sun of 3 W/m^2 at 30 degrees, black world, nothing else: Diffuse
    Direct is E cos(theta) / pi exactly (the colour divided out), Diffuse Color the albedo, nothing
    indirect."""
    scene = plane_scene()
    scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy, sun.data.angle, sun.rotation_euler = 3.0, 0.0, (math.radians(30), 0, 0)
    scene.collection.objects.link(sun)
    layer = scene.view_layers[0]
    layer.use_pass_diffuse_direct = layer.use_pass_diffuse_indirect = layer.use_pass_diffuse_color = True
    engine = render(scene, samples=2, use_denoising=False)
    np.testing.assert_allclose(engine.image("Diffuse Direct"), 3.0 * math.cos(math.radians(30)) / math.pi,
                               rtol=1e-5)
    np.testing.assert_allclose(engine.image("Diffuse Color"), np.broadcast_to([0.5, 0.4, 0.3], (16, 24, 3)),
                               rtol=1e-6)
    assert np.all(engine.image("Diffuse Indirect") == 0)


def test_shader_aov_outputs_reach_their_passes():
    """View Layer > Shader AOV: an AOV Output node's Color (a colour AOV) and Value (a value AOV) at the
    first hit, from a constant and from a node program (the Geometry's Position z: 0 on the floor)."""
    scene = plane_scene()
    layer = scene.view_layers[0]
    bpy.ops.scene.view_layer_add_aov()
    layer.aovs[-1].name, layer.aovs[-1].type = "tint", "COLOR"
    bpy.ops.scene.view_layer_add_aov()
    layer.aovs[-1].name, layer.aovs[-1].type = "height", "VALUE"
    material = bpy.data.materials["Floor"]
    nodes, links = material.node_tree.nodes, material.node_tree.links
    tint = nodes.new("ShaderNodeOutputAOV")
    tint.aov_name = "tint"
    tint.inputs["Color"].default_value = (0.25, 0.5, 0.75, 1.0)
    height = nodes.new("ShaderNodeOutputAOV")
    height.aov_name = "height"
    separate = nodes.new("ShaderNodeSeparateXYZ")
    geometry = nodes.new("ShaderNodeNewGeometry")
    links.new(geometry.outputs["Position"], separate.inputs[0])
    math_node = nodes.new("ShaderNodeMath")
    math_node.operation = "ADD"
    math_node.inputs[1].default_value = 2.0
    links.new(separate.outputs["Z"], math_node.inputs[0])
    links.new(math_node.outputs[0], height.inputs["Value"])
    engine = render(scene, use_denoising=False)
    np.testing.assert_allclose(engine.image("tint"), np.broadcast_to([0.25, 0.5, 0.75, 1.0], (16, 24, 4)), atol=1e-6)
    np.testing.assert_allclose(engine.image("height"), 2.0, atol=1e-5)


def test_denoising_off_is_the_noisy_image_and_a_failure_keeps_it(monkeypatch, capsys):
    """Off, Combined is exactly the Noisy Image a denoised render keeps; a denoiser that fails leaves that
    same noisy image and says so (a finished frame is never lost)."""
    scene = plane_scene()
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0.3, -0.2, 1.5))   # some noise to denoise
    scene.view_layers[0].ember.denoising_store_passes = True
    on = render(scene, samples=4, use_denoising=True)
    noisy = on.image("Noisy Image")
    assert not np.allclose(on.image("Combined"), noisy)          # the denoiser did something
    off = render(scene, samples=4, use_denoising=False)
    np.testing.assert_array_equal(off.image("Combined"), noisy)
    import ember.engine.denoise as dn
    import ember.engine.film_denoise as film_denoise

    def broken(*args, **kwargs):
        raise dn.DenoiseError("simulated failure")
    monkeypatch.setattr(film_denoise, "denoise_image", broken)
    capsys.readouterr()
    failed = render(scene, samples=4, use_denoising=True)
    np.testing.assert_array_equal(failed.image("Combined"), noisy)
    assert "denoising failed" in capsys.readouterr().out


# ---------------------------------------------------------------- the final denoise: which, tiles, stops
def noisy_scene():
    """plane_scene with a cube over the floor (noise to denoise) and the Noisy Image kept."""
    scene = plane_scene()
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0.3, -0.2, 1.5))
    scene.view_layers[0].ember.denoising_store_passes = True
    return scene


class StoppingEngine(RecordingEngine):
    """Esc injected: test_break() answers `stop` (headless Blender's is always False)."""
    stop = False

    def test_break(self):
        return self.stop


def spy_denoiser(monkeypatch, tile_size=None, on_tile=None):
    """Record the (quality, prefilter) of every film denoise; tile_size forces tiles; on_tile() after each
    tile written."""
    from ember.engine import denoise as dn
    from ember.engine import film_denoise
    calls = []

    def spy(read, height, width, write, **options):
        calls.append((options["quality"], options["prefilter"]))

        def write_then(rows, cols, rgb):
            write(rows, cols, rgb)
            if on_tile is not None:
                on_tile()
        return dn.denoise_image(read, height, width, write_then, tile_size=tile_size, **options)
    monkeypatch.setattr(film_denoise, "denoise_image", spy)
    return calls


def render_with(engine_class, scene, samples=4, **ember):
    """A final render through FinalRender with a stand-in engine of engine_class, as Blender would run it."""
    scene.ember.samples, scene.ember.use_adaptive_sampling = samples, False
    for key, value in ember.items():
        setattr(scene.ember, key, value)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    engine = engine_class(scene, depsgraph.view_layer)
    FinalRender(engine, depsgraph).run()
    return engine


def test_final_denoise_options():
    """Esc or Ctrl-C: none (Cycles keeps what was rendered); a time limit that stopped the render: OIDN's
    fast settings; else the scene's."""
    from types import SimpleNamespace

    from ember.engine.film_denoise import final_options
    ember = SimpleNamespace(use_denoising=True, denoising_quality="HIGH", denoising_prefilter="ACCURATE")
    assert final_options(ember, stopped_early=False, user_stopped=False) == ("HIGH", "ACCURATE")
    assert final_options(ember, stopped_early=True, user_stopped=False) == ("FAST", "FAST")
    assert final_options(ember, stopped_early=True, user_stopped=True) is None
    assert final_options(ember, stopped_early=False, user_stopped=True) is None
    ember.use_denoising = False
    assert final_options(ember, stopped_early=False, user_stopped=False) is None


def test_a_time_limit_denoises_fast_and_shows_progress(monkeypatch, capsys):
    """A render the time limit stopped (its first pass always completes) is denoised with OIDN's fast
    settings, its progress printed as the render's; a render that finished uses the scene's settings."""
    calls = spy_denoiser(monkeypatch)
    scene = noisy_scene()
    capsys.readouterr()
    engine = render_with(RecordingEngine, scene, samples=4096, use_denoising=True, time_limit=1e-6)
    out = capsys.readouterr().out
    assert calls == [("FAST", "FAST")] and "stopped: 1/4096 samples" in out
    # (Elapsed: whatever the machine's load makes it; the test asserts no time.)
    assert re.search(r"\| Denoising \(Fast\) 0% \| Elapsed \d\d:\d\d\.\d\d \| Remaining --:--", out), out
    assert not np.array_equal(engine.image("Combined"), engine.image("Noisy Image"))
    assert np.isfinite(engine.image("Combined")).all()
    render_with(RecordingEngine, scene, samples=4, use_denoising=True, time_limit=0.0)
    assert calls[1] == ("HIGH", "ACCURATE")


def test_esc_during_the_render_keeps_the_noisy_image(monkeypatch):
    calls = spy_denoiser(monkeypatch)

    class EscWhileRendering(StoppingEngine):
        def update_progress(self, fraction):
            self.stop = True      # Esc once the first wave is in
    engine = render_with(EscWhileRendering, noisy_scene(), samples=64, use_denoising=True)
    assert calls == []
    np.testing.assert_array_equal(engine.image("Combined"), engine.image("Noisy Image"))
    assert np.isfinite(engine.image("Combined")).all()


def test_esc_during_the_denoise_puts_the_noisy_image_back(monkeypatch):
    """Tiles already written denoised are written noisy again, every pass with them; nothing is lost."""
    box = {}
    calls = spy_denoiser(monkeypatch, tile_size=16, on_tile=lambda: setattr(box["engine"], "stop", True))

    class Esc(StoppingEngine):
        def __init__(self, *args):
            super().__init__(*args)
            box["engine"] = self
    engine = render_with(Esc, noisy_scene(), samples=4, use_denoising=True)
    assert calls == [("HIGH", "ACCURATE")] and engine.stop
    written = [box for box in engine.store["Combined"] if box[2] == 16]     # the first (16-pixel) tile
    assert written, "a denoised tile was written before Esc"
    np.testing.assert_array_equal(engine.image("Combined"), engine.image("Noisy Image"))
    assert np.isfinite(engine.image("Denoising Albedo")).all() and np.isfinite(engine.image("Depth")).all()


def test_tiles_are_written_with_every_pass(monkeypatch):
    """A tiled denoise writes each tile with all its passes (Blender merges every pass of a sub-result):
    the image is the whole image denoised at once; the passes are the undenoised render's."""
    scene = noisy_scene()
    plain = render_with(RecordingEngine, scene, samples=4, use_denoising=False)
    whole = render_with(RecordingEngine, scene, samples=4, use_denoising=True)
    spy_denoiser(monkeypatch, tile_size=16)
    tiled = render_with(RecordingEngine, scene, samples=4, use_denoising=True)
    assert {box[2] for box in tiled.store["Combined"]} >= {16, 8}    # 24 pixels wide: tiles of 16 and 8
    combined = tiled.image("Combined")
    assert np.isfinite(combined).all() and not np.array_equal(combined, tiled.image("Noisy Image"))
    np.testing.assert_allclose(combined, whole.image("Combined"), rtol=0, atol=1e-5 * np.abs(combined).max())
    for name in ("Depth", "Normal", "Denoising Albedo"):
        np.testing.assert_array_equal(tiled.image(name), plain.image(name))
    np.testing.assert_array_equal(tiled.image("Noisy Image"), plain.image("Combined"))


def test_denoised_render_keeps_its_passes_through_blender():
    """Through bpy.ops.render.render: the denoised Combined does not wipe the other passes (Blender merges
    every pass of the sub-results the denoised image is written in): Depth and Normal are the undenoised
    render's."""
    from exr import render_multilayer
    scene = plane_scene()
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0.3, -0.2, 1.5))
    scene.render.engine, scene.ember.samples = "EMBER", 4
    layer = scene.view_layers[0].name
    renders = {}
    for denoise in (False, True):
        scene.ember.use_denoising = denoise
        renders[denoise] = render_multilayer(scene)[0]
    assert not np.array_equal(renders[True][f"{layer}.Combined"]["R"], renders[False][f"{layer}.Combined"]["R"])
    for name in ("Depth", "Normal"):
        planes = renders[False][f"{layer}.{name}"]
        assert max(float(np.abs(plane).max()) for plane in planes.values()) > 0.1
        for channel, plane in planes.items():
            np.testing.assert_array_equal(renders[True][f"{layer}.{name}"][channel], plane)


def test_a_time_limit_denoises_fast_through_blender(monkeypatch, capsys):
    from exr import render_multilayer
    calls = spy_denoiser(monkeypatch)
    scene = noisy_scene()
    scene.render.engine = "EMBER"
    scene.ember.samples, scene.ember.use_adaptive_sampling, scene.ember.time_limit = 4096, False, 1e-6
    parts, _ = render_multilayer(scene)
    assert calls == [("FAST", "FAST")] and "| Denoising (Fast) 0% |" in capsys.readouterr().out
    combined = parts[f"{scene.view_layers[0].name}.Combined"]
    assert all(np.isfinite(combined[c]).all() for c in "RGBA")


def test_ambient_occlusion_pass_is_written_and_cycles_passes_ember_lacks_are_named(capfd):
    """View Layer > Passes > Ambient Occlusion gives an "Ambient Occlusion" pass (before, nothing and no word):
    under an open sky a plane's AO is 1 everywhere, a closed form (every ray escapes). The Cycles passes Ember
    writes nothing for (Sample Count, Render Time, Volume Scatter) are named in one warning."""
    scene = plane_scene()
    layer = scene.view_layers[0]
    layer.use_pass_ambient_occlusion = True
    layer.cycles.pass_debug_sample_count = layer.cycles.pass_render_time = True
    layer.cycles.use_pass_volume_scatter = True
    engine = render(scene)
    np.testing.assert_allclose(engine.image("Ambient Occlusion"), 1.0, atol=1e-6)
    said = capfd.readouterr().out.splitlines() + [m for _, m in engine.reports]   # printed in background mode
    warned = [m for m in said if "not supported (Cycles' own)" in m]
    assert len(warned) == 1 and all(n in warned[0] for n in ("Sample Count", "Render Time", "Volume Scatter")), said
