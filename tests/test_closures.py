"""The closure mixture of kernels.bsdf.closures, built by the shading nodes as the integrator builds it:
sampling against the mixture pdf, weights against eval / pdf, energy, and Cycles' layering rules."""
import numpy as np
import pytest

from ember.kernels.bsdf import lobes
from ember.kernels.scene import Closure, Materials, Param, Shader
from ember.kernels.shading import Shading
from stats import assert_chi2, mean_and_stderr

N = 200_000
THETA_BINS, PHI_BINS = 24, 24


class FakeHit:
    """n hits on the plane z = 0 with normal +z, seen from direction wo; material 0."""

    def __init__(self, n, wo, backfacing=False):
        wo = np.asarray(wo, np.float64) / np.linalg.norm(wo)
        ones = np.ones(n, np.float32)
        self.ns = self.ng = (0 * ones, 0 * ones, ones)
        self.d = tuple(np.float32(-c) * ones for c in wo)
        self.p = (0 * ones, 0 * ones, 0 * ones)
        self.u = self.v = 0 * ones
        self.mat = np.zeros(n, np.int32)
        self.prim = np.zeros(n, np.int64)
        self.backfacing = np.full(n, backfacing)

    def __len__(self):
        return len(self.mat)


def principled(**inputs):
    params = tuple((k.replace("_", " "), Param.of(v)) for k, v in inputs.items())
    return Closure("PRINCIPLED", params, (("distribution", "MULTI_GGX"),))


def closure_set(closure, n=N, wo=(0.4, 0.2, 0.8), backfacing=False):
    shading = Shading(Materials((Shader((closure,)),)), [])
    return shading.surface(FakeHit(n, wo, backfacing)).closures


def sphere_bins(x, y, z):
    theta = np.arccos(np.clip(z.astype(np.float64), -1, 1))
    phi = np.arctan2(y, x).astype(np.float64)
    counts, _, _ = np.histogram2d(theta, phi, bins=[THETA_BINS, PHI_BINS], range=[[0, np.pi], [-np.pi, np.pi]])
    return counts


def expected_counts(cs, n, sub=6):
    """Integrate the mixture pdf over every (theta, phi) bin by a sub x sub midpoint rule."""
    t_edges = np.linspace(0, np.pi, THETA_BINS + 1)
    p_edges = np.linspace(-np.pi, np.pi, PHI_BINS + 1)
    dt, dp = t_edges[1] - t_edges[0], p_edges[1] - p_edges[0]
    tt = (np.arange(THETA_BINS * sub) + 0.5) * dt / sub
    pp = -np.pi + (np.arange(PHI_BINS * sub) + 0.5) * dp / sub
    T, P = np.meshgrid(tt, pp, indexing="ij")
    w = tuple(np.float32(c).ravel() for c in (np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)))
    m = len(w[0])
    hits = np.arange(m)
    small = closure_set(cs, n=m)
    _, pdf = small.eval_at(hits, w)
    pdf = pdf.reshape(T.shape).astype(np.float64) * np.sin(T) * (dt / sub) * (dp / sub)
    return pdf.reshape(THETA_BINS, sub, PHI_BINS, sub).sum(axis=(1, 3)) * n


def draw(cs, n=N, seed=1):
    rng = np.random.default_rng(seed)
    u = [rng.random(n, dtype=np.float32) for _ in range(4)]
    return cs.sample(u[0], u[1], u[2], u[3])


LAYERED = principled(Base_Color=(0.8, 0.3, 0.2), Metallic=0.3, Roughness=0.4, Coat_Weight=0.5,
                     Coat_Roughness=0.3, Sheen_Weight=0.6, Sheen_Roughness=0.4, Diffuse_Roughness=0.5)


