"""The Ambient Occlusion and Bevel nodes' estimators (kernels/shading/raytrace.py) against closed forms, on
scenes traced by the real BVH: the AO of a point by a wall (and in a wedge's corner), Inside and Only Local;
Bevel's normal on a flat face and its tilt near a cube's edge."""
from __future__ import annotations

import numpy as np
import pytest

from ember.kernels import Renderer
from ember.kernels.scene import object_row
from ember.kernels.shading.program import TracedHits
from ember.kernels.shading.raytrace import ambient_occlusion, bevel, cubic_root

from kernel_helpers import make_scene

F32 = np.float32


def quad(corner, edge_u, edge_v):
    """Two triangles (2, 3, 3) of the parallelogram corner + [0, 1] edge_u + [0, 1] edge_v, front on the
    edge_u x edge_v side."""
    c, u, v = (np.asarray(x, F32) for x in (corner, edge_u, edge_v))
    return np.array([[c, c + u, c + u + v], [c, c + u + v, c + v]], F32)


def flat_normals(positions):
    n = np.cross(positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.repeat(n[:, None], 3, axis=1).astype(F32)


def renderer_of(parts):
    """A Renderer of quads or boxes: parts is a list of (T, 3, 3) triangle arrays, one object each."""
    positions = np.concatenate(parts).astype(F32)
    object_ids = np.concatenate([np.full(len(p), i, np.int32) for i, p in enumerate(parts)])
    objects = np.stack([object_row(np.eye(4)) for _ in parts])
    return Renderer(make_scene(positions, flat_normals(positions), objects=objects, object_ids=object_ids), 1)


def traced(renderer, p, n, obj=0, seed=1):
    """TracedHits at points p (k, 3) with normal n (3,) on object row obj, independent keys per point."""
    k = len(p)
    keys = np.random.default_rng(seed).integers(0, 2**32, (2, k), dtype=np.uint64).astype(np.uint32)
    normal = np.broadcast_to(np.asarray(n, F32), (k, 3)).copy()
    return TracedHits(renderer.shading.data.rays, np.asarray(p, F32), normal, normal.copy(), np.zeros(k, bool),
                      np.full(k, obj, np.int32), (keys[0], keys[1]))


def disk_beyond(c):
    """The share of a uniform unit disk with x > c (0 <= c <= 1): what a wall at distance c x Distance
    occludes of Cycles' AO rays (a cosine-distributed direction is a uniform disk point lifted)."""
    return (np.arccos(c) - c * np.sqrt(1 - c * c)) / np.pi


def assert_share(ao, expected, samples):
    """The mean of per-point unoccluded shares within 4.5 standard errors of the Bernoulli estimate."""
    se = np.sqrt(max(expected * (1 - expected), 1e-4) / (len(ao) * samples))
    assert abs(ao.mean() - expected) < 4.5 * se + 1e-6, (ao.mean(), expected, se)


BIG = 1000.0
FLOOR = quad((-BIG, -BIG, 0), (2 * BIG, 0, 0), (0, 2 * BIG, 0))
# A wall in the plane x = 0 facing +x, from the floor up to 50 (above any ray of Distance <= 10).
WALL = quad((0, -BIG, 0), (0, 2 * BIG, 0), (0, 0, 50))


def floor_points(k, x, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack([np.full(k, x), rng.uniform(-5, 5, k), np.zeros(k)], axis=1).astype(F32)


def test_ao_on_an_open_plane_is_one_and_inside_below_it_too():
    with renderer_of([FLOOR]) as r:
        hits = traced(r, floor_points(2000, 3.0), (0, 0, 1))
        for inside in (False, True):
            ao = ambient_occlusion(hits, hits.n, np.full(2000, 5.0, F32), 16, inside=inside)
            assert np.all(ao == 1.0)


@pytest.mark.parametrize("gap,distance", [(0.0, 10.0), (0.3, 1.0), (0.7, 1.0), (0.5, 2.0), (1.5, 1.0)])
def test_ao_by_a_wall_is_the_disk_share_beyond_gap_over_distance(gap, distance):
    """A point on the floor gap from a wall (a 90-degree wedge's corner at gap 0: AO 1/2)."""
    k, samples = 20000, 16
    with renderer_of([FLOOR, WALL]) as r:
        hits = traced(r, floor_points(k, max(gap, 1e-3)), (0, 0, 1))
        ao = ambient_occlusion(hits, hits.n, np.full(k, distance, F32), samples)
    c = min(gap / distance, 1.0)
    assert_share(ao, 1.0 - disk_beyond(c), samples)


def test_ao_only_local_sees_its_own_object_alone():
    k, samples = 20000, 8
    with renderer_of([FLOOR, WALL]) as r:          # the wall another object: Only Local ignores it
        hits = traced(r, floor_points(k, 0.3), (0, 0, 1), obj=0)
        assert np.all(ambient_occlusion(hits, hits.n, np.full(k, 1.0, F32), samples, only_local=True) == 1.0)
        everything = ambient_occlusion(hits, hits.n, np.full(k, 1.0, F32), samples)
        assert_share(everything, 1.0 - disk_beyond(0.3), samples)
    with renderer_of([np.concatenate([FLOOR, WALL])]) as r:   # floor and wall one object
        hits = traced(r, floor_points(k, 0.3), (0, 0, 1), obj=0)
        local = ambient_occlusion(hits, hits.n, np.full(k, 1.0, F32), samples, only_local=True)
        assert_share(local, 1.0 - disk_beyond(0.3), samples)


def test_ao_passes_objects_shadow_rays_do_not_see():
    """Cycles traces AO rays with PATH_RAY_VISIBILITY_SHADOW_OPAQUE (svm/ao.h): a wall whose Ray Visibility >
    Shadow is off does not occlude; a second wall behind it, seen by shadows, does, at its own distance."""
    from ember.kernels.scene.objects import ALL_RAYS, RAY_SHADOW
    k, samples = 20000, 8
    far_wall = quad((-0.7, -BIG, 0), (0, 2 * BIG, 0), (0, 0, 50))
    positions = np.concatenate([FLOOR, WALL, far_wall]).astype(F32)
    object_ids = np.repeat(np.arange(3, dtype=np.int32), 2)
    objects = np.stack([object_row(np.eye(4)) for _ in range(3)])
    visibility = np.array([ALL_RAYS, ALL_RAYS & ~RAY_SHADOW, ALL_RAYS], np.uint8)
    scene = make_scene(positions, flat_normals(positions), objects=objects, object_ids=object_ids,
                       object_visibility=visibility)
    with Renderer(scene, 1) as r:
        hits = traced(r, floor_points(k, 0.3), (0, 0, 1), obj=0)
        assert_share(ambient_occlusion(hits, hits.n, np.full(k, 2.0, F32), samples), 1.0 - disk_beyond(1.0 / 2.0),
                     samples)


def box(lo, hi):
    """The 12 triangles of an axis-aligned box, fronts outward."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    dx, dy, dz = (x1 - x0, 0, 0), (0, y1 - y0, 0), (0, 0, z1 - z0)
    return np.concatenate([quad((x0, y0, z0), dy, dx), quad((x0, y0, z1), dx, dy),
                           quad((x0, y0, z0), dx, dz), quad((x0, y1, z0), dz, dx),
                           quad((x0, y0, z0), dz, dy), quad((x1, y0, z0), dy, dz)])


def test_ao_inside_a_box_looks_into_it():
    """On the top of a closed box, Inside sends the rays into the box: occluded within its depth, not beyond;
    an object on top of it occludes the outside alone."""
    k, samples = 4000, 8
    lid = quad((-BIG, -BIG, 1.5), (2 * BIG, 0, 0), (0, 2 * BIG, 0))   # another object 0.5 above the top
    with renderer_of([box((-1, -1, 0), (1, 1, 1)), lid]) as r:
        rng = np.random.default_rng(3)
        p = np.stack([rng.uniform(-0.5, 0.5, k), rng.uniform(-0.5, 0.5, k), np.ones(k)], axis=1)
        hits = traced(r, p, (0, 0, 1))
        far = np.full(k, 100.0, F32)
        assert np.all(ambient_occlusion(hits, hits.n, far, samples, inside=True) == 0.0)
        lidded = ambient_occlusion(hits, hits.n, far, samples)   # the lid (all but rays too flat to reach it)
        assert lidded.mean() < 1e-3
        assert np.all(ambient_occlusion(hits, hits.n, far, samples, only_local=True) == 1.0)
        assert np.all(ambient_occlusion(hits, hits.n, far, samples, inside=True, only_local=True) == 0.0)
        # Within 0.25 the lid is out of reach and inside the floor (1 below) too, but not the sides for all.
        short = ambient_occlusion(hits, hits.n, np.full(k, 0.25, F32), samples)
        assert np.all(short == 1.0)
        # No distance, no rays: 1 (Cycles' early out).
        assert np.all(ambient_occlusion(hits, hits.n, np.zeros(k, F32), samples) == 1.0)


def test_the_cubic_radius_inverts_its_cdf():
    xi = np.linspace(0.001, 0.999, 999).astype(F32)
    x = cubic_root(xi).astype(np.float64)
    cdf = 10 * x**2 - 20 * x**3 + 15 * x**4 - 4 * x**5
    np.testing.assert_allclose(cdf, xi, atol=2e-5)


def test_bevel_on_a_flat_face_keeps_its_normal():
    with renderer_of([box((-1, -1, 0), (1, 1, 2))]) as r:
        rng = np.random.default_rng(5)
        k = 500
        p = np.stack([rng.uniform(-0.5, 0.5, k), rng.uniform(-0.5, 0.5, k), np.full(k, 2.0)], axis=1)
        hits = traced(r, p, (0, 0, 1))
        out = bevel(hits, np.full(k, 0.1, F32), 8)
        np.testing.assert_allclose(out, np.tile([0, 0, 1], (k, 1)), atol=1e-5)
        # A back face turns the result to the viewer, as Cycles' (sd->flag & SD_BACKFACING) ? -N.
        hits.backfacing[:] = True
        hits.n[:] = (0, 0, -1)
        hits.ng[:] = (0, 0, -1)
        np.testing.assert_allclose(bevel(hits, np.full(k, 0.1, F32), 8), np.tile([0, 0, -1], (k, 1)), atol=1e-5)


def test_bevel_near_an_edge_tilts_toward_the_other_face_less_with_distance():
    """On the top face of a cube, at distances from its +x edge: the normal leans to +x, symmetrically about
    the edge's bisector at the edge itself (about 45 degrees), less and less further in, and not at all beyond the
    radius."""
    radius, k = 0.2, 3000
    leans = []
    with renderer_of([box((-1, -1, -1), (1, 1, 1))]) as r:
        for gap in (0.0005, 0.05, 0.1, 0.15, 0.3):
            rng = np.random.default_rng(7)
            p = np.stack([np.full(k, 1.0 - gap), rng.uniform(-0.5, 0.5, k), np.ones(k)], axis=1)
            out = bevel(traced(r, p, (0, 0, 1), seed=11), np.full(k, radius, F32), 4)
            np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-5)
            mean = out.mean(axis=0)
            assert abs(mean[1]) < 0.02
            leans.append(np.degrees(np.arctan2(mean[0], mean[2])))
    assert 37 < leans[0] < 53, leans   # 45 for the summed normal; each point normalizes its 4 samples
    assert all(a > b for a, b in zip(leans, leans[1:-1])), leans
    assert leans[-2] > 0.1 and abs(leans[-1]) < 1e-3, leans


def test_bevel_skips_blurry_bounces_and_zero_radius():
    with renderer_of([box((-1, -1, -1), (1, 1, 1))]) as r:
        k = 200
        p = np.tile([0.99, 0.0, 1.0], (k, 1)).astype(F32)
        hits = traced(r, p, (0, 0, 1))
        tilted = bevel(hits, np.full(k, 0.2, F32), 4)
        assert tilted[:, 0].mean() > 0.2 and np.all(tilted[:, 0] >= 0)
        assert np.all(bevel(hits, np.zeros(k, F32), 4) == hits.n)
        hits.min_ray_pdf = np.full(k, 1 / np.pi, F32)   # after a diffuse bounce: Cycles' pdf < 8
        assert np.all(bevel(hits, np.full(k, 0.2, F32), 4) == hits.n)


def test_samples_in_one_query_are_the_samples_one_by_one(monkeypatch):
    """AO and Bevel trace all of a call's samples in one query (raytrace.GROUP_RAYS rays at most): the same
    numbers, bit for bit, as a query per sample, here with Bevel rays that cross more than LOCAL_MAX_HITS
    surfaces of their object (a comb of walls on the floor), so that which hits each keeps is drawn per sample."""
    from ember.kernels.shading import raytrace
    walls = [quad((x, -BIG, 0), (0, 2 * BIG, 0), (0, 0, 0.5)) for x in np.linspace(-0.1, 0.1, 9)]
    k = 3000
    with renderer_of([np.concatenate([FLOOR] + walls)]) as r:
        p = np.stack([np.random.default_rng(3).uniform(-0.15, 0.15, k), np.zeros(k), np.zeros(k)], axis=1)
        results = []
        for group_rays in (1, 1 << 18):
            monkeypatch.setattr(raytrace, "GROUP_RAYS", group_rays)
            hits = traced(r, p, (0, 0, 1), seed=5)
            distance = np.full(k, 0.3, F32)
            results.append((ambient_occlusion(hits, hits.n, distance, 8),
                            ambient_occlusion(hits, hits.n, distance, 8, only_local=True),
                            bevel(hits, np.full(k, 0.25, F32), 8)))
    for one_by_one, together in zip(*results):
        assert np.array_equal(one_by_one, together)
    assert 0.2 < results[0][0].mean() < 0.95 and np.abs(results[0][2][:, 0]).mean() > 0.05
