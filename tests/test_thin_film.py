"""Thin-film iridescence (kernels/bsdf/thin_film.py) against the published formula, its limits, and the
closures that carry it, as Cycles sets them up (`bsdf_util.h`, `bsdf_microfacet.h`, `svm/closure.h`).

The reference is independent of Cycles' series: the exact Airy reflectance of the film stack,
|(r12 + r23 e^{i delta}) / (1 + r12 r23 e^{i delta})|^2 with signed (complex, for a conductor n + ik) Fresnel
amplitudes and delta = 2 pi OPD / lambda, averaged over the two polarisations and integrated against the
spectral weights of each RGB channel. Those weights are recovered from the shipped Fourier table by an
inverse FFT (the spectrum sampled at wavenumbers k pi / 60 per um, as Cycles' table is made), so the test
checks the optics (interfaces, phases, OPD, the Airy sum and its truncation, the table lookup), not the CIE
data. Cycles' series stops after three round trips and interpolates the table linearly: within 1.5e-3.
"""
import numpy as np
import pytest

from ember.kernels.bsdf import fresnel as fr
from ember.kernels.bsdf import microfacet_closures as mfc
from ember.kernels.bsdf import thin_film as tf
from ember.kernels.scene import Closure, Param
from test_closures import closure_set, principled

TABLE_SAMPLES = 1022


def spectral_weights():
    """(3, 1022) weights of each channel over wavenumbers (3, 1022) in 1/um, summing to 1."""
    t = tf.rgb_table().astype(np.float64)
    w = np.fft.irfft(t[:3] + 1j * t[3:], n=TABLE_SAMPLES, axis=1)
    return w, np.arange(TABLE_SAMPLES) * np.pi / 60.0


def amplitudes(n_i, n_t, cos_i):
    """Signed amplitude reflection coefficients (s, p) from n_i into n_t (complex for a conductor), and the
    (complex) cosine in n_t."""
    sin_i = np.sqrt(1 - cos_i * cos_i + 0j)
    cos_t = np.sqrt(1 - (n_i * sin_i / n_t) ** 2 + 0j)
    r_s = (n_i * cos_i - n_t * cos_t) / (n_i * cos_i + n_t * cos_t)
    r_p = (n_t * cos_i - n_i * cos_t) / (n_t * cos_i + n_i * cos_t)
    return r_s, r_p, cos_t


def airy_reference(cos1, thickness_nm, film_ior, substrate):
    """(3,) RGB reflectance of a film over a substrate of (complex) IOR, outside IOR 1."""
    w, wavenumber = spectral_weights()
    r12_s, r12_p, cos2 = amplitudes(1.0, film_ior, cos1)
    r23_s, r23_p, _ = amplitudes(film_ior, substrate, cos2)
    phase = np.exp(2j * np.pi * wavenumber * 2 * film_ior * thickness_nm * cos2.real / 1000.0)
    reflect = sum(0.5 * np.abs((r12 + r23 * phase) / (1 + r12 * r23 * phase)) ** 2
                  for r12, r23 in ((r12_s, r23_s), (r12_p, r23_p)))
    return (w * reflect[None, :]).sum(axis=1)


def one(x):
    return np.array([x], np.float32)


@pytest.mark.parametrize("cos1, thickness, film_ior, eta", [
    (1.0, 500.0, 1.33, 1.5), (0.6, 300.0, 1.8, 1.5), (0.3, 800.0, 1.4, 1.0), (0.9, 150.0, 2.2, 1.5),
    (0.45, 1200.0, 1.25, 1.7)])
def test_dielectric_film_against_the_airy_reflectance_over_the_spectrum(cos1, thickness, film_ior, eta):
    got = tf.iridescence(one(cos1), one(thickness), one(film_ior), eta=one(eta))[:, 0]
    np.testing.assert_allclose(got, airy_reference(cos1, thickness, film_ior, eta), rtol=0, atol=1.5e-3)


@pytest.mark.parametrize("cos1, thickness, film_ior", [(1.0, 300.0, 1.5), (0.5, 250.0, 2.0), (0.8, 120.0, 1.4)])
def test_conductor_film_against_the_airy_reflectance_over_the_spectrum(cos1, thickness, film_ior):
    n, k = np.array([0.2, 0.9, 1.1]), np.array([3.0, 2.4, 2.3])
    got = tf.iridescence(one(cos1), one(thickness), one(film_ior), n=n[:, None].astype(np.float32),
                         k=k[:, None].astype(np.float32))[:, 0]
    expected = [airy_reference(cos1, thickness, film_ior, n[c] + 1j * k[c])[c] for c in range(3)]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1.5e-3)


