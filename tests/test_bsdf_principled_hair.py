"""Cycles' Principled Hair BSDF (kernels/bsdf/hair_chiang.py, hair_huang.py, kernels/shading/hair_nodes.py).

Chiang: the sampler against the density it draws (chi-square in the strand's angles, the density written here
again in float64 from the paper's formulas with the exact Bessel function), eval and pdf against the same formulas
with Cycles' truncated Bessel series at fixed directions, the pdf's integral and the white furnace against their
closed forms. Huang: its pdf is Cycles' constant 1, so its sampler is tested against its eval lobe by lobe (what
the sampler returns in each bin of directions against the eval's integral there). The closure's frame on a
triangle is Cycles' (dPdu = p1 - p0), and on meshes both models render as Cycles renders them.
"""
import math
import warnings

import numpy as np
import pytest

from ember.kernels.bsdf import hair_chiang as hc
from ember.kernels.bsdf import hair_huang as hh
from stats import assert_chi2

F32 = np.float32
Y709 = np.array([0.21263912, 0.71516913, 0.07219276])


# ---------------------------------------------------------------- Chiang, written again in float64
def fresnel(cos_i, eta):
    c = abs(cos_i)
    g = eta * eta - 1 + c * c
    if g <= 0:
        return 1.0
    g = math.sqrt(g)
    a, b = (g - c) / (g + c), (c * (g + c) - 1) / (c * (g - c) + 1)
    return 0.5 * a * a * (1 + b * b)


def mapped(rough, radial, coat):
    """(v, s, m0): the roughnesses clamped, Coat's share taken off R's, mapped by Chiang et al.'s polynomials."""
    v, s = np.clip(rough, 1e-3, 1), np.clip(radial, 1e-3, 1)
    m0 = np.clip((1 - np.clip(coat, 0, 1)) * v, 1e-3, 1)

    def var(r):
        return (0.726 * r + 0.812 * r ** 2 + 3.7 * r ** 20) ** 2
    return var(v), (0.265 * s + 1.194 * s ** 2 + 5.372 * s ** 22) * math.sqrt(math.pi / 8), var(m0)


def log_i0_series(x):
    """Cycles' log I0: its ten-term series, or the asymptotic expansion above 12."""
    x = np.asarray(x, np.float64)
    q = x * x / 4
    series = sum(q ** i / math.factorial(i) ** 2 for i in range(10))
    big = x + 0.5 * (1 / (8 * np.maximum(x, 1e-9)) - math.log(2 * math.pi) - np.log(np.maximum(x, 1e-9)))
    return np.where(x > 12, big, np.log(series))


def log_i0_exact(x):
    x = np.asarray(x, np.float64)
    big = x - 0.5 * np.log(2 * math.pi * np.maximum(x, 1e-9)) + np.log1p(1 / (8 * np.maximum(x, 1e-9)))
    return np.where(x > 600, big, np.log(np.i0(np.minimum(x, 600))))


def mp(sin_i, sin_o, cos_o, v, exact):
    """d'Eon's longitudinal function (per unit sin theta_i); Cycles' form (truncated series, its log form and
    ln 2 ~ 0.6931 for v <= 0.1) unless exact."""
    cos_i = np.sqrt(np.maximum(1 - sin_i * sin_i, 0))
    a, b = cos_i * cos_o / v, sin_i * sin_o / v
    if exact:
        log_sinh = 1 / v + np.log1p(-math.exp(-2 / v)) - math.log(2)
        return np.exp(log_i0_exact(a) - b - log_sinh - math.log(2 * v))
    if v <= 0.1:
        return np.exp(log_i0_series(a) - b - 1 / v + 0.6931 + math.log(0.5 / v))
    return np.exp(-b) * np.exp(log_i0_series(a)) / (math.sinh(1 / v) * 2 * v)


def trimmed_logistic(x, s):
    def cdf(t):
        return 1 / (1 + math.exp(-t / s))
    e = np.exp(-np.abs(x) / s)
    return e / (s * (1 + e) ** 2) / (1 - 2 * cdf(-math.pi))


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


