"""Panoramic cameras (kernels.panorama, engine/export/panorama.py) against Cycles 5.0.

The oracle for the mapping: Cycles' first sample of a pixel sits at the centre of its filter table, so a
one-sample Cycles render of a world whose colour is the view direction (0.5 d + 0.5) holds, per pixel, the
direction Cycles' mapping gives there, or black where it gives none. Ember's export and rays at the same
raster positions must give the same directions to float precision and no ray exactly where Cycles leaves
black. Ember's own renders must then match Cycles per pixel within the estimator's noise (that world), and
per block over an HDRI (forest.exr). Unit tests: each mapping's inverse, the rays' clipping and thin lens,
the pixel spread, validation.
"""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from bpy_helpers import (compare_to_cycles, emission_material, export_current, new_scene, quad_object,
                         render_to_array, set_world)
from ember.kernels import pixel_filter
from ember.kernels.camera import generate_rays
from ember.kernels.lens import sample_aperture
from ember.kernels.panorama import PANORAMA_TYPES, panorama_directions, panorama_raster, pixel_spread
from ember.kernels.scene import Camera
from ember.kernels.shapes import look_at

EPS32 = float(np.finfo(np.float32).eps)
# Cycles maps in float32: a few dozen operations on angles up to 2 pi, each within half an ulp, put its
# directions within about 32 x 2 pi x eps32 / 2 of the exact ones (measured: under 1e-6); colours are
# 0.5 d + 0.5. One hundredth of a pixel moves a colour by 10x this at the widest pixels here.
COLOUR_TOL = 0.5 * 32 * 2 * math.pi * EPS32 / 2
Z = 5.0  # per-pixel z-score bound of the noisy comparisons (~5k pixels x 3 channels per image)

# Blender settings (camera data, else render) of each case; non-default values everywhere they exist.
CONFIGS = {
    "equirectangular": dict(panorama_type="EQUIRECTANGULAR"),
    "equirectangular_ranges": dict(panorama_type="EQUIRECTANGULAR", latitude_min=-0.6, latitude_max=1.2,
                                   longitude_min=-2.5, longitude_max=1.0, shift_x=0.1, shift_y=-0.05),
    "cubemap_face": dict(panorama_type="EQUIANGULAR_CUBEMAP_FACE", shift_y=0.08),
    "mirrorball": dict(panorama_type="MIRRORBALL", shift_x=-0.07),
    "equidistant_shifted": dict(panorama_type="FISHEYE_EQUIDISTANT", fisheye_fov=math.radians(200), shift_x=0.12),
    "equisolid_vertical_fit": dict(panorama_type="FISHEYE_EQUISOLID", fisheye_lens=8.0,
                                   fisheye_fov=math.radians(160), sensor_fit="VERTICAL", sensor_height=20.0),
    # A tall frame of wide pixels: AUTO fits the sensor width to the longer side counting the pixel aspect.
    "equisolid_tall_auto": dict(panorama_type="FISHEYE_EQUISOLID", resolution=(32, 48), pixel_aspect_x=1.25,
                                fisheye_lens=6.0, fisheye_fov=math.radians(190), sensor_width=30.0),
    "polynomial": dict(panorama_type="FISHEYE_LENS_POLYNOMIAL", fisheye_polynomial_k0=0.02,
                       fisheye_polynomial_k1=-0.045, fisheye_polynomial_k2=3e-4, fisheye_polynomial_k3=-2e-5,
                       fisheye_polynomial_k4=1e-7, fisheye_fov=math.radians(100), sensor_fit="HORIZONTAL"),
    "central_cylindrical": dict(panorama_type="CENTRAL_CYLINDRICAL", central_cylindrical_range_u_min=-2.0,
                                central_cylindrical_range_u_max=1.5, central_cylindrical_range_v_min=-0.5,
                                central_cylindrical_range_v_max=1.5, central_cylindrical_radius=1.3),
}
WITH_HOLES = ("mirrorball", "equidistant_shifted", "equisolid_vertical_fit", "equisolid_tall_auto", "polynomial")
ONE_PER_TYPE = ("equirectangular_ranges", "cubemap_face", "mirrorball", "equidistant_shifted",
                "equisolid_tall_auto", "polynomial", "central_cylindrical")


