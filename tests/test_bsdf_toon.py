"""Cycles' Toon BSDF (kernels/bsdf/toon.py): both samplers against their pdfs (chi-square), eval against
sample, the intensity ramp and the cone at hand-computed angles, Size 0, and no NaN or warning on edge
cases."""
import math
import warnings

import numpy as np
import pytest

from ember.kernels.bsdf import toon
from ember.kernels.scene import Closure, Materials, Param, Shader
from ember.kernels.shading import Shading
from stats import mean_and_stderr
from test_bsdf_diffuse import assert_eval_matches_sample, assert_sampler_matches_pdf, edge_directions, uniforms, \
    viewer
from test_closures import FakeHit

N = 200_000
F32 = np.float32


def angles(size, smooth, n=1):
    s, m = toon.toon_angles(np.full(n, size, F32), np.full(n, smooth, F32))
    return s, m


@pytest.mark.parametrize("size,smooth", [(0.5, 0.0), (0.3, 0.4), (0.9, 0.6)])
def test_diffuse_sampler_matches_pdf_and_eval(size, smooth):
    s, m = angles(size, smooth, N)
    wo = viewer(0.7, N)
    wi, weight, pdf = toon.diffuse_toon_sample(wo, s, m, *uniforms(N, seed=31))
    cone = min((size + smooth) * math.pi / 2, math.pi / 2)
    # The histogram spans the cone exactly: its bins are equal solid angles of the uniform cone.
    assert_sampler_matches_pdf(wi, lambda d: toon.diffuse_toon_eval(viewer(0.7, len(d[0])), d,
                                                                    *angles(size, smooth, len(d[0])))[1],
                               z_lo=math.cos(cone), sub=16)
    assert_eval_matches_sample(wi, weight, pdf, *toon.diffuse_toon_eval(wo, wi, s, m))


@pytest.mark.parametrize("mu,size,smooth", [(0.8, 0.3, 0.0), (0.5, 0.2, 0.3), (0.3, 0.6, 0.2)])
def test_glossy_sampler_matches_pdf_and_eval(mu, size, smooth):
    s, m = angles(size, smooth, N)
    wo = viewer(mu, N, phi=0.9)
    wi, weight, pdf = toon.glossy_toon_sample(wo, s, m, *uniforms(N, seed=32))
    assert np.all(wi[2][pdf > 0] > 0)
    assert_sampler_matches_pdf(wi, lambda d: toon.glossy_toon_eval(viewer(mu, len(d[0]), 0.9), d,
                                                                   *angles(size, smooth, len(d[0])))[1], sub=24)
    ok = pdf > 0
    f_cos, pdf_eval = toon.glossy_toon_eval(wo, wi, s, m)
    np.testing.assert_allclose(pdf_eval[ok], pdf[ok], rtol=2e-6)
    # The intensity of the ramp: the sampler's angle and the eval's (acos of a rotated float32 direction)
    # differ by float32 rounding, about 1e-6 rad on the ramp.
    np.testing.assert_allclose(f_cos[ok] / pdf[ok], weight[ok], atol=1e-5)


def test_values_at_hand_computed_angles():
    """Size 0.5 and Smooth 0.2: full intensity within pi/4 of the axis, a ramp to 0 over the next pi/10,
    pdf 1 / (2 pi (1 - cos 0.35 pi)) inside the cone; the glossy cone is about the mirror direction."""
    size, smooth = angles(0.5, 0.2, 4)
    pdf_in = 1.0 / (2 * math.pi * (1 - math.cos(0.35 * math.pi)))
    theta = np.array([0.1, math.pi / 4 + math.pi / 20, math.pi / 4 + 0.09 * math.pi, 0.36 * math.pi])
    intensity = np.array([1.0, 0.5, 0.1, 0.0])
    wi = (np.sin(theta).astype(F32), np.zeros(4, F32), np.cos(theta).astype(F32))
    f_cos, pdf = toon.diffuse_toon_eval(viewer(0.5, 4), wi, size, smooth)
    np.testing.assert_allclose(pdf, [pdf_in] * 3 + [0.0], rtol=1e-5)
    np.testing.assert_allclose(f_cos, pdf_in * intensity, rtol=1e-4, atol=1e-6)
    # Glossy: the same angles from the mirror direction of a viewer 30 degrees off the normal, in its plane.
    t0 = math.radians(30)
    wo = (np.full(4, -math.sin(t0), F32), np.zeros(4, F32), np.full(4, math.cos(t0), F32))
    wg = (np.sin(t0 - theta).astype(F32), np.zeros(4, F32), np.cos(t0 - theta).astype(F32))
    f_g, pdf_g = toon.glossy_toon_eval(wo, wg, size, smooth)
    np.testing.assert_allclose(pdf_g, [pdf_in] * 3 + [0.0], rtol=1e-5)
    np.testing.assert_allclose(f_g, pdf_in * intensity, rtol=1e-4, atol=1e-6)
    # Below the surface: nothing, whatever the cone.
    assert not np.any(toon.glossy_toon_eval(wo, (wg[0], wg[1], -np.abs(wg[2])), size, smooth)[0])
    assert not np.any(toon.diffuse_toon_eval(wo, (wi[0], wi[1], -wi[2] - 0.01), size, smooth)[0])


