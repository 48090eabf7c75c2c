"""Lambert, Oren-Nayar and Translucent (kernels/bsdf/diffuse.py): samplers against their pdfs
(chi-square), eval against sample, reciprocity, energy, and no NaN or warning on edge cases.

Also home of `assert_sampler_matches_pdf`, the direction chi-square shared with test_bsdf_sheen.py."""
import math
import warnings

import numpy as np
import pytest

from ember.kernels import sampling
from ember.kernels.bsdf import diffuse
from stats import assert_chi2, mean_and_stderr

N = 200_000
Z_BINS, PHI_BINS = 16, 32


def uniforms(n=N, seed=0):
    rng = np.random.default_rng(seed)
    return rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32)


def fixed(n, *components):
    """A direction tuple repeating one direction n times (normalised in float64 first)."""
    v = np.asarray(components, np.float64)
    v /= np.linalg.norm(v)
    return tuple(np.full(n, c, np.float32) for c in v)


def viewer(mu, n=N, phi=0.3):
    s = math.sqrt(max(1.0 - mu * mu, 0.0))
    return fixed(n, s * math.cos(phi), s * math.sin(phi), mu)


def assert_sampler_matches_pdf(wi, pdf_of, z_lo=0.0, z_hi=1.0, sub=12):
    """Chi-square of sampled directions in (cos theta, phi) bins (equal solid angle per bin) against
    N * the integral of pdf_of over each bin (midpoint rule on sub x sub points per bin)."""
    x, y, z = (np.asarray(c, np.float64) for c in wi)
    counts, _, _ = np.histogram2d(z, np.arctan2(y, x), bins=[Z_BINS, PHI_BINS],
                                  range=[[z_lo, z_hi], [-np.pi, np.pi]])
    dz, dphi = (z_hi - z_lo) / (Z_BINS * sub), 2 * np.pi / (PHI_BINS * sub)
    zc = z_lo + (np.arange(Z_BINS * sub) + 0.5) * dz
    pc = -np.pi + (np.arange(PHI_BINS * sub) + 0.5) * dphi
    zz, pp = np.meshgrid(zc, pc, indexing="ij")
    s = np.sqrt(1 - zz * zz)
    grid = tuple(c.astype(np.float32).ravel() for c in (s * np.cos(pp), s * np.sin(pp), zz))
    pdf = pdf_of(grid).astype(np.float64).reshape(zz.shape)
    expected = pdf.reshape(Z_BINS, sub, PHI_BINS, sub).sum(axis=(1, 3)) * dz * dphi * len(z)
    assert_chi2(counts, expected)


def assert_eval_matches_sample(wi, weight, pdf, f_cos_eval, pdf_eval):
    """eval at a sampled direction returns weight * pdf and the same pdf (float32 rounding)."""
    ok = pdf > 0
    assert ok.mean() > 0.99
    np.testing.assert_allclose(pdf_eval[ok], pdf[ok], rtol=2e-6)
    np.testing.assert_allclose(f_cos_eval[..., ok], (weight * pdf)[..., ok], rtol=2e-6, atol=1e-12)


# ---------------------------------------------------------------- Lambert and Translucent
def test_lambert_sampler_matches_pdf_and_eval():
    wo = viewer(0.6)
    wi, weight, pdf = diffuse.lambert_sample(wo, *uniforms())
    assert_sampler_matches_pdf(wi, lambda d: diffuse.lambert_eval(viewer(0.6, len(d[0])), d)[1])
    assert_eval_matches_sample(wi, weight, pdf, *diffuse.lambert_eval(wo, wi))


def test_lambert_albedo_is_one_and_reciprocal():
    wo = viewer(0.2)
    _, weight, pdf = diffuse.lambert_sample(wo, *uniforms(seed=1))
    assert np.all(weight[pdf > 0] == 1.0) and np.mean(pdf > 0) > 0.9999
    a, b = random_upper(5000, 2), random_upper(5000, 3)
    fab = diffuse.lambert_eval(a, b)[0] / b[2]
    fba = diffuse.lambert_eval(b, a)[0] / a[2]
    np.testing.assert_allclose(fab, fba, rtol=1e-6)