# ---------------------------------------------------------------- scenes
def direction_world(scene):
    """A world whose colour is 0.5 x view direction + 0.5 (Texture Coordinate Generated on a world)."""
    world = bpy.data.worlds.new("Directions")
    scene.world = world
    tree = world.node_tree
    tree.nodes.clear()
    out, background = tree.nodes.new("ShaderNodeOutputWorld"), tree.nodes.new("ShaderNodeBackground")
    coords, affine = tree.nodes.new("ShaderNodeTexCoord"), tree.nodes.new("ShaderNodeVectorMath")
    affine.operation = "MULTIPLY_ADD"
    affine.inputs[1].default_value = affine.inputs[2].default_value = (0.5, 0.5, 0.5)
    tree.links.new(coords.outputs["Generated"], affine.inputs[0])
    tree.links.new(affine.outputs["Vector"], background.inputs["Color"])
    tree.links.new(background.outputs["Background"], out.inputs["Surface"])


def pano_scene(name, hdri=None):
    settings = dict(CONFIGS[name])
    scene = new_scene(*settings.pop("resolution", (48, 32)))
    scene.ember.pixel_filter_type = "BOX"
    if hdri is None:
        direction_world(scene)
    else:
        set_world(scene, hdri=hdri)
    # Nothing in the scene samples the world: spare Cycles its importance map.
    scene.world.cycles.sampling_method = "NONE"
    scene.camera.rotation_euler = (1.1, 0.2, 0.7)  # no camera axis along a world axis
    cam = scene.camera.data
    cam.type = "PANO"
    for key, value in settings.items():
        setattr(cam if hasattr(cam, key) else scene.render, key, value)
    return scene


def cycles_first_offset() -> np.float32:
    """Where Cycles' sample 0 lands in its pixel (from the corner): its box filter table read at 0.5,
    between entries 511 and 512 of 1024, a hair past the centre."""
    table = pixel_filter.table("BOX", 1.0)
    return np.float32(0.5 * (table[511] + table[512]))


def pixels(h, w):
    row, col = np.mgrid[0:h, 0:w]
    return row.ravel().astype(np.int32), col.ravel().astype(np.int32)


def sky(camera, row, col, jx, jy):
    """Ember's camera rays as the direction world's colours (P, 3) float64, and whether each has a ray."""
    n = len(row)
    _, dirs, t_max = generate_rays(camera, row, col, np.full(n, jx, np.float32), np.full(n, jy, np.float32))
    return 0.5 * dirs.astype(np.float64) + 0.5, t_max > 0


def sky_statistics(camera, grid=8):
    """Per pixel over a grid x grid of positions: the colour's mean and variance (P, 3) (0 where there is
    no ray, as Cycles counts those samples) and the fraction of positions with a ray (P,)."""
    row, col = pixels(camera.height, camera.width)
    colours, rays = [], []
    for j in (np.arange(grid) + 0.5) / grid:
        for i in (np.arange(grid) + 0.5) / grid:
            colour, valid = sky(camera, row, col, i, j)
            colours.append(np.where(valid[:, None], colour, 0.0))
            rays.append(valid)
    colours = np.stack(colours)
    return colours.mean(axis=0), colours.var(axis=0), np.mean(rays, axis=0)


