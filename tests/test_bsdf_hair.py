"""Cycles' Hair BSDF lobes (kernels/bsdf/hair.py): both samplers against the density they sample (chi-square
in the hair's own angles), eval against Cycles' formulas at hand-computed angles and against the samplers
where Cycles' eval and sampler agree, weight 1, and no NaN or warning on edge cases."""
import math
import warnings

import numpy as np
import pytest

from ember.kernels.bsdf import hair
from stats import assert_chi2
from test_bsdf_diffuse import edge_directions, uniforms

N = 200_000
F32 = np.float32
THETA_BINS, PHI_BINS = 24, 24


def unit(*v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def repeat(v, n):
    return tuple(np.full(n, c, F32) for c in v)


TANGENT = unit(0.2, 0.9, 0.3)   # not perpendicular to the normal (0, 0, 1), as on a triangle's edge
VIEWER = unit(0.3, -0.4, 0.85)


def hair_angles(w, tangent=TANGENT, viewer=VIEWER):
    """(theta latitude about T, phi azimuth about T from the viewer's azimuth), float64."""
    w = np.stack([np.asarray(c, np.float64) for c in w], axis=-1)
    z = w @ tangent
    locy = viewer - tangent * (viewer @ tangent)
    locy /= np.linalg.norm(locy)
    locx = np.cross(locy, tangent)
    return np.arcsin(np.clip(z, -1, 1)), np.arctan2(-(w @ locx), w @ locy)


def theta_density(theta, r1, offset, viewer=VIEWER, tangent=TANGENT):
    """The samplers' density of theta_i: a Cauchy lobe in theta_h = (theta_i + theta_r) / 2 about offset,
    truncated to theta_i in (-pi/2, pi/2) (d theta_h = d theta_i / 2)."""
    theta_r = math.asin(viewer @ tangent)
    a = math.atan(((math.pi / 2 + theta_r) / 2 - offset) / r1)
    b = math.atan(((-math.pi / 2 + theta_r) / 2 - offset) / r1)
    t = (theta + theta_r) / 2 - offset
    return r1 / (2 * (t * t + r1 * r1) * (a - b))


def phi_density(phi, r2, transmission):
    """The samplers' density of phi: reflection cos(phi / (2 r2)) / (4 r2) on |phi| <= pi r2; transmission a
    Cauchy lobe about pi of width r2, truncated to pi +- pi/2."""
    if transmission:
        p = np.mod(phi, 2 * math.pi) - math.pi
        c = 2 * math.atan(math.pi / (2 * r2))
        return np.where(np.abs(p) <= math.pi / 2, r2 / (c * (p * p + r2 * r2)), 0.0)
    return np.where(np.abs(phi) <= math.pi * r2, np.cos(phi / (2 * r2)) / (4 * r2), 0.0)


def expected_counts(r1, r2, offset, transmission, n, sub=8):
    """n x the density's integral over (theta, phi) bins (midpoint rule, sub x sub points per bin)."""
    te = np.linspace(-math.pi / 2, math.pi / 2, THETA_BINS * sub + 1)
    pe = np.linspace(-math.pi, math.pi, PHI_BINS * sub + 1)
    tc, pc = (te[1:] + te[:-1]) / 2, (pe[1:] + pe[:-1]) / 2
    cell = theta_density(tc, r1, offset)[:, None] * phi_density(pc, r2, transmission)[None, :] * \
        (te[1] - te[0]) * (pe[1] - pe[0])
    return cell.reshape(THETA_BINS, sub, PHI_BINS, sub).sum(axis=(1, 3)) * n


CASES = [(0.1, 1.0, 0.0), (0.3, 0.4, 0.1), (0.6, 0.8, -0.2)]


@pytest.mark.parametrize("transmission", [False, True])
@pytest.mark.parametrize("r1,r2,offset", CASES)
def test_sampler_draws_its_density(r1, r2, offset, transmission):
    sample = hair.hair_transmission_sample if transmission else hair.hair_reflection_sample
    wi, weight, pdf = sample(repeat(VIEWER, N), repeat(TANGENT, N), F32(r1), F32(r2), F32(offset), *uniforms(N, 41))
    ok = pdf > 0
    assert ok.mean() > 0.999 and np.all(weight[ok] == 1.0)
    theta, phi = hair_angles(wi)
    counts, _, _ = np.histogram2d(theta[ok], phi[ok], bins=[THETA_BINS, PHI_BINS],
                                  range=[[-math.pi / 2, math.pi / 2], [-math.pi, math.pi]])
    assert_chi2(counts, expected_counts(r1, r2, offset, transmission, N))


@pytest.mark.parametrize("transmission", [False, True])
def test_eval_is_the_sampled_pdf_where_cycles_eval_and_sampler_agree(transmission):
    """RoughnessV 1: the reflection sampler's pdf is its density; where the eval does not cut the lobe (its
    side of the normal; reflection within 90 degrees of the viewer's azimuth) eval = pdf = the sample's."""
    sample, evaluate = ((hair.hair_transmission_sample, hair.hair_transmission_eval) if transmission else
                        (hair.hair_reflection_sample, hair.hair_reflection_eval))
    args = (repeat(TANGENT, 5000), F32(0.3), F32(1.0), F32(0.05))
    wo = repeat(VIEWER, 5000)
    wi, weight, pdf = sample(wo, *args, *uniforms(5000, 42))
    f_cos, pdf_eval = evaluate(wo, wi, *args)
    theta, phi = hair_angles(wi)
    kept = (wi[2] < 0) if transmission else (wi[2] >= 0) & (np.cos(phi) >= 0)
    assert 0.1 < kept.mean() < 0.95
    # Away from the hair's axis, where 1 / cos(theta) magnifies float32 rounding of the angles.
    inner = kept & (np.abs(theta) < 1.3)
    np.testing.assert_allclose(pdf_eval[inner], pdf[inner], rtol=2e-3)
    np.testing.assert_array_equal(f_cos, pdf_eval)
    assert not pdf_eval[~kept].any()


def test_values_at_hand_computed_angles():
    """Tangent along x, normal z, viewer perpendicular to the hair (theta_r = 0): reflection toward
    theta_i = 0.2, 60 degrees round the hair, r1 = 0.2, r2 = 0.5, offset 0.05."""
    r1, r2, offset = 0.2, 0.5, 0.05
    tangent = (1.0, 0.0, 0.0)
    viewer = unit(0.0, -0.6, 0.8)
    theta_i, phi = 0.2, math.radians(-60)
    locy = np.array(viewer)
    locx = np.cross(locy, tangent)
    w = math.cos(phi) * math.cos(theta_i) * locy - math.sin(phi) * math.cos(theta_i) * locx + \
        math.sin(theta_i) * np.array(tangent)
    a = math.atan((math.pi / 4 - offset) / r1)
    b = math.atan((-math.pi / 4 - offset) / r1)
    t = theta_i / 2 - offset
    theta_pdf = r1 / (2 * (t * t + r1 * r1) * (a - b) * math.cos(theta_i))
    expected = theta_pdf * math.cos(phi / (2 * r2)) / (4 * r2)
    f_cos, pdf = hair.hair_reflection_eval(repeat(viewer, 1), repeat(w, 1), repeat(tangent, 1), F32(r1), F32(r2),
                                           F32(offset))
    assert w[2] > 0
    np.testing.assert_allclose(pdf, expected, rtol=1e-4)
    np.testing.assert_allclose(f_cos, expected, rtol=1e-4)
    # The same direction mirrored below the normal: only transmission sees it, a Cauchy lobe about pi.
    below = (w[0], w[1], -w[2])
    _, phi_b = hair_angles(repeat(below, 1), np.array(tangent), np.array(viewer))
    p = math.pi - abs(phi_b[0])
    c = 2 * math.atan(math.pi / (2 * r2))
    theta_b = math.asin(below[0])
    t = theta_b / 2 - offset
    expected_t = r1 / (2 * (t * t + r1 * r1) * (a - b) * math.cos(theta_b)) * r2 / (c * (p * p + r2 * r2))
    f_t, _ = hair.hair_transmission_eval(repeat(viewer, 1), repeat(below, 1), repeat(tangent, 1), F32(r1), F32(r2),
                                         F32(offset))
    np.testing.assert_allclose(f_t, expected_t, rtol=1e-4)
    assert not hair.hair_reflection_eval(repeat(viewer, 1), repeat(below, 1), repeat(tangent, 1), F32(r1), F32(r2),
                                         F32(offset))[0].any()


def test_edge_cases_give_no_nan_and_no_warning():
    wo, wi = edge_directions()
    n = len(wo[0])
    u = np.linspace(0, 1 - 2 ** -24, n).astype(F32)
    tangents = [repeat((1.0, 0.0, 0.0), n), repeat((0.0, 0.0, 1.0), n), repeat((0.0, 0.0, 0.0), n)]
    with warnings.catch_warnings(), np.errstate(all="warn"):
        warnings.simplefilter("error")
        outs = []
        for tangent in tangents:
            for r1, r2 in ((0.001, 0.001), (1.0, 1.0)):
                args = (tangent, F32(r1), F32(r2), F32(0.1))
                outs += [hair.hair_reflection_eval(wo, wi, *args), hair.hair_transmission_eval(wo, wi, *args),
                         hair.hair_reflection_sample(wo, *args, u, u[::-1]),
                         hair.hair_transmission_sample(wo, *args, u, u[::-1])]
    for out in outs:
        for a in out:
            for c in (a if isinstance(a, tuple) else (a,)):
                assert np.all(np.isfinite(c)) and c.dtype == np.float32


def test_the_reflection_sampler_reports_cycles_pdf():
    """Cycles' reflection sampler reports phi_pdf = cos(phi / 2) / (4 r2), not its density cos(phi / (2 r2)) /
    (4 r2), for RoughnessV below 1: the MIS weights take that pdf, as Cycles' do."""
    r1, r2, offset = 0.3, 0.4, 0.0
    n = 2000
    wi, _, pdf = hair.hair_reflection_sample(repeat(VIEWER, n), repeat(TANGENT, n), F32(r1), F32(r2), F32(offset),
                                             *uniforms(n, 43))
    theta, phi = hair_angles(wi)
    inner = np.abs(theta) < 1.3
    reported = theta_density(theta, r1, offset) / np.cos(theta) * np.cos(phi / 2) / (4 * r2)
    np.testing.assert_allclose(pdf[inner], reported[inner], rtol=2e-3)


def test_the_closure_takes_the_triangles_edge_and_its_samples_any_side():
    """Unlinked, a hair closure's tangent is its triangle's p2 - p0; its samples keep the sampler's weight (the
    colour), wherever they point, and leave the side test to the integrator (any_side); the Transmission Color
    pass counts the transmission component (Cycles' CLOSURE_IS_BSDF_TRANSMISSION)."""
    from ember.kernels.bsdf import light_passes, lobes
    from ember.kernels.scene import Closure, Materials, Param, Shader
    from ember.kernels.shading import Shading
    from test_closures import FakeHit

    class EdgeHit(FakeHit):
        def edges(self, idx):
            return np.tile(F32([[1, 0, 0]]), (len(idx), 1)), np.tile(F32([[0.6, 0.8, 0]]), (len(idx), 1))

    n = 4000
    color = (0.9, 0.6, 0.3)
    for component, lobe in (("Reflection", lobes.HAIR_REFLECTION), ("Transmission", lobes.HAIR_TRANSMISSION)):
        closure = Closure("HAIR", (("Color", Param.of(color)), ("RoughnessU", Param.of(0.3))),
                          (("component", component),))
        cs = Shading(Materials((Shader((closure,)),)), []).surface(EdgeHit(n, (0.3, -0.2, 0.9))).closures
        assert (cs.lobe == lobe).all()
        np.testing.assert_allclose(np.stack(cs.hair_t)[:, 0], [0.6, 0.8, 0.0], rtol=1e-6)
        rng = np.random.default_rng(44)
        s = cs.sample(*(rng.random(n, dtype=F32) for _ in range(4)))
        ok = s.pdf > 0
        assert s.any_side[ok].all() and (s.transmit[ok] == (component == "Transmission")).all()
        assert (s.wi[2][ok] < 0).any() and (s.wi[2][ok] > 0).any()  # no side test
        np.testing.assert_allclose(s.weight[:, ok], np.float32(color)[:, None].repeat(ok.sum(), axis=1), rtol=1e-5)
        _, _, transmission = light_passes.class_albedo(cs, n)
        assert transmission.any() == (component == "Transmission")


def test_the_export_reads_the_component_and_a_linked_tangent():
    pytest.importorskip("bpy")
    from bpy_helpers import camera_only_scene, export_current
    from test_export import add_cube
    from test_parity_bsdf_nodes import hair_card
    camera_only_scene()
    add_cube().data.materials.append(hair_card("Card", "Transmission", offset=0.2))
    add_cube(location=(3, 0, 0)).data.materials.append(hair_card("Edges", uv_tangent=False))
    result = export_current()
    card, edges = (result.scene.materials.shaders[i].closures[0] for i in (1, 2))
    assert card.kind == edges.kind == "HAIR"
    assert card.option("component") == "Transmission" and edges.option("component") == "Reflection"
    assert card.input("Tangent") is not None and edges.input("Tangent") is None
    assert card.input("Offset").value == pytest.approx((0.2,))
    assert not [w for w in result.warnings if "Hair" in w]
