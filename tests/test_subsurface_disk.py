"""Christensen-Burley subsurface scattering (kernels/subsurface_disk.py): the Burley profile's sampler against its
pdf, the disk estimator's energy on a plane (exactly 1 per channel in expectation), probes that see only the
object entered, and the closure's fall back to diffuse after a diffuse bounce. Through Blender: tests/test_subsurface.py."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ember.kernels import paths
from ember.kernels import subsurface_disk as disk
from ember.kernels.accel import Hits
from ember.kernels.bsdf import bssrdf, lobes
from ember.kernels.bsdf.closures import ClosureBuilder
from ember.kernels.geometry import NG
from ember.kernels.local_hits import LocalRays
from ember.kernels.paths import PathState

from stats import assert_chi2, trapezoid


def _cdf(x):
    """The Burley profile's CDF at r = x d (bssrdf.h's root_find solves it), truncated at 16 d and normalised."""
    x = np.minimum(x, float(disk.TRUNCATE))
    return (1.0 - 0.25 * np.exp(-x) - 0.75 * np.exp(-x / 3.0)) / float(disk.TRUNCATE_CDF)


def test_root_find_inverts_the_profile_cdf():
    xi = np.linspace(0.0, 0.999, 2001, dtype=np.float32)
    x = disk.root_find(xi * disk.TRUNCATE_CDF)
    assert np.all(x >= 0) and np.all(x <= 16.0 + 1e-3)
    assert np.allclose(_cdf(x.astype(np.float64)), xi, atol=2e-5)


@pytest.mark.parametrize("radius", [(0.3, 0.3, 0.3), (1.0, 0.25, 0.0)])
def test_profile_sampler_matches_its_pdf(radius):
    """Chi-square of sample_radius's r (the channel drawn among those with a radius, then the profile) against
    radius_pdf, integrated over bins in closed form; and radius_pdf integrates to 1."""
    n = 200000
    rng = np.random.default_rng(5)
    radii = np.repeat(np.asarray(radius, np.float32)[:, None], n, axis=1)
    r, h = disk.sample_radius(radii, rng.random(n, dtype=np.float32))
    rm = 16.0 * max(radius)
    assert np.all(r >= 0) and np.all(r < rm * (1 + 1e-5))
    # h is the probe's half-length on the truncation sphere of the channel drawn.
    d = np.array(radius)[np.argmin(np.abs((r[None] ** 2 + h[None] ** 2) - (16.0 * np.array(radius)[:, None]) ** 2),
                                   axis=0)]
    assert np.allclose(r ** 2 + h ** 2, (16.0 * d) ** 2, rtol=1e-4)
    edges = np.linspace(0.0, rm, 81)
    kept = [c for c in radius if c > 0]
    cdf = sum(_cdf(edges / c) for c in kept) / len(kept)
    expected = n * np.diff(cdf)
    observed = np.histogram(r, edges)[0]
    assert_chi2(observed, expected)
    fine = np.linspace(0.0, rm, 200001, dtype=np.float32)
    pdf = disk.radius_pdf(np.repeat(np.asarray(radius, np.float32)[:, None], len(fine), axis=1), fine)
    assert abs(trapezoid(pdf, fine) - 1.0) < 2e-3


class _Planes:
    """An accel stand-in: horizontal planes z = heights[k], object k, prim k (one triangle each)."""

    def __init__(self, heights):
        self.heights = np.asarray(heights, np.float64)

    def intersect(self, origins, dirs, t_max, split=True, time=None):
        oz, dz = origins[:, 2].astype(np.float64)[:, None], dirs[:, 2].astype(np.float64)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.heights[None] - oz) / dz
        t = np.where((t >= 0) & (t <= np.asarray(t_max, np.float64)[:, None]), t, np.inf)
        prim = np.argmin(t, axis=1).astype(np.int32)
        best = t[np.arange(len(t)), prim]
        prim[~np.isfinite(best)] = -1
        z = np.zeros(len(t), np.float32)
        return Hits(prim, np.where(np.isfinite(best), best, np.inf).astype(np.float32), z, z.copy())


class _PlaneTriangles:
    """The triangle table of _Planes: every prim's true normal is +z, its object row its index."""

    def rows_of(self, prim):
        rows = np.zeros((len(prim), 27), np.float32)
        rows[:, NG + 2] = 1.0
        return rows

    def object_rows(self, prim):
        return np.asarray(prim, np.int32)


def _probe(n, radius, heights, seed=3):
    rng = np.random.default_rng(seed)
    keys = (rng.integers(0, 2 ** 32, n, dtype=np.uint32), rng.integers(0, 2 ** 32, n, dtype=np.uint32))
    p = np.zeros((n, 3), np.float32)
    ng = np.zeros((n, 3), np.float32)
    ng[:, 2] = 1.0
    rays = LocalRays(_Planes(heights), _PlaneTriangles(), 1e-6)
    return disk.disk(rays, p, ng, np.zeros(n, bool), np.zeros(n, np.int32),
                     np.repeat(np.asarray(radius, np.float32)[:, None], n, axis=1), np.ones((3, n), np.float32),
                     rng.random((2, n), dtype=np.float32), keys)