COS = np.linspace(0.0, 1.0, 41).astype(np.float32)


def test_no_thickness_or_a_film_of_the_outer_medium_is_the_plain_fresnel():
    """Thickness 0 (the film IOR blends to the outer medium's) and a 500 nm film of IOR 1 both leave the
    substrate's own Fresnel: dielectric, conductor, and the F82 metal (its Gulbrandsen n, k and the F82 curve
    taken through the film)."""
    n = len(COS)
    plain = fr.dielectric(COS, np.float32(1.5))[0]
    f0 = np.array([[0.9], [0.6], [0.3]], np.float32) * np.ones((1, n), np.float32)
    b = fr.f82_tint_b(f0, np.array([[0.7], [0.9], [1.0]], np.float32))
    n_k = (np.array([[0.2], [0.9], [1.1]], np.float32), np.array([[3.0], [2.4], [2.3]], np.float32))
    for thickness, film_ior in ((0.0, 1.33), (500.0, 1.0)):
        t, i = np.full(n, thickness, np.float32), np.full(n, film_ior, np.float32)
        np.testing.assert_allclose(tf.iridescence(COS, t, i, eta=np.full(n, 1.5, np.float32)),
                                   np.broadcast_to(plain, (3, n)), atol=2e-6)
        np.testing.assert_allclose(tf.iridescence(COS, t, i, n=n_k[0], k=n_k[1]), fr.conductor(COS, *n_k), atol=2e-6)
        np.testing.assert_allclose(tf.iridescence(COS, t, i, *mfc._f82_film(f0, b)), fr.f82(COS, f0, b), atol=2e-5)


def test_thin_films_blend_the_film_ior_and_the_cutoff_is_a_tenth_of_a_nanometre():
    """Under 1 nm the film IOR moves toward 1 by smoothstep(thickness): a 0.5 nm film of IOR 2 and a 0.25 nm
    film of IOR 4.2 both become films of IOR 1.5 over glass of 1.5, which reflect as the glass alone; films of
    0.1 nm or less are none (Cycles' THINFILM_THICKNESS_CUTOFF)."""
    plain = np.broadcast_to(fr.dielectric(COS, np.float32(1.5))[0], (3, 41))
    for thickness, film_ior in ((0.5, 2.0), (0.25, 4.2)):
        f = tf.iridescence(COS, np.full(41, thickness, np.float32), np.full(41, film_ior, np.float32), eta=1.5)
        np.testing.assert_allclose(f, plain, atol=2e-6)
    assert list(tf.film_on(np.array([0.0, 0.1, 0.1001, 500.0], np.float32))) == [False, False, True, True]


def test_total_internal_reflection_through_the_film_reflects_everything():
    """From inside glass (eta 1 / 1.5, the film IOR divided by 1.5) past the critical angle: R = 1."""
    cos = np.array([0.3, 0.6, 0.7], np.float32)
    f = tf.iridescence(cos, np.full(3, 400.0, np.float32), np.full(3, 1.33 / 1.5, np.float32),
                       eta=np.float32(1 / 1.5))
    critical = np.sqrt(1 - (1 / 1.5) ** 2)
    assert np.all(f[:, cos < critical] == 1.0) and np.all(f[:, cos > critical] < 1.0)


def test_remapped_film_scales_toward_f0_by_closeness_to_f0():
    """Cycles' generalized Schlick under a film: F *= lerp(1, f0 / F0(eta), clamp01((F - 1) / (F0(eta) - 1))),
    nothing when f0 = F0(eta), and F = 1 stays 1."""
    n, eta = len(COS), np.float32(1.45)
    film = (np.full(n, 600.0, np.float32), np.full(n, 1.3, np.float32))
    plain_f0 = fr.f0_from_ior(eta)
    raw = tf.iridescence(COS, *film, eta=np.full(n, eta))
    np.testing.assert_array_equal(tf.remapped(COS, np.full(n, eta), np.full((3, n), plain_f0), *film), raw)
    f0 = np.array([[1.0], [0.5], [0.0]], np.float32) * plain_f0
    s = np.clip((raw.astype(np.float64) - 1) / (plain_f0 - 1), 0, 1)
    expected = raw * (1 + (f0 / plain_f0 - 1) * s)
    np.testing.assert_allclose(tf.remapped(COS, np.full(n, eta), np.broadcast_to(f0, (3, n)), *film), expected,
                               rtol=1e-5, atol=1e-7)
    assert np.all(tf.remapped(COS[:1], np.full(1, eta), np.broadcast_to(f0, (3, 1)), *(f[:1] for f in film)) == 1)


