"""Closures batched across materials (kernels/shading/shader.py _batches): materials whose inputs come from
node programs, textures and normal maps are built as one closure stack over all their hits, each input
evaluated over its own material's hits; so are the transparency of shadow rays' hits and the emission the
light sampler reads. The image must be the one the materials built one by one give, and Cycles'."""
import bpy
import numpy as np

from bpy_helpers import add_camera, add_lamp, compare_to_cycles, diffuse_material, mesh_object, new_scene, \
    node_material, render_to_array, set_world
from ember.kernels.shading import shader

P = "ShaderNodeBsdfPrincipled"


def _material(name, build):
    mat = node_material(name, P)
    build(mat.node_tree, next(n for n in mat.node_tree.nodes if n.bl_idname == P))
    return mat


def _checker(tree, socket, scale, first, second):
    checker = tree.nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = scale
    checker.inputs["Color1"].default_value = (*first, 1.0)
    checker.inputs["Color2"].default_value = (*second, 1.0)
    tree.links.new(checker.outputs["Color"], socket)


def _checker_colour(tree, bsdf, scale):
    _checker(tree, bsdf.inputs["Base Color"], scale, (0.8, 0.3, 0.1), (0.1, 0.4, 0.7))


def _noise_roughness(tree, bsdf):
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 6.0
    tree.links.new(noise.outputs["Fac"], bsdf.inputs["Roughness"])


def _normal_map(tree, socket):
    """A tangent-space Normal Map fed by a wave texture, into socket."""
    wave = tree.nodes.new("ShaderNodeTexWave")
    wave.inputs["Scale"].default_value = 4.0
    mix = tree.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.inputs["Factor"].default_value = 0.5
    mix.inputs[6].default_value = (0.5, 0.5, 1.0, 1.0)
    tree.links.new(wave.outputs["Color"], mix.inputs[7])
    normal_map = tree.nodes.new("ShaderNodeNormalMap")
    normal_map.inputs["Strength"].default_value = 0.8
    tree.links.new(mix.outputs[2], normal_map.inputs["Color"])
    tree.links.new(normal_map.outputs["Normal"], socket)


def _glow(tree, bsdf, scale):
    """Textured emission: the light sampler evaluates it at the points it samples on the sphere."""
    _checker(tree, bsdf.inputs["Emission Color"], scale, (1.0, 0.6, 0.2), (0.0, 0.0, 0.0))
    bsdf.inputs["Emission Strength"].default_value = 2.0


def _bump(tree, socket):
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 10.0
    bump = tree.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 0.5
    tree.links.new(noise.outputs["Fac"], bump.inputs["Height"])
    tree.links.new(bump.outputs["Normal"], socket)


def _materials():
    def chequered(tree, bsdf):
        _checker_colour(tree, bsdf, 5.0)
        bsdf.inputs["Roughness"].default_value = 0.4
        _glow(tree, bsdf, 6.0)

    def rough_noise(tree, bsdf):
        _checker_colour(tree, bsdf, 9.0)
        _noise_roughness(tree, bsdf)
        bsdf.inputs["Metallic"].default_value = 0.6
        _glow(tree, bsdf, 11.0)

    def normal_mapped(tree, bsdf):
        bsdf.inputs["Base Color"].default_value = (0.7, 0.7, 0.2, 1.0)
        bsdf.inputs["Roughness"].default_value = 0.25
        _normal_map(tree, bsdf.inputs["Normal"])

    def bumped_coat(tree, bsdf):
        _checker_colour(tree, bsdf, 3.0)
        bsdf.inputs["Coat Weight"].default_value = 1.0
        bsdf.inputs["Coat Roughness"].default_value = 0.1
        _bump(tree, bsdf.inputs["Coat Normal"])

    def masked(scale):
        def build(tree, bsdf):
            """An alpha mask from a program (as glTF's MASK mode imports): shadow rays pass the holes."""
            bsdf.inputs["Base Color"].default_value = (0.3, 0.8, 0.3, 1.0)
            checker = tree.nodes.new("ShaderNodeTexChecker")
            checker.inputs["Scale"].default_value = scale
            cut = tree.nodes.new("ShaderNodeMath")
            cut.operation = "GREATER_THAN"
            cut.inputs[1].default_value = 0.5
            tree.links.new(checker.outputs["Fac"], cut.inputs[0])
            tree.links.new(cut.outputs[0], bsdf.inputs["Alpha"])
        return build

    return [_material(name, build) for name, build in (("Chequered", chequered), ("Rough Noise", rough_noise),
                                                       ("Normal Mapped", normal_mapped), ("Bumped Coat", bumped_coat),
                                                       ("Mask A", masked(4.0)), ("Mask B", masked(7.0)))]


