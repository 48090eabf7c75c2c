"""Helpers for kernel tests: scenes with closed-form answers, and per-sample tracing for statistics."""
from __future__ import annotations

import numpy as np

from ember.kernels import Camera, Materials, Renderer, RenderSettings, SceneArrays, World
from ember.kernels.rng import PathRng, seed_paths
from ember.kernels.shapes import look_at, uv_sphere


def make_scene(positions, normals, material_ids=None, albedo=(0.8, 0.8, 0.8), emission=None,
               world_color=(0.0, 0.0, 0.0), camera=None, **kwargs) -> SceneArrays:
    t = len(positions)
    albedo = np.atleast_2d(np.asarray(albedo, np.float32))
    m = len(albedo)
    emission = np.zeros((m, 3), np.float32) if emission is None else np.atleast_2d(np.asarray(emission, np.float32))
    return SceneArrays(
        positions=positions, normals=normals, uvs=kwargs.pop("uvs", np.zeros((t, 3, 2), np.float32)),
        material_ids=np.zeros(t, np.int32) if material_ids is None else material_ids,
        materials=kwargs.pop("materials", Materials.diffuse(albedo, emission=emission)),
        world=kwargs.pop("world", World(color=np.asarray(world_color, np.float32))),
        camera=camera or Camera(world_from_camera=look_at((0, -5, 0), (0, 0, 0)), width=32, height=32,
                                fov_rad=np.radians(40)),
        **kwargs)


def sphere_in_furnace(albedo: float, world: float, width=32, height=32) -> SceneArrays:
    """A flat-shaded convex sphere of radius 1 at the origin, filling part of the view."""
    positions, normals = uv_sphere(16, smooth=False)
    cam = Camera(world_from_camera=look_at((0, -5, 0), (0, 0, 0)), width=width, height=height,
                 fov_rad=np.radians(30))
    return make_scene(positions, normals, albedo=(albedo,) * 3, world_color=(world,) * 3, camera=cam)


def inside_emitting_sphere(albedo: float, radiance: float, width=8, height=8) -> SceneArrays:
    """The camera inside a closed sphere that emits `radiance` and reflects diffusely with `albedo`."""
    positions, normals = uv_sphere(12, radius=2.0, smooth=False, inward=True)
    cam = Camera(world_from_camera=look_at((0.2, -0.3, 0.1), (1, 1, 0.5)), width=width, height=height,
                 fov_rad=np.radians(90))
    return make_scene(positions, normals, albedo=(albedo,) * 3, emission=(radiance,) * 3, camera=cam)


def trace_samples(scene: SceneArrays, settings: RenderSettings, samples: int, threads: int = 1):
    """Per-sample radiance for every pixel: (samples, 3, H*W) float64, each sample an independent path."""
    with Renderer(scene, threads) as renderer:
        cam = renderer.scene.camera
        pix = np.arange(cam.width * cam.height, dtype=np.uint32)
        row = (pix // cam.width).astype(np.int32)
        col = (pix % cam.width).astype(np.int32)
        out = np.empty((samples, 3, len(pix)))
        # Several samples' paths in one call (each path's numbers come from its own seed, so the radiance is the
        # same as one call per sample), up to BATCH_PATHS at a time.
        step = max(1, BATCH_PATHS // len(pix))
        for first in range(0, samples, step):
            group = np.arange(first, min(first + step, samples), dtype=np.uint32)
            rng = PathRng(*seed_paths(np.tile(pix, len(group)), np.repeat(group, len(pix)), settings.seed))
            radiance, _ = renderer.trace_paths(rng, np.tile(row, len(group)), np.tile(col, len(group)), settings)
            out[first:first + len(group)] = radiance.reshape(3, len(group), len(pix)).transpose(1, 0, 2)
    return out


BATCH_PATHS = 1 << 17


def assert_workers_render_as_threads(scene: SceneArrays, settings: RenderSettings) -> np.ndarray:
    """The image of scene rendered on the render's own thread, and again with a worker process (which builds the
    scene again from its arrays) rendering waves: the two must be equal bit for bit. Returns the image."""
    with Renderer(scene, threads=1) as renderer:
        alone = renderer.render(settings).image
    with Renderer(scene, threads=2, processes=True) as renderer:
        assert renderer.crew.wait_for_workers() == 1, renderer.crew.worker_failures
        image = renderer.render(settings).image
        assert renderer.crew.remote_waves > 0
    np.testing.assert_array_equal(image, alone)
    return image