def test_size_zero_is_a_narrow_cone_with_weight_one():
    """Size 0 (clamped to 1e-5): a cone of 1.6e-5 rad whose samples have weight 1 and a finite pdf, as in
    Cycles (1 - cos is a Taylor expansion there, not a float32 cancellation)."""
    s, m = angles(0.0, 0.0, 1000)
    u1, u2 = uniforms(1000, seed=33)
    for sample in (toon.diffuse_toon_sample, toon.glossy_toon_sample):
        wi, weight, pdf = sample(viewer(0.6, 1000), s, m, u1, u2)
        expected = 1.0 / (2 * math.pi * 0.5 * (1e-5 * math.pi / 2) ** 2)
        np.testing.assert_allclose(pdf, expected, rtol=1e-5)
        assert np.all(weight == 1.0)


def test_edge_cases_give_no_nan_and_no_warning():
    wo, wi = edge_directions()
    n = len(wo[0])
    u = np.linspace(0, 1 - 2 ** -24, n).astype(F32)
    with warnings.catch_warnings(), np.errstate(all="warn"):
        warnings.simplefilter("error")
        outs = []
        for size, smooth in ((0.0, 0.0), (1.0, 1.0), (2.0, -1.0), (0.5, np.nan)):
            s, m = angles(size, smooth, n)
            outs += [toon.diffuse_toon_eval(wo, wi, s, m), toon.glossy_toon_eval(wo, wi, s, m),
                     toon.diffuse_toon_sample(wo, s, m, u, u[::-1]), toon.glossy_toon_sample(wo, s, m, u, u[::-1])]
    for out in outs:
        for a in out:
            for c in (a if isinstance(a, tuple) else (a,)):
                assert np.all(np.isfinite(c)) and c.dtype == np.float32


def toon_closure(component, color, size, smooth=0.0, factors=()):
    return Closure("TOON", (("Color", Param.of(color)), ("Size", Param.of(size)), ("Smooth", Param.of(smooth))),
                   (("component", component),), factors)


def surface(closures, n, normal=(0.3, -0.5, 0.81), wo=(0.4, 0.2, 0.8)):
    """The closures' ClosureSet at n hits on a plane of that normal, seen from wo (world directions, as the
    integrator hands them: a tilted normal rounds directions on their way to the closures' frames)."""
    hit = FakeHit(n, wo)
    normal = np.asarray(normal, np.float64) / np.linalg.norm(normal)
    hit.ns = hit.ng = tuple(np.full(n, c, F32) for c in normal)
    return Shading(Materials((Shader(tuple(closures)),)), []).surface(hit).closures


@pytest.mark.parametrize("component", ["DIFFUSE", "GLOSSY"])
def test_size_zero_toon_mixed_with_diffuse_keeps_its_sampled_light(component):
    """A Size 0 toon half mixed with a diffuse: evaluated, the toon's cone is too narrow for float32 (0 almost
    everywhere), so its light comes from its own samples alone. The mixture's mean sample weight is the
    sum of the closures' albedos, the toon's weight (intensity 1 in its cone) plus the diffuse's."""
    half = ((Param.of(0.5), False),)
    toon_color, diffuse_color = np.float32([0.9, 0.6, 0.3]), np.float32([0.2, 0.4, 0.8])
    cs = surface([toon_closure(component, tuple(toon_color), 0.0, factors=half),
                  Closure("DIFFUSE", (("Color", Param.of(tuple(diffuse_color))),), (), ((Param.of(0.5), True),))], N)
    rng = np.random.default_rng(34)
    s = cs.sample(*(rng.random(N, dtype=F32) for _ in range(4)))
    mean, se = mean_and_stderr(s.weight, axis=1)
    expected = 0.5 * toon_color + 0.5 * diffuse_color
    assert np.all(np.abs(mean - expected) < 4 * se + 1e-6), (mean, expected, se)


def test_a_glossy_toon_is_diffuse_like_for_the_denoising_features():
    """Cycles counts every closure that is neither microfacet nor singular as rough (roughness^2 = 1): a
    glossy toon's colour is the denoising albedo, read at its own hit."""
    from ember.kernels import passes
    cs = surface([toon_closure("GLOSSY", (0.2, 0.5, 0.7), 0.1)], 3)
    _, diffuse, specular, done = passes.denoising_features(cs, 3, tuple(np.zeros((3, 3), F32)))
    assert done.all() and not specular.any()
    np.testing.assert_allclose(diffuse, np.float32([[0.2], [0.5], [0.7]]).repeat(3, axis=1), rtol=1e-6)
