"""Deformation motion blur of meshes in the kernel: deforming triangles as Embree time steps (kernels.embree,
kernels.accel), their corners and normals read at each hit's time (kernels.geometry.deform), as Cycles' motion
triangles (intern/cycles/kernel/geom/motion_triangle.h)."""
from __future__ import annotations

import dataclasses

import numpy as np

from ember.kernels import Camera, Materials, Renderer, RenderSettings, SceneArrays, World, motion, render
from ember.kernels.shapes import look_at

from kernel_helpers import assert_workers_render_as_threads

FLAT = np.ones(257, np.float32)   # a flat shutter curve, as Blender samples it


def square(half: float, x: float = 0.0) -> np.ndarray:
    """(2, 3, 3) float32 a square of side 2 half in the plane y = 0 centred at (x, 0, 0), facing -y."""
    a, b, c, d = ([x - half, 0, -half], [x + half, 0, -half], [x + half, 0, half], [x - half, 0, half])
    return np.array([[a, c, b], [a, d, c]], np.float32)


def sliding_scene(half=0.1, x0=-1.0, x1=1.0, steps=3, width=4, height=4, fov=1e-3, still=None) -> SceneArrays:
    """A black square at the origin at the frame whose corners slide along x from x0 to x1 over the shutter
    (deformation: its triangles' steps), a white world, a camera on -y looking at the origin, a flat shutter;
    still: more triangles that do not deform."""
    frames = np.stack([square(half, x) for x in np.linspace(x0, x1, steps)])
    positions = square(half)
    t = len(positions)
    deform_ids = np.arange(t, dtype=np.int32)
    if still is not None:
        positions = np.concatenate([positions, still])
        deform_ids = np.concatenate([deform_ids, np.full(len(still), -1, np.int32)])
    normals = np.broadcast_to(np.float32([0, -1, 0]), positions.shape).copy()
    cam = Camera(world_from_camera=look_at((0, -5, 0), (0, 0, 0)), width=width, height=height, fov_rad=fov)
    return SceneArrays(positions=positions, normals=normals, uvs=np.zeros((len(positions), 3, 2), np.float32),
                       material_ids=np.zeros(len(positions), np.int32),
                       materials=Materials.diffuse(np.zeros((1, 3), np.float32)),
                       world=World(color=np.ones(3, np.float32)), camera=cam, shutter_table=motion.shutter_table(FLAT),
                       deform_ids=deform_ids, deform_positions=np.ascontiguousarray(frames, np.float32),
                       deform_normals=np.broadcast_to(np.float32([0, -1, 0]), frames.shape).copy())


def test_rays_meet_a_deforming_square_where_it_is_at_their_time():
    """Rays along +y through the origin at times t meet the square centred at x = -1 + 2t while |x(t)| < half,
    at distance 5; occluded agrees; the hit's shading point is where the square is then (x = 0 on the ray)."""
    half = 0.3
    times = np.linspace(0.0, 1.0, 401, dtype=np.float32)
    n = len(times)
    origins = np.tile(np.float32([0, -5, 0]), (n, 1))
    dirs = np.tile(np.float32([0, 1, 0]), (n, 1))
    with Renderer(sliding_scene(half=half, steps=5), threads=1) as r:
        hits = r.accel.intersect(origins, dirs, np.full(n, np.inf, np.float32), time=times)
        blocked = r.accel.occluded(origins, dirs, np.full(n, 10, np.float32), time=times)
        from ember.kernels.geometry.deform import deformed_corners
        found = np.flatnonzero(hits.prim >= 0)
        rows, p, _ = deformed_corners(r.scene, hits.prim[found], times[found])
    x = -1.0 + 2.0 * times.astype(np.float64)
    edge = np.abs(np.abs(x) - half) < 1e-4
    assert ((hits.prim >= 0) == (np.abs(x) < half))[~edge].all()
    assert blocked.tolist() == (hits.prim >= 0).tolist()
    assert np.allclose(hits.t[found], 5.0, atol=1e-5)
    b1, b2 = hits.u[found][rows], hits.v[found][rows]
    point = p[:, 0] + b1[:, None] * (p[:, 1] - p[:, 0]) + b2[:, None] * (p[:, 2] - p[:, 0])
    assert np.allclose(point, 0.0, atol=1e-5)