def away_from_the_edge(mask):
    """(H, W) bool: the pixels of mask whose neighbours are all in it too. A pixel next to the edge of the
    image circle may hold a sliver on the other side between its grid's points (and near a mirror ball's
    rim the colour turns too fast for the grid to measure it). Beyond the image nothing was measured, so
    pixels on its border do not count as away from the edge: the shifted fisheye's circle grazes two border
    pixels that the grid finds full (0.99976 of them has a ray on a 64x64 grid), and one sample in 128
    beyond the circle put them 11 standard errors off once samples of neighbouring pixels were laid out
    together (the blue-noise pattern), by chance."""
    padded = np.pad(mask, 1, constant_values=False)
    h, w = mask.shape
    return np.all([padded[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)


def rays_or_not(camera):
    """(H, W) bool masks of the pixels surely without any ray, and surely all rays."""
    _, _, covered = sky_statistics(camera)
    covered = covered.reshape(camera.height, camera.width)
    return away_from_the_edge(covered == 0), away_from_the_edge(covered == 1)


# ---------------------------------------------------------------- the mapping, against Cycles exactly
@pytest.mark.parametrize("name", CONFIGS)
def test_sky_directions_match_cycles_mapping(name):
    scene = pano_scene(name)
    cycles = render_to_array(scene, "CYCLES", 1)
    result = export_current()
    camera = result.scene.camera
    assert camera.kind == "PANO" and camera.panorama_type == CONFIGS[name]["panorama_type"]
    assert not result.warnings
    h, w = cycles.shape[:2]
    row, col = pixels(h, w)
    c = cycles_first_offset()
    colour, valid = sky(camera, row, col, c, 1 - c)  # Cycles' raster y counts up from the bottom
    # Positions within float noise of the edge of the image circle may fall either way.
    edge = np.zeros(len(row), bool)
    for dx, dy in ((1e-3, 0), (-1e-3, 0), (0, 1e-3), (0, -1e-3)):
        edge |= sky(camera, row, col, c + dx, 1 - c + dy)[1] != valid
    rgb = cycles[..., :3].reshape(-1, 3).astype(np.float64)
    black = np.all(rgb == 0, axis=1)
    np.testing.assert_array_equal(black[~edge], ~valid[~edge], err_msg="pixels left black differ")
    assert valid.any() and (~valid).any() == (name in WITH_HOLES)
    error = np.abs(rgb - colour)[valid & ~edge].max()
    assert error < COLOUR_TOL, (error, COLOUR_TOL)


# ---------------------------------------------------------------- Ember's renders, against Cycles' noise
@pytest.mark.parametrize("name", ONE_PER_TYPE)
def test_ember_renders_the_sky_as_cycles(name):
    """Both engines, 128 box-filtered samples per pixel, per pixel within Z standard errors. The error of
    each is at most the colour's spread over the pixel / sqrt(samples) (independent samples; both engines
    stratify, which only lowers it). Pixels with a ray for part of their area only are the next test's."""
    samples = 128
    scene = pano_scene(name)
    cycles = render_to_array(scene, "CYCLES", samples)
    ember = render_to_array(scene, "EMBER", samples)
    camera = export_current().scene.camera
    _, var, covered = sky_statistics(camera)
    h, w = cycles.shape[:2]
    se = np.sqrt(2.0 * var / samples) + COLOUR_TOL
    full = away_from_the_edge(covered.reshape(h, w) == 1).ravel()
    z = (np.abs(ember[..., :3] - cycles[..., :3]).reshape(-1, 3) / se)[full]
    assert full.sum() > 300 and z.max() < Z, (z.max(), np.unravel_index(np.argmax(z), z.shape))
    assert np.all(ember[..., 3] == 1.0)


def test_cycles_leaves_pixels_outside_the_circle_black_and_opaque():
    """The fact Ember follows: with a transparent film, Cycles' pixels without a ray are RGB 0 and alpha 1
    (no path, the sample counted); sky pixels are alpha 0."""
    scene = pano_scene("equidistant_shifted")
    scene.render.film_transparent = True
    cycles = render_to_array(scene, "CYCLES", 16)
    outside, inside = rays_or_not(export_current().scene.camera)
    assert outside.sum() > 50 and inside.sum() > 50
    np.testing.assert_array_equal(cycles[outside], [[0, 0, 0, 1]] * int(outside.sum()))
    np.testing.assert_array_equal(cycles[inside, 3], 0.0)


def test_ember_leaves_pixels_outside_the_circle_black_and_opaque():
    """Ember against the same: black and opaque without a ray, transparent sky, and pixels cut by the
    circle as Cycles within noise (alpha 1 - the covered fraction)."""
    samples = 64
    scene = pano_scene("equidistant_shifted")
    scene.render.film_transparent = True
    cycles = render_to_array(scene, "CYCLES", samples)
    ember = render_to_array(scene, "EMBER", samples)
    camera = export_current().scene.camera
    outside, inside = rays_or_not(camera)
    np.testing.assert_array_equal(ember[outside], [[0, 0, 0, 1]] * int(outside.sum()))
    np.testing.assert_array_equal(ember[inside, 3], 0.0)
    _, var, covered = sky_statistics(camera)
    cycles, ember = cycles.reshape(-1, 4), ember.reshape(-1, 4)
    cut = (covered > 0) & (covered < 1)
    alpha_var = covered * (1 - covered)  # a sample either has a ray (alpha 0) or not (alpha 1)
    z_alpha = np.abs(ember[cut, 3] - cycles[cut, 3]) / (np.sqrt(2 * alpha_var[cut] / samples) + COLOUR_TOL)
    z_rgb = np.abs(ember[cut, :3] - cycles[cut, :3]) / (np.sqrt(2 * var[cut] / samples) + COLOUR_TOL)
    assert cut.any() and z_alpha.max() < Z and z_rgb.max() < Z


@pytest.mark.parametrize("name", ["equirectangular_ranges", "cubemap_face"])
def test_hdri_through_a_panorama_matches_cycles(name):
    scene = pano_scene(name, hdri="forest.exr")
    compare_to_cycles(scene, samples=64)


def test_depth_of_field_on_a_fisheye_matches_cycles():
    """Cycles' panoramic thin lens: emitters before, on and past the sphere of focus, ahead and far off the
    axis, through a five-bladed anamorphic aperture whose orientation across each ray shapes the blur."""
    scene = new_scene(48, 32)
    scene.ember.pixel_filter_type = "BOX"
    cam = scene.camera
    cam.location, cam.rotation_euler = (0, 0, 0), (math.radians(90), 0, 0)  # looking along +y
    cam.data.type, cam.data.panorama_type, cam.data.fisheye_fov = "PANO", "FISHEYE_EQUIDISTANT", math.pi
    dof = cam.data.dof
    dof.use_dof, dof.focus_distance, dof.aperture_fstop = True, 3.0, 0.05  # 50 mm lens: 0.5 m radius
    dof.aperture_blades, dof.aperture_rotation, dof.aperture_ratio = 5, 0.3, 1.5
    for name, colour, centre, size in (
            ("Near", (1.0, 0.2, 0.1), (-0.5, 1.2, 0.1), 0.3), ("Focus", (0.2, 1.0, 0.2), (0.8, 3.0, -0.4), 0.6),
            ("Far", (0.2, 0.3, 1.0), (0.0, 9.0, 2.0), 1.5), ("Side", (1.0, 0.8, 0.2), (2.8, 1.0, 0.3), 0.4)):
        # Each faces the camera: its edges span the plane across the line of sight.
        c = np.asarray(centre, float)
        ahead = c / np.linalg.norm(c)
        right = np.cross(ahead, (0, 0, 1))
        right /= np.linalg.norm(right)
        up = np.cross(right, ahead)
        quad_object(name, c - 0.5 * size * (right + up), size * right, size * up,
                    emission_material(name, colour, 2.0), uv=False)
    set_world(scene)
    compare_to_cycles(scene, samples=512, max_bounces=0)


# ---------------------------------------------------------------- kernel unit tests
KERNEL_PARAMS = {
    "EQUIRECTANGULAR": dict(latitude_min=-0.6, latitude_max=1.2, longitude_min=-2.5, longitude_max=1.0),
    "EQUIANGULAR_CUBEMAP_FACE": {},
    "MIRRORBALL": {},
    "FISHEYE_EQUIDISTANT": dict(fisheye_fov=3.5),
    "FISHEYE_EQUISOLID": dict(fisheye_fov=2.8, fisheye_lens=8.0, sensor_width=30.0, sensor_height=20.0),
    # theta(r) = 0.01 + 0.045 r - ..., increasing: one r per direction (Cycles' inverse takes theta >= 0).
    "FISHEYE_LENS_POLYNOMIAL": dict(fisheye_fov=1.75, fisheye_polynomial_k0=-0.01, fisheye_polynomial_k1=-0.045,
                                    fisheye_polynomial_k2=3e-4, fisheye_polynomial_k3=-2e-5,
                                    fisheye_polynomial_k4=1e-7, sensor_width=36.0, sensor_height=24.0),
    "CENTRAL_CYLINDRICAL": dict(central_cylindrical_range_u_min=-2.0, central_cylindrical_range_u_max=1.5,
                                central_cylindrical_range_v_min=-0.5, central_cylindrical_range_v_max=1.5,
                                central_cylindrical_radius=1.3),
}


def kernel_camera(panorama_type, **fields):
    fields = dict(dict(world_from_camera=look_at((1, 2, 3), (2, 4, 3.5)), width=48, height=32, shift_x=0.03,
                       shift_y=-0.02), **fields)
    camera = Camera(kind="PANO", panorama_type=panorama_type, panorama=KERNEL_PARAMS[panorama_type], **fields)
    camera.validate()
    return camera


def test_every_blender_panorama_type_is_mapped():
    assert set(PANORAMA_TYPES) == {e.identifier for e in bpy.types.Camera.bl_rna.properties["panorama_type"].enum_items}


@pytest.mark.parametrize("panorama_type", PANORAMA_TYPES)
def test_mapping_round_trip(panorama_type):
    """Raster -> direction -> raster. Directions are float32 (error ~eps32 radians), so raster positions
    come back within a few eps32 / (radians per pixel)."""
    camera = kernel_camera(panorama_type)
    rng = np.random.default_rng(3)
    sx, sy = rng.random(4000) * camera.width, rng.random(4000) * camera.height
    dirs, valid = panorama_directions(camera, sx, sy)
    assert valid.mean() > 0.4 and np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=4 * EPS32)
    if panorama_type == "MIRRORBALL":  # its rim all looks straight back: keep away from it
        u, v = (sx / camera.width + camera.shift_x) * 2 - 1, (1 - sy / camera.height + camera.shift_y) * 2 - 1
        valid &= u * u + v * v < 0.9
    bx, by = panorama_raster(camera, dirs[valid])
    error = np.hypot(bx - sx[valid], by - sy[valid]).max()
    tol = 64 * EPS32 / pixel_spread(camera)
    assert error < tol, (error, tol)


def test_pixel_spread_is_cycles_differential():
    """Equidistant fisheye, square frame: one pixel from the centre turns the ray by fov / width."""
    camera = Camera(kind="PANO", panorama_type="FISHEYE_EQUIDISTANT", panorama=dict(fisheye_fov=3.0), width=32,
                    height=32)
    assert pixel_spread(camera) == pytest.approx(2 * math.sin(3.0 / 64), rel=1e-5)


def test_rays_start_on_the_near_clip_sphere():
    """Cycles clips panoramic rays along each ray; no ray at all (t_max 0) outside the image circle."""
    camera = kernel_camera("FISHEYE_EQUIDISTANT", clip_start=0.25, clip_end=40.0)
    row, col = pixels(camera.height, camera.width)
    jx = np.random.default_rng(4).random(len(row), dtype=np.float32)
    jy = np.random.default_rng(5).random(len(row), dtype=np.float32)
    origins, dirs, t_max = generate_rays(camera, row, col, jx, jy)
    local, valid = panorama_directions(camera, col + jx, row + jy)
    eye, rot = camera.world_from_camera[:3, 3], camera.world_from_camera[:3, :3]
    np.testing.assert_allclose(dirs, local @ rot.T, atol=4 * EPS32)
    np.testing.assert_allclose(origins, eye + 0.25 * dirs, atol=16 * EPS32)
    assert (~valid).sum() > 50
    np.testing.assert_array_equal(t_max, np.where(valid, np.float32(40.0 - 0.25), 0.0))


def test_thin_lens_focuses_on_a_sphere():
    """Cycles' panoramic depth of field: the lens lies across each pinhole ray, its x axis along the
    panorama's forward axis made orthogonal to the ray (anamorphic ratio 2 halves that axis), and every
    ray passes through the pinhole ray's point at focus_distance."""
    radius, focus = 0.2, 3.0
    camera = kernel_camera("FISHEYE_EQUISOLID", aperture_radius=radius, aperture_ratio=2.0, focus_distance=focus)
    n = camera.width * camera.height
    row, col = pixels(camera.height, camera.width)
    rng = np.random.default_rng(6)
    jx, jy, lu, lv = (rng.random(n, dtype=np.float32) for _ in range(4))
    _, pinhole, t_pin = generate_rays(camera, row, col, jx, jy)
    origins, dirs, t_max = generate_rays(camera, row, col, jx, jy, lens=(lu, lv))
    valid = t_pin > 0
    np.testing.assert_array_equal(t_max > 0, valid)
    eye = camera.world_from_camera[:3, 3]
    d0, o, d = (a[valid].astype(np.float64) for a in (pinhole, origins, dirs))
    offset = o - 0.1 * d - eye  # the lens point (origins sit clip_start = 0.1 along the ray)
    to_focus = eye + focus * d0 - o
    assert np.abs(np.cross(to_focus, d)).max() < 1e-5 and (np.einsum("ij,ij->i", to_focus, d) > 0).all()
    assert np.abs(np.einsum("ij,ij->i", offset, d0)).max() < 1e-6  # the lens is across the pinhole ray
    forward = -camera.world_from_camera[:3, 2]
    lens_x = forward - np.einsum("ij,j->i", d0, forward)[:, None] * d0
    lens_x /= np.linalg.norm(lens_x, axis=1, keepdims=True)
    lens_y = np.cross(d0, lens_x)
    lx, ly = sample_aperture(camera, lu[valid], lv[valid])
    np.testing.assert_allclose(np.einsum("ij,ij->i", offset, lens_x), lx, atol=1e-6)
    np.testing.assert_allclose(np.einsum("ij,ij->i", offset, lens_y), ly, atol=1e-6)


@pytest.mark.parametrize("change, field", [
    (dict(panorama_type="FISHEYE"), "camera.panorama_type"),
    (dict(panorama={}), "camera.panorama"),
    (dict(panorama=dict(fisheye_fov=3.0, fisheye_lens=10.5)), "camera.panorama"),
    (dict(panorama=dict(fisheye_fov=0.0)), r"camera.panorama\['fisheye_fov'\]"),
    (dict(panorama=dict(fisheye_fov=float("nan"))), r"camera.panorama\['fisheye_fov'\]"),
])
def test_bad_panorama_raises_naming_the_field(change, field):
    fields = dict(kind="PANO", panorama_type="FISHEYE_EQUIDISTANT", panorama=dict(fisheye_fov=3.0))
    fields.update(change)
    with pytest.raises(ValueError, match=f"^{field}"):
        Camera(**fields).validate()


def test_export_warns_of_stereo():
    scene = pano_scene("equirectangular")
    scene.render.use_multiview = True
    warnings = export_current().warnings
    assert any("Camera 'Camera'" in w and "stereo" in w for w in warnings), warnings