def _scene():
    scene = new_scene(48, 24)
    for i, mat in enumerate(_materials()):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=(i - 2.5, 0, 0.5), segments=24, ring_count=12)
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(mat)
    mesh_object("Floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.4, 0.4, 0.4)))
    add_camera(scene, (0, -6.5, 1.4), (0, 0, 0.5), lens=45)
    set_world(scene, color=(0.5, 0.55, 0.6))
    add_lamp(scene, "Sun", "SUN", (0, 0, 5), rotation=(0.6, 0.2, 0.4), energy=3.0, angle=0.1)
    return scene


def _one_by_one(rest, bump_corrections):
    """_batches with every closure whose inputs vary built alone with its material, as before batching."""
    batches, alone = shader.SHADOWED_BATCHES(rest, bump_corrections)
    kept = []
    for members in batches:
        plain = [(m, c) for m, c in members if not any(not isinstance(p, shader.Param) or p.varies
                                                       for _, p in c.inputs)]
        if plain:
            kept.append(plain)
        for m, c in members:
            if (m, c) not in plain:
                alone[m] = alone[m] + (c,)
    return kept, alone


def _each_alone(closures):
    return [[(m, c)] for m, cs in enumerate(closures) for c in cs]


def test_batched_materials_render_as_built_one_by_one(monkeypatch):
    """The same estimator with the same numbers: only float rounding may differ (one closure per material,
    so every hit's closures come in the same order)."""
    scene = _scene()
    built, passed, emitted = [], [], []
    original_build, original_transparency = shader.nodes.build, shader.nodes.transparency

    def counting_build(closure, ctx, weight, builder):
        (built if builder is not None else emitted).append(len(getattr(closure, "pieces", ())))
        return original_build(closure, ctx, weight, builder)

    def counting_transparency(closure, ctx, weight):
        passed.append(len(getattr(closure, "pieces", ())))
        return original_transparency(closure, ctx, weight)

    monkeypatch.setattr(shader.nodes, "build", counting_build)
    monkeypatch.setattr(shader.nodes, "transparency", counting_transparency)
    batched = render_to_array(scene, "EMBER", 8, seed=3, max_bounces=3)
    assert max(built) == 6, "the six materials' Principled closures were not built as one batch"
    assert max(passed) == 2, "the two masks' transparency was not summed as one batch"
    assert max(emitted) == 2, "the two glowing materials' emission was not evaluated as one batch"
    monkeypatch.setattr(shader, "SHADOWED_BATCHES", shader._batches, raising=False)
    monkeypatch.setattr(shader, "_batches", _one_by_one)
    monkeypatch.setattr(shader, "_transparent_batches", _each_alone)
    built.clear()
    passed.clear()
    emitted.clear()
    alone = render_to_array(scene, "EMBER", 8, seed=3, max_bounces=3)
    assert max(built) <= 1 and max(passed) <= 1 and max(emitted) <= 1
    assert np.isfinite(batched).all() and batched[..., :3].mean() > 0.05
    np.testing.assert_allclose(batched, alone, rtol=1e-4, atol=1e-5)


def test_batched_materials_match_cycles():
    compare_to_cycles(_scene(), samples=64, max_bounces=4)