class Chiang:
    """One Chiang closure (float64): the viewer's latitude sin_o, the offset h, the node's Roughness, Radial
    Roughness, Coat, Offset, IOR and absorption sigma (3,)."""

    def __init__(self, sin_o, h, rough, radial, coat, offset, eta, sigma):
        self.args = (sin_o, h, rough, radial, coat, offset, eta, sigma)
        self.v, self.s, self.m0 = mapped(rough, radial, coat)
        self.sin_o, self.cos_o = sin_o, math.sqrt(1 - sin_o ** 2)
        sin_gt = h * self.cos_o / math.sqrt(eta ** 2 - sin_o ** 2)
        self.gamma_o, self.gamma_t = math.asin(h), math.asin(sin_gt)
        cos_t = math.sqrt(1 - (sin_o / eta) ** 2)
        t = np.exp(-np.asarray(sigma, np.float64) * 2 * math.sqrt(1 - sin_gt ** 2) / cos_t)
        f = fresnel(self.cos_o * math.sqrt(1 - h * h), eta)
        a1 = (1 - f) ** 2 * t
        a2 = a1 * t * f
        self.ap = [np.full(3, f), a1, a2, a2 * t * f / (1 - t * f)]
        gray = np.array([f] + [Y709 @ a for a in self.ap[1:]])
        self.ep = gray / gray.sum()
        al = -offset
        s1, c1 = math.sin(al), math.cos(al)
        s2, c2 = math.sin(2 * al), math.cos(2 * al)
        s4, c4 = math.sin(4 * al), math.cos(4 * al)
        so, co = self.sin_o, self.cos_o
        self.tilted = [(so * c2 - co * s2, abs(co * c2 + so * s2)), (so * c1 + co * s1, abs(co * c1 - so * s1)),
                       (so * c4 + co * s4, abs(co * c4 - so * s4)), (so, co)]

    def variances(self, sampler):
        return ((self.v if sampler else self.m0), self.v / 4, 4 * self.v, 4 * self.v)

    def lobes(self, sin_i, phi, exact=False, sampler=False):
        """[(A_p (3,), E_p, Mp (n,), Np (n,))] of R, TT, TRT and the residual at (sin theta_i, phi from the viewer)."""
        out = []
        for p, var in enumerate(self.variances(sampler)):
            m = mp(sin_i, *self.tilted[p], var, exact)
            if p < 3:
                n = trimmed_logistic(wrap(phi - (2 * p * self.gamma_t - 2 * self.gamma_o + p * math.pi)), self.s)
            else:
                n = np.full_like(m, 1 / (2 * math.pi))
            out.append((self.ap[p], self.ep[p], m, n))
        return out

    def eval(self, sin_i, phi, exact=False):
        """(F (3, n), pdf (n,)) per unit solid angle."""
        parts = self.lobes(sin_i, phi, exact)
        return sum(a[:, None] * m * n for a, _, m, n in parts), sum(e * m * n for _, e, m, n in parts)

    def sampler_density(self, sin_i, phi):
        """What the sampler draws: R with variance v, not m0 (Cycles'), every Mp exact."""
        return sum(e * m * n for _, e, m, n in self.lobes(sin_i, phi, exact=True, sampler=True))

    def kernel(self, n):
        """The Ember closure's columns for n copies, and the viewer in its local frame."""
        sin_o, h, rough, radial, coat, offset, eta, sigma = self.args
        v, s, m0 = hc.chiang_roughness(F32(rough), F32(radial), F32(coat))
        wo = (np.full(n, sin_o, F32), np.full(n, math.sqrt(1 - sin_o ** 2), F32), np.zeros(n, F32))
        cols = (np.full(n, h, F32), np.full(n, v, F32), np.full(n, s, F32), np.full(n, m0, F32),
                np.full(n, -offset, F32), np.full(n, eta, F32), np.tile(np.asarray(sigma, F32)[:, None], (1, n)))
        return wo, cols


def local(sin_i, phi, phi_o=-math.pi / 2):
    """The closure-frame direction of latitude sin_i and azimuth phi from the viewer's (module docstring of
    hair_chiang: Cycles' (X, Y, Z) are (x, z, -y))."""
    cos_i = np.sqrt(1 - np.square(sin_i))
    pi = phi + phi_o
    return (np.asarray(sin_i, F32), (-cos_i * np.sin(pi)).astype(F32), (cos_i * np.cos(pi)).astype(F32))


def angles(w):
    """(sin theta, phi from the viewer) of closure-frame directions (the viewer's azimuth is -pi/2)."""
    return np.asarray(w[0], np.float64), wrap(np.arctan2(-np.asarray(w[1], np.float64), w[2]) + math.pi / 2)


SIN_BINS, PHI_BINS = 20, 24
CHIANG_CASES = {
    "brown, tilted": Chiang(0.35, 0.3, 0.3, 0.3, 0.0, math.radians(2), 1.55, (0.4, 0.8, 1.6)),
    "white, rough, grazing": Chiang(-0.8, -0.85, 0.7, 0.9, 0.0, math.radians(-5), 1.4, (0.0, 0.0, 0.0)),
    "smooth, head on": Chiang(0.0, 0.05, 0.2, 0.25, 0.0, math.radians(3), 1.6, (0.05, 0.1, 0.2)),
    "coated": Chiang(0.5, -0.4, 0.35, 0.5, 0.6, math.radians(2), 1.55, (0.2, 0.3, 0.5)),
}


