"""Area lights with a Spread below 180 degrees and point and spot lights with Soft Falloff off, for the light they
cast, as Cycles casts it (kernels/lights/area_spread.py, kernels/lights/point_spot.py).

Kernel level: a spread lamp's light samples give the irradiance of a brute-force integral over the lamp (the
soft-box grid's attenuation times the cosines), rectangles, disks and ellipses at 30, 90 and 150 degrees, from
points near the lamp (the spread's footprint clamps the sampled shape) and far off its normal; the pdf a BSDF ray
that hits the lamp gets is the light sample's along the same direction; a sphere lamp gives the closed form
E = pi L (r / d)^2 of a sphere facing a point, by light samples and by BSDF rays alike. Through Blender: spread lamps
over a diffuse floor and a glossy one, a point and a spot with Soft Falloff off near a floor, each against Cycles
within noise, without warnings; the settings change the image (so the comparisons test them).
"""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from bpy_helpers import (add_camera, compare_to_cycles, diffuse_material, export_current, new_scene, node_material,
                         quad_object, render_to_array, set_world)
from ember.kernels import Lights
from test_lights import sampler_for

POINT, SPOT, RECT, DISK = 0, 1, 3, 4
N = 100_000


def _lamp(kind, size=(0.0, 0.0), spread=math.pi, radius=0.0, spot=(1.0, 0.0), sphere=False):
    return Lights(kind=np.int32([kind]), position=np.float32([(0, 0, 2)]), frame=np.float32([np.eye(3)]),
                  radiance=np.float32([(1, 1, 1)]), radius=np.float32([radius]), size=np.float32([size]),
                  spot_cos=np.float32([spot]), sun_half_angle=np.float32([0]), spread=np.float32([spread]),
                  sphere=np.bool_([sphere]))


def _points(p, seed):
    rng = np.random.default_rng(seed)
    return tuple(np.full(N, v, np.float32) for v in p), [rng.random(N, dtype=np.float32) for _ in range(3)]