def test_translucent_transmits_into_the_lower_hemisphere_with_albedo_one():
    wo = viewer(0.7)
    wi, weight, pdf = diffuse.translucent_sample(wo, *uniforms(seed=4))
    assert np.all(wi[2][pdf > 0] < 0) and np.all(weight[pdf > 0] == 1.0)
    assert np.mean(pdf > 0) > 0.9999
    assert_sampler_matches_pdf(wi, lambda d: diffuse.translucent_eval(viewer(0.7, len(d[0])), d)[1],
                               z_lo=-1.0, z_hi=0.0)
    assert_eval_matches_sample(wi, weight, pdf, *diffuse.translucent_eval(wo, wi))
    up = random_upper(1000, 5)
    assert not np.any(diffuse.translucent_eval(viewer(0.7, 1000), up)[0])


# ---------------------------------------------------------------- Oren-Nayar
def random_upper(n, seed):
    x, y, z = sampling.sample_uniform_sphere(*uniforms(n, seed))
    return x, y, np.abs(z)


COLOR = np.array([[0.2], [0.5], [0.9]], np.float32)


@pytest.mark.parametrize("sigma,mu", [(0.3, 0.8), (1.0, 0.15)])
def test_oren_nayar_sampler_matches_pdf_and_eval(sigma, mu):
    wo = viewer(mu)
    wi, weight, pdf = diffuse.oren_nayar_sample(wo, sigma, COLOR, *uniforms(seed=6))
    assert weight.shape == (3, N)
    assert_sampler_matches_pdf(
        wi, lambda d: diffuse.oren_nayar_eval(viewer(mu, len(d[0])), d, sigma, COLOR)[1])
    assert_eval_matches_sample(wi, weight, pdf, *diffuse.oren_nayar_eval(wo, wi, sigma, COLOR))


def test_oren_nayar_is_reciprocal():
    n = 20_000
    a, b = random_upper(n, 7), random_upper(n, 8)
    sigma = np.random.default_rng(9).random(n, dtype=np.float32)
    fab = diffuse.oren_nayar_eval(a, b, sigma, COLOR)[0] / b[2]
    fba = diffuse.oren_nayar_eval(b, a, sigma, COLOR)[0] / a[2]
    ok = (a[2] > 1e-3) & (b[2] > 1e-3)  # 1/cos amplifies float32 rounding at grazing angles
    np.testing.assert_allclose(fab[:, ok], fba[:, ok], rtol=1e-5)


def test_oren_nayar_mean_of_g_is_the_energy_constant():
    """Cycles' Eavg uses (2 pi - 5.6) / 3 for the cosine-weighted mean of G: it is exact, so the white
    furnace below must come out 1 up to Monte Carlo noise and float32 rounding."""
    x, w = np.polynomial.legendre.leggauss(400)
    mu, w = 0.5 * (x + 1.0), 0.5 * w
    g = diffuse._oren_nayar_g(mu.astype(np.float32)).astype(np.float64)
    assert abs(np.sum(w * 2 * mu * g) - (2 * np.pi - 5.6) / 3) < 1e-6  # float32 G: ~1e-7 per point


def closed_form_albedo(mu, sigma, rho):
    """E(mu) + Ems (1 - E(mu)) pi (1 - Eavg): the integral of the energy term over wi uses
    the integral of (1 - E(cos_i)) cos_i over the hemisphere = pi (1 - Eavg)."""
    a = 1 / (np.pi + sigma * (np.pi / 2 - 2 / 3))
    b = sigma * a
    eavg = a * np.pi + b * (2 * np.pi - 5.6) / 3
    ems = rho ** 2 * eavg / (np.pi * (1 - eavg) * (1 - rho * (1 - eavg)))
    e = float(diffuse.oren_nayar_single_scatter_albedo(np.float32([mu]), np.float32(sigma))[0])
    return e + ems * (1 - e) * np.pi * (1 - eavg)


