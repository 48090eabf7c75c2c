"""The viewport's rendered mode, headless: the view's projection against Blender's, the progressive
worker (refines, restarts on change and only on change, stops), the image handed to the GPU, and the
depsgraph diffing and view_update/view_draw glue with real bpy data. Only the GPU calls of view_draw
(texture upload and draw) cannot run here: the gpu module refuses to work in background mode."""
from __future__ import annotations

import dataclasses
import math
import sys
import time
from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from bpy_helpers import diffuse_material, mesh_object, new_scene, set_world
from ember.engine import viewport as vp
from ember.engine.render_engine import EmberRenderEngine
from ember.engine.session import render_settings
from ember.engine.export.camera import (camera_zoom_factor, region_camera, stand_in_camera, view_camera,
                                       view_camera_object)
from ember.engine.export.updates import scene_needs_export
from ember.engine.viewport import ViewportRender
from ember.engine.viewport import session as viewport_session
from ember.engine.viewport.draw import (HALF_MAX, UNLIMITED_SAMPLES, Display, Frame, display_pixels, gpu_pixels,
                                        status_text)
from ember.engine.viewport.session import ViewportSession, preview_size
from ember.kernels import RenderSettings
from ember.kernels.camera import generate_rays, view_plane
from ember.kernels.shapes import look_at
from kernel_helpers import make_scene

# Polling limit for anything the worker does; generous for a loaded 2-core machine, and never reached
# when things work (tests wait for states, they do not measure time).
TIMEOUT_S = 60.0
COSINE = RenderSettings(samples=UNLIMITED_SAMPLES, mode="COSINE", max_bounces=2)


def wait_until(predicate, timeout=TIMEOUT_S):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.005)
    raise AssertionError("the viewport worker did not reach the expected state")


def current_frame(session):
    """Wait for a frame of the session's current generation with at least one full sample."""
    def ready():
        frame = session.snapshot()
        return frame is not None and frame.generation == session.generation and frame.samples_done >= 1 and frame
    return wait_until(ready)


@pytest.fixture
def sessions():
    """Makes ViewportSessions and stops every one of them after the test."""
    made = []

    def make(threads=1, **options):
        options.setdefault("display_interval_s", 0.0)
        session = ViewportSession(threads, **options)
        made.append(session)
        return session

    yield make
    for session in made:
        assert session.stop(), "a viewport worker did not stop"


def world_scene(color=(1.0, 0.0, 0.0), emission=None):
    """A small quad at the origin facing -Y, seen from y = -5; the world fills the rest of the frame."""
    positions = np.array([[[-0.5, 0, -0.5], [0.5, 0, -0.5], [0.5, 0, 0.5]],
                          [[-0.5, 0, -0.5], [0.5, 0, 0.5], [-0.5, 0, 0.5]]], np.float32)
    normals = np.tile(np.array([0, -1, 0], np.float32), (2, 3, 1))
    return make_scene(positions, normals, albedo=(0.5, 0.5, 0.5), emission=emission, world_color=color)


def view(eye=(0, -5, 0), target=(0, 0, 0), width=32, height=24, lens=50.0):
    view_matrix = np.linalg.inv(look_at(eye, target))
    return view_camera(view_matrix, width, height, "PERSP", lens, 0.01, 100.0, 5.0)


def corner_color(frame):
    """Mean RGB of the top-left corner, where only the world is seen."""
    return frame.image[:4, :4, :3].reshape(-1, 3).mean(axis=0)


# ====================================================================== the view's projection
def project(perspective_matrix, points):
    """Blender's projection: world points (N, 3) -> NDC (N, 3)."""
    clip = np.c_[points, np.ones(len(points))] @ np.asarray(perspective_matrix, np.float64).T
    return clip[:, :3] / clip[:, 3:4]


