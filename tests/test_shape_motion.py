"""Motion blur of curves and points in the kernel: motion keys as Embree time steps, read at each ray's time."""
from __future__ import annotations

import numpy as np

from ember.kernels import Camera, Materials, Renderer, RenderSettings, SceneArrays, World, motion, render
from ember.kernels.interaction import SurfaceHit
from ember.kernels.scene import Curves, Points, ShapeInstances, object_row
from ember.kernels.shapes import look_at

from kernel_helpers import assert_workers_render_as_threads

FLAT = np.ones(257, np.float32)   # a flat shutter curve, as Blender samples it


def moving_scene(width=16, height=16, fov=np.radians(30), **fields) -> SceneArrays:
    """A black diffuse material, a white world, a camera on -y looking at the origin, a flat shutter."""
    empty = np.zeros((0, 3, 3), np.float32)
    cam = Camera(world_from_camera=look_at((0, -5, 0), (0, 0, 0)), width=width, height=height, fov_rad=fov)
    return SceneArrays(positions=empty, normals=empty, uvs=np.zeros((0, 3, 2), np.float32),
                       material_ids=np.zeros(0, np.int32), materials=Materials.diffuse(np.zeros((1, 3), np.float32)),
                       world=World(color=np.ones(3, np.float32)), camera=cam,
                       shutter_table=motion.shutter_table(FLAT), **fields)


