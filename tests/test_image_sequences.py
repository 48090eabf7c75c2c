"""Image sequences: an Image Texture on a numbered sequence of files reads the file its image user names at the
scene's frame, as Cycles' sync does (blender/shader.cpp image_user_frame_number: Blender's
BKE_image_user_frame_get), and a frame whose file is missing renders magenta with a warning."""
import bpy
import numpy as np
import pytest

from bpy_helpers import add_camera, emission_material, export_current, new_scene, quad_object, render_to_array, set_world

from ember.engine.export.images import sequence_file, sequence_frame

COLOURS = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0)]


def _write_frames(tmp_path):
    bpy.utils.expose_bundled_modules()
    import OpenImageIO as oiio
    for i, colour in enumerate(COLOURS, start=1):
        path = str(tmp_path / f"flag_{i:04d}.png")
        out = oiio.ImageOutput.create(path)
        assert out.open(path, oiio.ImageSpec(4, 4, 3, "uint8"))
        assert out.write_image(np.tile(np.array(colour, np.uint8), (4, 4, 1)))
        out.close()


def _card(tmp_path, frame, offset=0, cyclic=False, duration=4):
    _write_frames(tmp_path)
    scene = new_scene(8, 8)
    set_world(scene, (0.0, 0.0, 0.0))
    image = bpy.data.images.load(str(tmp_path / "flag_0001.png"), check_existing=False)
    image.source = "SEQUENCE"

    def build(tree):
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image = image
        user = node.image_user
        user.frame_start, user.frame_duration, user.frame_offset, user.use_cyclic = 1, duration, offset, cyclic
        return node.outputs["Color"]
    quad_object("Card", (-2, -2, 0), (4, 0, 0), (0, 4, 0), emission_material("Flag", build=build))
    add_camera(scene, (0, 0, 3), (0, 0, 0))
    scene.frame_set(frame)
    return scene


@pytest.mark.parametrize("frame, offset, cyclic", [(2, 0, False), (2, 1, False), (7, 0, True), (9, 0, False)])
def test_the_frame_the_image_user_names_as_cycles(tmp_path, frame, offset, cyclic):
    """Frame 2 reads file 2, with Offset 1 file 3; Cyclic wraps frame 7 of four to file 3; past the end, the last
    file is held."""
    scene = _card(tmp_path, frame, offset, cyclic)
    exported = export_current()
    assert not exported.warnings, exported.warnings
    cycles = render_to_array(scene, "CYCLES", 1)[..., :3].mean(axis=(0, 1))
    ember = render_to_array(scene, "EMBER", 1)[..., :3].mean(axis=(0, 1))
    np.testing.assert_allclose(ember, cycles, atol=1e-5)
    assert cycles.max() > 0.5


def test_a_missing_frame_renders_magenta_with_a_warning(tmp_path):
    scene = _card(tmp_path, 3, offset=5)    # file 8 of a sequence of four: none
    exported = export_current()
    assert any("frame 8 of the sequence" in w and "flag_0008.png" in w for w in exported.warnings), exported.warnings
    np.testing.assert_allclose(render_to_array(scene, "EMBER", 1)[..., :3].mean(axis=(0, 1)), (1, 0, 1), atol=1e-5)


def test_frame_numbers_and_file_names_follow_blender():
    class User:
        frame_start, frame_duration, frame_offset, use_cyclic = 10, 5, 0, False
    user = User()
    assert [sequence_frame(user, f) for f in (8, 9, 10, 14, 15, 20)] == [0, 0, 1, 5, 5, 5]
    user.use_cyclic = True
    assert [sequence_frame(user, f) for f in (9, 10, 14, 15, 16)] == [5, 1, 5, 1, 2]
    user.frame_offset = 100
    assert sequence_frame(user, 10) == 101

    class Image:
        filepath, library = "/renders/shot.v2.0012.exr", None
    assert sequence_file(Image(), 7) == "/renders/shot.v2.0007.exr"
    assert sequence_file(Image(), 12345) == "/renders/shot.v2.12345.exr"
