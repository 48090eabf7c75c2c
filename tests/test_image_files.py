"""engine.image_files.written_file_problem: every format Blender writes, whole and cut short (what a full
disk leaves behind), and a file with a hole."""
import os

import bpy
import numpy as np
import pytest

from bpy_helpers import diffuse_material, mesh_object, new_scene, set_world

FORMATS = ["PNG", "JPEG", "OPEN_EXR", "TIFF", "BMP", "TARGA", "TARGA_RAW", "IRIS", "JPEG2000", "CINEON", "DPX",
           "HDR", "WEBP"]


@pytest.fixture(scope="module")
def rendered():
    """A small Ember render with a few passes: the Render Result every save writes."""
    scene = new_scene(96, 64)  # JPEG 2000 needs 64 pixels or more a side
    mesh_object("Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2, 3)], diffuse_material("Floor"))
    set_world(scene, color=(0.3, 0.4, 0.5))
    scene.render.engine = "EMBER"
    scene.ember.samples, scene.ember.use_denoising = 1, False
    scene.view_layers[0].use_pass_z = scene.view_layers[0].use_pass_normal = True
    bpy.ops.render.render(write_still=False)
    return scene


def write(scene, path, file_format, media="IMAGE", **settings):
    image_settings = scene.render.image_settings
    image_settings.media_type = media
    image_settings.file_format = file_format
    for key, value in settings.items():
        setattr(image_settings, key, value)
    bpy.data.images["Render Result"].save_render(str(path), scene=scene)
    return path.read_bytes()


def cuts(size):
    """Lengths a failed write leaves: nothing, a few bytes, a page, the middle, the last bytes missing."""
    return sorted({1, 7, min(4096, size - 1), size // 3, size // 2, size - 100, size - 2, size - 1} - {0})


def assert_whole_and_cuts_caught(path, data, file_format):
    from ember.engine.image_files import written_file_problem
    assert written_file_problem(str(path), file_format) is None
    for n in cuts(len(data)):
        path.write_bytes(data[:n])
        assert written_file_problem(str(path), file_format) is not None, (file_format, n, len(data))
    path.write_bytes(b"")
    assert written_file_problem(str(path), file_format) == "it is empty"


@pytest.mark.parametrize("file_format", FORMATS)
def test_every_format_whole_passes_and_cut_short_fails(rendered, tmp_path, file_format):
    path = tmp_path / "frame"
    data = write(rendered, path, file_format)
    assert_whole_and_cuts_caught(path, data, file_format)


@pytest.mark.parametrize("codec", ["NONE", "ZIP", "PIZ", "DWAA", "RLE"])
def test_openexr_codecs_and_multilayer(rendered, tmp_path, codec):
    from ember.engine.image_files import EXR_MULTIPART
    """Each codec packs a different number of scanlines per chunk; the multilayer file has one part per
    layer and pass (the chunks' leaders carry a part number)."""
    path = tmp_path / "frame.exr"
    data = write(rendered, path, "OPEN_EXR", exr_codec=codec, color_depth="32")
    assert_whole_and_cuts_caught(path, data, "OPEN_EXR")
    data = write(rendered, path, "OPEN_EXR_MULTILAYER", media="MULTI_LAYER_IMAGE", exr_codec=codec)
    assert int.from_bytes(data[4:8], "little") & EXR_MULTIPART
    assert_whole_and_cuts_caught(path, data, "OPEN_EXR_MULTILAYER")


def test_a_zeroed_chunk_table_and_a_hole_are_caught(rendered, tmp_path):
    """What a writer leaves when it seeks back over a failed write: the right length, but an offset table
    never filled in, or a range never written (a sparse file)."""
    from ember.engine.image_files import exr_headers, written_file_problem
    path = tmp_path / "frame.exr"
    data = bytearray(write(rendered, path, "OPEN_EXR", exr_codec="ZIP", color_depth="32"))
    table = exr_headers(bytes(data))[2]
    zeroed = data[:table] + bytes(16) + data[table + 16:]
    path.write_bytes(zeroed)
    assert "chunk table" in written_file_problem(str(path), "OPEN_EXR")
    with open(path, "wb") as f:
        f.write(data[:100])
        f.seek(64 << 10)   # past a page or more, never written
        f.write(data[100:])
    has_holes = os.lseek(os.open(path, os.O_RDONLY), 0, os.SEEK_HOLE) < os.path.getsize(path)
    if not has_holes:
        pytest.skip("this file system does not report holes (SEEK_HOLE)")
    assert "never written" in written_file_problem(str(path), "OPEN_EXR")


def test_a_file_of_another_format_is_not_whole(rendered, tmp_path):
    from ember.engine.image_files import written_file_problem
    path = tmp_path / "frame"
    write(rendered, path, "PNG")
    assert written_file_problem(str(path), "OPEN_EXR") == "it is not an OpenEXR file"
    assert np.all([written_file_problem(str(path), f) is not None for f in ("JPEG", "TIFF", "BMP", "DPX", "WEBP")])