# ---------------------------------------------------------------- the closures
def film_rows(cs, lobe):
    return np.flatnonzero(cs.lobe == lobe)


def test_principled_specular_albedo_is_the_films_fresnel_and_its_compensation_the_plain_one():
    """Cycles estimates a filmed lobe's albedo (sample weight, layering) by its Fresnel at mu, since its
    tables know no film, and keeps the plain model's Fss for the multiscatter compensation: the closure weight
    is the one without the film."""
    wo = (0.3, 0.1, 0.9)
    mu = np.float32(0.9 / np.linalg.norm(wo))
    base = dict(Base_Color=(0.1, 0.1, 0.1), Roughness=0.3, IOR=1.5)
    plain = closure_set(principled(**base), n=8, wo=wo)
    filmed = closure_set(principled(**base, Thin_Film_Thickness=450.0, Thin_Film_IOR=1.35), n=8, wo=wo)
    spec_p, spec_f = film_rows(plain, mfc.lobes.REFLECTION), film_rows(filmed, mfc.lobes.REFLECTION)
    np.testing.assert_array_equal(filmed.fresnel[spec_f], mfc.F_REMAP_FILM)
    np.testing.assert_array_equal(filmed.weight[:, spec_f], plain.weight[:, spec_p])
    film_f = tf.remapped(np.full(1, mu), np.full(1, 1.5, np.float32), np.full((3, 1), fr.f0_from_ior(1.5)),
                         np.full(1, 450.0, np.float32), np.full(1, 1.35, np.float32))[:, 0]
    np.testing.assert_allclose(filmed.albedo[0][:, spec_f[0]], filmed.weight[:, spec_f[0]] * film_f, rtol=2e-6)
    np.testing.assert_allclose(filmed.sw[spec_f[0]], filmed.weight[:, spec_f[0]].mean() * film_f.mean(), rtol=2e-6)


@pytest.mark.parametrize("backfacing", [False, True])
def test_glass_film_seen_from_inside_divides_the_film_ior_by_the_glass_ior(backfacing):
    """On a back face the stack outside-film-glass reads glass-film-outside: eta = 1/IOR and film IOR / IOR
    (Cycles' adjust_thin_film_ior_at_backface); the reflection albedo is the film's Fresnel there."""
    glass = Closure("GLASS", (("IOR", Param.of(1.5)), ("Thin Film Thickness", Param.of(380.0)),
                              ("Thin Film IOR", Param.of(1.8))), (("distribution", "MULTI_GGX"),))
    wo = (0.2, 0.1, 0.95)
    cs = closure_set(glass, n=8, wo=wo, backfacing=backfacing)
    row = film_rows(cs, mfc.lobes.GLASS)[0]
    ior = 1.5 if not backfacing else 1 / 1.5
    assert cs.film_ior[row] == pytest.approx(1.8 * (1 / 1.5 if backfacing else 1.0), rel=1e-6)
    assert cs.eta[row] == pytest.approx(ior, rel=1e-6)
    mu = np.float32(0.95 / np.linalg.norm(wo))
    f = tf.iridescence(np.full(1, mu), np.full(1, 380.0, np.float32), np.full(1, cs.film_ior[row]), eta=ior)[:, 0]
    np.testing.assert_allclose(cs.albedo[0][:, row], cs.weight[:, row] * f, rtol=1e-5)
    np.testing.assert_allclose(cs.albedo[1][:, row], cs.weight[:, row] * (1 - f), rtol=1e-5)


def test_no_film_leaves_the_closure_table_as_it_was():
    """A film of 0.1 nm (the cutoff) makes no film columns: the closures of a material without a film are
    the same arrays as before thin film existed."""
    cs = closure_set(principled(Metallic=0.5, Transmission_Weight=0.3, Thin_Film_Thickness=0.1), n=8)
    assert not hasattr(cs.film_t, "base") or np.all(cs.film_t == 0)
    assert set(np.unique(cs.fresnel)) <= {mfc.F_F82, mfc.F_REMAP, mfc.F_ONE}
