"""A big plain mesh gets Embree's quick (low-quality) BVH first and the medium one once the render has more
than its first pass to go (kernels.accel.QUICK_BVH_TRIANGLES, Accel.refine): the first sample comes sooner,
the rest traces at full speed, and the hits, so the image, are the same bit for bit on either tree."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from ember.kernels import Camera, Renderer, RenderSettings, SceneArrays, World, accel, embree
from ember.kernels.accel import Accel
from ember.kernels.shapes import look_at, uv_sphere


def _indexed_sphere(n: int = 24):
    """A smooth sphere's corners and the same triangles indexed by shared vertices."""
    corners, normals = uv_sphere(n, smooth=True)
    vertices, inverse = np.unique(corners.reshape(-1, 3), axis=0, return_inverse=True)
    return corners, normals, vertices.astype(np.float32), inverse.reshape(-1, 3).astype(np.uint32)


def _rays(count: int = 4000, seed: int = 0):
    rng = np.random.default_rng(seed)
    origins = rng.normal(size=(count, 3)) * 3.0
    directions = -origins / np.linalg.norm(origins, axis=1, keepdims=True) + 0.1 * rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return origins.astype(np.float32), directions.astype(np.float32), np.full(count, np.inf, np.float32)


def test_the_quick_bvh_is_refined_to_the_same_hits(monkeypatch):
    corners, _, vertices, indices = _indexed_sphere()
    monkeypatch.setattr(accel, "QUICK_BVH_TRIANGLES", len(indices))
    o, d, t_max = _rays()
    with Accel(corners, threads=2, indexed=(vertices, indices)) as a:
        assert a.quality == "low"
        quick = a.intersect(o, d, t_max)
        shadowed_quick = a.occluded(o, d, np.full(len(o), 2.0, np.float32))
        monkeypatch.setattr(accel, "REFINE_SECONDS_PER_TRIANGLE", 1e-3)
        assert not a.refine(0.99e-3 * len(indices))   # not worth it for a render about to end
        assert a.refine(1.01e-3 * len(indices))
        assert not a.refine()            # once
        a.wait_refined()
        assert a.quality == "medium"
        refined = a.intersect(o, d, t_max)
        shadowed = a.occluded(o, d, np.full(len(o), 2.0, np.float32))
    assert (quick.prim >= 0).mean() > 0.5   # the rays do hit the sphere
    for name in ("prim", "t", "u", "v"):
        np.testing.assert_array_equal(getattr(quick, name), getattr(refined, name))
    np.testing.assert_array_equal(shadowed_quick, shadowed)
    # Below the bound a mesh gets the medium BVH at once, and nothing to refine.
    monkeypatch.setattr(accel, "QUICK_BVH_TRIANGLES", len(indices) + 1)
    with Accel(corners, threads=2, indexed=(vertices, indices)) as a:
        assert a.quality == "medium" and not a.refine()


def test_a_cancelled_build_raises_and_closing_stops_the_refine(monkeypatch):
    corners, _, vertices, indices = _indexed_sphere(64)
    stop = threading.Event()
    stop.set()
    with pytest.raises(embree.BuildCancelled):
        embree.Scene(embree.Device(), embree.Triangles(vertices, indices), cancel=stop)
    monkeypatch.setattr(accel, "QUICK_BVH_TRIANGLES", 1)
    a = Accel(corners, threads=2, indexed=(vertices, indices))
    assert a.refine()
    a.close()                            # cancels the build if it is still running, and waits for it
    assert a.refine_started and not a.refining
    assert a.quality in ("low", "medium")
    assert not a.refine()                # a closed Accel starts nothing


def test_a_failed_refine_keeps_the_quick_bvh(monkeypatch):
    corners, _, vertices, indices = _indexed_sphere()
    monkeypatch.setattr(accel, "QUICK_BVH_TRIANGLES", 1)
    o, d, t_max = _rays()
    with Accel(corners, threads=2, indexed=(vertices, indices)) as a:
        quick = a.intersect(o, d, t_max)
        real = embree.Scene

        def refused(*args, **kwargs):
            if kwargs.get("quality") == "medium":
                raise embree.EmbreeError("Embree refused the scene (error 4)")
            return real(*args, **kwargs)

        monkeypatch.setattr(embree, "Scene", refused)
        assert a.refine()
        a.wait_refined()
        assert a.quality == "low" and "error 4" in a.refine_error
        np.testing.assert_array_equal(a.intersect(o, d, t_max).prim, quick.prim)


def _scene():
    corners, normals, vertices, indices = _indexed_sphere()
    return SceneArrays(positions=corners, normals=normals, uvs=np.zeros((len(corners), 3, 2), np.float32),
                       material_ids=np.zeros(len(corners), np.int32),
                       world=World(color=np.float32([0.5, 0.6, 0.7])),
                       camera=Camera(world_from_camera=look_at((0, -4, 1), (0, 0, 0)), width=24, height=24),
                       bvh_vertices=vertices, bvh_indices=indices)


def test_a_render_moves_to_the_medium_bvh_after_its_first_pass_with_the_same_image(monkeypatch):
    """A render with time enough to go (by the rate of its waves so far) refines: the test's scenes are
    tiny, so REFINE_SECONDS_PER_TRIANGLE is set to 0 here and to a day per triangle at the end."""
    monkeypatch.setattr(accel, "REFINE_SECONDS_PER_TRIANGLE", 0.0)
    settings = RenderSettings(samples=8, seed=3)
    with Renderer(_scene(), threads=2) as renderer:     # medium from the start
        assert renderer.accel.quality == "medium"
        want = renderer.render(settings).image
    monkeypatch.setattr(accel, "QUICK_BVH_TRIANGLES", 1)
    with Renderer(_scene(), threads=2) as renderer:
        assert renderer.accel.quality == "low"
        # One sample is one quick pass: nothing more to come, no refine.
        renderer.render(RenderSettings(samples=1, seed=3))
        assert not renderer.accel.refine_started
        got = renderer.render(settings).image
        assert renderer.accel.refine_started      # started with the second pass
        renderer.accel.wait_refined()
        assert renderer.accel.quality == "medium"
        again = renderer.render(settings).image
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(again, want)
    # A render without the quick first pass (the command line's) refines from its first pass on when more
    # passes follow.
    with Renderer(_scene(), threads=2) as renderer:
        renderer.render(RenderSettings(samples=8, seed=3, quick_first_pass=False, wave_size=24 * 24))
        assert renderer.accel.refine_started      # a first pass of 4 samples, then another
    with Renderer(_scene(), threads=2) as renderer:
        renderer.render(RenderSettings(samples=4, seed=3, quick_first_pass=False, wave_size=24 * 24))
        assert not renderer.accel.refine_started          # one pass in all
    monkeypatch.setattr(accel, "REFINE_SECONDS_PER_TRIANGLE", 86400.0)
    with Renderer(_scene(), threads=2) as renderer:
        renderer.render(settings)
        assert not renderer.accel.refine_started          # the render ends long before a refine would pay
        assert renderer.accel.quality == "low"
