"""Light and data passes against Cycles' own on the same scene (issue 13), read from both engines'
multilayer EXRs: Diffuse/Glossy/Transmission Direct, Indirect and Color, Emission, Environment, Depth,
Normal, AO (Ambient Occlusion). Block means within noise: the z-score of each block's difference from replicate renders."""
from __future__ import annotations


import numpy as np
import bpy
import pytest

from bpy_helpers import REPLICATE_SEEDS, configure_cycles
from exr import render_multilayer
from test_passes import light_scene

SAMPLES = 64
PASSES = ("Diffuse Direct", "Diffuse Indirect", "Diffuse Color", "Glossy Direct", "Glossy Indirect", "Glossy Color",
          "Transmission Indirect", "Transmission Color", "Environment", "Depth", "Normal", "Ambient Occlusion")


def render(engine, seed):
    scene = light_scene()
    layer = scene.view_layers[0]
    layer.use_pass_z = layer.use_pass_normal = layer.use_pass_ambient_occlusion = True
    scene.world.light_settings.distance = 1.5   # the AO pass's reach (Cycles' integrator AO distance)
    scene.render.engine = engine
    if engine == "CYCLES":
        configure_cycles(scene, SAMPLES, seed, 8)
    else:
        e = scene.ember
        e.samples, e.seed, e.max_bounces, e.transparent_max_bounces = SAMPLES, seed, 8, 8
        e.diffuse_bounces = e.glossy_bounces = e.transmission_bounces = 8   # as configure_cycles
        e.use_adaptive_sampling = e.use_denoising = False
        e.sample_clamp_direct = e.sample_clamp_indirect = e.blur_glossy = 0.0
        e.pixel_filter_type = "BOX"
    parts, _ = render_multilayer(scene)
    layer_name = layer.name
    out = {}
    for name in PASSES:
        planes = parts[f"{layer_name}.{name}"]
        out[name] = np.stack([planes[c] for c in sorted(planes, key="RGBXYZ".find)], axis=-1)
    return out


@pytest.fixture(scope="module")
def renders():
    return {engine: [render(engine, seed) for seed in REPLICATE_SEEDS[:2]] for engine in ("CYCLES", "EMBER")}


@pytest.mark.parametrize("name", PASSES)
def test_pass_matches_cycles(renders, name):
    """Each pass's 4x4 blocks: the two engines' means within 5 standard errors (from the two replicates
    of each, pixel by pixel), with a floor of 2% of the block's value for what no noise explains (float, tessellation).
    Direct and Indirect light are compared as written, times their Color (Cycles divides by the colour when
    it reads them; a colour of its own microfacet albedo tables that Ember estimates differently would
    otherwise swing the quotient where the colour is small)."""
    blocks = 4
    if name == "Depth":
        # Taken at sample 0, which looks through the pixel's centre in both engines (Cycles'
        # init_from_camera.h): the same rays, so the same depths to float precision, silhouettes included.
        stack = np.minimum(np.stack([r[name] for engine in ("CYCLES", "EMBER") for r in renders[engine]]), 100.0)
        np.testing.assert_array_equal(stack[0], stack[1])   # one pixel centre whatever the seed
        np.testing.assert_allclose(stack[2:], stack[:2], rtol=1e-3, atol=1e-3)
        return
    if name == "Normal":
        # The closures' average normal over the samples, whose jitter differs between engines and seeds:
        # compared away from silhouettes (pixels next to a jump of more than 5% in any render), to 2% (the
        # spread of a pixel's footprint on a tilted surface).
        stack = np.minimum(np.stack([r[name] for engine in ("CYCLES", "EMBER") for r in renders[engine]]), 100.0)
        jump = np.zeros(stack.shape[1:3], bool)
        for axis in (1, 2):
            d = np.abs(np.diff(stack, axis=axis)).max(axis=(0, 3)) > 0.05 * np.maximum(
                np.abs(np.take(stack, range(stack.shape[axis] - 1), axis=axis)).max(axis=(0, 3)), 1e-2)
            if axis == 1:
                jump[:-1] |= d
                jump[1:] |= d
            else:
                jump[:, :-1] |= d
                jump[:, 1:] |= d
        interior = ~jump
        assert interior.mean() > 0.5
        np.testing.assert_allclose(stack[2:, interior], stack[:2, interior], rtol=2e-2, atol=2e-2)
        return

    def value(render):
        image = render[name]
        if name.endswith(("Direct", "Indirect")):
            image = image * render[name.rsplit(" ", 1)[0] + " Color"]
        return image

    assert_blocks_match([value(r) for r in renders["CYCLES"]], [value(r) for r in renders["EMBER"]], name, blocks)