def cell_integrals(density, sub=8):
    """The integral of density(sin_i, phi) over every (sin theta, phi) bin, midpoint rule with sub x sub points."""
    s = (np.arange(SIN_BINS * sub) + 0.5) / (SIN_BINS * sub) * 2 - 1
    p = (np.arange(PHI_BINS * sub) + 0.5) / (PHI_BINS * sub) * 2 * math.pi - math.pi
    ss, pp = np.meshgrid(s, p, indexing="ij")
    cell = density(ss.ravel(), pp.ravel()).reshape(ss.shape) * (2 / (SIN_BINS * sub)) * (2 * math.pi / (PHI_BINS * sub))
    return cell.reshape(SIN_BINS, sub, PHI_BINS, sub).sum(axis=(1, 3))


def histogram(w, weights=None):
    s, p = angles(w)
    counts, _, _ = np.histogram2d(s, p, bins=[SIN_BINS, PHI_BINS], range=[[-1, 1], [-math.pi, math.pi]],
                                  weights=weights)
    return counts


@pytest.mark.parametrize("case", list(CHIANG_CASES))
def test_chiang_sampler_draws_its_density(case):
    """Per unit solid angle the sampler draws sum_p E_p Mp Np with every Mp exact (d'Eon's sampling inverts it)
    and Np the trimmed logistic; dw = d(sin theta) d(phi). Coated: R drawn with variance v, as Cycles'."""
    ref = CHIANG_CASES[case]
    n = 200_000
    wo, cols = ref.kernel(n)
    rng = np.random.default_rng(71)
    wi, weight, pdf, transmit = hc.chiang_sample(wo, *cols, *(rng.random(n, dtype=F32) for _ in range(3)))
    assert (pdf > 0).all() and np.all(np.isfinite(weight))
    assert_chi2(histogram(wi), n * cell_integrals(ref.sampler_density))


@pytest.mark.parametrize("case", list(CHIANG_CASES))
def test_chiang_eval_and_pdf_at_fixed_directions(case):
    """eval = sum_p A_p Mp Np and pdf = sum_p E_p Mp Np, Cycles' series and all, at a spread of directions;
    and a sample's weight is eval / pdf at its direction."""
    ref = CHIANG_CASES[case]
    sin_i = np.array([-0.9, -0.5, -0.2, 0.0, 0.15, 0.4, 0.7, 0.95])
    phi = np.array([-3.0, -2.2, -1.0, -0.2, 0.3, 1.1, 2.0, 3.1])
    ss, pp = (a.ravel() for a in np.meshgrid(sin_i, phi))
    wo, cols = ref.kernel(len(ss))
    f, pdf = hc.chiang_eval(wo, local(ss, pp), *cols)
    f_ref, pdf_ref = ref.eval(ss, pp)
    np.testing.assert_allclose(pdf, pdf_ref, rtol=3e-4, atol=1e-7)
    np.testing.assert_allclose(f, f_ref, rtol=3e-4, atol=1e-7)
    wo, cols = ref.kernel(2000)
    wi, weight, pdf_s, _ = hc.chiang_sample(wo, *cols, *(np.random.default_rng(72).random(2000, dtype=F32)
                                                          for _ in range(3)))
    f_s, pdf_e = hc.chiang_eval(wo, wi, *cols)
    np.testing.assert_allclose(pdf_e, pdf_s, rtol=2e-4)
    np.testing.assert_allclose(weight * pdf_s, f_s, rtol=2e-4, atol=1e-7)


def sphere_integral(fn, n_sin=800, n_phi=720):
    """The integral of fn(sin_i, phi) over the sphere, midpoint rule in (sin theta, phi)."""
    s = (np.arange(n_sin) + 0.5) / n_sin * 2 - 1
    p = (np.arange(n_phi) + 0.5) / n_phi * 2 * math.pi - math.pi
    ss, pp = (a.ravel() for a in np.meshgrid(s, p, indexing="ij"))
    return fn(ss, pp).reshape(-1, len(ss)).sum(axis=1) * (2 / n_sin) * (2 * math.pi / n_phi)


def mp_integral(ref, p, exact, sampler=False):
    s = (np.arange(20000) + 0.5) / 20000 * 2 - 1
    return mp(s, *ref.tilted[p], ref.variances(sampler)[p], exact).sum() * (2 / 20000)


@pytest.mark.parametrize("case", list(CHIANG_CASES))
def test_chiang_pdf_integrates_to_one_but_for_cycles_bessel_series(case):
    """Each Np integrates to 1 over phi and each exact Mp to 1 over sin theta, so the pdf sum_p E_p Mp Np
    integrates to sum_p E_p = 1; Cycles' ten-term Bessel series (and its log form's ln 2 ~ 0.6931) makes its
    Mp integrate to a little less where cos theta_i cos theta_o / v is large. Ember's pdf integrates to that:
    sum_p E_p (the integral of Cycles' Mp_p), computed here in float64."""
    ref = CHIANG_CASES[case]
    for p in range(4):
        assert mp_integral(ref, p, exact=True) == pytest.approx(1.0, abs=2e-4)
    expected = sum(ref.ep[p] * mp_integral(ref, p, exact=False) for p in range(4))
    assert 0.99 < expected <= 1.0 + 1e-4

    def pdf(ss, pp):
        wo, cols = ref.kernel(len(ss))
        return hc.chiang_eval(wo, local(ss, pp), *cols)[1]
    assert sphere_integral(pdf)[0] == pytest.approx(expected, abs=2e-3)