def test_principled_mixture_samples_match_the_mixture_pdf():
    cs = closure_set(LAYERED)
    assert sorted(set(cs.lobe.tolist())) == [lobes.OREN_NAYAR, lobes.SHEEN, lobes.REFLECTION]
    s = draw(cs)
    ok = s.pdf > 0
    assert not s.delta.any()
    # Samples a lobe cannot use (a microfacet's reflection below the horizon) are the pdf's missing mass:
    # expected counts are per draw, not per valid sample.
    assert_chi2(sphere_bins(*(c[ok] for c in s.wi)), expected_counts(LAYERED, N))


def test_mixture_weight_is_f_over_the_mixture_pdf():
    cs = closure_set(LAYERED, n=5000)
    s = draw(cs, n=5000)
    f, pdf = cs.eval_at(np.arange(5000), s.wi)
    ok = s.pdf > 0
    np.testing.assert_allclose(pdf[ok], s.pdf[ok], rtol=1e-5)
    np.testing.assert_allclose(f[:, ok] / pdf[ok], s.weight[:, ok], rtol=2e-4, atol=1e-6)


def test_sampled_and_integrated_albedo_agree():
    """E[weight] under the mixture's own sampling equals the integral of f over the sphere (by uniform
    sphere sampling): two independent estimators of the same albedo."""
    cs = closure_set(LAYERED)
    s = draw(cs, seed=3)
    sampled, se_s = mean_and_stderr(s.weight, axis=1)
    rng = np.random.default_rng(4)
    z = 1 - 2 * rng.random(N)
    phi = 2 * np.pi * rng.random(N)
    r = np.sqrt(1 - z * z)
    w = tuple(np.float32(c) for c in (r * np.cos(phi), r * np.sin(phi), z))
    f, _ = cs.eval_at(np.arange(N), w)
    integral, se_i = mean_and_stderr(f * 4 * np.pi, axis=1)
    assert np.all(np.abs(sampled - integral) < 4 * np.hypot(se_s, se_i)), (sampled, integral)


@pytest.mark.parametrize("backfacing", [False, True])
def test_compensated_glass_keeps_all_energy(backfacing):
    """Principled glass with multiscatter GGX, white: every path goes on (reflected or refracted) with
    expected weight 1. Tolerance: 4 standard errors plus the albedo tables' own error (< 1e-3)."""
    cs = closure_set(principled(Base_Color=(1, 1, 1), Transmission_Weight=1.0, Roughness=0.3), wo=(0.3, 0.1, 0.9),
                     backfacing=backfacing)
    s = draw(cs, seed=5)
    mean, se = mean_and_stderr(s.weight, axis=1)
    assert np.all(np.abs(mean - 1.0) < 4 * se + 2e-3), mean
    assert 0.0 < s.transmit.mean() < 1.0


def test_layers_dim_what_lies_below():
    """Cycles' closure_layering_weight: a white coat over a diffuse base takes the coat's albedo off the
    base's weight; alpha 0.25 leaves three quarters to the transparent closure."""
    plain = closure_set(principled(Base_Color=(0.5, 0.5, 0.5), Specular_IOR_Level=0.0), n=4)
    coated = closure_set(principled(Base_Color=(0.5, 0.5, 0.5), Specular_IOR_Level=0.0, Coat_Weight=1.0), n=4)
    base = plain.weight[:, plain.lobe == lobes.LAMBERT][:, 0]
    under = coated.weight[:, coated.lobe == lobes.LAMBERT][:, 0]
    assert np.all(under < base) and np.all(under > 0.85 * base)  # a clear coat reflects about 4-10%
    cut = closure_set(principled(Base_Color=(0.5, 0.5, 0.5), Alpha=0.25, Specular_IOR_Level=0.0), n=4)
    np.testing.assert_allclose(cut.weight[:, cut.lobe == lobes.TRANSPARENT], 0.75)
    np.testing.assert_allclose(cut.weight[:, cut.lobe == lobes.LAMBERT], 0.5 * 0.25)


