"""SceneArrays validation, camera rays, texture and HDRI lookups, and the import rule."""
import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest

from ember.kernels import Camera, Materials, World, render, RenderSettings
from ember.kernels.camera import generate_rays, view_plane
from ember.kernels.environment import Environment, direction_to_equirect, equirect_to_direction
from ember.kernels.shapes import look_at, quad, uv_sphere
from ember.kernels.textures import Texture
from kernel_helpers import make_scene


def good_scene():
    positions, normals = uv_sphere(6)
    return make_scene(positions, normals)


# ---------------------------------------------------------------- validation
@pytest.mark.parametrize("change, field", [
    (lambda s: dict(positions=s.positions.astype(np.float64)), "positions"),
    (lambda s: dict(positions=s.positions[:, :2]), "positions"),
    (lambda s: dict(normals=s.normals[:-1]), "normals"),
    (lambda s: dict(uvs=np.zeros((len(s.positions), 3, 3), np.float32)), "uvs"),
    (lambda s: dict(material_ids=s.material_ids + 1), "material_ids"),
    (lambda s: dict(material_ids=s.material_ids.astype(np.int64)), "material_ids"),
    (lambda s: dict(materials=Materials.diffuse([[np.nan, 0, 0]])), r"materials\[0\] \(unnamed\) DIFFUSE Color"),
    (lambda s: dict(materials=Materials.diffuse([[0.5, 0.5, 0.5]], albedo_texture=[0])),
     r"materials\[0\] \(unnamed\) DIFFUSE Color"),
    (lambda s: dict(materials=Materials.diffuse([[0.5, 0.5, 0.5]], emission=[[np.nan, 1, 1]])),
     r"materials\[0\] \(unnamed\) EMISSION Color"),
    (lambda s: dict(materials=Materials(shaders=())), "materials"),
    (lambda s: dict(textures=(np.zeros((4, 4), np.float32),)), r"textures\[0\]"),
    (lambda s: dict(world=World(hdri=np.zeros((4, 8, 2), np.float32))), "world.hdri"),
    (lambda s: dict(world=World(strength=float("inf"))), "world.strength"),
    (lambda s: dict(camera=Camera(fov_rad=4.0)), "camera.fov_rad"),
    (lambda s: dict(camera=Camera(kind="FISHEYE")), "camera.kind"),
    (lambda s: dict(camera=Camera(clip_start=5.0, clip_end=1.0)), "camera.clip_start"),
    (lambda s: dict(camera=Camera(world_from_camera=np.zeros((4, 4)))), "camera.world_from_camera"),
    (lambda s: dict(camera=Camera(width=0)), "camera.width"),
])
def test_bad_scene_arrays_raise_a_value_error_naming_the_field(change, field):
    scene = good_scene()
    bad = dataclasses.replace(scene, **change(scene))
    with pytest.raises(ValueError, match=f"^{field}"):
        bad.validate()


def test_degenerate_and_nonfinite_triangles_are_dropped_and_counted():
    positions, normals = quad((-1, 0, -1), (2, 0, 0), (0, 0, 2))
    degenerate = np.array([[[0, 0, 0], [1, 1, 1], [2, 2, 2]]], np.float32)   # collinear
    point = np.zeros((1, 3, 3), np.float32)                                   # zero area
    nan = np.array([[[np.nan, 0, 0], [1, 0, 0], [0, 0, 1]]], np.float32)
    all_p = np.concatenate([positions, degenerate, point, nan])
    all_n = np.concatenate([normals, np.ones((3, 3, 3), np.float32)])
    all_n[0, 0] = np.inf  # a bad normal on a good triangle is repaired, not dropped
    scene = make_scene(all_p, all_n, world_color=(1, 1, 1))
    checked = scene.validate()
    assert checked.dropped_triangles == 3 and checked.repaired_normals == 1 and checked.nonfinite_triangles == 1
    assert checked.scene.triangle_count == 2 and np.isfinite(checked.scene.normals).all()
    result = render(scene, RenderSettings(samples=2))
    assert result.dropped_triangles == 3 and np.isfinite(result.image).all()


def test_big_meshes_are_checked_on_threads_with_the_same_answer(monkeypatch):
    """Above _PARALLEL_TRIANGLES the usable-triangle check runs in slices on threads, each in blocks of
    _BLOCK_TRIANGLES: the same answer, triangle for triangle (degenerate, non-finite and tiny ones among
    them, in every slice and block)."""
    from ember.kernels.scene import triangles
    rng = np.random.default_rng(1)
    pos = rng.random((30_001, 3, 3)).astype(np.float32)
    pos[::100, 1] = pos[::100, 0]
    pos[5::777, 2, 1] = np.nan
    pos[7::999] *= np.float32(1e-30)
    serial = triangles._usable_slice(pos)
    monkeypatch.setattr(triangles, "_PARALLEL_TRIANGLES", 1000)
    monkeypatch.setattr(triangles.os, "cpu_count", lambda: 4)
    np.testing.assert_array_equal(triangles.usable_triangles(pos), serial)
    monkeypatch.setattr(triangles, "_BLOCK_TRIANGLES", 1234)   # blocks that end inside each slice
    np.testing.assert_array_equal(triangles.usable_triangles(pos), serial)
    monkeypatch.setattr(triangles, "_PARALLEL_TRIANGLES", 10**9)
    np.testing.assert_array_equal(triangles.usable_triangles(pos), serial)
    assert (~serial).sum() > 300


