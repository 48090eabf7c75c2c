"""Headless bpy helpers for tests: register Ember, build scenes in code, render with Cycles or Ember
to linear float images, and compare two renders with tolerances derived from their noise."""
from __future__ import annotations

import math
import os
import tempfile

import bpy
import numpy as np

import ember
from ember.engine.demo import build_world
from ember.engine.merge import load_pixels


def ensure_registered() -> None:
    if not hasattr(bpy.types.Scene, "ember"):
        ember.register()


def new_scene(width=64, height=64) -> bpy.types.Scene:
    """An empty scene (factory settings) with Ember registered and a camera looking at the origin."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    add_camera(scene, (0, -6, 1.5), (0, 0, 1.0))
    return scene


def camera_only_scene() -> bpy.types.Scene:
    """An empty factory scene holding only a camera at (0, -10, 0) looking along +y (the export tests')."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.object.camera_add(location=(0, -10, 0), rotation=(math.pi / 2, 0, 0))
    bpy.context.scene.camera = bpy.context.object
    return bpy.context.scene


def export_current():
    """Export the current scene's evaluated depsgraph."""
    from ember.engine.export import export_scene
    return export_scene(bpy.context.evaluated_depsgraph_get())


def add_camera(scene, location, target, lens=35.0, name="Camera"):
    data = bpy.data.cameras.new(name)
    data.lens = lens
    cam = bpy.data.objects.new(name, data)
    scene.collection.objects.link(cam)
    cam.location = location
    d = np.asarray(target, float) - np.asarray(location, float)
    d /= np.linalg.norm(d)
    cam.rotation_euler = (math.acos(-d[2]), 0.0, math.atan2(d[1], d[0]) - math.pi / 2)
    scene.camera = cam
    return cam


def add_lamp(scene, name, kind, location, rotation=(0, 0, 0), **settings):
    """A light object of `kind` (POINT, SPOT, AREA, SUN) at location, turned by rotation (Euler), its light's
    settings given by keyword (energy=..., size=...), linked to the scene."""
    lamp = bpy.data.objects.new(name, bpy.data.lights.new(name, kind))
    for key, value in settings.items():
        setattr(lamp.data, key, value)
    lamp.location, lamp.rotation_euler = location, rotation
    scene.collection.objects.link(lamp)
    return lamp


def diffuse_material(name, color=(0.8, 0.8, 0.8), principled=False, image=None):
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    shader = tree.nodes.new("ShaderNodeBsdfPrincipled" if principled else "ShaderNodeBsdfDiffuse")
    socket = shader.inputs["Base Color" if principled else "Color"]
    socket.default_value = (*color, 1.0)
    if principled:
        shader.inputs["Roughness"].default_value = 1.0
        # Principled's specular layer is on by default; Ember renders base colour as diffuse only.
        shader.inputs["Specular IOR Level"].default_value = 0.0
    if image is not None:
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image = image
        tree.links.new(tex.outputs["Color"], socket)
    tree.links.new(shader.outputs[0], out.inputs["Surface"])
    return mat


def node_material(name, idname, output="Surface", **inputs):
    """A material made of one shader node with the given input values (and node options as attributes), in the
    material output's `output` (Surface or Volume)."""
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    node = tree.nodes.new(idname)
    for key, value in inputs.items():
        if key.startswith("opt_"):
            setattr(node, key[4:], value)
        else:
            socket = node.inputs[key.replace("_", " ")]
            socket.default_value = (*value, 1.0) if socket.type == "RGBA" and len(value) == 3 else value
    tree.links.new(node.outputs[0], out.inputs[output])
    return mat


def emission_material(name, color=(1, 1, 1), strength=1.0, build=None, into="Color"):
    """A material that emits color at strength; build: a function of the node tree (called after the output and
    emission nodes are made) whose returned socket drives the Emission's `into` input instead."""
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    em = tree.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*color, 1.0)
    em.inputs["Strength"].default_value = strength
    if build is not None:
        tree.links.new(build(tree), em.inputs[into])
    tree.links.new(em.outputs[0], out.inputs["Surface"])
    return mat