def test_chiang_white_furnace():
    """Without absorption (T = 1) the attenuations sum to one: f + (1 - f)^2 + (1 - f)^2 f + (1 - f) f^2 = 1,
    and equal their luminances, so every sample's weight eval / pdf is exactly 1: a white hair in a white
    furnace returns all the light the sampler sends, as Cycles' does. Evaluated (as light sampling sees it)
    the lobe reflects sum_p A_p (the integral of Cycles' Mp_p): 1 less Cycles' Bessel truncation loss, which
    this test computes in float64 (the exact model loses nothing)."""
    for rough, radial, h, sin_o in ((0.3, 0.3, 0.3, 0.2), (0.5, 0.5, -0.6, 0.0), (0.9, 0.4, 0.9, -0.7)):
        ref = Chiang(sin_o, h, rough, radial, 0.0, math.radians(2), 1.55, (0.0, 0.0, 0.0))
        assert sum(ref.ap)[0] == pytest.approx(1.0, abs=1e-12)
        n = 20_000
        wo, cols = ref.kernel(n)
        rng = np.random.default_rng(73)
        _, weight, _, _ = hc.chiang_sample(wo, *cols, *(rng.random(n, dtype=F32) for _ in range(3)))
        np.testing.assert_allclose(weight, 1.0, rtol=5e-6)
        expected = sum(ref.ap[p][0] * mp_integral(ref, p, exact=False) for p in range(4))

        def value(ss, pp):
            wo_, cols_ = ref.kernel(len(ss))
            return hc.chiang_eval(wo_, local(ss, pp), *cols_)[0]
        integral = sphere_integral(value)
        np.testing.assert_allclose(integral, expected, atol=2e-3)
        assert 0.99 < expected <= 1.0 + 1e-4


def test_chiang_edge_cases_give_no_nan_and_no_warning():
    """Grazing offsets, a viewer along the strand, the smallest and largest roughness, steep tilts and opaque or
    clear hair: finite float32 values, no NumPy warning."""
    n = 400
    rng = np.random.default_rng(79)
    z = rng.random(n) * 2 - 1
    phi = rng.random(n) * 2 * math.pi
    d = local(z.astype(F32), phi)
    with warnings.catch_warnings(), np.errstate(all="warn"):
        warnings.simplefilter("error")
        for sin_o, h, rough, offset, sigma in ((0.0, 1.0, 0.001, 0.0, 0.0), (1.0, -1.0, 1.0, 0.5, 1e4),
                                               (-0.999999, 0.0, 0.3, -0.7, 0.0), (0.5, 0.999, 0.05, 0.03, 50.0)):
            v, s, m0 = hc.chiang_roughness(np.full(n, rough, F32), np.full(n, rough, F32), np.full(n, 0.2, F32))
            wo = (np.full(n, sin_o, F32), np.full(n, math.sqrt(max(1 - sin_o * sin_o, 0)), F32), np.zeros(n, F32))
            cols = (np.full(n, h, F32), v, s, m0, np.full(n, -offset, F32), np.full(n, 1.55, F32),
                    np.full((3, n), sigma, F32))
            f, pdf = hc.chiang_eval(wo, d, *cols)
            wi, weight, pdf_s, _ = hc.chiang_sample(wo, *cols, *(rng.random(n, dtype=F32) for _ in range(3)))
            for a in (f, pdf, weight, pdf_s, *wi):
                assert a.dtype == np.float32 and np.isfinite(a).all()


def test_chiang_parametrizations():
    """Cycles' numbers: the roughness mapping, melanin and Direct Coloring's inversion
    (bsdf_principled_hair_sigma_from_*), and the Random Color scaling of melanin."""
    v, s, m0 = hc.chiang_roughness(F32([0.3, 0.0005, 1.0]), F32([0.3, 0.5, 2.0]), F32([0.0, 0.0, 0.5]))
    v_ref, s_ref, m0_ref = mapped(np.array([0.3, 0.0005, 1.0]), np.array([0.3, 0.5, 2.0]), np.array([0.0, 0.0, 0.5]))
    np.testing.assert_allclose(v, v_ref, rtol=1e-5)
    np.testing.assert_allclose(s, s_ref, rtol=1e-5)
    np.testing.assert_allclose(m0, m0_ref, rtol=1e-5)
    scale = 5.969 - 0.215 * 0.3 + 2.532 * 0.09 - 10.73 * 0.027 + 5.574 * 0.0081 + 0.245 * 0.00243
    color = np.array([[0.8], [0.5], [0.2]], F32)
    np.testing.assert_allclose(hc.sigma_from_reflectance(color, F32(0.3))[:, 0], (np.log([0.8, 0.5, 0.2]) / scale) ** 2,
                               rtol=1e-5)
    melanin = -math.log(1 - 0.5 * (1 + 2 * (0.9 - 0.5) * 0.25))
    expected = melanin * 0.7 * np.array([0.506, 0.841, 1.653]) + melanin * 0.3 * np.array([0.343, 0.733, 1.924])
    got = hc.sigma_from_melanin(F32([0.5]), F32([0.3]), F32([0.25]), F32([0.9]))[:, 0]
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    assert np.isfinite(hc.sigma_from_melanin(F32([1.0]), F32([0.0]), F32([0.0]), F32([0.0]))).all()