def sliding_point(radius=0.1, x0=-1.0, x1=1.0, steps=3) -> Points:
    """One sphere at the origin at the frame, sliding along x from x0 to x1 over the shutter."""
    keys = np.zeros((steps, 1, 4), np.float32)
    keys[:, 0, 0] = np.linspace(x0, x1, steps)
    keys[:, 0, 3] = radius
    return Points(keys[steps // 2].copy(), np.zeros(1, np.int32), motion=keys)


def test_rays_meet_a_moving_point_where_it_is_at_their_time():
    """Rays down -y through the origin at times t meet the sphere whose centre is at x = -1 + 2t exactly where
    the sphere is then: hit for |x(t)| < r, at distance 5 - sqrt(r^2 - x^2), with the normal from that centre."""
    scene = moving_scene(points=sliding_point(radius=0.3))
    times = np.linspace(0.0, 1.0, 401, dtype=np.float32)
    n = len(times)
    origins = np.tile(np.float32([0, -5, 0]), (n, 1))
    dirs = np.tile(np.float32([0, 1, 0]), (n, 1))
    with Renderer(scene, threads=1) as r:
        hits = r.accel.intersect(origins, dirs, np.full(n, np.inf, np.float32), time=times)
        assert r.accel.occluded(origins, dirs, np.full(n, 10, np.float32), time=times).tolist() == \
            (hits.prim >= 0).tolist()
        found = np.flatnonzero(hits.prim >= 0)
        hit = SurfaceHit(r.triangles, hits.prim[found], hits.u[found], hits.v[found],
                         tuple(dirs[found, k] for k in range(3)), False,
                         ray=(origins[found], hits.t[found], times[found]))
    x = -1.0 + 2.0 * times.astype(np.float64)
    inside = np.abs(x) < 0.3
    edge = np.abs(np.abs(x) - 0.3) < 1e-4
    assert ((hits.prim >= 0) == inside)[~edge].all()
    expect_t = 5.0 - np.sqrt(np.maximum(0.09 - x ** 2, 0.0))
    assert np.allclose(hits.t[found], expect_t[found], atol=2e-5)
    centre = np.stack([x[found], np.zeros(len(found)), np.zeros(len(found))], axis=1)
    p = origins[found] + dirs[found] * hits.t[found][:, None]
    normal = (p - centre) / 0.3
    assert np.allclose(hit.shapes.centre, centre, atol=1e-6)
    assert np.allclose(np.stack(hit.shapes.ng, axis=1) if isinstance(hit.shapes.ng, tuple) else hit.shapes.ng,
                       normal, atol=1e-4)


def test_a_point_sliding_across_a_pixel_covers_it_for_its_width_over_its_travel():
    """The closed form of motion blur: a black sphere of radius r sliding at constant speed from x = -1 to 1 over
    the shutter covers a ray through the origin for 2r of its travel of 2, a time share r; Cycles' shutter table
    of a flat curve spreads times uniformly over 255/256 of the shutter, so the share is r 256/255. The pixel
    (a tiny field of view: the ray's neighbours see the same) is white world times the share it is uncovered."""
    r, samples = 0.1, 512
    scene = moving_scene(width=4, height=4, fov=1e-3, points=sliding_point(radius=r))
    image = render(scene, RenderSettings(samples=samples, seed=11)).image[..., :3]
    share = r * 256 / 255
    n = image.shape[0] * image.shape[1] * samples
    sigma = np.sqrt(share * (1 - share) / n)
    assert abs((1.0 - image.mean()) - share) < 4 * sigma, (1.0 - image.mean(), share, sigma)


def test_moving_curves_take_their_keys_at_each_ray_time():
    """A linear curve (a capsule along z) moving along x as the sliding point does covers a ray through the
    origin at the same times; its hits report the segment's keys where they are then."""
    steps = 5
    keys = np.zeros((steps, 2, 4), np.float32)
    keys[:, :, 0] = np.linspace(-1, 1, steps)[:, None]
    keys[:, 0, 2], keys[:, 1, 2] = -1.0, 1.0
    keys[:, :, 3] = 0.2
    curves = Curves("LINEAR", keys[steps // 2].copy(), np.array([0, 2], np.int32), np.zeros(1, np.int32),
                    motion=keys)
    times = np.linspace(0.0, 1.0, 201, dtype=np.float32)
    n = len(times)
    origins, dirs = _rays_along_y(n, 0.0)
    with Renderer(moving_scene(curves=(curves,)), threads=1) as r:
        hits = r.accel.intersect(origins, dirs, np.full(n, np.inf, np.float32), time=times)
    x = -1.0 + 2.0 * times.astype(np.float64)
    edge = np.abs(np.abs(x) - 0.2) < 1e-4
    assert ((hits.prim >= 0) == (np.abs(x) < 0.2))[~edge].all()
    found = (hits.prim >= 0) & ~edge
    assert np.allclose(hits.t[found], 5.0 - np.sqrt(0.04 - x[found] ** 2), atol=2e-5)


def _rays_along_y(n: int, z: float):
    """n rays from (0, -5, z) along +y: (origins, directions)."""
    return np.tile(np.float32([0, -5, z]), (n, 1)), np.tile(np.float32([0, 1, 0]), (n, 1))


def test_a_curve_whose_radius_moves_reports_the_frames_for_huangs_near_field():
    """A still linear curve whose keys' radii grow over the shutter: a hit's radius (Curves Info's Thickness, Cycles'
    curve_thickness reads the motion keys) is the one at the ray's time, its key_radius the frame's keys' mixed at u
    whatever the time (what Cycles' Huang setup reads for the near field: curve_keys, never the motion steps)."""
    steps = 3
    keys = np.zeros((steps, 2, 4), np.float32)
    keys[:, 0, 2], keys[:, 1, 2] = -1.0, 1.0
    keys[:, 0, 3] = [0.1, 0.2, 0.3]
    keys[:, 1, 3] = [0.2, 0.3, 0.4]
    curves = Curves("LINEAR", keys[1].copy(), np.array([0, 2], np.int32), np.zeros(1, np.int32), motion=keys)
    times = np.linspace(0.0, 1.0, 9, dtype=np.float32)
    n = len(times)
    origins, dirs = _rays_along_y(n, 0.3)
    with Renderer(moving_scene(curves=(curves,)), threads=1) as r:
        hits = r.accel.intersect(origins, dirs, np.full(n, np.inf, np.float32), time=times)
        assert (hits.prim >= 0).all()
        hit = SurfaceHit(r.triangles, hits.prim, hits.u, hits.v, tuple(dirs[:, k] for k in range(3)), False,
                         ray=(origins, hits.t, times))
    u = hit.shapes.b1
    assert np.all((u > 0.5) & (u < 0.8))
    np.testing.assert_allclose(hit.shapes.key_radius, 0.2 + 0.1 * u, atol=1e-6)
    np.testing.assert_allclose(hit.shapes.radius, 0.1 + 0.2 * times + 0.1 * u, atol=1e-6)

def test_a_still_record_with_equal_motion_keys_renders_as_without_them():
    """Motion keys that do not move give the image the record gives alone, bit for bit (same rays, same hits)."""
    still = Points(np.array([[0, 0, 0, 0.8]], np.float32), np.zeros(1, np.int32))
    keys = np.repeat(still.points[None], 3, axis=0)
    a = render(moving_scene(points=still), RenderSettings(samples=2, seed=3)).image
    b = render(moving_scene(points=Points(still.points, still.material_ids, motion=keys)),
               RenderSettings(samples=2, seed=3)).image
    assert np.array_equal(a, b)


def _turn(angle):
    c, s = np.cos(angle), np.sin(angle)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def test_a_turning_instance_moves_its_points_along_the_arc():
    """An instance turning half a circle about z over three motion steps (0, 90 and 180 degrees) carries its
    sphere (at x = 1 in object space) along the arc, as Cycles' slerped object motion does: at time t its centre
    is at angle pi t. A ray down through that point hits the sphere's top; one through the chord between steps
    (where world-space keys mixed linearly would put it) misses."""
    keys = np.stack([_turn(a) for a in (0.0, np.pi / 2, np.pi)])
    placed = ShapeInstances((Points(np.array([[1, 0, 0, 0.2]], np.float32), np.zeros(1, np.int32)),),
                            np.zeros(1, np.int32), keys[1:2].copy(), np.zeros(1, np.int32), (keys,),
                            np.zeros(1, np.int32))
    scene = moving_scene(shape_instances=placed, objects=object_row(np.eye(4))[None],
                         object_ids=np.zeros(0, np.int32))
    assert scene.has_motion
    times = np.linspace(0.05, 0.95, 19, dtype=np.float32)
    angle = np.pi * times.astype(np.float64)
    arc = np.stack([np.cos(angle), np.sin(angle), np.full(len(times), 5.0)], axis=1)
    step = np.minimum((times * 2).astype(int), 1)
    f = times * 2 - step
    chord = (1 - f)[:, None] * keys[step, :3, 0] + f[:, None] * keys[step + 1, :3, 0]
    chord[:, 2] = 5.0
    down = np.tile(np.float32([0, 0, -1]), (len(times), 1))
    with Renderer(scene, threads=1) as r:
        on_arc = r.accel.intersect(arc.astype(np.float32), down, np.full(len(times), np.inf, np.float32),
                                   time=times)
        hit = SurfaceHit(r.triangles, on_arc.prim, on_arc.u, on_arc.v, tuple(down[:, k] for k in range(3)), False,
                         ray=(arc.astype(np.float32), on_arc.t, times))
        on_chord = r.accel.intersect(chord.astype(np.float32), down, np.full(len(times), np.inf, np.float32),
                                     time=times)
    assert (on_arc.prim >= 0).all() and np.allclose(on_arc.t, 4.8, atol=1e-4)
    assert np.allclose(hit.shapes.centre[:, :2], arc[:, :2], atol=1e-4)
    gap = np.linalg.norm(chord[:, :2] - arc[:, :2], axis=1)
    assert ((on_chord.prim >= 0) == (gap < 0.2 - 1e-4))[np.abs(gap - 0.2) > 1e-3].all()


def test_worker_processes_render_moving_curves_and_points_as_threads_do():
    """A deforming sphere and a turning instance: worker processes (which build the scene again from its arrays)
    give the image the render's own thread gives, bit for bit."""
    keys = np.stack([_turn(a) for a in (0.0, np.pi / 2, np.pi)])
    placed = ShapeInstances((Points(np.array([[1, 0, 0, 0.3]], np.float32), np.zeros(1, np.int32)),),
                            np.zeros(1, np.int32), keys[1:2].copy(), np.zeros(1, np.int32), (keys,),
                            np.zeros(1, np.int32))
    sliding = sliding_point(radius=0.4)
    scene = moving_scene(width=24, height=24, points=Points(sliding.points, sliding.material_ids,
                                                               np.zeros(1, np.int32), motion=sliding.motion),
                         shape_instances=placed, objects=np.repeat(object_row(np.eye(4))[None], 1, axis=0),
                         object_ids=np.zeros(0, np.int32))
    settings = RenderSettings(samples=8, seed=2, wave_size=128)
    image = assert_workers_render_as_threads(scene, settings)
    assert (image[..., :3] < 0.99).any()


def test_joined_records_keep_each_ones_motion():
    """World-space records joined into one (engine/export/shapes.py): a still one repeats its keys at every step,
    one of 3 steps put on the 5 steps of another moves as it did (the kernel's interpolation between its steps)."""
    from ember.engine.export.shapes import _join_points
    rng = np.random.default_rng(4)
    still = Points(rng.random((2, 4)).astype(np.float32), np.zeros(2, np.int32), np.zeros(2, np.int32))
    three = rng.random((3, 3, 4)).astype(np.float32)
    five = rng.random((5, 1, 4)).astype(np.float32)
    joined = _join_points([still,
                           Points(three[1].copy(), np.zeros(3, np.int32), np.zeros(3, np.int32), motion=three),
                           Points(five[2].copy(), np.zeros(1, np.int32), np.zeros(1, np.int32), motion=five)])
    assert joined.motion.shape == (5, 6, 4)
    assert np.array_equal(joined.motion[:, :2], np.broadcast_to(still.points, (5, 2, 4)))
    assert np.array_equal(joined.motion[:, 5], five[:, 0])
    assert np.array_equal(joined.motion[::2, 2:5], three)
    assert np.allclose(joined.motion[1, 2:5], 0.5 * (three[0] + three[1]))