def veil_material(name, transparency=0.6):
    """A material that is (1 - transparency) diffuse and `transparency` Transparent BSDF (a Mix Shader): each camera
    path sees it with matte weight 1 - transparency and what lies behind it with the rest."""
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    tree.nodes.clear()
    out, mix = tree.nodes.new("ShaderNodeOutputMaterial"), tree.nodes.new("ShaderNodeMixShader")
    diffuse, clear = tree.nodes.new("ShaderNodeBsdfDiffuse"), tree.nodes.new("ShaderNodeBsdfTransparent")
    mix.inputs["Fac"].default_value = transparency
    tree.links.new(diffuse.outputs[0], mix.inputs[1])
    tree.links.new(clear.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def mesh_object(name, verts, faces, material=None, scene=None, smooth=False):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(map(float, v)) for v in verts], [], [tuple(f) for f in faces])
    if smooth:
        mesh.shade_smooth()
    if material is not None:
        mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    (scene or bpy.context.scene).collection.objects.link(obj)
    return obj


def quad_object(name, corner, edge_u, edge_v, material=None, uv=True):
    c, u, v = (np.asarray(x, float) for x in (corner, edge_u, edge_v))
    obj = mesh_object(name, [c, c + u, c + u + v, c + v], [(0, 1, 2, 3)], material)
    if uv:
        layer = obj.data.uv_layers.new(name="UVMap")
        for loop, coord in zip(obj.data.loops, [(0, 0), (1, 0), (1, 1), (0, 1)]):
            layer.data[loop.index].uv = coord
    return obj


def set_world(scene, color=(0.0, 0.0, 0.0), strength=1.0, hdri=None, rotation=(0.0, 0.0, 0.0)):
    return build_world(scene, color=color, strength=strength, hdri=hdri, rotation=rotation)


def manual_world_map(world, width: int):
    """World > Settings > Sampling Method Manual with a map `width` texels wide. Cycles' Automatic bakes the world
    on 4096 x 2048 texels at every render to sample it, seconds of each small test render; the map moves its noise,
    not its image. Ember samples a plain HDRI from the image's own texels whatever the setting; a world program
    is baked at this width by both engines."""
    world.cycles.sampling_method, world.cycles.sample_map_resolution = "MANUAL", width
    return world


def hdri_world(scene, hdri: str, strength=1.0, rotation=(0.0, 0.0, 0.0), width: int = 1024):
    """set_world with one of Blender's HDRIs (1024 x 512) and a manual_world_map as wide as the image."""
    return manual_world_map(set_world(scene, hdri=hdri, strength=strength, rotation=rotation), width)


# ---------------------------------------------------------------- rendering to numpy
def render_to_array(scene, engine: str, samples: int, seed: int = 0, max_bounces: int = 8,
                    threads: int = 2, clamp: tuple = (0.0, 0.0), blur_glossy: float = 0.0,
                    pixel_filter: tuple = ("BOX", 1.0), denoise: bool = False,
                    caustics: tuple = (True, True), type_bounces: tuple | None = None) -> np.ndarray:
    """Render the scene with CYCLES or EMBER; return (H, W, 4) float32 linear RGBA, row 0 at the top.
    clamp: (direct, indirect) sample clamping and blur_glossy Filter Glossy on both engines (0: off, the
    oracle's configuration); caustics: the (reflective, refractive) Caustics switches on both engines (on,
    the oracle's); pixel_filter: (type, width) on both engines (the oracle's: a 1-pixel box);
    denoise: each engine's default denoiser (off for the oracle); type_bounces: (diffuse, glossy, transmission)
    bounce limits on both engines (None: max_bounces each, the oracle's)."""
    configure_engine(scene, engine, samples, seed, max_bounces, threads, clamp, blur_glossy, pixel_filter, denoise,
                     caustics, type_bounces)
    render = scene.render
    render.image_settings.file_format = "OPEN_EXR"
    render.image_settings.color_depth = "32"
    render.use_file_extension = True
    with tempfile.TemporaryDirectory() as tmp:
        render.filepath = os.path.join(tmp, "frame.exr")
        bpy.ops.render.render(write_still=True)
        return load_exr(render.filepath)


