"""Cryptomatte: ids, the ranked accumulation and the manifest, against the specification's and Blender's
published values and against what Cycles writes (a tiny Cycles render's multilayer EXR: its pixels and
its header metadata)."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from ember.engine import cryptomatte as ecrypto
from exr import render_multilayer
from ember.kernels.cryptomatte import (CryptoFilm, hash_name, hash_name_u32, hash_names, hash_to_float,
                                       layer_count, murmur3_32)


# ---------------------------------------------------------------- ids
def test_murmur3_reference_vectors():
    """MurmurHash3_x86_32 test vectors (stackoverflow.com/questions/14747343, as Boost.Hash2's tests use):
    every tail length, seeds, and bytes >= 0x80."""
    vectors = [(b"", 0, 0), (b"", 1, 0x514E28B7), (b"", 0xFFFFFFFF, 0x81F16F39),
               (b"\xff\xff\xff\xff", 0, 0x76293B50), (b"\x21\x43\x65\x87", 0, 0xF55B516B),
               (b"\x21\x43\x65\x87", 0x5082EDEE, 0x2362F9DE), (b"\x21\x43\x65", 0, 0x7E4A8634),
               (b"\x21\x43", 0, 0xA0F7B07A), (b"\x21", 0, 0x72661CF4), (b"\0\0\0\0", 0, 0x2362F9DE),
               (b"\0\0\0", 0, 0x85F0B427), (b"\0\0", 0, 0x30F4C306), (b"\0", 0, 0x514E28B7)]
    for data, seed, expected in vectors:
        assert murmur3_32(data, seed) == expected, (data, seed)


def test_name_hashes_match_published_manifests():
    """Names and hashes from the Cryptomatte specification 1.1.0 (its metadata example), Psyop's sample
    sidecar manifest (sample_images/sidecar_manifest/bunny_CryptoObject_manifest.json) and the Houdini
    manifest Blender's cryptomatte_test.cc parses."""
    published = {"bunny": "13851a76", "default": "42c9679f", "bunny_porcelain_mat": "b24b26d4",
                 "bush": "f763d090", "flowerA.flowerA_petal1.:1015": "914754e4",
                 "flowerA.flowerA_petal10.:2709": "ff67145b", "/obj/box:polygons:1": "9d416418",
                 "/obj/instance1:instances:0": "0d54c6cc", "/obj/instance1:instances:117": "b2bd969a"}
    for name, hex_hash in published.items():
        assert f"{hash_name_u32(name):08x}" == hex_hash, name
    assert json.loads(ecrypto.manifest(published)) == published


def test_metadata_keys_match_blenders_tests():
    """cryptomatte_test.cc: the 7-hex key of a layer name, UTF-8 names included."""
    assert ecrypto.metadata_prefix("ViewLayer.CryptoMaterial") == "cryptomatte/c7dbf5e/"
    assert ecrypto.metadata_prefix("𝖚𝖓𝖎𝖈𝖔𝖉𝖊.CryptoMaterial") == "cryptomatte/b990b65/"
    assert ecrypto.metadata_prefix("viewlayername.layer1") == "cryptomatte/87f095e/"
    assert ecrypto.metadata_prefix("viewlayername.layer2") == "cryptomatte/c42daa7/"


def test_float_conversion_clamps_the_exponent_only():
    """uint32_to_float32: the hash's bits, the exponent clamped to [1, 254]: every id is a finite normal
    float (never 0, which means no id); sign and mantissa are kept."""
    edge = np.array([0x00000000, 0x006CF718, 0x7FD89B93, 0xFF800000, 0x80000001, 0x3F800000], np.uint32)
    expected = np.array([0x00800000, 0x00ECF718, 0x7F589B93, 0xFF000000, 0x80800001, 0x3F800000], np.uint32)
    np.testing.assert_array_equal(hash_to_float(edge).view(np.uint32), expected)
    h = np.random.default_rng(3).integers(0, 2**32, 200_000, dtype=np.uint64).astype(np.uint32)
    f = hash_to_float(h)
    assert np.all(np.isfinite(f)) and np.all(np.abs(f) >= np.finfo(np.float32).tiny)
    exponent = (h >> 23) & 0xFF
    same = (exponent >= 1) & (exponent <= 254)
    np.testing.assert_array_equal(f.view(np.uint32)[same], h[same])
    np.testing.assert_array_equal(f.view(np.uint32) & 0x807FFFFF, h & 0x807FFFFF)


def test_hash_names_is_hash_name_per_name():
    names = ["Cube", "Cube", "Ärger.001", "", "Obj.160", "Cube"]
    ids = hash_names(names)
    assert ids.dtype == np.float32 and ids.shape == (6,)
    np.testing.assert_array_equal(ids.view(np.uint32), [hash_name(n).view(np.uint32) for n in names])
    assert hash_names([]).shape == (0,)


# ---------------------------------------------------------------- accumulation
def _reference_layers(pixels, ids, weights, spp, height, width, slots):
    """Per pixel the exact weight of every id (a dict), ranked; the top `slots` over spp."""
    out = np.zeros((height * width, slots, 2), np.float64)
    sums = {}
    for p, i, w in zip(pixels, ids, weights.astype(np.float64)):
        if w > 0 and i != 0:
            sums.setdefault(int(p), {}).setdefault(float(i), 0.0)
            sums[int(p)][float(i)] += w
    for p, table in sums.items():
        ranked = sorted(table.items(), key=lambda kv: -kv[1])[:slots]
        for s, (i, w) in enumerate(ranked):
            out[p, s] = i, w / spp
    return out.reshape(height, width, 2 * slots)


def _samples(rng, height, width, n, ids_per_pixel):
    """n samples over the region: each pixel draws from its own ids_per_pixel ids with skewed odds, weights
    in (0, 1], a fifth of them background (weight 0)."""
    palette = hash_names([f"Object.{k:03d}" for k in range(64)])
    pixels = rng.integers(0, height * width, n)
    choice = np.minimum(rng.geometric(0.45, n) - 1, ids_per_pixel - 1)
    ids = palette[(pixels * 7 + choice) % len(palette)]
    weights = np.where(rng.random(n) < 0.2, 0.0, rng.uniform(0.05, 1.0, n)).astype(np.float32)
    return pixels, ids, weights


def test_layers_rank_and_normalise_like_an_exact_tally():
    """With at most `slots` ids a pixel, the slots hold every id's exact weight: ranked by it, divided by
    the pixel's samples, laid out as Cycles' layers (RGBA = id, coverage, id, coverage); the result does
    not depend on how the samples are split between calls. float32 output of float64 sums: 1e-6."""
    rng = np.random.default_rng(7)
    h, w, spp = 5, 7, 40
    pixels, ids, weights = _samples(rng, h, w, h * w * spp, ids_per_pixel=6)
    film = CryptoFilm(h, w, depth=6)
    for chunk in np.array_split(np.arange(len(pixels)), 13):
        film.add(pixels[chunk], ids[chunk], weights[chunk])
    layers = film.layers(np.full((h, w), spp))
    assert layers.shape == (h, w, 12) and layers.dtype == np.float32
    reference = _reference_layers(pixels, ids, weights, spp, h, w, 6)
    np.testing.assert_array_equal(layers[..., 0::2], reference[..., 0::2].astype(np.float32))
    np.testing.assert_allclose(layers[..., 1::2], reference[..., 1::2], rtol=1e-6, atol=0)
    assert np.all(np.diff(layers[..., 1::2], axis=-1) <= 0)
    once = CryptoFilm(h, w, depth=6)
    once.add(pixels, ids, weights)
    np.testing.assert_allclose(once.layers(spp), layers, rtol=1e-6, atol=0)


@pytest.mark.parametrize("bands", [[range(0, 2), range(2, 5), range(5, 6)],          # consecutive rows
                                   [range(0, 6, 3), range(1, 6, 3), range(2, 6, 3)]])  # interleaved (plan_pass)
def test_merge_rows_equals_accumulating_in_place(bands):
    """Each band's accumulator (its rows numbered from 0, filled in two calls) merges into the band's rows."""
    rng = np.random.default_rng(11)
    h, w, spp = 6, 4, 24
    pixels, ids, weights = _samples(rng, h, w, h * w * spp, ids_per_pixel=4)
    whole = CryptoFilm(h, w, depth=4)
    whole.add(pixels, ids, weights)
    merged = CryptoFilm(h, w, depth=4)
    for rows in bands:
        part = CryptoFilm(len(rows), w, depth=4)
        row = pixels // w
        inside = np.flatnonzero(np.isin(row, rows))
        for half in np.array_split(inside, 2):
            part.add((row[half] - rows.start) // rows.step * w + pixels[half] % w, ids[half], weights[half])
        merged.merge(part, rows)
    np.testing.assert_allclose(merged.layers(spp), whole.layers(spp), rtol=1e-6, atol=0)
    np.testing.assert_array_equal(merged.layers(spp, 2, 5), merged.layers(spp)[2:5])


def test_more_ids_than_slots():
    """Ids past the slots are dropped (Cycles adds them to the last slot): the kept coverages stay exact;
    within one call the heaviest new ids take the free slots; across calls the first come keep them."""
    a, b, c, d = hash_names(["A", "B", "C", "D"])
    film = CryptoFilm(1, 2, depth=2)                     # 1 layer: 2 slots
    film.add([0, 0, 0, 0], [a, b, c, d], [0.1, 0.3, 0.2, 0.05])
    film.add([0, 0], [d, d], [1.0, 1.0])                 # D is heavy now, but both slots are taken
    film.add([1, 1, 1], [a, a, b], [1.0, 1.0, 1.0])
    layers = film.layers(4)
    np.testing.assert_array_equal(layers[0, 0], np.array([b, 0.3 / 4, c, 0.2 / 4], np.float32))
    np.testing.assert_array_equal(layers[0, 1], np.array([a, 0.5, b, 0.25], np.float32))


def test_background_and_empty_pixels():
    """Weight 0 (the background) and id 0 (no id) add nothing, yet count as samples: a half-background
    pixel has coverage 0.5; a pixel without samples is 0 (as Cycles' film scale); (H, 1) counts per row."""
    cube = hash_name("Cube")
    film = CryptoFilm(2, 2, depth=6)
    film.add([0, 0, 1, 2, 2], [cube, cube, cube, 0.0, cube], [1.0, 0.0, 0.0, 1.0, 1.0])
    layers = film.layers(np.array([[2], [0]]))
    np.testing.assert_array_equal(layers[0, 0], [cube, 0.5] + [0] * 10)
    assert not layers[0, 1].any() and not layers[1, 1].any()
    np.testing.assert_array_equal(layers[1, 0], [cube, 0] + [0] * 10)


def test_layer_counts_follow_levels():
    """Levels rounded up to even, 2 ids a layer, at most 16 (Cycles: (min(16, depth) + 1) // 2)."""
    assert [layer_count(n) for n in (1, 2, 5, 6, 7, 16, 20)] == [1, 1, 3, 3, 4, 8, 8]
    assert CryptoFilm(3, 4, depth=5).layers(1).shape == (3, 4, 12)
    assert ecrypto.pass_names("object", 5) == ["CryptoObject00", "CryptoObject01", "CryptoObject02"]
    assert ecrypto.pass_names("asset", 2) == ["CryptoAsset00"]
    assert ecrypto.layer_names("Back", "material", 3) == ["Back.CryptoMaterial00", "Back.CryptoMaterial01"]


# ---------------------------------------------------------------- names, manifest, metadata
def test_manifest_format():
    """Compact JSON in first-seen order, each name once (Cycles' layout); a quote or a backslash escaped as
    Blender's own manifest writer does (std::quoted), so the JSON stays valid where Cycles' would not."""
    text = ecrypto.manifest(["Cube", "Ärger.001", "Cube", 'Say "hi"', "back\\slash"])
    assert text.startswith('{"Cube":"a8fce865","Ärger.001":"81c1b167",')
    assert '"Say \\"hi\\""' in text
    assert list(json.loads(text)) == ["Cube", "Ärger.001", 'Say "hi"', "back\\slash"]
    quoted = 'Say "hi"'
    assert json.loads(text)[quoted] == f"{hash_name_u32(quoted):08x}"
    assert ecrypto.manifest([]) == "{}"


def test_metadata_and_asset_names():
    meta = ecrypto.metadata("ViewLayer", "object", ["Cube"])
    assert meta == {"cryptomatte/542cafa/name": "ViewLayer.CryptoObject",
                    "cryptomatte/542cafa/hash": "MurmurHash3_32",
                    "cryptomatte/542cafa/conversion": "uint32_to_float32",
                    "cryptomatte/542cafa/manifest": '{"Cube":"a8fce865"}'}
    root = SimpleNamespace(name="Root", parent=None)
    leaf = SimpleNamespace(name="Leaf", parent=SimpleNamespace(name="Mid", parent=root))
    assert ecrypto.asset_name(leaf) == "Root" and ecrypto.asset_name(root) == "Root"
    layer = SimpleNamespace(use_pass_cryptomatte_object=False, use_pass_cryptomatte_material=True,
                            use_pass_cryptomatte_asset=True, pass_cryptomatte_depth=4)
    assert ecrypto.enabled_kinds(layer) == ("material", "asset") and ecrypto.levels(layer) == 4


# ---------------------------------------------------------------- against Cycles
# Strips under an orthographic camera, one world unit a pixel, x in [-6, 6): pixel 5 holds three objects,
# pixel 8 is half background; "Obj.160" and "Obj.184" hash to exponents 0 and 255 (clamped to 1 and 254).
STRIPS = (("Ärger.001", -6.0, -3.5, None, "Rot ü"), ("Kind", -3.5, -1.25, "Ärger.001", "Obj.184"),
          ("Enkel", -1.25, -0.7, "Kind", None), ("Obj.160", -0.7, -0.2, None, "Rot ü"),
          ("Obj.184", -0.2, 2.5, None, "Obj.160"))
SAMPLES = 16


def strips_scene():
    """The STRIPS quads under an orthographic camera (parents at the identity: world positions unchanged),
    all three Cryptomatte kinds on at 6 levels."""
    from bpy_helpers import diffuse_material, new_scene, quad_object
    scene = new_scene(12, 4)                          # Blender's smallest height
    cam = scene.camera
    cam.location, cam.rotation_euler = (0.0, 0.0, 5.0), (0.0, 0.0, 0.0)
    cam.data.type, cam.data.ortho_scale = "ORTHO", 12.0
    materials, objects = {}, {}
    for name, x0, x1, parent, material in STRIPS:
        if material and material not in materials:
            materials[material] = diffuse_material(material)
        objects[name] = quad_object(name, (x0, -5, 0), (x1 - x0, 0, 0), (0, 10, 0), materials.get(material))
        if parent:
            objects[name].parent = objects[parent]
    view_layer = scene.view_layers[0]
    for kind in ecrypto.KINDS:
        setattr(view_layer, f"use_pass_cryptomatte_{kind}", True)
    view_layer.pass_cryptomatte_depth = 6
    return scene


@pytest.fixture(scope="module")
def cycles_render():
    from bpy_helpers import configure_cycles
    scene = strips_scene()
    view_layer = scene.view_layers[0]
    scene.render.engine = "CYCLES"
    configure_cycles(scene, SAMPLES, 0, 1)
    parts, strings = render_multilayer(scene)
    names = {"object": [s[0] for s in STRIPS], "asset": ["Ärger.001", "Obj.160", "Obj.184"],
             "material": ["Rot ü", "Obj.184", "default_surface", "Obj.160"]}
    return SimpleNamespace(parts=parts, strings=strings, names=names, view_layer=view_layer.name)


def _cycles_layers(render, kind):
    """(H, W, 4 L) of one kind, channels ordered as CryptoFilm.layers."""
    names = ecrypto.layer_names(render.view_layer, kind, 6)
    return np.concatenate([np.stack([render.parts[n][c] for c in "rgba"], axis=-1) for n in names], axis=-1)


def test_cycles_registers_the_same_passes_and_metadata(cycles_render):
    """The parts of Cycles' EXR are our layer names; its header holds our metadata keys and values, its
    manifests our hashes (Cycles also lists its built-in shaders among the materials)."""
    expected = {n for kind in ecrypto.KINDS for n in ecrypto.layer_names(cycles_render.view_layer, kind, 6)}
    assert {p for p in cycles_render.parts if "Crypto" in p} == expected
    for kind in ecrypto.KINDS:
        ours = ecrypto.metadata(cycles_render.view_layer, kind, cycles_render.names[kind])
        for key, value in ours.items():
            theirs = cycles_render.strings[key]
            if key.endswith("/manifest"):
                theirs = json.loads(theirs)
                assert {n: theirs[n] for n in cycles_render.names[kind]} == json.loads(value), kind
            else:
                assert theirs == value, key


def test_cycles_pixels_hold_our_ids(cycles_render):
    """Every id in Cycles' layers is bit for bit hash_name of the object, of its material (no material:
    Cycles' "default_surface") or of its top-most parent (pixel 2: "Ärger.001" and its child "Kind", one
    asset); Obj.184 covers pixel 7 fully."""
    for kind in ecrypto.KINDS:
        layers = _cycles_layers(cycles_render, kind)
        ours = set(hash_names(cycles_render.names[kind]).view(np.uint32).tolist()) | {0}
        assert set(layers[..., 0::2].view(np.uint32).ravel().tolist()) <= ours, kind
    objects = _cycles_layers(cycles_render, "object")
    assert np.all(objects[:, 7, 0] == hash_name("Obj.184")) and np.all(objects[:, 7, 1] == 1.0)
    assert hash_name("Obj.160").view(np.uint32) == 0x00ECF718      # exponent 0 -> 1
    assert hash_name("Obj.184").view(np.uint32) == 0x7F589B93      # exponent 255 -> 254
    assets = _cycles_layers(cycles_render, "asset")
    assert np.all(assets[:, 2, 0] == hash_name("Ärger.001")) and np.all(assets[:, 2, 1] == 1.0)


def test_layers_reproduce_cycles_layout(cycles_render):
    """Fed the samples Cycles' Object layers imply (coverage x 16 samples of weight 1 per id, in its rank
    order), CryptoFilm.layers returns Cycles' layers bit for bit: ranking, ties, normalisation, the
    half-background pixel (coverages summing to less than 1) and the pixel holding three objects."""
    cycles = _cycles_layers(cycles_render, "object")
    h, w, _ = cycles.shape
    ids, coverage = cycles[..., 0::2].reshape(h * w, -1), cycles[..., 1::2].reshape(h * w, -1)
    counts = np.rint(coverage * SAMPLES).astype(np.int64)
    np.testing.assert_array_equal(counts / SAMPLES, coverage)
    pixel, slot = np.nonzero(counts)
    film = CryptoFilm(h, w, depth=6)
    film.add(np.repeat(pixel, counts[pixel, slot]), np.repeat(ids[pixel, slot], counts[pixel, slot]),
             np.ones(counts.sum(), np.float32))
    np.testing.assert_array_equal(film.layers(SAMPLES).view(np.uint32), cycles.view(np.uint32))
    assert np.all(np.count_nonzero(counts.reshape(h, w, -1)[:, 5], axis=-1) == 3)
    assert np.all(coverage.reshape(h, w, -1)[:, 8].sum(axis=-1) < 1)
