"""Camera and film (issue 12): the pixel filter and depth of field.

Closed forms: the filter table against its profile's CDF, its sampling against the table (chi-square),
the aperture's uniformity, the circle of confusion of an out-of-focus point against the thin-lens
formula. Parity: Cycles with each filter on a sharp edge, and a strong depth of field with hexagonal bokeh.
"""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from bpy_helpers import (compare_to_cycles, diffuse_material, emission_material, new_scene, quad_object,
                         render_to_array, set_world)
from ember.kernels import lens, pixel_filter
from ember.kernels.scene import Camera
from stats import assert_chi2, trapezoid

FILTERS = [("GAUSSIAN", 1.5), ("BLACKMAN_HARRIS", 1.5), ("BLACKMAN_HARRIS", 2.5), ("GAUSSIAN", 0.7)]


def _exact_cdf(kind, width, x):
    """The profile's CDF at offsets x from the pixel centre, by fine trapezoid integration."""
    half = pixel_filter.support(kind, width)
    grid = np.linspace(-half, half, 400_001)
    f = pixel_filter.profile(kind, grid, width)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(grid))])
    return np.interp(x, grid, cdf / cdf[-1])


# ---------------------------------------------------------------- pixel filter
@pytest.mark.parametrize("kind,width", FILTERS)
def test_filter_table_is_the_profiles_inverse_cdf(kind, width):
    """Entry i of the table sits where the profile's CDF reaches i / (entries - 1), up to the error of
    Cycles' construction: a left Riemann sum over steps of h = support / 1022 moves the CDF by at most
    max(f) h / integral(f)."""
    table = pixel_filter.table(kind, width) - np.float32(0.5)
    half = pixel_filter.support(kind, width)
    assert np.all(np.diff(table) >= 0) and table[0] == pytest.approx(-half) and table[-1] == pytest.approx(half)
    assert np.allclose(table + table[::-1], 0.0, atol=1e-6)  # symmetric about the pixel centre
    grid = np.linspace(-half, half, 100_001)
    f = pixel_filter.profile(kind, grid, width)
    h = half / (pixel_filter.TABLE_SIZE - 2)
    delta = f.max() * h / trapezoid(f, grid)
    levels = np.arange(len(table)) / (len(table) - 1)
    error = np.abs(_exact_cdf(kind, width, table) - levels)
    assert error.max() <= delta, (error.max(), delta)


@pytest.mark.parametrize("kind,width", FILTERS[:2])
def test_filter_samples_follow_the_table(kind, width):
    """offsets() draws from the table's piecewise-uniform distribution: each group of 32 of its intervals
    holds that many / (entries - 1) of the samples (chi-square), and no sample leaves the support."""
    n = 200_000
    u = np.random.default_rng(5).random(n, dtype=np.float32)
    x = pixel_filter.offsets(kind, width, u)
    table = pixel_filter.table(kind, width)
    idx = np.append(np.arange(0, len(table) - 1, 32), len(table) - 1)
    observed = np.histogram(x, table[idx])[0]
    assert_chi2(observed, n * np.diff(idx) / (len(table) - 1))
    assert np.all(np.abs(x - 0.5) <= pixel_filter.support(kind, width) + 1e-5)


def _cycles_density(kind, width, x):
    """Cycles' filter profiles written out apart from the code under test (scene/film.cpp): Gaussian
    exp(-8 x^2 / w^2) cut at 1.5 w; Blackman-Harris over a window of 2 w (Cycles doubles the width),
    v = 2 pi (x / 2w + 1/2)."""
    if kind == "GAUSSIAN":
        return np.where(np.abs(x) <= 1.5 * width, np.exp(-8.0 * x * x / (width * width)), 0.0)
    v = 2.0 * np.pi * (x / (2.0 * width) + 0.5)
    bh = 0.35875 - 0.48829 * np.cos(v) + 0.14128 * np.cos(2 * v) - 0.01168 * np.cos(3 * v)
    return np.where(np.abs(x) <= width, bh, 0.0)


@pytest.mark.parametrize("kind,width", FILTERS)
def test_filter_samples_spread_as_cycles_filter(kind, width):
    """The samples' distances from the pixel centre follow the Cycles profile (integrated here from its own
    definition, not from pixel_filter's support or profile): the share within each quartile and the 95%
    point of |x| is that probability, within 5 standard errors of a share plus the table's resolution
    (1/1022 of the mass per entry). A filter of another width or support fails (halved Blackman-Harris puts
    0.85 of the samples within the true median)."""
    n = 400_000
    u = np.random.default_rng(11).random(n, dtype=np.float32)
    r = np.abs(pixel_filter.offsets(kind, width, u).astype(np.float64) - 0.5)
    grid = np.linspace(0.0, 3 * width, 600_001)
    f = _cycles_density(kind, width, grid)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(grid))])
    cdf /= cdf[-1]
    for p in (0.25, 0.5, 0.75, 0.95):
        share = np.mean(r < np.interp(p, cdf, grid))
        assert abs(share - p) < 5 * np.sqrt(p * (1 - p) / n) + 2 / (pixel_filter.TABLE_SIZE - 2), (p, share)