def configure_engine(scene, engine: str, samples: int, seed: int = 0, max_bounces: int = 8, threads: int = 2,
                     clamp: tuple = (0.0, 0.0), blur_glossy: float = 0.0, pixel_filter: tuple = ("BOX", 1.0),
                     denoise: bool = False, caustics: tuple = (True, True), type_bounces: tuple | None = None) -> None:
    """Set the scene up to render with CYCLES or EMBER as render_to_array does (its arguments)."""
    render = scene.render
    render.engine = engine
    render.threads_mode = "FIXED"
    render.threads = threads
    if engine == "CYCLES":
        configure_cycles(scene, samples, seed, max_bounces, type_bounces)
        scene.cycles.sample_clamp_direct, scene.cycles.sample_clamp_indirect = clamp
        scene.cycles.blur_glossy = blur_glossy
        scene.cycles.caustics_reflective, scene.cycles.caustics_refractive = caustics
        scene.cycles.pixel_filter_type, scene.cycles.filter_width = pixel_filter
        scene.cycles.use_denoising = denoise
    else:
        scene.ember.samples = samples
        scene.ember.seed = seed
        scene.ember.max_bounces = max_bounces
        e = scene.ember
        e.diffuse_bounces, e.glossy_bounces, e.transmission_bounces = type_bounces or (max_bounces,) * 3
        scene.ember.transparent_max_bounces = max_bounces
        scene.ember.sample_clamp_direct, scene.ember.sample_clamp_indirect = clamp
        scene.ember.blur_glossy = blur_glossy
        scene.ember.caustics_reflective, scene.ember.caustics_refractive = caustics
        scene.ember.use_adaptive_sampling = False   # as configure_cycles
        scene.ember.pixel_filter_type, scene.ember.filter_width = pixel_filter
        scene.ember.use_denoising = denoise


def configure_cycles(scene, samples: int, seed: int, max_bounces: int, type_bounces: tuple | None = None) -> None:
    """Cycles as the oracle: CPU, plain path tracing, no clamping, denoising or adaptive sampling,
    one-pixel box filter; light tree at its default. type_bounces: (diffuse, glossy, transmission) limits,
    None for max_bounces each."""
    c = scene.cycles
    c.device = "CPU"
    c.samples = samples
    c.seed = seed
    c.use_animated_seed = False
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.max_bounces = max_bounces
    c.diffuse_bounces, c.glossy_bounces, c.transmission_bounces = type_bounces or (max_bounces,) * 3
    c.transparent_max_bounces = max_bounces
    c.blur_glossy = 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.use_auto_tile = False


def load_exr(path: str) -> np.ndarray:
    """A single-layer image file as (H, W, 4) float32, row 0 at the top."""
    pixels, w, h = load_pixels(path)
    return pixels.reshape(h, w, 4)[::-1].copy()


# ---------------------------------------------------------------- comparing noisy renders
REPLICATE_SEEDS = (11, 29, 47, 83)


def replace_world(monkeypatch, **fields) -> None:
    """Make Ember's renderers build their world with these kernels.scene.World fields replaced, for the rest of
    the test (worker processes get the renderer's scene, so they follow)."""
    import dataclasses

    from ember.kernels import renderer as renderer_module
    build = renderer_module.Renderer.__init__

    def replaced(self, arrays, *args, **kwargs):
        build(self, dataclasses.replace(arrays, world=dataclasses.replace(arrays.world, **fields)), *args, **kwargs)
    monkeypatch.setattr(renderer_module.Renderer, "__init__", replaced)


def plain_world_sampling(monkeypatch) -> None:
    """Make Ember's renderers sample the world as Cycles does, for the rest of the test: in proportion to its
    radiance (World.mis_compensation False) and from the whole map at every shading point (World.focus False)."""
    replace_world(monkeypatch, mis_compensation=False, focus=False)


