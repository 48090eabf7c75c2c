"""`python -m ember render` in a subprocess, as a user or a render farm runs it."""
import os
import subprocess
import sys

import bpy
import numpy as np
import pytest

from bpy_helpers import diffuse_material, mesh_object, new_scene, set_world

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def ember(*args, timeout=300):
    """Run the command line with this interpreter, the checkout importable as `ember`."""
    code = ("import sys; sys.path.insert(0, %r); from bench.common import import_ember; import_ember(); "
            "import runpy; sys.argv = ['ember'] + sys.argv[1:]; runpy.run_module('ember', run_name='__main__')" % ROOT)
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=timeout,
                          cwd=ROOT)


def load_image(path):
    image = bpy.data.images.load(path, check_existing=False)
    try:
        w, h = image.size
        pixels = np.empty(w * h * 4, np.float32)
        image.pixels.foreach_get(pixels)
        return pixels.reshape(h, w, 4)
    finally:
        bpy.data.images.remove(image)


def test_demo_renders_end_to_end(tmp_path):
    out = tmp_path / "demo.png"
    run = ember("render", "-o", str(out), "--samples", "2", "--resolution", "160x90")
    assert run.returncode == 0, run.stderr
    assert "saved" in run.stdout and "Ember" in run.stdout
    image = load_image(str(out))
    assert image.shape == (90, 160, 4)
    rgb = image[..., :3]
    assert 0.05 < rgb.mean() < 0.95 and rgb.std() > 0.05  # a lit, varied picture, not a flat fill


@pytest.fixture
def blend_file(tmp_path):
    """A small saved .blend using Ember; saved by the test, never by Ember."""
    scene = new_scene(32, 24)
    mesh_object("Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2, 3)], diffuse_material("Floor"))
    set_world(scene, color=(0.3, 0.4, 0.5))
    scene.render.engine = "EMBER"
    scene.ember.samples = 2
    scene.ember.use_denoising = False  # the checks read exact colours
    path = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    return path


def test_file_frames_and_exr_output(tmp_path, blend_file):
    before = os.path.getmtime(blend_file), os.path.getsize(blend_file)
    run = ember("render", blend_file, "-o", str(tmp_path / "f_##.exr"), "--frames", "2-3", "--samples", "1")
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "f_02.exr").exists() and (tmp_path / "f_03.exr").exists()
    assert (os.path.getmtime(blend_file), os.path.getsize(blend_file)) == before  # never saved
    image = load_image(str(tmp_path / "f_02.exr"))
    assert image.shape == (24, 32, 4) and np.isfinite(image).all()
    assert np.isclose(image[-1, 0, 2], 0.5, rtol=1e-4)  # a corner sees the world: linear, no view transform


@pytest.mark.parametrize("args, message", [
    (["render", "/nonexistent/scene.blend"], "no such file"),
    (["render", "--frames", "9-3"], "ends before"),
    (["render", "--resolution", "wide"], "--resolution"),
    (["render", "-o", "/proc/ember/out.png"], "cannot create the directory '/proc/ember'"),
    (["render", "-o", "out/picture.gif"], "extensions"),
    (["render", "--samples", "zero"], "invalid int"),
])
def test_bad_input_is_one_clear_line_and_a_nonzero_exit(args, message):
    run = ember(*args, timeout=120)
    assert run.returncode != 0
    lines = [line for line in run.stderr.strip().splitlines() if line.startswith("ember: error")]
    assert len(lines) == 1 and message in lines[0], run.stderr
    assert "Traceback" not in run.stderr


def test_scene_without_camera(tmp_path):
    new_scene(16, 16)
    bpy.data.objects.remove(bpy.context.scene.camera)
    path = str(tmp_path / "nocam.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    run = ember("render", path, "-o", str(tmp_path / "x.png"))
    assert run.returncode == 1
    assert run.stderr.strip().splitlines()[-1] == "ember: error: scene 'Scene' has no camera"
    assert not (tmp_path / "x.png").exists()


def test_passes_write_a_multilayer_exr(tmp_path, blend_file):
    """--passes: Blender's multilayer OpenEXR with each pass as Cycles names it; --no-denoise honoured."""
    out = tmp_path / "frame.exr"
    run = ember("render", blend_file, "-o", str(out), "--samples", "1", "--no-denoise",
                "--passes", "depth,normal,object_index,denoising")
    assert run.returncode == 0, run.stderr
    data = out.read_bytes()
    for name in (b"Combined", b"Depth", b"Normal", b"Object Index", b"Denoising Albedo", b"Denoising Normal"):
        assert b"ViewLayer." + name in data, name
    assert b"Noisy Image" not in data  # not denoised: no noisy copy
    bad = ember("render", blend_file, "-o", str(tmp_path / "frame.png"), "--passes", "depth")
    assert bad.returncode != 0 and "ending in .exr" in bad.stderr
    bad = ember("render", blend_file, "-o", str(out), "--passes", "depth,shadows")
    assert bad.returncode != 0 and "unknown shadows" in bad.stderr


def test_sample_ranges_merge_into_the_whole(tmp_path, blend_file):
    """Samples 0-3 and 4-15 rendered apart (--sample-offset) and merged equal a 0-15 render up to float
    rounding (unequal ranges: a merge that does not weigh by sample count fails); the merge refuses a render
    without a sample count."""
    from ember.engine.merge import exr_strings
    whole, first, second, merged = (str(tmp_path / f"{n}.exr") for n in ("whole", "a", "b", "merged"))
    for out, extra in ((whole, ["--sample-offset", "0", "--samples", "16"]),
                       (first, ["--sample-offset", "0", "--samples", "4"]),
                       (second, ["--sample-offset", "4", "--samples", "12"])):
        run = ember("render", blend_file, "-o", out, *extra)
        assert run.returncode == 0, run.stderr
    assert exr_strings(second)["ember.samples"] == "12" and exr_strings(second)["ember.sample_offset"] == "4"
    run = ember("merge", first, second, "-o", merged)
    assert run.returncode == 0 and "16 samples" in run.stdout, run.stderr
    a, b = load_image(whole), load_image(merged)
    assert a.shape == b.shape and not np.array_equal(load_image(first), a)  # the halves differ from the whole
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6)
    bad = ember("merge", first, str(tmp_path / "missing.exr"), "-o", merged)
    assert bad.returncode != 0 and "no such file" in bad.stderr
    bad = ember("render", blend_file, "-o", merged, "--sample-offset", "8", "--samples", "8", "--pattern", "automatic")
    assert bad.returncode != 0 and "cannot render sample ranges" in bad.stderr