def assert_blocks_match(cycles_images, ember_images, name, blocks=4):
    """Two renders of a pass by each engine: every block's means within 5 standard errors (see
    test_pass_matches_cycles)."""
    def blocked(a):
        """(2, H, W, C) -> (2, blocks, blocks, pixels per block, C)"""
        _, h, w, c = a.shape
        bh, bw = h // blocks, w // blocks
        a = a[:, :bh * blocks, :bw * blocks].reshape(2, blocks, bh, blocks, bw, c)
        return a.transpose(0, 1, 3, 2, 4, 5).reshape(2, blocks, blocks, bh * bw, c)

    def mean_and_variance(images):
        """Each block's mean over both replicates, and that mean's variance. The variance comes from the
        replicates' difference pixel by pixel (pixels are independent: each has its own sequence), an
        estimate with as many degrees of freedom as the block has pixels; the spread of two block means
        would have one, and its 5-sigma bound would fail about one block in thirty by chance."""
        a = blocked(np.stack(images).astype(np.float64))
        n = a.shape[3]
        one_render = ((a[0] - a[1]) ** 2).sum(axis=2) / 2 / n ** 2   # variance of one render's block mean
        return a.mean(axis=(0, 3)), one_render / 2

    cyc, cyc_var = mean_and_variance(cycles_images)
    emb, emb_var = mean_and_variance(ember_images)
    diff = emb - cyc
    se = np.sqrt(cyc_var + emb_var)
    floor = 0.02 * np.abs(cyc) + 1e-4
    z = np.abs(diff) / np.maximum(se, floor)
    assert z.max() < 5, (name, float(z.max()), np.unravel_index(int(z.argmax()), z.shape))


@pytest.mark.xfail(bpy.app.version[:2] >= (5, 3), strict=True,
                   reason="Cycles 5.3 weighs the Denoising Albedo by roughness (smooth specular-to-diffuse blend, "
                          "736ebe56f, 0ea9d49a4, 00d09f9f5); Ember follows 5.0's (docs/blender-versions.md)")
def test_colour_albedos_of_metal_and_tinted_glass_match_cycles():
    """A metal's colour lives in its Fresnel (F82 tint, F0 = base colour) and tinted glass's in its
    transmission tint, not in their closure weights: the Denoising Albedo, Glossy Color and Transmission
    Color are Cycles' bsdf_albedo of each closure, in colour. They read grey before (the weight times the
    mean albedo): copper's denoising albedo 0.62 in every channel where Cycles has (0.95, 0.55, 0.35).
    These albedos are closed forms of the viewing angle read from the same tables, so the block means agree
    to the tables' precision and the 16 samples' jitter of that angle: measured within 0.0008, asserted
    within 0.005."""
    import bpy
    from bpy_helpers import add_camera, new_scene, set_world
    scene = new_scene(40, 20)
    set_world(scene, (0.5, 0.5, 0.5), 1.0)
    for name, x, inputs in (("Copper", -1.1, {"Base Color": (0.95, 0.55, 0.35, 1.0), "Metallic": 1.0,
                                              "Roughness": 0.28}),
                            ("Tinted glass", 1.1, {"Base Color": (0.5, 0.9, 0.6, 1.0), "Transmission Weight": 1.0,
                                                   "Roughness": 0.3})):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(x, 0, 0), segments=48, ring_count=24)
        bpy.ops.object.shade_smooth()
        material = bpy.data.materials.new(name)
        bsdf = material.node_tree.nodes["Principled BSDF"]
        for key, value in inputs.items():
            bsdf.inputs[key].default_value = value
        bpy.context.object.data.materials.append(material)
    add_camera(scene, (0, -7, 0), (0, 0, 0), lens=50)
    layer = scene.view_layers[0]
    layer.use_pass_glossy_color = layer.use_pass_transmission_color = True
    layer.cycles.denoising_store_passes = layer.ember.denoising_store_passes = True
    names = ("Denoising Albedo", "Glossy Color", "Transmission Color")
    out = {}
    for engine in ("CYCLES", "EMBER"):
        scene.render.engine = engine
        if engine == "CYCLES":
            configure_cycles(scene, 16, 0, 8)
        else:
            e = scene.ember
            e.samples, e.max_bounces = 16, 8
            e.diffuse_bounces = e.glossy_bounces = e.transmission_bounces = 8   # as configure_cycles
            e.use_adaptive_sampling = e.use_denoising = False
            e.pixel_filter_type = "BOX"
        parts, _ = render_multilayer(scene)
        out[engine] = {name: np.stack([parts[f"{layer.name}.{name}"][c] for c in "RGB"], axis=-1) for name in names}
    centre = (slice(6, 14), slice(None))
    for name in names:
        for half in (slice(4, 14), slice(26, 36)):   # the copper sphere, the glass sphere: their middles
            cycles = out["CYCLES"][name][centre][:, half].reshape(-1, 3).mean(axis=0)
            ember = out["EMBER"][name][centre][:, half].reshape(-1, 3).mean(axis=0)
            np.testing.assert_allclose(ember, cycles, atol=0.005, err_msg=name)