def test_box_filter_is_the_plain_jitter():
    """Box keeps the jitter as it is: images without a filter do not change, bit for bit."""
    u = np.random.default_rng(1).random(1000, dtype=np.float32)
    assert pixel_filter.offsets("BOX", 1.0, u) is u


# ---------------------------------------------------------------- the lens
def test_disk_aperture_is_uniform():
    n = 200_000
    rng = np.random.default_rng(2)
    u, v = rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32)
    x, y = lens.sample_disk_concentric(u, v)
    r2 = x.astype(np.float64) ** 2 + y ** 2
    assert r2.max() <= 1.0 + 1e-6
    # equal-area cells: 8 rings of r^2 times 16 sectors
    ring = np.minimum((r2 * 8).astype(int), 7)
    sector = ((np.arctan2(y, x) + np.pi) / (2 * np.pi) * 16).astype(int) % 16
    observed = np.bincount(ring * 16 + sector, minlength=128)
    assert_chi2(observed, np.full(128, n / 128))


@pytest.mark.parametrize("blades,rotation", [(6, 0.4), (3, 0.0), (5, 1.0)])
def test_polygon_aperture_is_uniform_inside_the_polygon(blades, rotation):
    n = 200_000
    rng = np.random.default_rng(3)
    u, v = rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32)
    x, y = lens.sample_regular_polygon(blades, rotation, u, v)
    # inside: on the inner side of every edge (vertices at rotation + (2k+1) pi / n on the unit circle)
    apothem = math.cos(math.pi / blades)
    normals = rotation + 2 * math.pi * np.arange(blades) / blades
    dist = np.outer(x, np.cos(normals)) + np.outer(y, np.sin(normals))
    assert dist.max() <= apothem + 1e-5
    # uniform: square cells of a grid, counted only where the cell lies wholly inside the polygon
    cells = 24
    ix = np.floor((x + 1) / 2 * cells).astype(int)
    iy = np.floor((y + 1) / 2 * cells).astype(int)
    observed = np.bincount(ix * cells + iy, minlength=cells * cells)
    corners = np.array([(i, j) for i in range(cells) for j in range(cells)], np.float64)
    inside = np.ones(cells * cells, bool)
    for dx in (0, 1):
        for dy in (0, 1):
            cx = (corners[:, 0] + dx) / cells * 2 - 1
            cy = (corners[:, 1] + dy) / cells * 2 - 1
            inside &= (np.outer(cx, np.cos(normals)) + np.outer(cy, np.sin(normals))).max(axis=1) <= apothem
    area = 0.5 * blades * math.sin(2 * math.pi / blades)
    expected = n * (2.0 / cells) ** 2 / area
    obs = np.append(observed[inside], n - observed[inside].sum())
    exp = np.append(np.full(inside.sum(), expected), n - expected * inside.sum())
    assert_chi2(obs, exp)


def test_anamorphic_ratio_squeezes_x():
    camera = Camera(aperture_radius=0.5, aperture_ratio=2.0)
    rng = np.random.default_rng(4)
    x, y = lens.sample_aperture(camera, rng.random(50_000, dtype=np.float32), rng.random(50_000, dtype=np.float32))
    assert np.abs(x).max() <= 0.25 + 1e-6 and np.abs(y).max() == pytest.approx(0.5, abs=5e-3)


# ---------------------------------------------------------------- circle of confusion
SPHERE = 0.06


def _point_scene(blades: int, size: int = 96):
    """A small emissive sphere at depth 4 on the axis of a camera focused at depth 0.2, black world."""
    scene = new_scene(size, size)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0, 0, 0), (math.radians(90), 0, 0)  # looks along +y
    cam.data.lens, cam.data.sensor_width, cam.data.sensor_fit = 50.0, 36.0, "HORIZONTAL"
    dof = cam.data.dof
    dof.use_dof, dof.aperture_fstop, dof.focus_distance = True, 1.4, 0.2
    dof.aperture_blades, dof.aperture_rotation = blades, 0.3
    bpy.ops.mesh.primitive_uv_sphere_add(radius=SPHERE, location=(0.0, 4.0, 0.0), segments=48, ring_count=24)
    bpy.context.object.data.materials.append(emission_material("Point", (1, 1, 1), 1.0))
    set_world(scene, (0, 0, 0), 0.0)
    return scene