def test_mix_factor_weights_and_zero_weight_closures_are_dropped():
    diffuse = Closure("DIFFUSE", (("Color", Param.of((0.8, 0.8, 0.8))),), (), ((Param.of(0.25), False),))
    glossy = Closure("GLOSSY", (("Color", Param.of((1, 1, 1))), ("Roughness", Param.of(0.3))),
                     (("distribution", "GGX"),), ((Param.of(0.25), True),))
    shading = Shading(Materials((Shader((diffuse, glossy)),)), [])
    cs = shading.surface(FakeHit(3, (0, 0, 1))).closures
    np.testing.assert_allclose(cs.weight[:, cs.lobe == lobes.LAMBERT], 0.8 * 0.75)
    np.testing.assert_allclose(cs.weight[:, cs.lobe == lobes.REFLECTION], 0.25)
    black = Closure("DIFFUSE", (("Color", Param.of((0, 0, 0))),))
    assert len(Shading(Materials((Shader((black,)),)), []).surface(FakeHit(3, (0, 0, 1))).closures) == 0


def test_mixed_distributions_in_one_table():
    """Glossy GGX, Beckmann and Ashikhmin-Shirley closures of one hit: each row evaluates with its own
    distribution, the mixture's samples follow its pdf and weigh f / pdf."""
    def glossy(distribution, roughness):
        return Closure("GLOSSY", (("Color", Param.of((0.8, 0.7, 0.6))), ("Roughness", Param.of(roughness))),
                       (("distribution", distribution),))
    shader = Shader((glossy("GGX", 0.5), glossy("BECKMANN", 0.4), glossy("ASHIKHMIN_SHIRLEY", 0.6)))

    def mixture(n):
        return Shading(Materials((shader,)), []).surface(FakeHit(n, (0.4, 0.2, 0.8))).closures
    cs = mixture(N)
    assert sorted(cs.lobe[:3].tolist()) == [lobes.REFLECTION, lobes.REFLECTION, lobes.ASHIKHMIN_SHIRLEY]
    assert sorted(cs.dist[cs.lobe == lobes.REFLECTION][:2].tolist()) == [0.0, 1.0]
    s = draw(cs, seed=6)
    ok = s.pdf > 0
    assert not s.delta.any()
    f, pdf = cs.eval_at(np.arange(N)[ok][:5000], tuple(c[ok][:5000] for c in s.wi))
    np.testing.assert_allclose(pdf, s.pdf[ok][:5000], rtol=1e-5)
    np.testing.assert_allclose(f / pdf, s.weight[:, ok][:, :5000], rtol=2e-4, atol=1e-6)
    # The expected histogram: the mixture pdf integrated over the bins, times all draws (the lobes lose
    # the samples they send below the horizon, and their pdfs integrate to less than 1 accordingly).
    sub = 6
    t_edges = np.linspace(0, np.pi, THETA_BINS + 1)
    dt, dp = t_edges[1] - t_edges[0], 2 * np.pi / PHI_BINS
    tt = (np.arange(THETA_BINS * sub) + 0.5) * dt / sub
    pp = -np.pi + (np.arange(PHI_BINS * sub) + 0.5) * dp / sub
    T, P = np.meshgrid(tt, pp, indexing="ij")
    w = tuple(np.float32(c).ravel() for c in (np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)))
    _, grid_pdf = mixture(len(w[0])).eval_at(np.arange(len(w[0])), w)
    expected = (grid_pdf.reshape(T.shape) * np.sin(T) * (dt / sub) * (dp / sub)).reshape(
        THETA_BINS, sub, PHI_BINS, sub).sum(axis=(1, 3)) * N  # lost samples (below the horizon) included
    assert_chi2(sphere_bins(*(c[ok] for c in s.wi)), expected)