def test_ambient_occlusion_pass_through_transparency_and_holdouts_matches_cycles():
    """The Ambient Occlusion pass (View Layer > Passes > Light), before ignored without a word: one ray per sample
    from the surface the camera sees, about its diffuse closures' normal, as far as the world's AO distance (0.5 m
    here: the box's foot darkens the floor, the open floor stays white), through transparent surfaces, times the
    surface's alpha; a half-transparent leaf in front adds its own half and lets the camera see the half behind it;
    a holdout ball gives nothing."""
    from bpy_helpers import add_camera, configure_engine, diffuse_material, new_scene, quad_object, set_world
    images = {"CYCLES": [], "EMBER": []}
    for engine in images:
        for seed in REPLICATE_SEEDS[:2]:
            scene = new_scene(32, 24)
            add_camera(scene, (0, -4, 2.2), (0, 0, 0.4), lens=35)
            set_world(scene, (0.5, 0.5, 0.5))
            scene.world.light_settings.distance = 0.5
            quad_object("Floor", (-3, -3, 0), (6, 0, 0), (0, 6, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
            bpy.ops.mesh.primitive_cube_add(size=0.8, location=(0.5, 0.4, 0.4), rotation=(0, 0, 0.5))
            bpy.context.active_object.data.materials.append(diffuse_material("Box", (0.7, 0.3, 0.2)))
            leaf = bpy.data.materials.new("Leaf")
            leaf.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.4
            quad_object("Leaf", (-1.4, -1.0, 0.1), (1.0, 0, 0), (0, 0, 0.9), leaf)
            bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(-0.6, 0.9, 0.35))
            ball = bpy.context.active_object
            ball.data.materials.append(diffuse_material("Ball", (0.8, 0.8, 0.8)))
            ball.is_holdout = True
            scene.view_layers[0].use_pass_ambient_occlusion = True
            configure_engine(scene, engine, 64, seed=seed)
            parts, _ = render_multilayer(scene)
            planes = parts[f"{scene.view_layers[0].name}.Ambient Occlusion"]
            images[engine].append(np.stack([planes[c] for c in "RGB"], axis=-1))
    ember = np.mean(images["EMBER"], axis=0)
    grey = ember.mean(axis=-1)
    assert ((grey > 0.1) & (grey < 0.8)).sum() > 20 and (grey > 0.95).sum() > 100   # occluded in places, open elsewhere
    assert_blocks_match(images["CYCLES"], images["EMBER"], "Ambient Occlusion")


def test_data_passes_behind_a_transparent_leaf_match_cycles():
    """A leaf of alpha 0.3 (under View Layer > Passes > Alpha Threshold, 0.5) over a floor: as Cycles'
    film_write_data_passes, a camera path takes Normal from the first surface opaque enough, the floor where it
    passes the leaf (about 70% of the samples) and nothing where it scatters off it; Depth and Object Index from
    the last surface it saw (sample 0: floor or leaf, at random); Mist and Diffuse Color add each surface's share;
    an AOV adds the values of the surfaces up to the opaque one (Cycles' svm_node_aov_check); the leaf's Cryptomatte
    weight is its alpha. Before, every data pass was the leaf's, whatever its alpha: Normal and Depth the leaf's
    everywhere behind it, its matte weight 1."""
    from bpy_helpers import add_camera, configure_engine, diffuse_material, new_scene, quad_object, set_world
    from ember.kernels.cryptomatte import hash_names
    names = ("Normal", "Mist", "Diffuse Color", "Depth", "Object Index", "Tag", "CryptoObject00", "CryptoObject01")
    renders = {"CYCLES": [], "EMBER": []}
    for engine in renders:
        for seed in REPLICATE_SEEDS[:2]:
            scene = new_scene(32, 24)
            add_camera(scene, (0, -3, 3.0), (0, 0, 0), lens=35)
            set_world(scene, (0.4, 0.4, 0.4))
            # Mist from the camera to 8 m, linear: the leaf and the floor at 3-5 m read 0.4-0.6 (with Blender's
            # default start of 5 m every surface here reads 0, a float32 sum's rounding in Cycles).
            mist = scene.world.mist_settings
            mist.start, mist.depth, mist.falloff = 0.0, 8.0, "LINEAR"
            floor = quad_object("Floor", (-3, -3, 0), (6, 0, 0), (0, 6, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
            floor.pass_index = 1
            leaf = bpy.data.materials.new("Leaf")
            bsdf = leaf.node_tree.nodes["Principled BSDF"]
            bsdf.inputs["Alpha"].default_value = 0.3
            bsdf.inputs["Base Color"].default_value = (0.2, 0.7, 0.1, 1.0)
            plane = quad_object("Leaf", (-1.0, -1.2, 1.0), (2.0, 0, 0), (0, 1.4, 0.6), leaf)
            plane.pass_index = 2
            for material, tag in ((leaf, 1.0), (floor.data.materials[0], 2.0)):   # an AOV: 1 on the leaf, 2 below
                node = material.node_tree.nodes.new("ShaderNodeOutputAOV")
                node.aov_name, node.inputs["Value"].default_value = "Tag", tag
            layer = scene.view_layers[0]
            aov = layer.aovs.add()
            aov.name, aov.type = "Tag", "VALUE"
            layer.use_pass_cryptomatte_object = True
            layer.use_pass_normal = layer.use_pass_mist = layer.use_pass_diffuse_color = True
            layer.use_pass_z = layer.use_pass_object_index = True
            configure_engine(scene, engine, 64, seed=seed)
            parts, _ = render_multilayer(scene)
            out = {}
            for name in names:
                planes = parts[f"{layer.name}.{name}"]
                out[name] = np.stack([planes[c] for c in sorted(planes, key="RGBAXYZ".find)], axis=-1)
            renders[engine].append(out)
    for name in ("Normal", "Mist", "Diffuse Color", "Tag"):
        assert_blocks_match([r[name] for r in renders["CYCLES"]], [r[name] for r in renders["EMBER"]], name)
    leaf_id = hash_names(["Leaf"])[0]

    def leaf_weight(r):   # (H, W) the leaf's Cryptomatte weight: the other value of the pair holding its id
        pairs = np.concatenate([r["CryptoObject00"], r["CryptoObject01"]], axis=-1).reshape(*r["Tag"].shape[:2], 4, 2)
        return (np.where(pairs[..., 0] == leaf_id, pairs[..., 1], 0.0) +
                np.where(pairs[..., 1] == leaf_id, pairs[..., 0], 0.0)).sum(axis=-1)
    weights = {engine: np.stack([leaf_weight(r) for r in rs]) for engine, rs in renders.items()}
    covered = (weights["CYCLES"] > 0).all(axis=0) & (weights["EMBER"] > 0).all(axis=0)
    assert covered.sum() > 50
    np.testing.assert_allclose(weights["EMBER"][:, covered].mean(), weights["CYCLES"][:, covered].mean(), rtol=0.05)
    # Sample 0 of a leaf pixel sees the floor behind it with probability 0.7 in both engines (binomial noise).
    index = {engine: np.stack([r["Object Index"][..., 0] for r in rs]) for engine, rs in renders.items()}
    region = np.concatenate(list(index.values())).__eq__(2).any(axis=0)   # the leaf's pixels, in any render
    n = int(region.sum())
    fractions = {engine: float(np.mean(values[:, region] == 1)) for engine, values in index.items()}
    fc, fe = fractions["CYCLES"], fractions["EMBER"]
    assert n > 50 and 0.4 < fc < 0.9, (n, fractions)
    se = np.sqrt(2 * fc * (1 - fc) / (2 * n))   # both engines' fractions over 2 renders x n pixels
    assert abs(fe - fc) < 5 * se, (n, fractions)


def test_denoising_features_stop_at_the_transparent_limit_as_in_cycles():
    """A wholly transparent card before a red wall, Transparent Bounces 1: Cycles ends the path at the wall before
    writing its denoising features (film_write_denoising_features_surface comes after the path's termination), so
    the Denoising Albedo behind the card is black there; with 2 the wall's red. Before, Ember wrote the wall's."""
    from bpy_helpers import (add_camera, configure_engine, diffuse_material, new_scene, node_material, quad_object,
                             set_world)
    out = {}
    for limit in (1, 2):
        for engine in ("CYCLES", "EMBER"):
            scene = new_scene(16, 16)
            add_camera(scene, (0, -3, 0), (0, 0, 0), lens=20)
            set_world(scene, (0.2, 0.2, 0.2))
            quad_object("Wall", (-9, 1, -9), (18, 0, 0), (0, 0, 18), diffuse_material("Wall", (0.8, 0.1, 0.1)))
            quad_object("Card", (-9, 0, -9), (18, 0, 0), (0, 0, 18), node_material("Card", "ShaderNodeBsdfTransparent"))
            layer = scene.view_layers[0]
            (layer.cycles if engine == "CYCLES" else layer.ember).denoising_store_passes = True
            configure_engine(scene, engine, 4, max_bounces=limit)
            parts, _ = render_multilayer(scene)
            planes = parts[f"{layer.name}.Denoising Albedo"]
            out[limit, engine] = np.stack([planes[c] for c in "RGB"], axis=-1).mean(axis=(0, 1))
    np.testing.assert_allclose(out[1, "EMBER"], out[1, "CYCLES"], atol=1e-3)
    np.testing.assert_allclose(out[2, "EMBER"], out[2, "CYCLES"], atol=1e-3)
    assert out[2, "CYCLES"][0] > 0.5 and out[1, "CYCLES"][0] < 0.1, out


def test_velvet_light_goes_to_the_glossy_passes_as_in_cycles():
    """Cycles files its Ashikhmin velvet closure as glossy (CLOSURE_IS_BSDF_GLOSSY) though it labels its samples
    diffuse: a velvet floor seen at a grazing angle by an orthographic camera under a sun (no world, no other
    surface) has its light in Glossy Direct, nothing in Diffuse Direct, in both engines, and the same Glossy Direct:
    one sun sample per pixel, the lobe's value at one pair of directions, so to float precision."""
    from bpy_helpers import node_material
    from test_passes import plane_scene
    out = {}
    for engine in ("CYCLES", "EMBER"):
        scene = plane_scene(8, 8, ortho=True)
        scene.world = None
        scene.camera.location, scene.camera.rotation_euler = (0.0, -4.0, 2.0), (1.25, 0.0, 0.0)
        velvet = node_material("Velvet", "ShaderNodeBsdfSheen", Color=(0.8, 0.5, 0.3), Roughness=0.35,
                               opt_distribution="ASHIKHMIN")
        bpy.data.objects["Floor"].data.materials[0] = velvet
        sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
        sun.data.energy, sun.data.angle, sun.rotation_euler = 2.0, 0.0, (1.3, 0.0, 0.2)
        scene.collection.objects.link(sun)
        layer = scene.view_layers[0]
        layer.use_pass_diffuse_direct = layer.use_pass_glossy_direct = True
        scene.render.engine = engine
        if engine == "CYCLES":
            configure_cycles(scene, 4, 0, 8)
        else:
            scene.ember.samples, scene.ember.use_denoising, scene.ember.use_adaptive_sampling = 4, False, False
            scene.ember.pixel_filter_type = "BOX"
        parts, _ = render_multilayer(scene)
        out[engine] = {name: np.stack([parts[f"{layer.name}.{name}"][c] for c in "RGB"], -1)
                       for name in ("Diffuse Direct", "Glossy Direct")}
    for engine in out:
        assert out[engine]["Diffuse Direct"].max() == 0.0, engine
        assert out[engine]["Glossy Direct"].min() > 0.01, engine
    np.testing.assert_allclose(out["EMBER"]["Glossy Direct"], out["CYCLES"]["Glossy Direct"], rtol=2e-3)