# ---------------------------------------------------------------- Huang
def huang_params(n, wo, rough=0.4, tilt=-0.05, b=1.0, sigma=(0.0, 0.0, 0.0), lobes=(1, 1, 1), h=0.0, coverage=1.0,
                 eta=1.55):
    full = lambda x: np.full(n, x, F32)  # noqa: E731
    return hh.HuangParams(full(rough), full(tilt), full(eta), full(b), np.tile(np.asarray(sigma, F32)[:, None], (1, n)),
                          np.tile(np.asarray(lobes, F32)[:, None], (1, n)), full(h), full(coverage), hh.to_cycles(wo))


def viewer(n, sin_t, across=0.0):
    """The viewer in the closure frame (x the tangent, z the fibre's normal): across 0 is a hit off a curve
    (the frame faces the viewer), else an elliptical fibre turned by that much."""
    c = math.sqrt(1 - sin_t * sin_t)
    return (np.full(n, sin_t, F32), np.full(n, c * math.cos(across), F32), np.full(n, c * math.sin(across), F32))


HUANG_CASES = {
    "brown, circular": dict(sin_t=0.35, rough=0.4, sigma=(0.2, 0.4, 0.8)),
    "white, elliptical, turned": dict(sin_t=-0.6, rough=0.5, b=0.7, across=0.6),
    "blond, smooth": dict(sin_t=0.1, rough=0.25, sigma=(0.05, 0.1, 0.3), eta=1.5),
}


def huang_estimates(case, lobe, n, m, seed):
    """What the far-field sampler returns from `lobe` alone (its scale the only one on) toward n samples, as
    (direction, weight x [the sample took that lobe]), and a uniform estimate of the eval's part of that lobe (R,
    or TT + TRT) over m directions, as (direction, 4 pi x value): both estimate the lobe's scattering."""
    kw = dict(HUANG_CASES[case], tilt=0.0)
    sin_t, across = kw.pop("sin_t"), kw.pop("across", 0.0)
    scales = tuple(1.0 if k == lobe else 0.0 for k in range(3))
    rng = np.random.default_rng(seed)
    wi, weight, _, _, picked = hh.huang_sample_lobes(huang_params(n, viewer(n, sin_t, across), lobes=scales, **kw),
                                                     *(rng.random(n, dtype=F32) for _ in range(3)))
    z = rng.random(m) * 2 - 1
    phi = rng.random(m) * 2 * math.pi - math.pi
    r = np.sqrt(1 - z * z)
    d = (z.astype(F32), (r * np.sin(phi)).astype(F32), (r * np.cos(phi)).astype(F32))
    parts = hh.huang_eval_parts(huang_params(m, viewer(m, sin_t, across), lobes=scales, **kw), viewer(m, sin_t, across),
                                d)
    return (wi, np.where(picked == lobe, weight[0], 0.0)), (d, (parts[0] if lobe == 0 else parts[1])[0] * 4 * math.pi)


# Cycles' eval approximates what its sampler draws: Simpson's rule over h across the fibre with nodes 0.7 (R) or
# 0.8 roughness apart, of an integrand singular at the fibre's edges (R up to 10% off the sampler here, 50% in
# some directions), and the fibre's projection without its tilt. So the sampler is tested against the eval
# lobe by lobe in total (energy) with the tilt off and R's nodes 20 times closer, not direction by direction:
# near the edges, where the light leaves forward, Simpson's nodes stay several standard errors from what the
# sampler draws even then. (Its pdf is Cycles' constant 1, which no sampler draws.) Cycles' own spacing is
# what the renders compare.
FINE_NODES = (F32(0.035), F32(0.8))


