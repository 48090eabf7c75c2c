"""Cryptomatte through Ember's final render against Cycles' on the same scene (issue 13): the same layers
and manifests in Blender's multilayer EXR, the same ids ranked the same way, coverage within noise."""
from __future__ import annotations

import json
import os
import tempfile

import bpy
import numpy as np
import pytest

from bpy_helpers import configure_cycles, diffuse_material, new_scene, quad_object, veil_material
from ember.engine import cryptomatte as ecrypto
from exr import render_multilayer
from test_cryptomatte import strips_scene

SAMPLES = 128


def render(engine):
    scene = strips_scene()
    scene.render.engine = engine
    if engine == "CYCLES":
        configure_cycles(scene, SAMPLES, 0, 1)
    else:
        e = scene.ember
        e.samples, e.max_bounces, e.use_adaptive_sampling, e.use_denoising = SAMPLES, 1, False, False
        e.pixel_filter_type = "BOX"
    return render_multilayer(scene), scene.view_layers[0].name


@pytest.fixture(scope="module")
def renders():
    return {engine: render(engine) for engine in ("CYCLES", "EMBER")}


def layers(parts, view_layer, kind):
    names = ecrypto.layer_names(view_layer, kind, 6)
    return np.concatenate([np.stack([parts[n][c] for c in "rgba"], axis=-1) for n in names], axis=-1)


def test_same_layers_and_manifests(renders):
    (cycles, cycles_strings), layer = renders["CYCLES"]
    (ember, ember_strings), _ = renders["EMBER"]
    assert {p for p in ember if "Crypto" in p} == {p for p in cycles if "Crypto" in p}
    for kind in ecrypto.KINDS:
        prefix = ecrypto.metadata_prefix(ecrypto.layer_name(layer, kind))
        for field in ("name", "hash", "conversion"):
            assert ember_strings[prefix + field] == cycles_strings[prefix + field]
        ours, theirs = json.loads(ember_strings[prefix + "manifest"]), json.loads(cycles_strings[prefix + "manifest"])
        assert ours and all(theirs[name] == value for name, value in ours.items()), kind


@pytest.mark.parametrize("kind", ecrypto.KINDS)
def test_same_ids_and_coverage(renders, kind):
    """Per pixel: the same ids hold coverage in both; each id's coverage within 5 standard errors of the
    two binomial estimates at 128 samples (ids covering a pixel wholly: exactly 1 in both)."""
    (cycles, _), layer = renders["CYCLES"]
    (ember, _), _ = renders["EMBER"]
    c, e = layers(cycles, layer, kind), layers(ember, layer, kind)
    h, w, _ = c.shape
    for y in range(h):
        for x in range(w):
            theirs = {float(i): float(v) for i, v in zip(c[y, x, 0::2], c[y, x, 1::2]) if v > 0}
            ours = {float(i): float(v) for i, v in zip(e[y, x, 0::2], e[y, x, 1::2]) if v > 0}
            assert ours.keys() == theirs.keys(), (kind, y, x)
            for i, p in theirs.items():
                se = np.sqrt(2 * max(p * (1 - p), 1 / SAMPLES) / SAMPLES)
                assert abs(ours[i] - p) <= 5 * se, (kind, y, x, ours[i], p)
            ranked = [i for i in e[y, x, 0::2] if i != 0]
            assert ranked == sorted(ranked, key=lambda i: -ours[float(i)])  # heaviest first