def _grid_irradiance(kind, size, spread, p, n=2000, cells=None):
    """Irradiance at p (normal +z) from a unit-radiance lamp at z = 2 emitting down: the integral over the lamp of
    the grid's attenuation (Cycles' area_light_spread_attenuation, normalised as scene/light.cpp) x cos x cos / d^2,
    by the midpoint rule. cells: instead, the integral of the attenuation alone over the solid angle of each of
    cells x cells parts of the lamp's (u, v) box."""
    lu, lv = size
    u = (np.arange(n) + 0.5) / n - 0.5
    uu, vv = np.meshgrid(u * lu, u * lv)
    inside = np.ones_like(uu, bool) if kind == RECT else (uu / lu) ** 2 + (vv / lv) ** 2 <= 0.25
    q = np.stack([uu - p[0], vv - p[1], np.full_like(uu, 2.0 - p[2])], -1)
    d = np.linalg.norm(q, axis=-1)
    cos = q[..., 2] / d
    tan_a = np.sqrt(1 - cos ** 2) / cos
    half = spread / 2
    attenuation = np.maximum((math.tan(half) - tan_a) / (math.tan(half) - half), 0)
    if cells is not None:
        solid = (attenuation * cos / d ** 2 * inside) * lu * lv / n ** 2
        return solid.reshape(cells, n // cells, cells, n // cells).sum(axis=(1, 3))
    return float((attenuation * cos * cos / d ** 2 * inside).sum() * lu * lv / n ** 2)


def _cell_of(ls, p, size, cells):
    """(n,) the cell of the lamp's (u, v) box (as _grid_irradiance's) each light sample's point lies in."""
    t = (2.0 - p[2]) / ls.wz
    u = (p[0] + t * ls.wx) / size[0] + 0.5
    v = (p[1] + t * ls.wy) / size[1] + 0.5
    return np.clip((v * cells).astype(int), 0, cells - 1) * cells + np.clip((u * cells).astype(int), 0, cells - 1)


SHAPES = {"rectangle": (RECT, (1.0, 0.6)), "disk": (DISK, (1.0, 1.0)), "ellipse": (DISK, (1.2, 0.5))}


@pytest.mark.parametrize("shape", list(SHAPES))
@pytest.mark.parametrize("degrees", [30, 90, 150])
def test_spread_light_samples_integrate_the_grid_and_bsdf_rays_get_their_pdf(shape, degrees):
    kind, size = SHAPES[shape]
    sampler = sampler_for(_lamp(kind, size, math.radians(degrees)))
    # Under the lamp's edge, off to the side, close below it (a footprint much smaller than the lamp).
    for seed, p in enumerate(((0.1, 0.05, 0.0), (0.7, 0.3, 0.5), (0.3, -0.2, 1.7))):
        (px, py, pz), u = _points(p, seed)
        ls = sampler.sample(px, py, pz, *u)
        lit = (ls.pdf > 0) & (ls.radiance[0] > 0)
        estimate = np.where(lit, ls.radiance[0] * np.maximum(ls.wz, 0) / np.where(lit, ls.pdf, 1), 0)
        mean, se = estimate.mean(), estimate.std() / math.sqrt(N)
        expected = _grid_irradiance(kind, size, math.radians(degrees), p)
        # The midpoint rule's error at the grid's kink is below 1e-3 of it.
        assert abs(mean - expected) < 4.5 * se + 1e-3 * expected, (p, mean, se, expected)
        # The samples' density is their pdf part by part: the grid's factor / pdf summed over each part of the lamp
        # is its solid angle weighed by the factor.
        cells = 4
        per_sample = np.where(lit, ls.radiance[0] / np.where(lit, ls.pdf, 1), 0)
        cell = _cell_of(ls, p, size, cells)
        sums = np.bincount(cell[lit], per_sample[lit], cells * cells) / N
        squares = np.bincount(cell[lit], per_sample[lit] ** 2, cells * cells) / N
        spreads = np.sqrt(np.maximum(squares - sums ** 2, 0) / N)
        parts = _grid_irradiance(kind, size, math.radians(degrees), p, cells=cells).ravel()
        assert np.all(np.abs(sums - parts) < 4.5 * spreads + 2e-3 * parts.max()), (p, sums, parts, spreads)
        rows = np.flatnonzero(lit)[:3000]
        hits = sampler.intersect(px[rows], py[rows], pz[rows], ls.wx[rows], ls.wy[rows], ls.wz[rows],
                                 np.full(len(rows), np.inf, np.float32))
        assert hits.hit.all()
        np.testing.assert_allclose(hits.pdf, ls.pdf[rows], rtol=2e-5)
        np.testing.assert_allclose(hits.radiance, ls.radiance[:, rows], rtol=2e-5)


def test_the_light_tree_takes_each_lamps_spread(monkeypatch):
    """Six spread lamps in a row with the light tree on (theta_e = spread / 2): it gives 0 to the lamps whose spread
    cannot reach a point, never to one that lights it (the light samples still integrate every lamp's light), and the
    pdf a BSDF ray's hit gets, selection included, is the sample's."""
    from ember.kernels.lights import selection
    monkeypatch.setattr(selection, "TREE_MIN_DIVERGENCE", 0.0)
    xs, spreads = np.float32([-2.5, -1.5, -0.5, 0.5, 1.5, 2.5]), np.radians([20, 60, 120, 30, 90, 150])
    kinds = np.int32([RECT, DISK] * 3)
    k = len(xs)
    lights = Lights(kind=kinds, position=np.stack([xs, np.zeros(k), np.full(k, 2)], 1).astype(np.float32),
                    frame=np.float32(np.tile(np.eye(3), (k, 1, 1))), radiance=np.ones((k, 3), np.float32),
                    radius=np.zeros(k, np.float32), size=np.full((k, 2), 0.8, np.float32),
                    spot_cos=np.zeros((k, 2), np.float32), sun_half_angle=np.zeros(k, np.float32),
                    spread=np.float32(spreads))
    sampler = sampler_for(lights)
    assert sampler.uses_tree
    for seed, p in enumerate(((0.0, 0.0, 0.0), (-2.3, 0.2, 1.2), (1.7, -0.3, 0.4))):
        (px, py, pz), u = _points(p, seed)
        pmf = sampler.selection_pmf(np.arange(k), *(np.full(k, v, np.float32) for v in p))
        expected = [_grid_irradiance(kinds[i], (0.8, 0.8), spreads[i], (p[0] - xs[i], p[1], p[2]), 1000)
                    for i in range(k)]
        assert all(pmf[i] > 0 for i in range(k) if expected[i] > 0), (pmf, expected)
        assert (pmf == 0).any(), pmf
        ls = sampler.sample(px, py, pz, *u)
        lit = (ls.pdf > 0) & (ls.radiance[0] > 0)
        estimate = np.where(lit, ls.radiance[0] * np.maximum(ls.wz, 0) / np.where(lit, ls.pdf, 1), 0)
        mean, se = estimate.mean(), estimate.std() / math.sqrt(N)
        assert abs(mean - sum(expected)) < 4.5 * se + 1e-3 * sum(expected), (p, mean, se, expected)
        rows = np.flatnonzero(lit)[:3000]
        hits = sampler.intersect(px[rows], py[rows], pz[rows], ls.wx[rows], ls.wy[rows], ls.wz[rows],
                                 np.full(len(rows), np.inf, np.float32))
        np.testing.assert_allclose(hits.pdf, ls.pdf[rows], rtol=2e-5)


def test_spread_zero_lights_a_point_along_the_normal_only():
    """Spread 0: a collimated lamp, pi L on a point facing it under the lamp (Cycles' pdf 1 and grid factor pi),
    nothing beside it; no BSDF ray gets its light."""
    sampler = sampler_for(_lamp(RECT, (1.0, 1.0), 0.0))
    (px, py, pz), u = _points((0.2, 0.1, 0.0), 1)
    ls = sampler.sample(px, py, pz, *u)
    assert ls.delta.all() and np.allclose(ls.wz, 1) and np.allclose(ls.radiance[0] / ls.pdf, np.pi)
    (px, py, pz), u = _points((0.7, 0.1, 0.0), 1)
    assert (sampler.sample(px, py, pz, *u).radiance == 0).all()
    hits = sampler.intersect(px, py, pz, np.zeros(N, np.float32), np.zeros(N, np.float32), np.ones(N, np.float32),
                             np.full(N, np.inf, np.float32))
    assert not hits.hit.any()


@pytest.mark.parametrize("p", [(0.0, 0.0, 1.0), (0.8, 0.0, 1.0), (0.3, 0.2, 0.0)])
def test_a_sphere_lamp_lights_a_point_as_a_sphere(p):
    """Soft Falloff off: E = pi L (r / d)^2 on a point facing the sphere (fully above its horizon), by light samples
    and by cosine-distributed BSDF rays, whose pdfs agree; the soft-falloff disk gives less."""
    r = 0.45
    (px, py, pz), u = _points(p, 3)
    d = math.dist(p, (0, 0, 2))
    cos_p = (2 - p[2]) / d
    expected = math.pi * (r / d) ** 2 * cos_p
    results = {}
    for sphere in (True, False):
        sampler = sampler_for(_lamp(POINT, radius=r, sphere=sphere))
        ls = sampler.sample(px, py, pz, *u)
        estimate = ls.radiance[0] * np.maximum(ls.wz, 0) / ls.pdf
        results[sphere] = estimate.mean()
        rows = np.arange(3000)
        hits = sampler.intersect(px[rows], py[rows], pz[rows], ls.wx[rows], ls.wy[rows], ls.wz[rows],
                                 np.full(len(rows), np.inf, np.float32))
        assert hits.hit.all()
        np.testing.assert_allclose(hits.pdf, ls.pdf[rows], rtol=2e-5)
        if sphere:
            assert abs(results[sphere] - expected) < 4.5 * estimate.std() / math.sqrt(N) + 1e-4, (results, expected)
            radius = np.sqrt(u[0])
            phi = np.float32(2 * np.pi) * u[1]
            dx, dy = (radius * np.cos(phi)).astype(np.float32), (radius * np.sin(phi)).astype(np.float32)
            dz = np.sqrt(np.maximum(1 - u[0], 0)).astype(np.float32)
            met = sampler.intersect(px, py, pz, dx, dy, dz, np.full(N, np.inf, np.float32))
            bsdf = np.where(met.hit, met.radiance[0], 0) * np.pi     # L cos / (cos / pi)
            assert abs(bsdf.mean() - expected) < 4.5 * bsdf.std() / math.sqrt(N), (bsdf.mean(), expected)
    assert results[False] < 0.97 * results[True]


# ---------------------------------------------------------------- through Blender, against Cycles
def _stage(floor_material):
    """floor_material() makes the floor's material (after new_scene, which empties the file)."""
    scene = new_scene(32, 32)
    add_camera(scene, (0, -4.0, 2.6), (0, 0, 0.2))
    set_world(scene, color=(0.0, 0.0, 0.0))
    quad_object("Floor", (-3, -3, 0), (6, 0, 0), (0, 6, 0), floor_material())
    return scene


def _light(scene, name, kind, location, rotation=(0, 0, 0), **settings):
    lamp = bpy.data.objects.new(name, bpy.data.lights.new(name, kind))
    for key, value in settings.items():
        setattr(lamp.data, key, value)
    lamp.location, lamp.rotation_euler = location, rotation
    scene.collection.objects.link(lamp)
    return lamp


def _spread_lamps(scene):
    """A square lamp of 30 degrees low over the floor (a footprint smaller than the lamp) and a disk of 90, tilted."""
    return [_light(scene, "Square", "AREA", (-0.8, 0.2, 0.6), (0.2, 0, 0), energy=60.0, shape="SQUARE", size=1.0,
                   spread=math.radians(30)),
            _light(scene, "Disk", "AREA", (0.9, -0.1, 1.0), (0, -0.4, 0), energy=80.0, shape="DISK", size=0.8,
                   spread=math.radians(90))]


FLOORS = {"diffuse": lambda: diffuse_material("Floor", (0.8, 0.8, 0.8)),
          "glossy": lambda: node_material("Floor", "ShaderNodeBsdfGlossy", Color=(0.8, 0.8, 0.8), Roughness=0.35)}


@pytest.mark.parametrize("floor", list(FLOORS))
def test_spread_area_lamps_light_a_floor_as_cycles(floor):
    scene = _stage(FLOORS[floor])
    lamps = _spread_lamps(scene)
    assert export_current().warnings == []
    report = compare_to_cycles(scene, samples=64, blocks=8, max_bounces=2)
    print(report)
    # The spread matters: the same lamps at 180 degrees light the floor otherwise.
    spread = render_to_array(scene, "EMBER", 16, seed=2)[..., :3]
    for lamp in lamps:
        lamp.data.spread = math.pi
    plain = render_to_array(scene, "EMBER", 16, seed=2)[..., :3]
    assert abs(plain.mean() / spread.mean() - 1) > 0.1 or np.abs(plain - spread).max() > 0.5


SPHERES = {"point": ("POINT", (0.0, 0.3, 0.7), (0, 0, 0), dict(energy=60.0, shadow_soft_size=0.45)),
           "spot": ("SPOT", (0.0, 0.3, 0.8), (0.3, 0, 0), dict(energy=120.0, shadow_soft_size=0.45,
                                                                spot_size=math.radians(100), spot_blend=0.3))}


@pytest.mark.parametrize("kind", list(SPHERES))
def test_soft_falloff_off_lights_a_floor_as_cycles_sphere(kind):
    scene = _stage(FLOORS["diffuse"])
    blender_kind, location, rotation, settings = SPHERES[kind]
    lamp = _light(scene, "Lamp", blender_kind, location, rotation, **settings)
    lamp.data.use_soft_falloff = False
    assert export_current().warnings == []
    report = compare_to_cycles(scene, samples=64, blocks=8, max_bounces=2)
    print(report)
    sphere = render_to_array(scene, "EMBER", 16, seed=2)[..., :3]
    lamp.data.use_soft_falloff = True
    disk = render_to_array(scene, "EMBER", 16, seed=2)[..., :3]
    print("sphere / disk", sphere.mean() / disk.mean())
    assert sphere.mean() > 1.05 * disk.mean()