@pytest.mark.parametrize("lobe", [0, 1, 2], ids=["R", "TT", "TRT"])
@pytest.mark.parametrize("case", list(HUANG_CASES))
def test_huang_lobe_energies_match_their_eval(case, lobe, monkeypatch):
    """Each lobe's energy, what the sampler returns from it on average, against the eval's integral over the
    sphere (Cycles' TT and TRT nodes; R's closer, FINE_NODES), within 4 standard errors. The lobes' directions
    agree only roughly: Cycles' sampler and eval test the microfacets' visibility differently at the fibre's
    edges, and take the chord's cosine at its other end (equal on a circle only, a 2% effect on the ellipse)."""
    monkeypatch.setattr(hh, "NODE_SPACING", FINE_NODES)
    n, m = 100_000, 20_000
    (_, mine), (_, value) = huang_estimates(case, lobe, n, m, seed=78 + lobe)
    z = abs(mine.mean() - value.mean()) / math.sqrt(mine.var() / n + value.var() / m)
    assert z < 4.0, (z, mine.mean(), value.mean())
    assert mine.mean() > 0.01


def test_huang_eval_is_a_fixed_random_quadrature_and_never_nan():
    """Two evaluations of one pair of directions agree (the quadrature's numbers are hashed from them), pdf is 1
    everywhere (Cycles'), and edge cases (grazing, along the fibre, near field, elliptical, lobes off) give finite
    float32 and no warning; a near-field hit integrates over its pixel only, which changes the value."""
    n = 200
    rng = np.random.default_rng(75)
    z = rng.random(n) * 2 - 1
    phi = rng.random(n) * 2 * math.pi
    r = np.sqrt(1 - z * z)
    d = (z.astype(F32), (r * np.sin(phi)).astype(F32), (r * np.cos(phi)).astype(F32))
    with warnings.catch_warnings(), np.errstate(all="warn"):
        warnings.simplefilter("error")
        for kw in (dict(), dict(b=0.5, across=1.2), dict(rough=0.001), dict(lobes=(0, 0, 0)), dict(h=0.3, coverage=0.1),
                   dict(sin_t=0.99999), dict(sin_t=-1.0), dict(tilt=1.4)):
            kw = dict(kw)
            sin_t, across = kw.pop("sin_t", 0.3), kw.pop("across", 0.0)
            p = huang_params(n, viewer(n, sin_t, across), **kw)
            f1, pdf = hh.huang_eval(p, viewer(n, sin_t, across), d)
            f2, _ = hh.huang_eval(p, viewer(n, sin_t, across), d)
            assert f1.dtype == np.float32 and np.isfinite(f1).all() and (f1 >= 0).all()
            np.testing.assert_array_equal(f1, f2)
            np.testing.assert_array_equal(pdf, 1.0)
            wi, weight, pdf_s, transmit = hh.huang_sample(p, *(rng.random(n, dtype=F32) for _ in range(3)))
            assert np.isfinite(weight).all() and set(np.unique(pdf_s)) <= {0.0, 1.0} and not transmit.any()
            assert all(np.isfinite(c).all() for c in wi)
    far = hh.huang_eval(huang_params(n, viewer(n, 0.3), h=0.5), viewer(n, 0.3), d)[0]
    near = hh.huang_eval(huang_params(n, viewer(n, 0.3), h=0.5, coverage=0.1), viewer(n, 0.3), d)[0]
    assert not np.allclose(far, near)


# ---------------------------------------------------------------- the closure on a triangle
class EdgeHit:
    """n hits on the plane z = 0 (normal +z) of a triangle whose edge p1 - p0 is `edge`, seen from wo."""

    def __init__(self, n, wo, edge=(1.0, 0.0, 0.0), backfacing=False):
        from test_closures import FakeHit
        self.__dict__.update(vars(FakeHit(n, wo, backfacing)))
        self._edge = np.asarray(edge, F32)

    def __len__(self):
        return len(self.mat)

    def edges(self, idx):
        return np.tile(self._edge, (len(idx), 1)), np.tile(F32([0.0, 1.0, 0.0]), (len(idx), 1))


def hair_closures(inputs, options, hit):
    from ember.kernels.scene import Closure, Materials, Param, Shader
    from ember.kernels.shading import Shading
    closure = Closure("PRINCIPLED_HAIR", tuple((k, Param.of(v)) for k, v in inputs.items()), tuple(options.items()))
    return Shading(Materials((Shader((closure,)),)), []).surface(hit).closures