@pytest.mark.parametrize("closure, expected, after_blur", [
    (principled(Metallic=1.0, Roughness=0.0), False, True),             # a mirror: singular only
    (principled(Transmission_Weight=1.0, Roughness=0.0), False, True),  # smooth glass
    (principled(Alpha=0.0), False, False),                              # transparent only, blur or not
    (principled(Metallic=1.0, Roughness=0.2), True, True),
    (principled(Transmission_Weight=1.0, Roughness=0.0, Coat_Weight=0.5, Coat_Roughness=0.3), True, True),
    (principled(Metallic=1.0, Roughness=0.0, Alpha=0.5), False, True),
    (principled(Roughness=0.0), True, True),                            # smooth plastic: its diffuse base
])
def test_next_event_skips_hits_whose_closures_all_evaluate_to_zero(closure, expected, after_blur):
    """ClosureSet.evaluable: False exactly where eval_at is zero in every direction, so that next-event
    estimation may skip those hits without changing the image."""
    cs = closure_set(closure, n=4000)
    evaluable = cs.evaluable()
    assert evaluable.tolist() == [expected] * 4000
    rng = np.random.default_rng(2)
    w = rng.normal(size=(3, 4000)).astype(np.float32)
    w /= np.linalg.norm(w, axis=0)
    f, pdf = cs.eval_at(np.arange(4000), tuple(w))
    assert ((f > 0).any(axis=0) | (pdf > 0)).any() == expected
    assert not ((f > 0).any(axis=0) & ~evaluable).any()
    # Filter Glossy makes a mirror rough: then it is evaluated.
    cs.blur(np.full(4000, 0.3, np.float32))
    assert cs.evaluable().tolist() == [after_blur] * 4000


@pytest.mark.parametrize("switches", [(False, True), (True, False), (False, False)])
def test_caustics_switches_drop_closures_after_diffuse_bounces(switches):
    """Cycles' Caustics switches (svm_node_closure_bsdf): at hits whose ray comes from a diffuse bounce,
    reflective caustics off makes no specular, metal or coat closure, and the diffuse below keeps the light
    their layers would have taken; refractive caustics off zeroes glass's transmission tint (its reflection
    tint with reflective off; no glass closure with both off). Hits reached from the camera or by a glossy
    bounce keep every closure."""
    from ember.kernels.interaction import RayInfo
    from ember.kernels.paths import DIFFUSE, GLOSSY, REFLECT, TRANSMIT
    reflective, refractive = switches
    labels = np.array([0, DIFFUSE | REFLECT, GLOSSY | REFLECT, DIFFUSE | TRANSMIT], np.int32)
    after_diffuse = (labels & DIFFUSE) != 0

    def built(closure, caustics):
        hit = FakeHit(len(labels), (0.4, 0.2, 0.8))
        state = np.zeros((4, len(labels)), np.int32)
        state[0] = labels
        hit.ray = RayInfo(np.ones(len(labels), np.int32), np.zeros(len(labels), np.int32), lobes=state,
                          caustics=caustics)
        return Shading(Materials((Shader((closure,)),)), []).surface(hit).closures

    def lobes_at(cs, kind):
        return np.isin(np.arange(len(labels)), cs.hit[cs.lobe == kind])

    layered = principled(Base_Color=(0.5, 0.5, 0.5), Roughness=0.3, Coat_Weight=1.0, Metallic=0.25)
    every, switched = built(layered, None), built(layered, switches)
    reflecting = lobes_at(switched, lobes.REFLECTION)
    assert lobes_at(every, lobes.REFLECTION).all()
    np.testing.assert_array_equal(reflecting, ~after_diffuse if not reflective else True)
    diffuse_every = every.weight[:, every.lobe == lobes.LAMBERT]
    diffuse_switched = switched.weight[:, switched.lobe == lobes.LAMBERT]
    if reflective:
        np.testing.assert_array_equal(diffuse_switched, diffuse_every)
    else:  # no layer above it: the base's weight times (1 - metallic) alone
        np.testing.assert_allclose(diffuse_switched[:, after_diffuse], 0.5 * 0.75, rtol=1e-6)
        np.testing.assert_array_equal(diffuse_switched[:, ~after_diffuse], diffuse_every[:, ~after_diffuse])
        assert np.all(diffuse_every < 0.5 * 0.75 * 0.95)

    glass = principled(Base_Color=(0.8, 0.9, 1.0), Transmission_Weight=1.0, Roughness=0.2)
    cs = built(glass, switches)
    made = lobes_at(cs, lobes.GLASS)
    np.testing.assert_array_equal(made, ~after_diffuse if not (reflective or refractive) else True)
    rows = np.flatnonzero(cs.lobe == lobes.GLASS)
    diffuse_rows = after_diffuse[cs.hit[rows]]
    reflection_tint, transmission_tint = cs.c1[:, rows], cs.c2[:, rows]
    assert np.all(reflection_tint[:, ~diffuse_rows] == 1) and np.all(transmission_tint[:, ~diffuse_rows] > 0.8)
    assert np.all((reflection_tint[:, diffuse_rows] == 0) == (not reflective))
    assert np.all((transmission_tint[:, diffuse_rows] == 0) == (not refractive))

    metal = Closure("METALLIC", (("Roughness", Param.of(0.3)),), (("distribution", "MULTI_GGX"),))
    np.testing.assert_array_equal(lobes_at(built(metal, switches), lobes.REFLECTION),
                                  ~after_diffuse if not reflective else True)
    refraction = Closure("REFRACTION", (("Roughness", Param.of(0.3)),), (("distribution", "GGX"),))
    np.testing.assert_array_equal(lobes_at(built(refraction, switches), lobes.REFRACTION),
                                  ~after_diffuse if not refractive else True)