def _matte_render(engine):
    """The compositor's Cryptomatte node picking the object "Ball" from a render of engine: its Matte."""
    from bpy_helpers import load_exr, set_world
    scene = new_scene(40, 30)
    quad_object("Floor", (-4, -4, 0), (8, 0, 0), (0, 8, 0), diffuse_material("Floor"))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(0, 0, 1.0))
    bpy.context.object.name = "Ball"
    set_world(scene, (0.5, 0.5, 0.5), 1.0)
    layer = scene.view_layers[0]
    layer.use_pass_cryptomatte_object = True
    tree = bpy.data.node_groups.new("Matte", "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    layers = tree.nodes.new("CompositorNodeRLayers")
    layers.scene = scene
    crypto = tree.nodes.new("CompositorNodeCryptomatteV2")
    crypto.source, crypto.scene, crypto.layer_name = "RENDER", scene, f"{layer.name}.CryptoObject"
    crypto.matte_id = "Ball"
    output = tree.nodes.new("NodeGroupOutput")
    tree.links.new(layers.outputs["Image"], crypto.inputs["Image"])
    tree.links.new(crypto.outputs["Matte"], output.inputs[0])
    scene.compositing_node_group = tree
    scene.render.use_compositing = True
    scene.render.engine = engine
    if engine == "CYCLES":
        configure_cycles(scene, SAMPLES, 0, 1)
    else:
        e = scene.ember
        e.samples, e.use_denoising, e.use_adaptive_sampling, e.pixel_filter_type = SAMPLES, False, False, "BOX"
    scene.render.image_settings.file_format, scene.render.image_settings.color_depth = "OPEN_EXR", "32"
    with tempfile.TemporaryDirectory() as tmp:
        scene.render.filepath = os.path.join(tmp, "matte.exr")
        bpy.ops.render.render(write_still=True)
        return load_exr(scene.render.filepath)[..., 0]


def test_compositor_cryptomatte_node_isolates_an_object():
    """Blender's own Cryptomatte node (compositor, Render source) picks "Ball" from an Ember render: 1 over
    the ball, 0 on the floor, and its total coverage that of Cycles' matte within noise (edge pixels:
    binomial coverage estimates of both engines)."""
    ember, cycles = _matte_render("EMBER"), _matte_render("CYCLES")
    assert ember[15, 20] == 1.0 and ember[2, 2] == 0.0 and ember[28, 2] == 0.0
    p = np.clip(cycles, 0, 1)
    se = np.sqrt(2 * (p * (1 - p)).sum() / SAMPLES)
    assert abs(ember.sum() - cycles.sum()) < 5 * max(se, 1.0), (ember.sum(), cycles.sum(), se)


def _behind_glass_render(engine):
    """The strips behind a quad over their left half whose material is 40% diffuse, 60% Transparent BSDF (a Mix
    Shader): each pixel there sees the quad with matte weight 0.4 and the strip behind it with 0.6."""
    scene = strips_scene()
    quad_object("Veil", (-6.0, -5, 1.0), (6.0, 0, 0), (0, 10, 0), veil_material("Veil"))
    scene.render.engine = engine
    if engine == "CYCLES":
        configure_cycles(scene, SAMPLES, 0, 1)
        scene.cycles.transparent_max_bounces = 8
    else:
        e = scene.ember
        e.samples, e.max_bounces, e.use_adaptive_sampling, e.use_denoising = SAMPLES, 1, False, False
        e.transparent_max_bounces, e.pixel_filter_type = 8, "BOX"
    return render_multilayer(scene), scene.view_layers[0].name


def test_surfaces_behind_a_transparent_one_keep_their_coverage_as_in_cycles():
    """Cycles records every surface a camera path sees through transparent ones, each weighed by what reaches the
    camera from it times its alpha (film_write_data_passes: matte_weight). Under the veil each pixel holds the veil
    (0.4) and the strip behind it (0.6) in every kind, as Cycles' does, within 5 binomial standard errors. Before,
    Ember recorded the veil alone: the strips' ids were missing there."""
    ((cycles, _), layer), ((ember, _), _) = _behind_glass_render("CYCLES"), _behind_glass_render("EMBER")
    for kind in ecrypto.KINDS:
        c, e = layers(cycles, layer, kind), layers(ember, layer, kind)
        h, w, _ = c.shape
        for y in range(h):
            for x in range(w // 2):           # the veiled half
                theirs = {float(i): float(v) for i, v in zip(c[y, x, 0::2], c[y, x, 1::2]) if v > 0}
                ours = {float(i): float(v) for i, v in zip(e[y, x, 0::2], e[y, x, 1::2]) if v > 0}
                assert len(theirs) >= 2 and ours.keys() == theirs.keys(), (kind, y, x, ours, theirs)
                for i, p in theirs.items():
                    se = np.sqrt(2 * max(p * (1 - p), 1 / SAMPLES) / SAMPLES)
                    assert abs(ours[i] - p) <= 5 * se, (kind, y, x, ours[i], p)