def test_the_closure_on_a_triangle_takes_cycles_frame():
    """Chiang: X = dPdu = p1 - p0 (reversed on a back face), the normal Y = X x viewer, h = (Ng x X) . (X x Y);
    Random Roughness scales both roughnesses by 1 + 2 (Random - 1/2) Random Roughness before Cycles' mapping.
    Huang: the tangent dPdu, the normal dPdu x viewer, h = -N . (dPdu x viewer)."""
    from ember.kernels.bsdf import lobes
    wo = np.array([0.3, -0.5, 0.8])
    wo /= np.linalg.norm(wo)
    for backfacing in (False, True):
        edge = np.array([0.6, 0.8, 0.0])
        cs = hair_closures({"Roughness": 0.4, "Radial Roughness": 0.2, "Random Roughness": 0.5, "Random": 0.8,
                            "Coat": 0.3}, {"model": "CHIANG", "parametrization": "ABSORPTION"},
                           EdgeHit(3, wo, edge, backfacing))
        assert (cs.lobe == lobes.HAIR_CHIANG).all()
        x = edge * (-1 if backfacing else 1)
        y = np.cross(x, wo)
        y /= np.linalg.norm(y)
        z = np.cross(x, y)
        ng = np.array([0.0, 0.0, 1.0])   # FakeHit's, toward the viewer
        t, _, nrm = (a[:, 0] for a in cs.frame)
        np.testing.assert_allclose(t, x, atol=1e-6)
        np.testing.assert_allclose(nrm, y, atol=1e-6)
        np.testing.assert_allclose(cs.hair_h[0], np.cross(ng, x) @ z, atol=1e-6)
        factor = 1 + 2 * (0.8 - 0.5) * 0.5
        v, s, m0 = mapped(0.4 * factor, 0.2 * factor, 0.3)
        np.testing.assert_allclose([cs.hair_v[0], cs.hair_s[0], cs.hair_m0[0]], [v, s, m0], rtol=1e-5)
        np.testing.assert_allclose(cs.offset[0], -0.034906585, rtol=1e-6)
        np.testing.assert_allclose(cs.c0[:, 0], [0.245531, 0.52, 1.365], rtol=1e-6)
        assert abs(cs.wo[2][0]) < 1e-6   # the viewer lies in the frame's x-y plane
    cs = hair_closures({"Aspect Ratio": 0.85, "Roughness": 0.2}, {"model": "HUANG", "parametrization": "MELANIN"},
                       EdgeHit(3, wo, (0.0, 2.0, 0.0)))
    assert (cs.lobe == lobes.HAIR_HUANG).all()
    normal = np.cross([0.0, 2.0, 0.0], wo)
    normal /= np.linalg.norm(normal)
    t, _, nrm = (a[:, 0] for a in cs.frame)
    np.testing.assert_allclose(t, [0, 1, 0], atol=1e-6)
    np.testing.assert_allclose(nrm, normal, atol=1e-6)
    np.testing.assert_allclose(cs.hair_h[0], -normal[2], atol=1e-6)
    np.testing.assert_allclose(cs.rough[0], 0.2, rtol=1e-6)
    np.testing.assert_allclose(cs.c1[:, 0], 1.0)
    assert cs.aspect[0] == pytest.approx(0.85)


def test_huang_with_every_lobe_off_makes_no_closure_and_samples_keep_their_value():
    """Cycles makes no Huang closure when R, TT and TRT are all 0; a Huang closure alone at its hit keeps its
    sample's value (lobes.SAMPLED_ALONE) with the mixture's usual result: weight x the lobe's own weight."""
    wo = np.array([0.2, -0.6, 0.7])
    off = hair_closures({"R lobe": 0.0, "TT lobe": 0.0, "TRT lobe": 0.0}, {"model": "HUANG"}, EdgeHit(4, wo))
    assert len(off) == 0
    n = 2000
    cs = hair_closures({"Color": (0.7, 0.5, 0.3)}, {"model": "HUANG"}, EdgeHit(n, wo))
    rng = np.random.default_rng(76)
    u = [rng.random(n, dtype=F32) for _ in range(4)]
    s = cs.sample(*u)
    from ember.kernels.bsdf.registry import huang_params as params
    rows = np.arange(n)
    wi, own, pdf, _ = hh.huang_sample(params(cs, rows, cs.wo), u[1], u[2], u[3])
    np.testing.assert_array_equal(s.pdf, pdf)
    np.testing.assert_allclose(s.weight, own * cs.weight, rtol=1e-6)
    assert s.any_side.all() and not s.transmit.any()


def test_hair_closures_are_glossy_for_the_passes_and_filter_glossy_raises_their_roughness():
    """Cycles files both models as glossy (CLOSURE_IS_BSDF_GLOSSY) with bsdf_hair_*_albedo as their colour, and
    its Filter Glossy raises Chiang's mapped variances and scale and Huang's roughness to the blur's value."""
    from ember.kernels.bsdf import light_passes
    wo = np.array([0.2, -0.6, 0.7])
    n = 3
    for model in ("CHIANG", "HUANG"):
        cs = hair_closures({"Color": (0.7, 0.5, 0.3), "Roughness": 0.2}, {"model": model}, EdgeHit(n, wo))
        diffuse, glossy, transmission = light_passes.class_albedo(cs, n)
        assert not diffuse.any() and not transmission.any() and (glossy > 0).all()
        if model == "CHIANG":
            expected = hc.chiang_albedo(cs.wo[0], cs.hair_h, cs.hair_v, cs.eta, cs.c0)
        else:
            from ember.kernels.bsdf.registry import huang_params as params
            expected = hh.huang_albedo(params(cs, np.arange(n), cs.wo))
        np.testing.assert_allclose(glossy, expected * cs.weight, rtol=1e-5)
        before = (cs.hair_v.copy(), cs.rough.copy())
        cs.blur(np.full(n, 0.6, F32))
        if model == "CHIANG":
            assert (before[0] < 0.6).all() and (cs.hair_v == F32(0.6)).all() and (cs.hair_s >= F32(0.6)).all()
            assert (cs.hair_m0 == F32(0.6)).all()
        else:
            assert (before[1] < 0.6).all() and (cs.rough == F32(0.6)).all()