def assert_same_image(a, var_a, b, var_b, block: int = 8, z_block: float = 4.5, z_whole: float = 4.0) -> None:
    """Two estimates of one image (H, W, 3) with their variances of the mean (replicate_render) agree within
    noise: every block x block sum within z_block standard errors of their difference, the whole image within
    z_whole."""
    h, w, _ = a.shape

    def blocks(x):
        x = x[:h // block * block, :w // block * block]
        return x.reshape(h // block, block, w // block, block, 3).sum(axis=(1, 3))
    diff, spread = blocks(a) - blocks(b), np.sqrt(blocks(var_a) + blocks(var_b))
    # Blocks without noise (a uniform sky seen directly) must be equal.
    z = np.where(spread > 0, diff / np.where(spread > 0, spread, 1.0), np.where(diff == 0, 0.0, np.inf))
    assert np.abs(z).max() < z_block, z
    whole = (a.sum() - b.sum()) / np.sqrt(var_a.sum() + var_b.sum())
    assert abs(whole) < z_whole, whole


def replicate_render(scene, engine: str, samples: int, alpha: bool = False, seeds: tuple = REPLICATE_SEEDS,
                     **kwargs):
    """Independent renders with different seeds splitting `samples` between them: their mean is the
    estimate, their spread its noise (len(seeds) - 1 degrees of freedom per pixel; the blocks compare_to_cycles
    sums pool many pixels' estimates).
    Returns (mean (H, W, 3), per-pixel variance of the mean (H, W, 3)): of RGB, or with alpha of the alpha
    channel (in all three)."""
    k = len(seeds)
    renders = np.stack([_channels(render_to_array(scene, engine, max(samples // k, 1), seed=seed, **kwargs), alpha)
                        for seed in seeds]).astype(np.float64)
    return renders.mean(axis=0), renders.var(axis=0, ddof=1) / k


def _channels(image: np.ndarray, alpha: bool) -> np.ndarray:
    return np.repeat(image[..., 3:4], 3, axis=-1) if alpha else image[..., :3]


def compare_to_cycles(scene, samples: int = 64, blocks: int = 8, z: float = 4.5, mean_tol: float = 0.02,
                      mean_z: float | None = None, **kwargs) -> dict:
    """Render with both engines and assert parity: the whole-image mean within mean_tol (relative), or, given
    mean_z, within the larger of mean_tol and mean_z standard errors of the means' difference (for scenes whose
    mean is noisier than 2% at the samples a test can afford); every block of a blocks x blocks grid within z
    standard errors of the difference."""
    cycles, var_c = replicate_render(scene, "CYCLES", samples, **kwargs)
    ember_img, var_e = replicate_render(scene, "EMBER", samples, **kwargs)
    h, w, _ = cycles.shape
    bh, bw = h // blocks, w // blocks

    def block_sums(a):
        return a[:bh * blocks, :bw * blocks].reshape(blocks, bh, blocks, bw, 3).sum(axis=(1, 3))

    n = bh * bw
    diff = (block_sums(ember_img) - block_sums(cycles)) / n
    se = np.sqrt(block_sums(var_c) + block_sums(var_e)) / n
    # A floor on the standard error for blocks with (almost) no noise: float differences, not noise.
    se = np.maximum(se, 1e-4 * np.maximum(np.abs(block_sums(cycles)) / n, 1e-3))
    zscores = np.abs(diff) / se
    mean_c, mean_e = cycles.mean(), ember_img.mean()
    worst = np.unravel_index(np.argmax(zscores), zscores.shape)
    report = {"mean_cycles": mean_c, "mean_ember": mean_e, "relative": mean_e / mean_c - 1.0,
              "max_z": float(zscores.max()), "worst_block": worst,
              "worst_block_relative": float(diff[worst] / max(abs(block_sums(cycles)[worst] / n), 1e-12)),
              "worst_block_se_relative": float(se[worst] / max(abs(block_sums(cycles)[worst] / n), 1e-12))}
    report["mean_se_relative"] = float(np.sqrt(var_c.sum() + var_e.sum()) / cycles.size / max(mean_c, 1e-12))
    if mean_z is not None:
        mean_tol = max(mean_tol, mean_z * report["mean_se_relative"])
    assert mean_c > 1e-3, f"Cycles rendered an almost black image: {report}"
    assert abs(report["relative"]) < mean_tol, f"image means differ: {report}"
    assert report["max_z"] < z, f"a block differs beyond noise: {report}"
    return report
