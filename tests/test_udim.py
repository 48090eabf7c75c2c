"""Tiled (UDIM) images: each tile a texture of its own, each lookup in the tile its UV falls in, as Cycles'
kernel_image_udim_map (kernel/util/image_2d.h): tile 1001 + 10 x int(v) + int(u), int() truncating toward zero,
u in [0, 10) and v >= 0, the UV made relative to the tile; magenta where the image has no such tile.

Cycles is not the oracle here: in Blender as a Python module it does not resolve the <UDIM> token of a tiled
image set up by a script ("Image file ...<UDIM>.png does not exist", every lookup magenta), so these tests check
Ember against that rule directly."""
import bpy
import numpy as np
import pytest

from bpy_helpers import emission_material, export_current, new_scene, quad_object, render_to_array, set_world

RED, GREEN, BLUE = (255, 0, 0), (0, 255, 0), (0, 0, 255)


def _write(path, colour, size=4):
    bpy.utils.expose_bundled_modules()
    import OpenImageIO as oiio
    out = oiio.ImageOutput.create(path)
    assert out.open(path, oiio.ImageSpec(size, size, 3, "uint8"))
    assert out.write_image(np.tile(np.array(colour, np.uint8), (size, size, 1)))
    out.close()


def _tiled_card(tmp_path, tiles: dict, packed=False):
    """An emitting card whose Image Texture (Closest) reads a tiled image of flat-coloured tiles, its UVs spanning
    [-1, 3] x [-1, 3], seen whole by an orthographic camera: pixel block (row, column) of a 4 x 4 grid sees the UV
    square [column - 1, column) x [2 - row, 3 - row)."""
    for number, colour in tiles.items():
        _write(str(tmp_path / f"skin.{number}.png"), colour)
    scene = new_scene(40, 40)
    set_world(scene, (0.0, 0.0, 0.0))
    image = bpy.data.images.load(str(tmp_path / f"skin.{min(tiles)}.png"))
    image.source = "TILED"
    if packed:
        image.pack()
    assert sorted(t.number for t in image.tiles) == sorted(tiles)

    def build(tree):
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image, node.interpolation = image, "Closest"
        return node.outputs["Color"]
    card = quad_object("Card", (-2, -2, 0), (4, 0, 0), (0, 4, 0), emission_material("Skin", build=build))
    for loop, uv in zip(card.data.loops, [(-1, -1), (3, -1), (3, 3), (-1, 3)]):
        card.data.uv_layers[0].data[loop.index].uv = uv
    camera = bpy.data.cameras.new("Top")
    camera.type, camera.ortho_scale = "ORTHO", 4.0
    ob = bpy.data.objects.new("Top", camera)
    ob.location = (0, 0, 3)
    scene.collection.objects.link(ob)
    scene.camera = ob
    return scene


def _grid(scene):
    image = render_to_array(scene, "EMBER", 4)[..., :3]
    return np.array([[image[r * 10 + 2:r * 10 + 8, c * 10 + 2:c * 10 + 8].mean(axis=(0, 1)) for c in range(4)]
                     for r in range(4)])


@pytest.mark.parametrize("packed", [False, True])
def test_each_uv_reads_its_tile_and_missing_tiles_are_magenta(tmp_path, packed):
    scene = _tiled_card(tmp_path, {1001: RED, 1002: GREEN, 1011: BLUE}, packed)
    exported = export_current()
    assert not exported.warnings, exported.warnings
    grid = _grid(scene)
    red, green, blue, magenta = (np.array(c, np.float32) for c in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1)))
    # Rows top to bottom: v in [2, 3), [1, 2), [0, 1), [-1, 0); columns: u in [-1, 0), [0, 1), [1, 2), [2, 3).
    # int() truncates toward zero: u in (-1, 0) reads tile column 0, v in (-1, 0) tile row 0.
    expected = [[magenta, magenta, magenta, magenta],
                [blue, blue, magenta, magenta],
                [red, red, green, magenta],
                [red, red, green, magenta]]
    np.testing.assert_allclose(grid, np.array(expected), atol=1e-3)


def test_an_unreadable_tile_is_named_and_renders_magenta(tmp_path):
    scene = _tiled_card(tmp_path, {1001: RED, 1002: GREEN})
    (tmp_path / "skin.1002.png").write_bytes(b"not an image")
    exported = export_current()
    assert any("UDIM tile 1002" in w and "'skin.1001.png'" in w for w in exported.warnings), exported.warnings
    grid = _grid(scene)
    np.testing.assert_allclose(grid[2, 2], (1, 0, 1), atol=1e-3)
    np.testing.assert_allclose(grid[2, 1], (1, 0, 0), atol=1e-3)
