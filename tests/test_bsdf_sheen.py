"""Cycles' sheen (kernels/bsdf/sheen.py): the table and its lookup, the LTC sampler against its pdf
(chi-square), eval against sample, albedo = the tabulated albedo, edge cases, and one small render
by Cycles (bpy) against our eval."""
import math
import os
import sys
import warnings

import numpy as np
import pytest

from ember.kernels import sampling
from ember.kernels.bsdf import sheen
from stats import mean_and_stderr
from test_bsdf_diffuse import (assert_eval_matches_sample, assert_sampler_matches_pdf, edge_directions,
                               uniforms, viewer)

N = 200_000
CASES = [(0.5, 0.5), (0.9, 0.6), (0.15, 1.0), (0.05, 0.35)]  # (mu, roughness)


def test_table_grid_and_lookup_follow_cycles_conventions():
    with np.load(sheen.TABLE_PATH) as data:
        np.testing.assert_array_equal(data["mu_grid"], np.arange(32, dtype=np.float32) / 31)
        np.testing.assert_array_equal(data["roughness_grid"], np.arange(32, dtype=np.float32) / 31)
    table = sheen.load_table()
    assert table.dtype == np.float32 and np.all(np.isfinite(table))
    assert np.all(table[0] > 0) and np.all((table[2] >= 0) & (table[2] <= 1))
    # Nodes read back exactly (x = mu fastest); clamping of mu to [0, 1] and r to [1e-3, 1].
    i, j = np.meshgrid(np.arange(32), np.arange(1, 32))
    a, b, alb = sheen.lookup_table_2d(table, (i / 31).astype(np.float32).ravel(), (j / 31).astype(np.float32).ravel())
    np.testing.assert_allclose(a, table[0, j, i].ravel(), rtol=1e-6)
    np.testing.assert_allclose(alb, table[2, j, i].ravel(), rtol=1e-6, atol=1e-9)
    lo = sheen.ltc_parameters(np.float32([-0.5, 2.0]), np.float32([0.0, 7.0]))
    hi = sheen.ltc_parameters(np.float32([0.0, 1.0]), np.float32([1e-3, 1.0]))
    np.testing.assert_array_equal(np.stack(lo), np.stack(hi))
    # Half way between nodes: the mean of the corners (bilinear).
    mid = sheen.lookup_table_2d(table, np.float32([10.5 / 31]), np.float32([20.5 / 31]))[0, 0]
    np.testing.assert_allclose(mid, table[0, 20:22, 10:12].mean(), rtol=1e-5)


@pytest.mark.parametrize("mu,roughness", CASES)
def test_sampler_matches_pdf_and_eval(mu, roughness):
    wo = viewer(mu, N, phi=1.1)  # off-axis azimuth: exercises the frame rotation
    wi, weight, pdf = sheen.sheen_sample(wo, np.float32(roughness), *uniforms(N, seed=20))
    assert np.all(wi[2][pdf > 0] > 0)
    assert_sampler_matches_pdf(wi, lambda d: sheen.sheen_eval(viewer(mu, len(d[0]), 1.1), d,
                                                               np.float32(roughness))[1], sub=16)
    assert_eval_matches_sample(wi, weight, pdf, *sheen.sheen_eval(wo, wi, np.float32(roughness)))
    albedo = sheen.sheen_albedo(np.float32([wo[2][0]]), np.float32(roughness))[0]
    np.testing.assert_array_equal(weight[pdf > 0], albedo)


@pytest.mark.parametrize("mu,roughness", CASES)
def test_albedo_is_the_tabulated_albedo(mu, roughness):
    """The integral of f_cos over the hemisphere by uniform sampling (independent of the LTC sampler)
    equals the tabulated albedo, within four standard errors: the LTC density integrates to 1."""
    x, y, z = sampling.sample_uniform_sphere(*uniforms(N, seed=21))
    wi = (x, y, np.abs(z))
    f_cos, _ = sheen.sheen_eval(viewer(mu, N), wi, np.float32(roughness))
    estimate, se = mean_and_stderr(2 * np.pi * f_cos.astype(np.float64))
    albedo = float(sheen.sheen_albedo(np.float32([mu]), np.float32(roughness))[0])
    assert albedo > 0.01 and abs(estimate - albedo) < 4 * se, (estimate, albedo, se)


def test_edge_cases_give_no_nan_and_no_warning():
    wo, wi = edge_directions()
    n = len(wo[0])
    u = np.linspace(0, 1 - 2 ** -24, n).astype(np.float32)
    with warnings.catch_warnings(), np.errstate(all="warn"):
        warnings.simplefilter("error")
        outs = []
        for r in (0.0, 0.02, 0.5, 1.0):  # 0 and 0.02: cells where Cycles drops the closure
            outs += [sheen.sheen_eval(wo, wi, np.float32(r)), sheen.sheen_sample(wo, np.float32(r), u, u[::-1])]
    for out in outs:
        for a in out:
            for c in (a if isinstance(a, tuple) else (a,)):
                assert np.all(np.isfinite(c)) and c.dtype == np.float32
    f_cos, pdf = sheen.sheen_eval(wo, wi, np.float32(0.0))
    steep = wo[2] >= 0.5  # r = 1e-3 away from grazing: albedo < 1e-5, dropped like Cycles
    assert not np.any(f_cos[steep]) and not np.any(pdf[steep])