def test_empty_scene_renders_the_world():
    scene = make_scene(np.zeros((0, 3, 3), np.float32), np.zeros((0, 3, 3), np.float32), world_color=(0.25, 0.5, 1))
    img = render(scene, RenderSettings(samples=1)).image
    assert np.allclose(img, [0.25, 0.5, 1.0, 1.0])


# ---------------------------------------------------------------- camera
def test_perspective_rays_follow_the_field_of_view_and_shift():
    fov = np.radians(60)
    cam = Camera(world_from_camera=look_at((0, 0, 0), (0, 1, 0)), fov_rad=fov, width=200, height=100,
                 clip_start=0.5)
    half = np.float32(0.5)
    o, d, t = generate_rays(cam, np.array([50, 50]), np.array([0, 100]), np.array([0, 0], np.float32),
                            np.array([half, 0], np.float32))
    assert np.allclose(d[1], [0, 1, 0], atol=1e-6)  # the centre of the frame looks down the view axis
    assert np.isclose(np.degrees(np.arccos(d[0] @ [0, 1, 0])), 30.0, atol=1e-4)  # left edge: half the FOV
    assert np.allclose(o[1], [0, 0.5, 0], atol=1e-6) and np.isclose(t[1], cam.clip_end - 0.5)
    # Portrait with AUTO fit: the FOV spans the taller axis.
    xmin, xmax, ymin, ymax = view_plane(dataclasses.replace(cam, width=100, height=200))
    assert np.isclose(ymax, np.tan(fov / 2)) and np.isclose(xmax, np.tan(fov / 2) / 2)
    # Shift moves the window by a fraction of the fitted axis.
    xmin_s, xmax_s, _, _ = view_plane(dataclasses.replace(cam, shift_x=0.25))
    width = 2 * np.tan(fov / 2)
    assert np.isclose(xmin_s, -width / 2 + 0.25 * width) and np.isclose(xmax_s, width / 2 + 0.25 * width)
    # VERTICAL fit on a landscape frame: the FOV spans the height.
    _, _, ymin_v, ymax_v = view_plane(dataclasses.replace(cam, sensor_fit="VERTICAL"))
    assert np.isclose(ymax_v - ymin_v, width)


def test_orthographic_rays_are_parallel_and_span_the_ortho_scale():
    cam = Camera(world_from_camera=look_at((0, -10, 0), (0, 0, 0)), kind="ORTHO", ortho_scale=4.0,
                 width=100, height=50, clip_start=1.0, clip_end=20.0)
    z = np.zeros(2, np.float32)
    o, d, t = generate_rays(cam, np.array([0, 0]), np.array([0, 99]), z, z)
    assert np.allclose(d, [0, 1, 0], atol=1e-6)
    assert np.isclose(o[1, 0] - o[0, 0], 4.0 * 99 / 100, atol=1e-5)
    assert np.allclose(o[:, 1], -9.0) and np.allclose(t, 19.0)


def test_pixel_aspect_stretches_the_vertical_extent():
    cam = Camera(width=100, height=100, pixel_aspect=2.0, sensor_fit="HORIZONTAL")
    xmin, xmax, ymin, ymax = view_plane(cam)
    assert np.isclose((ymax - ymin) / (xmax - xmin), 0.5)


def test_row_zero_is_the_top_of_the_image():
    # A bright quad above the view axis shows up in the top rows only.
    positions, normals = quad((-5, 3, 0.2), (10, 0, 0), (0, 0, 5))
    scene = make_scene(positions, normals, albedo=(0, 0, 0), emission=(1, 1, 1),
                       camera=Camera(world_from_camera=look_at((0, -3, 0), (0, 0, 0)), width=16, height=16))
    img = render(scene, RenderSettings(samples=1)).image
    assert img[0, 8, 0] == 1.0 and img[15, 8, 0] == 0.0