@pytest.mark.parametrize("sigma", [0.1, 0.5, 1.0])
@pytest.mark.parametrize("mu", [0.05, 0.5, 1.0])
def test_oren_nayar_white_furnace_is_one(sigma, mu):
    """rho = 1: E + (1 - E)(1 - Eavg_exact)/(1 - Eavg) = 1 exactly (Eavg is exact, test above), so the
    tolerance is the estimator's standard error alone."""
    wo = viewer(mu)
    _, weight, _ = diffuse.oren_nayar_sample(wo, sigma, np.ones((3, 1), np.float32), *uniforms(seed=10))
    mean, se = mean_and_stderr(weight[0])
    assert abs(mean - 1.0) < 4 * se + 1e-6, (mean, se)
    assert abs(closed_form_albedo(mu, sigma, 1.0) - 1.0) < 1e-6


def test_oren_nayar_matches_numerical_integration_of_its_formula():
    """The albedo for a coloured rho by uniform hemisphere sampling (independent of the lobe's sampler)
    against the closed form, per channel, within four standard errors."""
    mu, sigma = 0.35, 0.7
    n = 400_000
    wi = random_upper(n, 11)
    f_cos, _ = diffuse.oren_nayar_eval(viewer(mu, n), wi, sigma, COLOR)
    estimate, se = mean_and_stderr(2 * np.pi * f_cos.astype(np.float64), axis=1)
    expected = closed_form_albedo(mu, sigma, COLOR[:, 0].astype(np.float64))
    assert np.all(np.abs(estimate - expected) < 4 * se), (estimate, expected, se)


def test_oren_nayar_at_zero_roughness_is_lambert():
    a, b = random_upper(1000, 12), random_upper(1000, 13)
    f_on, pdf_on = diffuse.oren_nayar_eval(a, b, 0.0, COLOR)
    f_l, pdf_l = diffuse.lambert_eval(a, b)
    np.testing.assert_allclose(f_on, np.broadcast_to(f_l, f_on.shape), rtol=1e-6)
    np.testing.assert_allclose(pdf_on, pdf_l)


# ---------------------------------------------------------------- edge cases
def edge_directions():
    """Grazing, below, exactly normal and antiparallel directions, paired every way."""
    dirs = np.array([[0, 0, 1], [1, 0, 0], [0, 0, -1], [0.6, 0, -0.8], [0.6, 0, 0.8], [-1, 0, 0],
                     [0, 1e-8, 1.0]], np.float32).T
    k = dirs.shape[1]
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    return tuple(dirs[:, i.ravel()]), tuple(dirs[:, j.ravel()])


def test_edge_cases_give_no_nan_and_no_warning():
    wo, wi = edge_directions()
    n = len(wo[0])
    u = np.array([0, 0, 1 - 2 ** -24, 0.5, 0, 1 - 2 ** -24, 0.25] * 7, np.float32)[:n]
    color = np.ones((3, n), np.float32)
    with warnings.catch_warnings(), np.errstate(all="warn"):
        warnings.simplefilter("error")
        outs = [diffuse.lambert_eval(wo, wi), diffuse.translucent_eval(wo, wi),
                diffuse.lambert_sample(wo, u, u[::-1]), diffuse.translucent_sample(wo, u, u[::-1])]
        for sigma in (0.0, 1e-6, 0.5, 1.0):
            outs += [diffuse.oren_nayar_eval(wo, wi, sigma, color),
                     diffuse.oren_nayar_sample(wo, sigma, color, u, u[::-1])]
    for out in outs:
        for a in out:
            for c in (a if isinstance(a, tuple) else (a,)):
                assert np.all(np.isfinite(c)) and c.dtype == np.float32
    f_cos, pdf = diffuse.oren_nayar_eval(wo, wi, 0.5, color)
    assert np.all(f_cos[:, pdf == 0] == 0) and np.all(f_cos >= 0)