def test_a_square_sliding_across_a_pixel_covers_it_for_its_width_over_its_travel():
    """The closed form of motion blur: a black square of side 2 h sliding at constant speed from x = -1 to 1 over
    the shutter covers a ray through the origin for 2 h of its travel of 2, a time share h; Cycles' shutter table
    of a flat curve spreads times over 255/256 of the shutter, so the share is h 256/255. The pixel (a tiny field
    of view) is the white world times the share it is uncovered."""
    h, samples = 0.1, 512
    image = render(sliding_scene(half=h), RenderSettings(samples=samples, seed=11)).image[..., :3]
    share = h * 256 / 255
    n = image.shape[0] * image.shape[1] * samples
    sigma = np.sqrt(share * (1 - share) / n)
    assert abs((1.0 - image.mean()) - share) < 4 * sigma, (1.0 - image.mean(), share, sigma)


def test_still_triangles_beside_deforming_ones_keep_their_numbers_and_hits():
    """A still square beside the deforming one is hit at every time, reported by its own triangle numbers."""
    still = square(0.2, x=3.0)
    times = np.linspace(0.0, 1.0, 33, dtype=np.float32)
    n = len(times)
    origins = np.tile(np.float32([3, -5, 0]), (n, 1))
    dirs = np.tile(np.float32([0, 1, 0]), (n, 1))
    with Renderer(sliding_scene(still=still), threads=1) as r:
        hits = r.accel.intersect(origins, dirs, np.full(n, np.inf, np.float32), time=times)
    assert set(hits.prim.tolist()) <= {2, 3} and (hits.prim >= 0).all()


def test_deformation_steps_equal_to_the_frame_render_as_without_them():
    """Steps that do not move give the image the triangles give without them (the same hits, the same shading),
    within float rounding of the interpolation."""
    scene = sliding_scene(half=0.5, x0=0.0, x1=0.0, width=8, height=8, fov=np.radians(20))
    plain = dataclasses.replace(scene, deform_ids=None, deform_positions=None, deform_normals=None,
                                materials=Materials.diffuse(np.full((1, 3), 0.5, np.float32)))
    scene = dataclasses.replace(plain, deform_ids=scene.deform_ids, deform_positions=scene.deform_positions,
                                deform_normals=scene.deform_normals)
    settings = RenderSettings(samples=4, seed=3)
    a = render(plain, settings).image
    b = render(scene, settings).image
    assert np.allclose(a, b, atol=1e-5)


def test_worker_processes_render_deforming_triangles_as_threads_do():
    """Worker processes (which build the scene again from its arrays) give the image the render's own thread gives,
    bit for bit."""
    scene = sliding_scene(half=0.4, width=24, height=24, fov=np.radians(30))
    settings = RenderSettings(samples=8, seed=2, wave_size=128)
    image = assert_workers_render_as_threads(scene, settings)
    assert (image[..., :3] < 0.99).any()


def test_deforming_triangles_beside_points_keep_the_numbering():
    """With points in the scene (numbered after the triangles) the deforming square is still found at each ray's
    time and the point by its own number."""
    from ember.kernels.scene import Points
    point = Points(np.array([[3, 0, 0, 0.3]], np.float32), np.zeros(1, np.int32))
    scene = dataclasses.replace(sliding_scene(half=0.3), points=point)
    times = np.linspace(0.0, 1.0, 101, dtype=np.float32)
    n = len(times)
    dirs = np.tile(np.float32([0, 1, 0]), (n, 1))
    with Renderer(scene, threads=1) as r:
        hits = r.accel.intersect(np.tile(np.float32([0, -5, 0]), (n, 1)), dirs, np.full(n, np.inf, np.float32),
                                 time=times)
        beside = r.accel.intersect(np.tile(np.float32([3, -5, 0]), (n, 1)), dirs, np.full(n, np.inf, np.float32),
                                   time=times)
    x = -1.0 + 2.0 * times.astype(np.float64)
    edge = np.abs(np.abs(x) - 0.3) < 1e-4
    assert ((hits.prim >= 0) == (np.abs(x) < 0.3))[~edge].all()
    assert set(hits.prim[hits.prim >= 0].tolist()) <= {0, 1}
    assert (beside.prim == 2).all() and np.allclose(beside.t, 4.7, atol=1e-5)


def test_a_render_with_deforming_triangles_and_points_sees_both():
    """The closed form of the sliding square holds in a scene with points too (out of view: hits and shading go
    through the primitive table of triangles, curves and points)."""
    from ember.kernels.scene import Points
    h, samples = 0.1, 256
    point = Points(np.array([[3, 0, 0, 0.3]], np.float32), np.zeros(1, np.int32))
    scene = dataclasses.replace(sliding_scene(half=h), points=point)
    image = render(scene, RenderSettings(samples=samples, seed=5)).image[..., :3]
    share = h * 256 / 255
    n = image.shape[0] * image.shape[1] * samples
    sigma = np.sqrt(share * (1 - share) / n)
    assert abs((1.0 - image.mean()) - share) < 4 * sigma, (1.0 - image.mean(), share, sigma)