def pixel_rays(camera, width, height):
    """Rays through the centres of a few pixels, corners included; and those pixels' NDC x, y."""
    row = np.array([0, height - 1, height // 2, 3, height - 2], np.int32)
    col = np.array([0, width - 1, width // 3, width - 5, 7], np.int32)
    half = np.full(len(row), 0.5, np.float32)
    origins, dirs, t_max = generate_rays(camera, row, col, half, half)
    ndc = np.stack([(col + 0.5) / width * 2 - 1, 1 - (row + 0.5) / height * 2], 1)
    return origins.astype(np.float64), dirs.astype(np.float64), t_max.astype(np.float64), ndc


@pytest.mark.parametrize("screen", ["Layout", "Texture Paint"])  # a wide and a tall region: both fits
def test_perspective_view_projects_like_blenders_own_matrices(screen):
    """The factory startup file stores each 3D view's matrices as Blender computed them: every ray of
    the kernel camera must land on its pixel's centre under Blender's perspective matrix."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    area = next(a for a in bpy.data.screens[screen].areas if a.type == "VIEW_3D")
    space, r3d = area.spaces.active, area.spaces.active.region_3d
    region = next(r for r in area.regions if r.type == "WINDOW")
    assert r3d.view_perspective == "PERSP"
    camera = region_camera(space, r3d, region.width, region.height)
    origins, dirs, t_max, ndc = pixel_rays(camera, region.width, region.height)
    for distance in (0.5, 3.0, 40.0):
        got = project(r3d.perspective_matrix, origins + dirs * distance)
        np.testing.assert_allclose(got[:, :2], ndc, atol=2e-5)
    # Rays start on Blender's near plane (NDC z = -1).
    np.testing.assert_allclose(project(r3d.perspective_matrix, origins)[:, 2], -1.0, atol=5e-3)


def test_perspective_view_is_a_72mm_sensor():
    """BKE_camera_params_from_view3d: lens with the default 36 mm sensor and CameraParams.zoom = 2."""
    camera = view_camera(np.eye(4), 400, 300, "PERSP", 50.0, 0.01, 1000.0, 10.0)
    assert camera.fov_rad == pytest.approx(2 * math.atan(72.0 / (2 * 50.0)))
    assert view_plane(camera) == pytest.approx((-0.72, 0.72, -0.54, 0.54))


def ortho_window_matrix(xmin, xmax, ymin, ymax, near, far):
    """Blender's orthographic_m4 (the window matrix of an ortho view)."""
    m = np.eye(4)
    m[0, 0], m[1, 1], m[2, 2] = 2 / (xmax - xmin), 2 / (ymax - ymin), -2 / (far - near)
    m[0, 3], m[1, 3], m[2, 3] = -(xmax + xmin) / (xmax - xmin), -(ymax + ymin) / (ymax - ymin), -(far + near) / (far - near)
    return m


def test_ortho_view_matches_blenders_formula():
    """An ortho view with lens 50 at distance 10, 800x600, clip_end 1000. Blender's formula:
    ortho_scale = dist * 36 / lens = 7.2, zoom 2 -> a view plane 14.4 wide; clipping -500..500."""
    world_from_view = look_at((3, -4, 2), (0, 0, 0.5))
    view_matrix = np.linalg.inv(world_from_view)
    camera = view_camera(view_matrix, 800, 600, "ORTHO", 50.0, 0.01, 1000.0, 10.0)
    assert camera.kind == "ORTHO"
    assert view_plane(camera) == pytest.approx((-7.2, 7.2, -5.4, 5.4))
    perspective = ortho_window_matrix(-7.2, 7.2, -5.4, 5.4, -500.0, 500.0) @ view_matrix
    origins, dirs, t_max, ndc = pixel_rays(camera, 800, 600)
    np.testing.assert_allclose(project(perspective, origins)[:, :2], ndc, atol=1e-4)
    # Each ray runs from Blender's near plane to its far plane: 500 behind the view point to 500 ahead.
    np.testing.assert_allclose(project(perspective, origins)[:, 2], -1.0, atol=1e-5)
    np.testing.assert_allclose(project(perspective, origins + dirs * t_max[:, None])[:, 2], 1.0, atol=1e-4)
    np.testing.assert_allclose(dirs, np.broadcast_to(-world_from_view[:3, 2], dirs.shape), atol=1e-6)


def test_camera_view_zoom_offset_and_shift():
    """Looking through a 50 mm camera (36 mm sensor) in a 1000x500 region. At view_camera_zoom 0
    Blender's factor is (sqrt 2)^2 / 4 = 0.5: the frame (+-0.36 at unit distance) fills half the
    region. Pan offset 0.1 and shift 0.2 move the centre by 2 * 0.1 * 0.72 + 0.2 * 0.72."""
    camera_ob = stand_in_camera(lens=50.0, clip_start=0.5, clip_end=80.0)
    assert camera_zoom_factor(0.0) == pytest.approx(0.5)
    at_zero = view_camera(np.eye(4), 1000, 500, "CAMERA", 20.0, 0.01, 1000.0, 3.0, camera_ob, 0.0)
    assert view_plane(at_zero) == pytest.approx((-0.72, 0.72, -0.36, 0.36))
    assert (at_zero.clip_start, at_zero.clip_end) == (0.5, 80.0)  # the camera's clipping, not the view's
    fills = view_camera(np.eye(4), 1000, 500, "CAMERA", 20.0, 0.01, 1000.0, 3.0, camera_ob,
                        50.0 * (2.0 - math.sqrt(2.0)))
    assert view_plane(fills) == pytest.approx((-0.36, 0.36, -0.18, 0.18))
    shifted = dict(lens=50.0, shift_x=0.2, clip_start=0.5, clip_end=80.0)
    panned = view_camera(np.eye(4), 1000, 500, "CAMERA", 20.0, 0.01, 1000.0, 3.0, stand_in_camera(**shifted),
                         0.0, (0.1, 0.0))
    xmin, xmax, ymin, ymax = view_plane(panned)
    assert ((xmin + xmax) / 2, xmax - xmin, (ymin + ymax) / 2) == pytest.approx((0.288, 1.44, 0.0))
    ortho = view_camera(np.eye(4), 1000, 500, "CAMERA", 20.0, 0.01, 1000.0, 3.0,
                        stand_in_camera(type="ORTHO", ortho_scale=4.0), 0.0)
    assert ortho.kind == "ORTHO" and view_plane(ortho) == pytest.approx((-4.0, 4.0, -2.0, 2.0))


def test_camera_view_reads_the_scene_camera():
    scene = new_scene()
    scene.camera.data.shift_y = 0.1
    area = next(a for a in bpy.data.screens["Layout"].areas if a.type == "VIEW_3D")
    space, r3d = area.spaces.active, area.spaces.active.region_3d
    r3d.view_perspective = "CAMERA"
    r3d.view_camera_zoom = 10.0
    camera_ob = view_camera_object(space, scene).evaluated_get(bpy.context.evaluated_depsgraph_get())
    camera = region_camera(space, r3d, 600, 400, camera_ob)
    fac = camera_zoom_factor(10.0)
    assert camera.fov_rad == pytest.approx(2 * math.atan(36.0 / (2 * 35.0 * fac)))  # add_camera's 35 mm
    assert camera.shift_y == pytest.approx(0.1 * fac)
    assert (camera.clip_start, camera.clip_end) == pytest.approx((scene.camera.data.clip_start,
                                                                  scene.camera.data.clip_end))


def test_camera_view_takes_the_cameras_depth_of_field_and_the_films_filter():
    """Looking through a camera with depth of field, the viewport renders with its lens (Cycles does);
    the scene's pixel filter applies to every view."""
    scene = new_scene()
    dof = scene.camera.data.dof
    dof.use_dof, dof.aperture_fstop, dof.focus_distance, dof.aperture_blades = True, 2.0, 4.0, 6
    scene.ember.pixel_filter_type, scene.ember.filter_width = "GAUSSIAN", 2.0
    area = next(a for a in bpy.data.screens["Layout"].areas if a.type == "VIEW_3D")
    space, r3d = area.spaces.active, area.spaces.active.region_3d
    depsgraph = bpy.context.evaluated_depsgraph_get()
    camera_ob = view_camera_object(space, scene).evaluated_get(depsgraph)
    r3d.view_perspective = "CAMERA"
    kernel = region_camera(space, r3d, 600, 400, camera_ob, scene)
    assert kernel.aperture_radius == pytest.approx(35e-3 / 4.0) and kernel.focus_distance == pytest.approx(4.0)
    assert kernel.aperture_blades == 6 and (kernel.filter_type, kernel.filter_width) == ("GAUSSIAN", 2.0)
    r3d.view_perspective = "PERSP"  # a free view has no lens
    free = region_camera(space, r3d, 600, 400, camera_ob, scene)
    assert free.aperture_radius == 0.0 and free.filter_type == "GAUSSIAN"


@pytest.mark.parametrize("kind", ["FISHEYE_EQUIDISTANT", "EQUIRECTANGULAR"])
def test_camera_view_through_a_panoramic_camera(kind):
    """Looking through a panoramic camera, the viewport shows the panorama: with the frame filling the
    region its rays are the final render's, pixel for pixel; zoomed out, the region's centre still looks
    where the frame's centre does."""
    from ember.engine.export.camera import export_camera
    from ember.kernels.camera import camera_frame, generate_rays

    def local(camera, dirs):  # in the camera's own frame (the test's view matrix is not the camera's)
        return dirs @ camera_frame(camera)[1]
    scene = new_scene(60, 40)
    cam = scene.camera.data
    cam.type, cam.panorama_type, cam.shift_x = "PANO", kind, 0.05
    area = next(a for a in bpy.data.screens["Layout"].areas if a.type == "VIEW_3D")
    space, r3d = area.spaces.active, area.spaces.active.region_3d
    r3d.view_perspective = "CAMERA"
    r3d.view_camera_offset = (0.0, 0.0)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    camera_ob = view_camera_object(space, scene).evaluated_get(depsgraph)
    final = dataclasses.replace(export_camera(camera_ob, scene, 60, 40, []), filter_type="BOX")
    rows, cols = (a.ravel() for a in np.indices((40, 60)))
    half = np.full(len(rows), 0.5, np.float32)
    _, want, _ = generate_rays(final, rows, cols, half, half)
    r3d.view_camera_zoom = 50.0 * (2.0 - math.sqrt(2.0))  # factor 1: the frame fills a region of its size
    view = region_camera(space, r3d, 60, 40, camera_ob, scene)
    assert view.kind == "PANO" and view.panorama_type == kind
    _, got, _ = generate_rays(dataclasses.replace(view, filter_type="BOX"), rows, cols, half, half)
    np.testing.assert_allclose(local(view, got), local(final, want), atol=2e-5)
    r3d.view_camera_zoom = 0.0  # factor 0.5: the frame is half the region
    view = region_camera(space, r3d, 60, 40, camera_ob, scene)
    centre = np.array([20]), np.array([30])
    zero = np.zeros(1, np.float32)
    np.testing.assert_allclose(local(view, generate_rays(dataclasses.replace(view, filter_type="BOX"), *centre,
                                                         zero, zero)[1]),
                               local(final, generate_rays(final, *centre, zero, zero)[1]), atol=2e-5)


def test_equal_views_compare_equal():
    assert view() == view() and hash(view()) == hash(view())
    assert view() != view(eye=(0, -5, 0.001)) and view() != view(width=33) and view() != view(lens=51)


# ====================================================================== the worker
def test_session_refines_progressively(sessions):
    session = sessions()
    session.update_view(view())
    session.update_scene(world_scene(), COSINE)
    counts = []
    wait_until(lambda: counts.append(session.samples_done) or len(set(counts) - {0}) >= 3)
    assert counts == sorted(counts), "samples went down without a change"
    frame = session.snapshot()
    assert frame.image.shape == (24, 32, 4) and frame.image.dtype == np.float32
    np.testing.assert_allclose(corner_color(frame), (1, 0, 0), atol=1e-6)
    assert frame.image[12, 16, :3].max() < 0.9  # the grey quad in the middle


def test_finite_sample_count_finishes(sessions):
    session = sessions()
    session.update_view(view())
    session.update_scene(world_scene(), RenderSettings(samples=5, mode="COSINE"))
    wait_until(lambda: not session.busy)
    frame = session.snapshot()
    assert (frame.samples_done, frame.samples_total) == (5, 5)
    assert not session.needs_redraw  # finished and taken: nothing more to draw
    assert status_text(frame, session.busy, session.error) == "Sample 5/5"


def test_scene_change_restarts_from_zero(sessions):
    session = sessions()
    session.update_view(view())
    session.update_scene(world_scene((1, 0, 0)), COSINE)
    wait_until(lambda: session.samples_done >= 2)
    before = session.generation
    with session._cond:  # the check must see the restart before the worker can refine again
        assert session.update_scene(world_scene((0, 0, 1)), COSINE)
        assert session.samples_done == 0 and session.generation > before
    frame = current_frame(session)
    np.testing.assert_allclose(corner_color(frame), (0, 0, 1), atol=1e-6)


def test_view_change_restarts_and_an_identical_view_does_not(sessions):
    session = sessions()
    session.update_view(view())
    session.update_scene(world_scene((0.2, 0.2, 0.2)), COSINE)
    wait_until(lambda: session.samples_done >= 2)
    generation = session.generation
    assert not session.update_view(view())                 # the same view, a new object
    assert not session.update_settings(COSINE)             # the same settings
    assert session.generation == generation and session.samples_done >= 2
    # Close up, the quad fills the frame: the corner is no longer the world.
    with session._cond:
        assert session.update_view(view(eye=(0, -0.6, 0)))
        assert session.samples_done == 0 and session.generation > generation
    frame = current_frame(session)
    assert corner_color(frame).max() < 0.15
    generation = session.generation
    assert session.update_settings(RenderSettings(samples=UNLIMITED_SAMPLES, mode="COSINE", max_bounces=2, seed=7))
    assert session.generation > generation


def test_rapid_changes_coalesce(sessions):
    """A burst of edits ends in one render of the last state, not a queue of stale ones. The burst is
    made while holding the session's lock, so the worker cannot slip in between two edits."""
    session = sessions()
    started = []
    render = session._render

    def recording(renderer, job):
        started.append(job.generation)
        render(renderer, job)

    session._render = recording
    session.update_view(view())
    session.update_scene(world_scene(), COSINE)
    wait_until(lambda: session.samples_done >= 1)
    first = session.generation
    with session._cond:
        for k in range(1, 31):
            session.update_view(view(eye=(0, -5, 0.01 * k)))
    last = session.generation
    assert current_frame(session).generation == last
    assert [g for g in started if g > first] == [last]


def test_stop_joins_the_worker_mid_render(sessions):
    session = sessions(threads=2)
    session.update_view(view(width=160, height=120))
    session.update_scene(world_scene(), COSINE)
    wait_until(lambda: session.alive and session.samples_done >= 1)
    assert session.stop() and not session.alive
    session.update_view(view(width=100, height=75))
    assert not session.alive  # a stopped session stays stopped


def test_free_stops_the_viewport_worker():
    viewport = ViewportRender(1, display_interval_s=0.0)
    viewport.session.update_view(view())
    viewport.session.update_scene(world_scene(), COSINE)
    wait_until(lambda: viewport.session.samples_done >= 1)
    viewport.free()
    assert not viewport.session.alive


def test_engine_del_frees_the_viewport_and_tolerates_a_removed_struct():
    viewport = ViewportRender(1, display_interval_s=0.0)
    viewport.session.update_view(view())
    viewport.session.update_scene(world_scene(), COSINE)
    wait_until(lambda: viewport.session.alive)
    EmberRenderEngine.__del__(SimpleNamespace(_viewport=viewport))
    assert not viewport.session.alive

    class Removed:
        def __getattr__(self, name):
            raise ReferenceError("StructRNA of type EmberRenderEngine has been removed")

    EmberRenderEngine.__del__(Removed())  # must not raise


def test_each_engine_instance_has_its_own_worker(sessions):
    """Quad view: four engine instances, four sessions; stopping one leaves the others running."""
    first, second = sessions(), sessions()
    for session, color in ((first, (1, 0, 0)), (second, (0, 1, 0))):
        session.update_view(view())
        session.update_scene(world_scene(color), COSINE)
    wait_until(lambda: first.samples_done >= 1 and second.samples_done >= 1)
    assert first._thread is not second._thread
    assert first.stop()
    done = second.samples_done
    wait_until(lambda: second.samples_done > done)
    np.testing.assert_allclose(corner_color(second.snapshot()), (0, 1, 0), atol=1e-6)


def test_quick_preview_comes_first(sessions):
    """A large film first gets one sample at low resolution, shown at the full size."""
    session = sessions(preview_pixels=64)
    published = []
    publish = session._publish

    def recording(job, display, samples_done, finished=False):
        published.append((samples_done, display.shape))
        publish(job, display, samples_done, finished)

    session._publish = recording
    session.update_view(view())
    session.update_scene(world_scene(), COSINE)
    wait_until(lambda: session.samples_done >= 1)
    assert published[0] == (0, (24, 32, 4))
    assert preview_size(32, 24, 64) == (9, 7) and preview_size(32, 24, 10_000) is None


def test_invalid_scene_is_reported_not_raised(sessions):
    session = sessions()
    scene = world_scene()
    bad = make_scene(scene.positions, scene.normals, material_ids=np.array([0, 5], np.int32))
    session.update_view(view())
    session.update_scene(bad, COSINE)
    error = wait_until(lambda: session.error)
    assert "material_ids" in error and not session.busy
    assert status_text(session.snapshot(), session.busy, error).startswith("Ember: ")
    session.update_scene(world_scene(), COSINE)  # a good scene renders again
    wait_until(lambda: session.samples_done >= 1)
    assert session.error is None


# ====================================================================== the image handed to drawing
def test_display_pixels_are_finite_and_half_float():
    image = np.array([[[np.nan, np.inf, -np.inf, 1e9], [0.5, -1e6, 65504.0, 1.0]]], np.float32)
    out = display_pixels(image)
    assert out.dtype == np.float32 and np.isfinite(out).all()
    np.testing.assert_array_equal(out, [[[0, HALF_MAX, -HALF_MAX, HALF_MAX], [0.5, -HALF_MAX, HALF_MAX, 1]]])
    assert np.isfinite(out.astype(np.float16)).all()


def test_gpu_pixels_are_bottom_up_contiguous_float32():
    image = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4)
    flat = gpu_pixels(image)
    assert flat.shape == (24,) and flat.flags.c_contiguous and flat.dtype == np.float32
    np.testing.assert_array_equal(flat[:12], image[1].ravel())  # GPU textures start at the bottom row


def test_session_frames_stay_in_half_float_range(sessions):
    """An emitter far brighter than a half float holds: the frame is clamped, never inf."""
    session = sessions()
    session.update_view(view(eye=(0, -1.0, 0)))
    session.update_scene(world_scene(emission=(1e9, 1e9, 1e9)), COSINE)
    frame = current_frame(session)
    assert np.isfinite(frame.image).all() and frame.image.max() == HALF_MAX
    assert not frame.image.flags.writeable  # frames are snapshots: the worker never changes them


def test_status_text():
    frame = Frame(np.zeros((1, 1, 4), np.float32), 3, 32, 1)
    assert status_text(frame, True, None) == "Sample 3/32"
    assert status_text(frame._replace(samples_total=UNLIMITED_SAMPLES), True, None) == "Sample 3"
    assert status_text(frame._replace(samples_done=0), True, None) == "Ember: preview"
    assert status_text(None, True, None) == "Ember: preparing"
    assert status_text(frame, False, "Scene has no camera") == "Ember: Scene has no camera"


# ====================================================================== bpy: diffing and glue
def box_scene():
    scene = new_scene()
    mat = diffuse_material("Grey", (0.5, 0.5, 0.5))
    quad = mesh_object("Quad", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [(0, 1, 2, 3)], mat)
    world = set_world(scene, color=(0.1, 0.2, 0.3))
    return scene, quad, mat, world


class DepsgraphUpdates:
    """depsgraph.updates is filled only while Blender reports an update (view_update, or the
    depsgraph_update_post handler): run `on_update(depsgraph)` there."""

    def __init__(self, on_update):
        self.on_update = on_update
        self.results = []

    def __enter__(self):
        bpy.app.handlers.depsgraph_update_post.append(self._handler)
        return self

    def __exit__(self, *exc):
        bpy.app.handlers.depsgraph_update_post.remove(self._handler)

    def _handler(self, scene, depsgraph):
        self.results.append(self.on_update(depsgraph))

    def after(self, edit):
        """Apply an edit, let Blender evaluate, return what on_update said (None: no update at all)."""
        self.results.clear()
        edit()
        bpy.context.evaluated_depsgraph_get()
        return self.results[-1] if self.results else None


def test_which_depsgraph_updates_trigger_an_export():
    scene, quad, mat, world = box_scene()
    bpy.context.evaluated_depsgraph_get()
    diffuse = mat.node_tree.nodes["Diffuse BSDF"].inputs["Color"]
    background = world.node_tree.nodes["Background"].inputs["Color"]
    with DepsgraphUpdates(lambda depsgraph: scene_needs_export(depsgraph.updates)) as updates:
        assert updates.after(lambda: setattr(quad, "location", (0.5, 0, 0))) is True
        assert updates.after(lambda: setattr(diffuse, "default_value", (1, 0, 0, 1))) is True
        assert updates.after(lambda: setattr(background, "default_value", (0, 1, 0, 1))) is True

        def move_vertex():
            quad.data.vertices[0].co.z = 0.3
            quad.data.update()

        assert updates.after(move_vertex) is True
        light = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
        assert updates.after(lambda: scene.collection.objects.link(light)) is True
        assert updates.after(lambda: setattr(light.data, "energy", 50.0)) is True
        # Cameras are not rendered; a view looking through one follows it in view_draw.
        assert updates.after(lambda: setattr(scene.camera, "location", (1, -6, 2))) is False
        assert updates.after(lambda: setattr(scene.camera.data, "lens", 20.0)) is False
        # Selecting reaches Blender as a bare scene update: no restart.
        assert updates.after(lambda: quad.select_set(True)) is False


def engine_and_context(pixel_size=16):
    """A 3D view of the factory startup file (1574x954 'Layout'), a film of 1/pixel_size of it, and a
    stand-in for the engine's update_stats / tag_redraw / get_preview_pixel_size."""
    area = next(a for a in bpy.data.screens["Layout"].areas if a.type == "VIEW_3D")
    context = SimpleNamespace(space_data=area.spaces.active, region_data=area.spaces.active.region_3d,
                              region=next(r for r in area.regions if r.type == "WINDOW"))
    engine = SimpleNamespace(stats=[], redraws=0)
    engine.get_preview_pixel_size = lambda scene: pixel_size
    engine.update_stats = lambda a, b: engine.stats.append(b)

    def tag_redraw():
        engine.redraws += 1

    engine.tag_redraw = tag_redraw
    return engine, context


def test_view_update_and_draw_glue():
    scene, quad, mat, world = box_scene()
    scene.ember.preview_samples = 0
    scene.ember.sampling_mode = "COSINE"
    engine, context = engine_and_context()
    viewport = ViewportRender(1, display_interval_s=0.0)
    session = viewport.session
    try:
        with DepsgraphUpdates(lambda depsgraph: viewport.view_update(engine, context, depsgraph)) as updates:
            updates.after(lambda: setattr(quad, "location", (0.0, 0.0, 0.01)))  # first call: export
            assert session.busy
            frame = wait_until(lambda: viewport.prepare_draw(engine, context, bpy.context.evaluated_depsgraph_get()))
            assert frame.image.shape == (60, 98, 4)  # 1574x954 at 16 screen pixels per film pixel
            assert engine.redraws >= 1 and engine.stats[-1]  # refining: asks for the next draw, reports
            np.testing.assert_allclose(corner_color(current_frame(session)), (0.1, 0.2, 0.3), atol=1e-6)

            generation = session.generation
            updates.after(lambda: quad.select_set(True))
            assert session.generation == generation  # selection: no export, no restart

            background = world.node_tree.nodes["Background"].inputs["Color"]
            updates.after(lambda: setattr(background, "default_value", (0.9, 0.1, 0.1, 1)))
            assert session.generation > generation
            frame = current_frame(session)
            np.testing.assert_allclose(corner_color(frame), (0.9, 0.1, 0.1), atol=1e-6)

            # Hiding an object (the eye icon) is a bare scene update; the visible set tells.
            generation = session.generation
            updates.after(lambda: quad.hide_set(True))
            assert session.generation > generation

            # Settings edits reach view_draw even when no depsgraph update comes.
            generation = session.generation
            scene.ember.preview_samples = 3
            viewport.prepare_draw(engine, context, bpy.context.evaluated_depsgraph_get())
            assert session.generation > generation
            wait_until(lambda: not session.busy)
            frame = viewport.prepare_draw(engine, context, bpy.context.evaluated_depsgraph_get())
            assert frame.samples_done == 3 and engine.stats[-1] == "Sample 3/3"
            redraws = engine.redraws
            viewport.prepare_draw(engine, context, bpy.context.evaluated_depsgraph_get())
            assert engine.redraws == redraws  # converged: no more redraws requested
    finally:
        viewport.free()
    assert not session.alive


def test_view_draw_follows_the_view():
    scene, quad, mat, world = box_scene()
    engine, context = engine_and_context()
    viewport = ViewportRender(1, display_interval_s=0.0)
    try:
        depsgraph = bpy.context.evaluated_depsgraph_get()
        viewport.view_update(engine, context, depsgraph)
        generation = viewport.session.generation
        viewport.prepare_draw(engine, context, depsgraph)
        assert viewport.session.generation == generation  # nothing moved
        context.space_data.lens = 30.0                   # zoom the view: only view_draw sees it
        viewport.prepare_draw(engine, context, depsgraph)
        assert viewport.session.generation > generation
        generation = viewport.session.generation
        engine.get_preview_pixel_size = lambda scene: 8  # region or pixel size change: a new film size
        viewport.prepare_draw(engine, context, depsgraph)
        assert viewport.session.generation > generation
        assert current_frame(viewport.session).image.shape == (119, 197, 4)
    finally:
        viewport.free()


def test_a_scene_without_camera_renders_in_the_viewport():
    scene, quad, mat, world = box_scene()
    bpy.data.objects.remove(scene.camera)
    engine, context = engine_and_context()
    viewport = ViewportRender(1, display_interval_s=0.0)
    try:
        viewport.view_update(engine, context, bpy.context.evaluated_depsgraph_get())
        frame = current_frame(viewport.session)
        assert viewport.session.error is None and np.isfinite(frame.image).all()
    finally:
        viewport.free()


def test_viewport_settings_follow_scene_ember():
    scene = new_scene()
    scene.ember.preview_samples = 0
    scene.ember.max_bounces = 3
    scene.ember.seed = 9
    settings = vp.viewport_settings(scene)
    assert (settings.samples, settings.max_bounces, settings.seed) == (UNLIMITED_SAMPLES, 3, 9)
    assert settings.mode == scene.ember.sampling_mode and settings.time_limit_s == 0.0
    scene.ember.preview_samples = 16
    assert vp.viewport_settings(scene).samples == 16
    # Cycles' interactive pattern (Blue-Noise First) in the viewport; F12 keeps the final renders' one.
    scene.ember.sampling_pattern = "SOBOL_BURLEY"
    assert vp.viewport_settings(scene).sampling_pattern == "SOBOL_BURLEY"
    assert vp.viewport_settings(scene).blue_noise_first and not render_settings(scene, None).blue_noise_first
    assert vp.film_size(1574, 954, 2) == (787, 477) and vp.film_size(3, 3, 16) == (1, 1)


def test_engine_uses_its_own_viewport_not_eevee():
    assert not getattr(EmberRenderEngine, "bl_use_eevee_viewport", False)
    for name in ("view_update", "view_draw", "__del__"):
        assert name in EmberRenderEngine.__dict__


def test_a_view_change_reuses_the_built_scene(sessions, monkeypatch):
    """Orbiting must not rebuild Embree's BVH: only a new export builds a new Renderer."""
    builds = []

    class CountingRenderer(viewport_session.Renderer):
        def __init__(self, *args, **kwargs):
            builds.append(1)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(viewport_session, "Renderer", CountingRenderer)
    session = sessions()
    session.update_view(view())
    session.update_scene(world_scene(), COSINE)
    current_frame(session)
    for k in range(1, 4):
        session.update_view(view(eye=(0.1 * k, -5, 0)))
        current_frame(session)
    assert len(builds) == 1
    session.update_scene(world_scene((0, 1, 0)), COSINE)
    current_frame(session)
    assert len(builds) == 2


def test_view_draw_follows_the_drawing_recipe(monkeypatch):
    """The GPU calls themselves, against a recording stand-in for the gpu module (the real one
    refuses to run headless): blend, display-space shader, one texture per new frame, bottom row first."""
    calls, uploaded = [], []

    class Buffer:
        def __init__(self, fmt, size, data):
            assert fmt == "FLOAT" and size == data.size and data.dtype == np.float32 and data.flags.c_contiguous
            self.data = data

    class GPUTexture:
        def __init__(self, size, format, data):
            calls.append(("texture", size, format))
            uploaded.append(data.data)

    gpu = SimpleNamespace(types=SimpleNamespace(Buffer=Buffer, GPUTexture=GPUTexture),
                          state=SimpleNamespace(blend_set=lambda mode: calls.append(("blend", mode))))
    presets = SimpleNamespace(draw_texture_2d=lambda tex, pos, w, h: calls.append(("draw", pos, w, h)))
    monkeypatch.setitem(sys.modules, "gpu", gpu)
    monkeypatch.setitem(sys.modules, "gpu_extras.presets", presets)
    engine = SimpleNamespace(bind_display_space_shader=lambda scene: calls.append(("bind", scene)),
                             unbind_display_space_shader=lambda: calls.append(("unbind",)))
    display = Display()
    image = np.zeros((2, 3, 4), np.float32)
    image[0] = 1.0  # the top row
    frame = Frame(image, 1, 4, 1)
    display.draw(engine, "scene", frame, 300, 200)
    assert calls == [("texture", (3, 2), "RGBA16F"), ("blend", "ALPHA_PREMULT"), ("bind", "scene"),
                     ("draw", (0, 0), 300, 200), ("unbind",), ("blend", "NONE")]
    np.testing.assert_array_equal(uploaded[-1][-12:], 1.0)  # the top row goes last
    calls.clear()
    display.draw(engine, "scene", frame, 300, 200)
    assert not [c for c in calls if c[0] == "texture"]  # the same frame is not uploaded again
    display.free()


def test_viewport_previews_are_denoised_when_asked(sessions):
    """Render > Denoise > Viewport: the finished preview is the denoised film. Inside the Cornell box at 4
    samples, its squared error against 256-sample references (less their own variance, estimated from two
    seeds) is at most half the noisy preview's (measured 0.31 at this tiny 64x48 size, where the denoiser
    has little context); the same render without it keeps its noise."""
    from ember.kernels.shapes import cornell_box
    aux = ("denoising_albedo", "denoising_normal")
    frames = {}
    runs = (("noisy", 4, 0, None), ("clean", 4, 0, ("HIGH", "ACCURATE")), ("ref1", 256, 1, None), ("ref2", 256, 2, None))
    for name, samples, seed, denoise in runs:
        session = sessions(threads=2)
        session.update_view(view(eye=(0, -1.9, 1.0), target=(0, 0, 1.0), width=64, height=48, lens=24.0))
        settings = RenderSettings(samples=samples, max_bounces=2, seed=seed, passes=aux if denoise else ())
        session.update_scene(cornell_box(64, 48), settings, denoise)
        wait_until(lambda: not session.busy, timeout=120)
        frames[name] = np.clip(session.snapshot().image[..., :3], 0, 1)  # the light's 15 would dominate
    reference = (frames["ref1"] + frames["ref2"]) / 2
    reference_variance = ((frames["ref1"] - frames["ref2"]) ** 2).mean() / 4
    error = {name: ((frames[name] - reference) ** 2).mean() - reference_variance for name in ("noisy", "clean")}
    assert error["clean"] < 0.5 * error["noisy"], error
