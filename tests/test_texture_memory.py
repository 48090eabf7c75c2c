"""8-bit images stay bytes from the file to the kernel (engine/export/images.py, kernels/textures.py): read
from their file as Blender reads it, 1 byte per channel, never a float copy of the whole image; lookups on
them equal, bit for bit, lookups on the float values Blender's image.pixels gives."""
import os
import tracemalloc

import bpy
import numpy as np
import pytest

from bpy_helpers import export_current, new_scene, quad_object

from ember.engine.export.images import associated_bytes, file_bytes, read_image
from ember.kernels import Renderer
from ember.kernels.textures import BYTE_SCALE, WORD_SCALE, Texture, sample_texture


def _oiio():
    bpy.utils.expose_bundled_modules()
    import OpenImageIO
    return OpenImageIO


def write_image(path: str, pixels: np.ndarray) -> str:
    """Write (H, W, C) uint8 or uint16 pixels, row 0 at the top, with Blender's OpenImageIO (the format by
    extension)."""
    oiio = _oiio()
    height, width, channels = pixels.shape
    out = oiio.ImageOutput.create(path)
    assert out.open(path, oiio.ImageSpec(width, height, channels, str(pixels.dtype))), oiio.geterror()
    assert out.write_image(np.ascontiguousarray(pixels)), out.geterror()
    out.close()
    return path


def _pattern(height: int, width: int, channels: int, seed: int = 1) -> np.ndarray:
    """Every byte value, in a pattern that compresses (a smooth field plus a little noise)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width]
    planes = [(x * 7 + y * 3) % 256, (x * y) % 256, (x + 5 * y) % 256, 128 + 127 * np.sin(x / 9.0 + y / 5.0)]
    image = np.stack(planes[:channels], -1) + rng.integers(0, 2, (height, width, channels))
    return np.clip(image, 0, 255).astype(np.uint8)


def _blender_floats(image) -> np.ndarray:
    """image.pixels as Blender gives them: (H, W, 4) float32, row 0 at the bottom."""
    flat = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(flat)
    width, height = image.size
    return flat.reshape(height, width, -1)


@pytest.mark.parametrize("name, channels", [("grey.png", 1), ("grey_alpha.png", 2), ("rgb.png", 3),
                                            ("rgba.png", 4), ("photo.jpg", 3), ("grey.jpg", 1),
                                            ("rgba.tif", 4)])
@pytest.mark.parametrize("packed", [False, True])
def test_8bit_files_are_read_as_blender_reads_them(tmp_path, name, channels, packed):
    """From their file, or packed (as glTF files and many .blend files carry their textures; the file is then
    gone): as bytes, equal to what Blender reads."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    path = write_image(str(tmp_path / name), _pattern(37, 53, channels))
    image = bpy.data.images.load(path)
    if packed:
        image.pack()
        os.remove(path)
    read = file_bytes(image)
    assert (image.packed_file is not None) == packed and not image.is_dirty
    assert read is not None and read.dtype == np.uint8
    expected = _blender_floats(image)          # Blender: RGBA, grey in R, G and B, alpha 255 when absent
    got = read.astype(np.float32) * BYTE_SCALE
    if got.shape[2] == 1:
        got = np.repeat(got, 3, axis=2)
    np.testing.assert_array_equal(got, expected[:, :, :got.shape[2]])
    if got.shape[2] == 3:
        assert (expected[:, :, 3] == 1).all()