# ---------------------------------------------------------------- through Blender
def test_the_export_reads_the_node():
    pytest.importorskip("bpy")
    from bpy_helpers import camera_only_scene, export_current, node_material
    from test_export import add_cube
    camera_only_scene()
    add_cube().data.materials.append(node_material("Hair", HAIR, opt_model="HUANG", opt_parametrization="MELANIN",
                                                   Melanin=0.4, Reflection=0.5))
    result = export_current()
    (closure,) = result.scene.materials.shaders[1].closures
    assert closure.kind == "PRINCIPLED_HAIR"
    assert closure.option("model") == "HUANG" and closure.option("parametrization") == "MELANIN"
    assert closure.input("Melanin").value == pytest.approx((0.4,)) and closure.input("R lobe").value == (0.5,)
    assert closure.input("Absorption Coefficient").value == pytest.approx((0.245531, 0.52, 1.365))
    assert not [w for w in result.warnings if "Hair" in w]


HAIR = "ShaderNodeBsdfHairPrincipled"


def hair_materials():
    """Principled Hair materials over both models and every parametrization and input."""
    from bpy_helpers import node_material
    return [
        node_material("Chiang colour", HAIR, opt_model="CHIANG", opt_parametrization="COLOR", Color=(0.8, 0.5, 0.3),
                      Coat=0.4, Offset=0.08),
        node_material("Chiang melanin", HAIR, opt_model="CHIANG", opt_parametrization="MELANIN", Melanin=0.35,
                      Melanin_Redness=0.6, Tint=(0.9, 0.7, 0.9), Random_Color=0.5, Random_Roughness=0.4, Random=0.9,
                      Radial_Roughness=0.5),
        node_material("Chiang absorption", HAIR, opt_model="CHIANG", opt_parametrization="ABSORPTION", Roughness=0.5,
                      IOR=1.4),
        node_material("Huang colour", HAIR, opt_model="HUANG", opt_parametrization="COLOR", Color=(0.7, 0.6, 0.4),
                      Aspect_Ratio=0.6, Roughness=0.35),
        node_material("Huang melanin", HAIR, opt_model="HUANG", opt_parametrization="MELANIN", Melanin=0.3,
                      Transmission=0.6, Offset=0.1),
        node_material("Huang absorption", HAIR, opt_model="HUANG", opt_parametrization="ABSORPTION", Roughness=0.5,
                      Aspect_Ratio=1.0, Reflection=2.0),
    ]


def test_principled_hair_on_spheres_matches_cycles():
    """On a mesh Cycles shades the node about each triangle's first edge (dPdu), its frame facing the viewer:
    six spheres, both models, every parametrization, lit by a lamp (light tree off, as for the Hair BSDF:
    test_parity_bsdf_nodes.hair_scene) and a dim world."""
    pytest.importorskip("bpy")
    from bpy_helpers import add_camera, compare_to_cycles, set_world
    from test_parity_bsdf_nodes import add_light, hair_scene, no_terminator_offset
    from test_parity_materials import grid_of_spheres
    scene = hair_scene(48, 32)
    grid_of_spheres(hair_materials(), 3)
    no_terminator_offset()
    set_world(scene, color=(0.05, 0.05, 0.06))
    add_light(scene, "AREA", (2, -3, 4), 600, size=2.0, rotation=(0.6, 0.3, 0.0))
    add_camera(scene, (0, -5.2, 1.0), (0, 0, 1.0), lens=45)
    compare_to_cycles(scene, samples=64, max_bounces=4)


def test_white_hair_in_a_furnace_matches_cycles(monkeypatch):
    """A white Chiang sphere and a white Huang one (no absorption) under a uniform white world, sampled as Cycles
    samples it: what the lobes keep of the light, bounce after bounce, is Cycles'."""
    pytest.importorskip("bpy")
    from bpy_helpers import add_camera, compare_to_cycles, new_scene, node_material, plain_world_sampling, set_world
    from test_parity_materials import sphere
    plain_world_sampling(monkeypatch)
    scene = new_scene(32, 16)
    for i, model in enumerate(("CHIANG", "HUANG")):
        sphere((1.1 * i - 0.55, 0, 0), node_material(f"White {model}", HAIR, opt_model=model,
                                                    opt_parametrization="COLOR", Color=(1.0, 1.0, 1.0)))
    set_world(scene, color=(1.0, 1.0, 1.0))
    add_camera(scene, (0, -4.0, 0), (0, 0, 0), lens=50)
    compare_to_cycles(scene, samples=32, max_bounces=8)