def test_disk_estimator_conserves_energy_on_a_plane():
    """On a plane the probes along the normal (half of them) always find the surface at the disk point and those
    along the tangents never do: the weight, profile over the channels' mixture pdf x the axis MIS (2), averages
    exactly 1 per channel (the truncated profile is normalised). Exits are seen along the plane's normal."""
    n = 60000
    radius = (0.2, 0.08, 0.02)
    rows, prim, u, v, t, direction, thr = _probe(n, radius, [0.0])
    assert 0.45 * n < len(rows) < 0.55 * n
    assert np.all(prim == 0) and np.allclose(direction, [[0], [0], [1]])
    mean = thr.sum(axis=1) / n
    se = np.sqrt(((np.concatenate([thr, np.zeros((3, n - len(rows)), np.float32)], axis=1) - mean[:, None]) ** 2)
                 .mean(axis=1) / n)
    assert np.all(np.abs(mean - 1.0) < 4 * se + 1e-3), (mean, se)


def test_probes_see_only_the_object_entered():
    """A plane of another object just below the entry (object 1 at z = -0.001) is passed: every exit is on
    object 0, and the energy is what the plane alone gives."""
    n = 20000
    alone = _probe(n, (0.1, 0.1, 0.1), [0.0])
    both = _probe(n, (0.1, 0.1, 0.1), [0.0, -0.001])
    assert np.all(both[1] == 0)
    assert np.array_equal(alone[0], both[0]) and np.allclose(alone[6], both[6])


def test_burley_is_diffuse_after_a_diffuse_bounce():
    """bssrdf_setup with PATH_RAY_DIFFUSE_ANCESTOR: a Burley closure becomes a Lambert closure of its whole weight
    where the path had a diffuse bounce; a Random Walk closure stays one."""
    n = 4
    weight = np.full((3, n), 0.5, np.float32)
    radius = np.full((3, n), 0.1, np.float32)
    ancestor = np.array([True, False, True, False])
    ns = tuple(np.full(n, c, np.float32) for c in (0.0, 0.0, 1.0))
    for method, lambert_hits in ((bssrdf.BURLEY, [0, 2]), (bssrdf.RANDOM_WALK, [])):
        b = ClosureBuilder(n, ns, ns)
        bssrdf.add_bssrdf(b, np.arange(n), weight, weight, radius, 1.4, 1.0, 0.0, method, ancestor=ancestor)
        made = b.finish()
        lambert = made.lobe == lobes.LAMBERT
        assert list(made.hit[lambert]) == lambert_hits and np.allclose(made.weight[:, lambert], 0.5)
        assert list(made.hit[made.lobe == lobes.BSSRDF]) == [h for h in range(n) if h not in lambert_hits]


def test_burley_radius_is_scaled_by_one_over_four_pi():
    """bssrdf_setup_radius: Burley's d is Radius x Scale / (4 pi) in every Cycles 5.x (bssrdf_burley_setup,
    with its albedo fit, is defined but not called)."""
    r = bssrdf.setup_radius(np.full((3, 1), 1.0), np.full((3, 1), 0.8), np.array([1.4]), np.array([bssrdf.BURLEY]))
    assert np.allclose(r, 0.25 / math.pi)


def test_diffuse_ancestor_is_kept_past_later_bounces():
    """PathState.track_lobes: a diffuse bounce sets DIFFUSE_ANCESTOR in the label row and later glossy bounces
    keep it (path_state_next sets PATH_RAY_DIFFUSE_ANCESTOR and never clears it); the Light Path bits stay."""
    n = 2
    state = PathState.start(n, None)
    state.lobes = np.zeros((4, n), np.int32)
    ns = tuple(np.full(n, c, np.float32) for c in (0.0, 0.0, 1.0))

    def bounce(lobe):
        b = ClosureBuilder(n, ns, ns)
        b.add(lobe, np.arange(n), np.ones((3, n), np.float32))
        cs = b.finish()
        bs = cs.sample(None, np.full(n, 0.3, np.float32), np.full(n, 0.6, np.float32), np.zeros(n, np.float32))
        state.track_lobes(bs, cs, np.zeros(n, bool))
    bounce(lobes.REFLECTION)
    assert not (state.lobes[0] & paths.DIFFUSE_ANCESTOR).any()
    bounce(lobes.LAMBERT)
    assert (state.lobes[0] & paths.DIFFUSE_ANCESTOR).all() and (state.lobes[0] & paths.DIFFUSE).all()
    bounce(lobes.REFLECTION)
    assert (state.lobes[0] & paths.DIFFUSE_ANCESTOR).all() and not (state.lobes[0] & paths.DIFFUSE).any()