def test_matches_cycles_render():
    """A few quads rendered by Cycles under a delta sun (pixel = albedo D exactly, see the tool) against
    sheen_eval. Tolerance: the table's fit residual (stored, <= 4e-6 relative) times a margin of 4, plus
    the direction rounding: Cycles uses the float32 triangle normal, ours differs by ~1e-7 rad, which
    moves D by ~1e-7 / z relative (z = cos of the light); we allow 1e-6 / z."""
    pytest.importorskip("bpy")
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))
    import fit_sheen_table as tool

    rng = np.random.default_rng(5)
    count, suns = 24, 3
    mus, rs = rng.uniform(0.05, 1.0, count), rng.uniform(0.15, 1.0, count)
    quads = tool.build_quads(mus, rs, rng.uniform(0, 2 * math.pi, count))
    local, values = tool.measure(quads, rs, suns=suns, log=lambda *_: None)
    mu_q = quads["normals"][:-1, 2]
    wo = tuple(np.tile(c, suns).astype(np.float32) for c in (np.sqrt(1 - mu_q ** 2), 0 * mu_q, mu_q))
    wi = tuple(local[..., k].ravel().astype(np.float32) for k in range(3))
    f_cos, _ = sheen.sheen_eval(wo, wi, np.tile(rs, suns).astype(np.float32))
    v = values.ravel()
    lit = np.isfinite(v) & (wi[2] > 0.02)
    assert lit.sum() > count  # about half the quads face each sun
    with np.load(sheen.TABLE_PATH) as data:
        fit_rms = float(np.nanmax(data["fit_rms"]))
    tolerance = (4 * fit_rms + 1e-6 / wi[2][lit]) * v[lit] + 1e-7
    err = np.abs(f_cos[lit] - v[lit])
    assert np.all(err <= tolerance), (err / v[lit]).max()


# ---------------------------------------------------------------- Ashikhmin velvet (kernels/bsdf/velvet.py)
@pytest.mark.parametrize("mu,sigma", [(0.5, 0.5), (0.2, 0.1), (0.9, 1.0), (0.05, 0.005)])
def test_velvet_sampler_is_uniform_and_matches_its_eval(mu, sigma):
    """Cycles samples the velvet uniformly over the hemisphere (pdf 1 / 2 pi), and eval at a sampled direction
    gives the sample's weight times its pdf; directions nearly along the normal's half vector are dropped."""
    from ember.kernels.bsdf import velvet
    wo = viewer(mu)
    wi, weight, pdf = velvet.velvet_sample(wo, np.full(N, sigma, np.float32), *uniforms())
    assert_sampler_matches_pdf(wi, lambda d: np.full(len(d[0]), 0.5 / math.pi, np.float32))
    f_cos, pdf_eval = velvet.velvet_eval(wo, wi, np.full(N, sigma, np.float32))
    assert_eval_matches_sample(wi, weight, pdf, f_cos, pdf_eval)


def test_velvet_eval_is_ashikhmins_sheen():
    """The lobe against its formula in float64 at a few pairs of directions: D = exp(-cot^2 h / s^2) / (pi s^2
    sin^4 h), G = min(1, 2 cos h cos v / cos hv, 2 cos h cos l / cos hv), f cos = D G / (4 cos v), s at least
    0.01; nothing with the light or the viewer below the surface."""
    from ember.kernels.bsdf import velvet
    rng = np.random.default_rng(3)
    n = 400
    def unit(v):
        return v / np.linalg.norm(v, axis=1, keepdims=True)
    wo = unit(rng.normal(size=(n, 3)))
    wi = unit(rng.normal(size=(n, 3)))
    sigma = rng.choice([0.005, 0.2, 0.6, 1.0], n)
    s2 = np.maximum(sigma, 0.01) ** 2
    h = unit(wo + wi)
    cos_h, cos_hv = h[:, 2], np.abs(np.einsum("ij,ij->i", wo, h))
    g = np.minimum(1.0, np.minimum(2 * cos_h * wo[:, 2] / cos_hv, 2 * cos_h * wi[:, 2] / cos_hv))
    sin2 = 1 - cos_h ** 2
    d = np.exp(-(cos_h ** 2 / sin2) / s2) / (math.pi * s2 * sin2 ** 2)
    expect = np.where((wo[:, 2] > 0) & (wi[:, 2] > 0), 0.25 * d * g / wo[:, 2], 0.0)
    f_cos, pdf = velvet.velvet_eval(tuple(wo.T.astype(np.float32)), tuple(wi.T.astype(np.float32)),
                                    sigma.astype(np.float32))
    np.testing.assert_allclose(f_cos, expect, rtol=2e-4, atol=1e-7)
    np.testing.assert_array_equal(pdf > 0, (wo[:, 2] > 0) & (wi[:, 2] > 0))
    assert (expect > 1e-3).sum() > n // 10