def test_images_blender_reads_itself_still_become_bytes():
    """Generated or painted images come through image.pixels and are turned back into bytes."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    image = bpy.data.images.new("Painted", 19, 11, alpha=True)
    values = _pattern(11, 19, 4).astype(np.float32) / 255
    image.pixels.foreach_set(values.ravel())
    assert file_bytes(image) is None
    pixels = read_image(image, [], alpha=True)
    assert pixels.array.dtype == np.uint8 and pixels.array.shape == (11, 19, 4)
    straight = np.rint(_blender_floats(image) * 255).astype(np.uint8)
    np.testing.assert_array_equal(straight * BYTE_SCALE, _blender_floats(image))
    # Colour associated with alpha as Cycles stores a straight 8-bit image: c x a / 255 rounded down.
    np.testing.assert_array_equal(pixels.array[:, :, 3], straight[:, :, 3])
    np.testing.assert_array_equal(pixels.array[:, :, :3],
                                  straight[:, :, :3].astype(np.int32) * straight[:, :, 3:].astype(np.int32) // 255)


def test_an_8bit_texture_stays_bytes_from_file_to_kernel(tmp_path):
    """The design promise: an 8-bit RGB image costs Ember 3 bytes per texel, in the export (while reading
    it, beside blocks of a few MB) and in the renderer, which shares the export's array."""
    size = 2048
    path = write_image(str(tmp_path / "big.png"), _pattern(size, size, 3))
    scene = new_scene(8, 8)
    material = bpy.data.materials.new("Textured")
    tree = material.node_tree
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.image = bpy.data.images.load(path)
    tree.links.new(texture.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    quad_object("Plane", (-2, 0, -1), (4, 0, 0), (0, 0, 4), material)
    tracemalloc.start()
    try:
        exported = export_current()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    (stored,) = exported.scene.textures
    assert stored.dtype == np.uint8 and stored.nbytes == 3 * size * size
    assert peak < 3 * size * size + (16 << 20), f"export peak {peak / 2**20:.0f} MB"
    scene_arrays = exported.scene.validate().scene
    with Renderer(scene_arrays, threads=1) as renderer:
        kept = renderer.textures[0]
        assert kept.nbytes == stored.nbytes and np.shares_memory(kept.texels, stored)


def test_image_files_are_decoded_on_threads_during_the_export(tmp_path, monkeypatch):
    """The export starts decoding the image files of every material's tree (and of the node groups they use;
    each material's own tree is named alike) and of the world's on threads, each once (a plain HDRI world
    too), and the textures are what reading them one by one gives."""
    import threading
    from ember.engine.export import images
    paths = [write_image(str(tmp_path / f"t{k}.png"), _pattern(29 + k, 31, 3, seed=k)) for k in range(4)]
    scene = new_scene(8, 8)
    world = bpy.data.worlds.new("Sky")
    scene.world = world
    sky = world.node_tree.nodes.new("ShaderNodeTexEnvironment")
    sky.image = bpy.data.images.load(paths[3])
    world.node_tree.links.new(sky.outputs["Color"], world.node_tree.nodes["Background"].inputs["Color"])
    group = bpy.data.node_groups.new("Wear", "ShaderNodeTree")
    group.interface.new_socket("Color", in_out="OUTPUT", socket_type="NodeSocketColor")
    inner = group.nodes.new("ShaderNodeTexImage")
    inner.image = bpy.data.images.load(paths[2])
    inner.image.pack()
    output = group.nodes.new("NodeGroupOutput")
    group.links.new(inner.outputs["Color"], output.inputs["Color"])
    for k, name in enumerate(("A", "B")):
        material = bpy.data.materials.new(name)
        tree = material.node_tree
        texture = tree.nodes.new("ShaderNodeTexImage")
        texture.image = bpy.data.images.load(paths[k])
        bsdf = tree.nodes["Principled BSDF"]
        tree.links.new(texture.outputs["Color"], bsdf.inputs["Base Color"])
        if k == 1:
            node = tree.nodes.new("ShaderNodeGroup")
            node.node_tree = group
            tree.links.new(node.outputs["Color"], bsdf.inputs["Emission Color"])
        quad_object(f"Plane{k}", (-2 + 2 * k, 0, -1), (2, 0, 0), (0, 0, 2), material)
    decoded = []
    original = images._read_file
    monkeypatch.setattr(images, "_read_file",
                        lambda oiio, path, words=False: decoded.append(threading.current_thread().name)
                        or original(oiio, path, words))
    exported = export_current()
    assert len(decoded) == 4 and all(name.startswith("ember-images") for name in decoded)
    assert exported.scene.world.hdri is not None
    expected = sorted((images.file_bytes(bpy.data.images[f"t{k}.png"]) for k in range(3)), key=len)
    got = sorted(exported.scene.textures, key=len)
    assert len(got) == 3
    for texture, pixels in zip(got, expected):
        np.testing.assert_array_equal(np.asarray(texture), pixels)


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_byte_texture_lookups_equal_float_lookups_bit_for_bit(channels):
    """What the export handed over before (k / 255 as float32, grey in three channels) and what it hands over
    now (the bytes; RGBA associated in bytes, as Cycles stores them) look up alike, in every filter and
    extension."""
    rng = np.random.default_rng(7)
    stored = rng.integers(0, 256, (13, 17, channels), dtype=np.uint8)
    stored[0, :3, -1] = (0, 255, 128)          # alpha 0, 1 and between, for unassociation
    if channels == 4:
        stored = associated_bytes(stored)
    floats = stored.astype(np.float32) * BYTE_SCALE
    if channels == 1:
        floats = np.repeat(floats, 3, axis=2)
    as_bytes, as_floats = Texture(stored, srgb=True), Texture(floats, srgb=True)
    u = rng.uniform(-1.5, 2.5, 500).astype(np.float32)
    v = rng.uniform(-1.5, 2.5, 500).astype(np.float32)
    for interpolation in ("Closest", "Linear", "Cubic"):
        for extension in ("REPEAT", "EXTEND", "CLIP", "MIRROR"):
            np.testing.assert_array_equal(sample_texture(as_bytes, u, v, interpolation, extension),
                                          sample_texture(as_floats, u, v, interpolation, extension))
    for unassociate in (False, True):
        np.testing.assert_array_equal(as_bytes.lookup(u, v, unassociate=unassociate),
                                      as_floats.lookup(u, v, unassociate=unassociate))
    np.testing.assert_array_equal(as_bytes.lookup_alpha(u, v), as_floats.lookup_alpha(u, v))
    np.testing.assert_allclose(as_bytes.means(), as_floats.means(), rtol=1e-6)
    assert as_bytes.nbytes == stored.nbytes


@pytest.mark.parametrize("interpolation", ["Closest", "Linear"])
@pytest.mark.parametrize("alpha_output", [False, True])
@pytest.mark.parametrize("depth, space", [(8, "sRGB"), (16, "sRGB"), (16, "Linear Rec.709"), (16, "ACEScg"),
                                          (8, "Display P3"), (16, "Display P3")])
def test_straight_rgba_files_are_filtered_as_cycles_stores_them(tmp_path, interpolation, alpha_output, depth, space):
    """A straight-alpha RGBA PNG (foliage cards, decals) through an Image Texture at a constant UV, emitted. Cycles
    reads image files with OpenImageIO and stores them 8- or 16-bit, each colour value associated as c x a /
    255 (65,535) rounded down (util_image_multiply_native); it filters them and decodes sRGB after filtering,
    8-bit and 16-bit alike (util/image_metadata.cpp: is_compressible_as_srgb), and converts other linear
    spaces at load, and any other space of Blender's configuration through OpenColorIO (Display P3 here). Before,
    8-bit colour associated in float rendered 0.3-1.1% brighter; 16-bit files came through Blender's decoded
    floats, filtered after decoding (the red channel here 5x brighter with Linear interpolation) and, in a linear
    space, associated twice (36% darker); 8-bit Display P3 was read as sRGB, with a warning. Both engines'
    pixels are the same number here (no noise: one texel lookup per pixel), so the tolerance is float rounding
    (float16 where a space is converted at load, in both)."""
    from bpy_helpers import add_camera, emission_material, render_to_array, set_world
    rng = np.random.default_rng(7)
    one = (1 << depth) - 1
    pixels = rng.integers(0, one + 1, (4, 4, 4)).astype(np.uint8 if depth == 8 else np.uint16)
    pixels[:, :, 3] = rng.integers(one // 6, one - one // 6, (4, 4))   # every texel partly transparent
    path = write_image(str(tmp_path / "straight.png"), pixels)
    scene = new_scene(8, 8)
    set_world(scene, (0.0, 0.0, 0.0))

    def texture(tree):
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image = bpy.data.images.load(path, check_existing=False)
        node.image.colorspace_settings.name = space
        assert node.image.alpha_mode == "STRAIGHT"
        node.interpolation = interpolation
        uv = tree.nodes.new("ShaderNodeCombineXYZ")
        uv.inputs[0].default_value, uv.inputs[1].default_value = 0.33, 0.61
        tree.links.new(uv.outputs[0], node.inputs["Vector"])
        if not alpha_output:
            return node.outputs["Color"]
        mix = tree.nodes.new("ShaderNodeMix")   # black where transparent: the colour unassociated, then mixed
        mix.data_type = "RGBA"
        tree.links.new(node.outputs["Alpha"], mix.inputs["Factor"])
        mix.inputs[6].default_value = (0.0, 0.0, 0.0, 1.0)
        tree.links.new(node.outputs["Color"], mix.inputs[7])
        return mix.outputs[2]

    quad_object("Card", (-2, -2, 0), (4, 0, 0), (0, 4, 0), emission_material("Decal", build=texture))
    add_camera(scene, (0, 0, 3), (0, 0, 0))
    cycles = render_to_array(scene, "CYCLES", 1)[..., :3]
    ember = render_to_array(scene, "EMBER", 1)[..., :3]
    assert np.ptp(cycles, axis=(0, 1)).max() < 1e-6 and np.abs(cycles).min() > 0.01
    converted = space not in ("sRGB", "Linear Rec.709")
    np.testing.assert_allclose(ember, cycles, rtol=4e-3 if converted else 2e-5, atol=1e-4 if converted else 1e-6)


@pytest.mark.parametrize("packed", [False, True])
def test_a_16bit_file_stays_16bit_where_cycles_keeps_it_so(tmp_path, packed):
    """A 16-bit sRGB PNG is read from its file as uint16, 2 bytes a channel, sRGB-encoded (decoded after
    filtering); packed in the .blend, Cycles takes it from Blender as linear floats, and so does Ember."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    pixels = (_pattern(9, 13, 3).astype(np.uint16) * 257)
    image = bpy.data.images.load(write_image(str(tmp_path / "deep.png"), pixels))
    if packed:
        image.pack()
    read = read_image(image, [])
    if packed:
        assert read.array.dtype == np.float32 and not read.srgb
        return
    assert read.array.dtype == np.uint16 and read.srgb
    np.testing.assert_array_equal(read.array, pixels[::-1])
    texture = Texture(read.array, srgb=True)
    assert texture.nbytes == 9 * 13 * 3 * 2
    np.testing.assert_array_equal(texture.gather(np.arange(3)), (pixels[-1, :3].T * WORD_SCALE).astype(np.float32))