@pytest.mark.parametrize("blades", [0, 6])
def test_circle_of_confusion_matches_the_thin_lens(blades):
    """A point at depth d seen through a lens of radius A focused at f spreads over the aperture's shape
    scaled to radius A |1/f - 1/d| on the view plane at unit distance. The image's second moment about its
    centroid, in pixels^2: R^2 (2 + cos(2 pi / n)) / 6 for an n-gon of circumradius R (R^2 / 2 for the disk),
    plus 1/6 for the one-pixel box of the film, plus rho^2 / 2 for the sphere's own disk of radius rho.
    Tolerance: 4 standard errors of that moment from 4 independent renders, plus 0.1% for the sphere's
    faceted silhouette (a 48-gon's moment is 0.3% under the disk's)."""
    size = 96
    scene = _point_scene(blades, size)
    aperture = 50e-3 / (2 * 1.4)
    pixel = (36.0 / 50.0) / size                       # view-plane units per pixel
    radius_px = aperture * abs(1 / 0.2 - 1 / 4.0) / pixel
    sphere_px = math.tan(math.asin(SPHERE / 4.0)) / pixel
    shape = 0.5 if blades == 0 else (2 + math.cos(2 * math.pi / blades)) / 6
    expected = radius_px ** 2 * shape + 1 / 6 + sphere_px ** 2 / 2
    moments = []
    for seed in (1, 2, 3, 4):
        image = render_to_array(scene, "EMBER", 256, seed=seed, max_bounces=0)[..., :3].sum(axis=2)
        rows, cols = np.indices(image.shape) + 0.5
        total = image.sum()
        cy, cx = (image * rows).sum() / total, (image * cols).sum() / total
        assert abs(cx - size / 2) < 1 and abs(cy - size / 2) < 1
        moments.append((image * ((rows - cy) ** 2 + (cols - cx) ** 2)).sum() / total)
    mean, se = np.mean(moments), np.std(moments, ddof=1) / 2
    assert abs(mean - expected) < 4 * se + 1e-3 * expected, (mean, expected, se)
    assert radius_px > 10  # the test would not see a wrong radius otherwise


# ---------------------------------------------------------------- parity with Cycles
def _edge_scene():
    """A white emissive half-plane against black, its edge slanted across the frame."""
    scene = new_scene(32, 32)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0, 0, 5), (0, 0, 0)
    cam.data.type, cam.data.ortho_scale = "ORTHO", 2.0
    quad_object("Lit", (-3, -0.6, 0), (6, 1.2, 0), (-0.6, 3, 0), emission_material("White", (1, 1, 1), 1.0))
    set_world(scene, (0, 0, 0), 0.0)
    return scene


@pytest.mark.parametrize("kind,width", [("GAUSSIAN", 1.5), ("BLACKMAN_HARRIS", 1.5), ("BLACKMAN_HARRIS", 3.0)])
def test_pixel_filter_matches_cycles_on_an_edge(kind, width):
    scene = _edge_scene()
    compare_to_cycles(scene, samples=64, blocks=8, max_bounces=0, pixel_filter=(kind, width))


def test_filtered_edge_differs_from_box():
    """The parity test above could not tell filters apart if the edge did not change under them."""
    scene = _edge_scene()
    box = render_to_array(scene, "EMBER", 64, max_bounces=0)
    bh = render_to_array(scene, "EMBER", 64, max_bounces=0, pixel_filter=("BLACKMAN_HARRIS", 3.0))
    assert np.abs(box - bh)[..., 0].max() > 0.1


def dof_scene(kind="PERSP", blades=6, focus_object=False):
    """Strong depth of field (f/1.2 at 100 mm): a near sphere in focus, a far one blurred, and a small
    very bright sphere far behind whose bokeh is the aperture's hexagon."""
    scene = new_scene(72, 48)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0, -6, 0.8), (math.radians(90), 0, 0)
    cam.data.type, cam.data.lens, cam.data.ortho_scale = kind, 100.0, 2.0
    dof = cam.data.dof
    dof.use_dof = True
    dof.aperture_fstop = 1.2 if kind == "PERSP" else 0.3
    dof.aperture_blades, dof.aperture_rotation, dof.aperture_ratio = blades, 0.4, 1.3
    dof.focus_distance = 2.5
    quad_object("Floor", (-4, -8, 0), (8, 0, 0), (0, 24, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    for name, colour, radius, location in (("Near", (0.8, 0.1, 0.1), 0.25, (-0.3, -3.5, 0.6)),
                                           ("Far", (0.1, 0.2, 0.8), 0.5, (0.5, 0.0, 0.6))):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=location)
        bpy.context.object.data.materials.append(diffuse_material(name, colour))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.05, location=(0.2, 6.0, 1.0))
    bpy.context.object.data.materials.append(emission_material("Glint", (1, 0.9, 0.7), 20.0))
    if focus_object:
        bpy.ops.object.empty_add(location=(2.0, -3.0, 3.0))  # depth 3 along the view axis
        dof.focus_object = bpy.context.object
    set_world(scene, (0.2, 0.25, 0.3), 1.0)
    return scene


@pytest.mark.parametrize("kind,blades,focus_object", [("PERSP", 6, False), ("PERSP", 0, True), ("ORTHO", 5, False)])
def test_depth_of_field_matches_cycles(kind, blades, focus_object):
    compare_to_cycles(dof_scene(kind, blades, focus_object), samples=64, blocks=6, max_bounces=2)


def test_focus_object_sets_the_focus_distance():
    from ember.engine.export.camera import depth_of_field
    scene = dof_scene(focus_object=True)
    camera = scene.camera.evaluated_get(bpy.context.evaluated_depsgraph_get())
    fields = depth_of_field(camera, "PERSP")
    assert fields["focus_distance"] == pytest.approx(3.0, abs=1e-5)
    assert fields["aperture_radius"] == pytest.approx(0.1 / 2.4)
