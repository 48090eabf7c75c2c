"""Light portals (an area lamp's Portal, Cycles' own setting): they emit nothing and are not seen, and guide the
world's light samples through windows as Cycles' background light samples through them (kernel/light/background.h;
kernels/lights/portals.py)."""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from bpy_helpers import (add_camera, compare_to_cycles, diffuse_material, export_current, manual_world_map, new_scene,
                         quad_object, render_to_array, set_world)

F32 = np.float32


# ---------------------------------------------------------------- the portal method in the kernel
def _portals():
    """A 1 x 0.5 m window at y = 2 facing -y (into a room), a disk of diameter 0.6 at x = 2 facing -x, and a
    square at z = -1 facing down (no point above it is on its inner side)."""
    from ember.kernels.lights.portals import Portals
    rows = [[0, 2, 1.2, 1, 0, 0, 0, 0, 0.5, 0, -1, 0, 0],
            [2, 0, 1.0, 0, 0.6, 0, 0, 0, 0.6, -1, 0, 0, 1],
            [0, 0, -1, 1, 0, 0, 0, 1, 0, 0, 0, -1, 0]]
    return Portals(np.array(rows, F32))


def _rect_solid_angle(a: float, b: float, d: float) -> float:
    """A rectangle of half sides a, b seen from distance d on its axis."""
    return 4.0 * math.asin(a * b / math.sqrt((a * a + d * d) * (b * b + d * d)))


def _disk_solid_angle(r: float, d: float) -> float:
    return 2.0 * math.pi * (1.0 - d / math.sqrt(d * d + r * r))


@pytest.mark.parametrize("point,through,expected", [
    ((0.0, 0.5, 1.2), 0, _rect_solid_angle(0.5, 0.25, 1.5)),
    ((0.8, 0.0, 1.0), 1, _disk_solid_angle(0.3, 1.2))], ids=["window", "disk"])
def test_portal_samples_follow_their_pdf(point, through, expected):
    """From a point on a portal's axis, with another portal also in reach, the samples' 1 / pdf over those that
    pass through the first portal estimates its solid angle (closed form): the sampling and its pdf agree, every
    portal the direction passes through counted. The pdf each sample carries is the one pdf() gives its direction,
    which MIS weighs BSDF rays with; the downward square is never possible from above it."""
    portals = _portals()
    n = 200_000
    rng = np.random.default_rng(7)
    p = [np.full(n, c, F32) for c in point]
    possible = portals.possible(*p)
    assert possible[:2].all() and not possible[2].any()
    u1, u2 = rng.random(n, dtype=F32), rng.random(n, dtype=F32)
    wx, wy, wz, pdf = portals.sample(*p, u1, u2, possible)
    again = portals.pdf(*p, wx, wy, wz, possible)
    assert np.allclose(pdf, again, rtol=2e-3), np.abs(pdf / again - 1).max()
    hits = np.flatnonzero(portals._pdf_through(through, *p, wx, wy, wz) > 0)
    weights = np.zeros(n)
    weights[hits] = 1.0 / pdf[hits].astype(np.float64)
    estimate, se = weights.mean(), weights.std(ddof=1) / math.sqrt(n)
    assert abs(estimate - expected) < 4.0 * se + 1e-4 * expected, (estimate, expected, se)


def test_portals_are_possible_on_their_inner_side_only():
    """A point outside the window (beyond y = 2) has no portal of it to sample, nor below the floor square."""
    portals = _portals()
    inside = portals.possible(*(np.array([v], F32) for v in (0.0, 1.0, 1.0)))[:, 0]
    outside = portals.possible(*(np.array([v], F32) for v in (0.0, 3.0, 1.0)))[:, 0]
    below = portals.possible(*(np.array([v], F32) for v in (0.0, 0.0, -2.0)))[:, 0]
    assert inside.tolist() == [True, True, False]
    assert outside.tolist() == [False, True, False]
    assert below.tolist() == [True, True, True]