# ---------------------------------------------------------------- textures and the world
def test_bilinear_texture_hits_texel_centres_and_wraps():
    image = np.arange(2 * 4 * 3, dtype=np.float32).reshape(2, 4, 3)  # row 0 is the bottom (v = 0)
    tex = Texture(image)
    u = np.float32([0.125, 0.375, 0.125, 0.0, 1.125])
    v = np.float32([0.25, 0.25, 0.75, 0.25, 0.25])
    out = tex.lookup(u, v)
    assert np.allclose(out[:, 0], image[0, 0]) and np.allclose(out[:, 1], image[0, 1])
    assert np.allclose(out[:, 2], image[1, 0])
    assert np.allclose(out[:, 3], (image[0, 0] + image[0, 3]) / 2)  # u = 0 sits between the first and last column
    assert np.allclose(out[:, 4], image[0, 0])  # repeat


def test_srgb_textures_are_decoded_after_filtering():
    """Cycles filters 8-bit sRGB images in their encoded form, then decodes: so does Ember."""
    from ember.kernels.textures import srgb_to_linear
    encoded = np.float32([[[0.1, 0.1, 0.1], [0.9, 0.9, 0.9]]])  # 1 x 2, sRGB-encoded
    between = Texture(encoded, srgb=True).lookup(np.float32([0.5]), np.float32([0.5]))
    assert np.allclose(between[:, 0], srgb_to_linear(np.float32(0.5)))
    linear = Texture(srgb_to_linear(encoded)).lookup(np.float32([0.5]), np.float32([0.5]))
    assert not np.allclose(linear, between)
    assert np.allclose(srgb_to_linear(np.float32([0.0, 0.04045, 1.0])), [0.0, 0.04045 / 12.92, 1.0])


def test_equirect_mapping_matches_cycles_convention():
    d = np.float32([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0]]).T
    u, v = direction_to_equirect(*d)
    assert np.allclose(u, [0.5, 0.25, u[2], 0.0]) or np.allclose(u, [0.5, 0.25, u[2], 1.0])
    assert np.allclose(v[[0, 1, 3]], 0.5) and np.isclose(v[2], 1.0)
    rng = np.random.default_rng(0)
    w = rng.normal(size=(3, 1000)).astype(np.float32)
    w /= np.linalg.norm(w, axis=0)
    back = equirect_to_direction(*direction_to_equirect(*w))[:3]
    assert np.allclose(np.stack(back), w, atol=1e-4)


def test_world_rotation_turns_the_map():
    hdri = np.zeros((8, 16, 3), np.float32)
    hdri[4, 8] = 1.0  # the +X direction (u = 0.5, v = 0.5)
    rot = np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], np.float32)  # takes +Y to +X
    env = Environment(World(hdri=hdri, strength=2.0, env_from_world=rot))
    plain = Environment(World(hdri=hdri, strength=2.0))
    x = np.float32([1]), np.float32([0]), np.float32([0])
    y = np.float32([0]), np.float32([1]), np.float32([0])
    assert plain.radiance(*x)[0, 0] > plain.radiance(*y)[0, 0]
    assert env.radiance(*y)[0, 0] > env.radiance(*x)[0, 0]


def test_textured_material_multiplies_albedo():
    positions, normals = quad((-1, 0, -1), (2, 0, 0), (0, 0, 2))
    uvs = np.float32([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])
    tex = np.full((4, 4, 4), 0.5, np.float32)
    scene = make_scene(positions, normals, uvs=uvs, world_color=(1, 1, 1),
                       materials=Materials.diffuse(np.ones((1, 3), np.float32), albedo_texture=[0]),
                       textures=(tex,), camera=Camera(world_from_camera=look_at((0, -3, 0), (0, 0, 0)),
                                                     width=8, height=8, fov_rad=np.radians(20)))
    img = render(scene, RenderSettings(samples=2, max_bounces=0, mode="COSINE")).image
    # The quad faces the camera with the world behind it: a diffuse plane of albedo 0.5 under a
    # uniform hemisphere of radiance 1 reflects 0.5.
    assert np.allclose(img[4, 4, :3], 0.5, rtol=1e-5)


# ---------------------------------------------------------------- the import rule
def test_kernels_import_without_blender():
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    code = (
        "import sys, os, tempfile\n"
        "for name in ('bpy', 'mathutils', 'gpu', 'bmesh', 'bpy_extras'): sys.modules[name] = None\n"
        f"d = tempfile.mkdtemp(); os.symlink({root!r}, os.path.join(d, 'ember')); sys.path.insert(0, d)\n"
        "import ember.kernels, ember.kernels.shapes\n"
        "from ember.kernels import render, RenderSettings\n"
        "from ember.kernels.shapes import cornell_box\n"
        "img = render(cornell_box(8, 8), RenderSettings(samples=1)).image\n"
        "assert img.shape == (8, 8, 4)\n"
        "assert not [m for m in sys.modules if m.split('.')[0] in ('bpy', 'mathutils', 'gpu') and sys.modules[m]]\n"
        "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