def test_closure_picked_by_the_directions_own_number_samples_the_mixture():
    """NEE_MIS picks the closure with the direction's first number, rescaled (choose_rescaled): the same
    closures in the same proportions, the number uniform again within each, and the mixture pdf sampled."""
    cs = closure_set(LAYERED)
    u = np.random.default_rng(3).random(N, dtype=np.float32)
    row, stretched = cs.choose_rescaled(u)
    np.testing.assert_array_equal(row, cs.choose(u))
    assert stretched.min() >= 0 and stretched.max() < 1
    lobe = cs.lobe[row]
    kinds, picked = np.unique(lobe, return_counts=True)
    assert len(kinds) == 3 and picked.min() > 1000
    for kind in kinds:   # uniform within each closure: its deciles hold a tenth each (chi-square)
        mine = stretched[lobe == kind]
        counts = np.histogram(mine, bins=10, range=(0, 1))[0]
        assert_chi2(counts[None, :].astype(float), np.full((1, 10), len(mine) / 10))
    rng = np.random.default_rng(4)
    u1, u2, uc = (rng.random(N, dtype=np.float32) for _ in range(3))
    s = cs.sample(None, u1, u2, uc)
    ok = s.pdf > 0
    assert_chi2(sphere_bins(*(c[ok] for c in s.wi)), expected_counts(LAYERED, N))


def test_every_lobe_is_in_the_one_table_and_the_integrator_names_none():
    """bsdf/registry.py's LOBES holds every lobe id, with a sample function (the Ray Portal's is the closure
    table's own) and an eval for every lobe that is not always singular; lobes.CLASSES says what each is. The
    integrator asks the closure set about two-branched lobes and never names one."""
    import os
    import re

    from ember.kernels.bsdf import registry
    ids = set(range(len(lobes.CLASSES)))
    assert set(registry.LOBES) == ids
    for k, lobe in registry.LOBES.items():
        assert (lobe.eval is None) == (k in lobes.SINGULAR_LOBES), lobe.name
        assert (lobe.sample is None) == (k == lobes.PORTAL), lobe.name
    names = [n for n in dir(lobes) if n.isupper()]
    source = open(os.path.join(os.path.dirname(lobes.__file__), "..", "integrator.py")).read()
    assert not [n for n in names if re.search(r"\b" + n + r"\b", source)]