# ---------------------------------------------------------------- through Blender
def room(shape: str = "SQUARE", hdri: str | None = None):
    """A closed 4 x 4 x 2.5 m room whose one window (1 x 1 m) opens on the world, a portal in the window."""
    scene = new_scene(32, 32)
    add_camera(scene, (0, -1.8, 1.0), (0, 1, 0.9), lens=18)
    if hdri is None:
        set_world(scene, color=(2.0, 2.0, 2.0))
    else:
        set_world(scene, hdri=hdri)
    # At 1024 (the HDRIs' width) Cycles' noise is its Automatic map's; a constant world needs none.
    manual_world_map(scene.world, 1024)
    wall = diffuse_material("Wall", (0.7, 0.7, 0.7))
    for name, corner, u, v in (("Floor", (-2, -2, 0), (4, 0, 0), (0, 4, 0)),
                               ("Ceiling", (-2, -2, 2.5), (0, 4, 0), (4, 0, 0)),
                               ("Back", (-2, -2, 0), (0, 0, 2.5), (4, 0, 0)),
                               ("Left", (-2, -2, 0), (0, 4, 0), (0, 0, 2.5)),
                               ("Right", (2, -2, 0), (0, 0, 2.5), (0, 4, 0)),
                               # the front wall around the window
                               ("Below", (-2, 2, 0), (4, 0, 0), (0, 0, 0.7)),
                               ("Above", (-2, 2, 1.7), (4, 0, 0), (0, 0, 0.8)),
                               ("WestSide", (-2, 2, 0.7), (1.5, 0, 0), (0, 0, 1.0)),
                               ("EastSide", (0.5, 2, 0.7), (1.5, 0, 0), (0, 0, 1.0))):
        quad_object(name, corner, u, v, wall)
    data = bpy.data.lights.new("Portal", "AREA")
    data.energy, data.shape, data.size = 500.0, shape, 1.0
    data.cycles.is_portal = True
    portal = bpy.data.objects.new("Portal", data)
    portal.location, portal.rotation_euler = (0, 1.99, 1.2), (math.radians(-90), 0, 0)
    scene.collection.objects.link(portal)
    return scene, portal


@pytest.mark.parametrize("shape,hdri", [("SQUARE", None), ("DISK", "forest.exr")], ids=["square", "disk_hdri"])
def test_a_room_lit_through_its_portal_matches_cycles(shape, hdri):
    """A portal emits nothing and is not seen, in Cycles and in Ember (before Ember had portals it rendered this one
    as a 500 W lamp, the room 49x too bright); the room lit through it matches Cycles', and nothing is named."""
    scene, _ = room(shape, hdri)
    assert not any("Portal" in w for w in export_current().warnings)
    compare_to_cycles(scene, samples=64, max_bounces=3, mean_z=4.0)


def _pixel_variance(scene, engine: str, seeds=range(6), samples: int = 16) -> float:
    images = np.stack([render_to_array(scene, engine, samples, seed=s, max_bounces=3)[..., :3] for s in seeds])
    return float(images.astype(np.float64).var(axis=0, ddof=1).mean())


def test_a_portal_takes_the_noise_out_of_a_room_as_in_cycles():
    """The room under a constant world: without its portal every world light sample of a wall point heads for a
    random direction, of which 1% leave through the window; with it half go through the window. Per pixel the
    variance falls to about 7% (Cycles' 6%: 2.0e-4 against 3.3e-3), as much as Cycles'. The mean over the 1024
    pixels of six seeds' variances is known to a few percent, far inside the bounds: a third of the variance
    without the portal, and no more than 1.5x Cycles' with it. Fails before: Ember sampled the world without the
    portal (the variance then the same with and without)."""
    scene, portal = room()
    with_portal = _pixel_variance(scene, "EMBER")
    cycles = _pixel_variance(scene, "CYCLES")
    portal.hide_render = True
    without = _pixel_variance(scene, "EMBER")
    print(f"per-pixel variance, room under a constant sky: Ember {without:.2e} without the portal, {with_portal:.2e} "
          f"with it; Cycles {cycles:.2e} with it")
    assert with_portal < without / 3, (with_portal, without)
    assert with_portal < 1.5 * cycles, (with_portal, cycles)


def test_portals_alone_guide_a_world_of_sampling_method_none_as_in_cycles(monkeypatch):
    """World > Sampling Method None with a portal: Cycles samples the world through the portal alone where a point
    has one, a uniform direction elsewhere (background_light_sample without the map's method). The room under an
    HDRI matches Cycles, as noisy as Cycles' (within 1.5x, per pixel over the comparison's own replicates: four
    of 16 spp per engine)."""
    import bpy_helpers
    scene, _ = room("SQUARE", "forest.exr")
    scene.world.cycles.sampling_method = "NONE"
    replicates, replicate = {}, bpy_helpers.replicate_render

    def kept(scene, engine, *args, **kwargs):
        replicates[engine] = replicate(scene, engine, *args, **kwargs)
        return replicates[engine]
    monkeypatch.setattr(bpy_helpers, "replicate_render", kept)
    compare_to_cycles(scene, samples=64, max_bounces=3, mean_z=4.0)
    # Each engine's variance of its mean over the same four seeds: their ratio is the renders' own.
    variance = {engine: var.mean() for engine, (_, var) in replicates.items()}
    assert variance["EMBER"] < 1.5 * variance["CYCLES"], variance
