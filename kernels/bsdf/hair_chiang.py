"""Cycles' Principled Hair BSDF, Chiang model (`kernel/closure/bsdf_principled_hair_chiang.h`, Chiang, Bitterli,
Tappan and Burley 2016 as Cycles implements it), and the hair absorption parametrizations both models share
(`kernel/closure/bsdf_util.h`).

The lobe's local frame (the closure table's: x along its tangent, z along its normal) is Cycles' hair frame:
x = X, the unit curve tangent (dPdu); z = Y = normalize(X x viewer), Cycles' bsdf->N; y = z x x = -Z. The viewer
then lies in the x-y plane. Cycles' local coordinates (X, Y, Z) of a direction are (x, z, -y) here. `wo` points
to the viewer (Cycles' sd->wi), `wi` to the light or the sampled direction (Cycles' wo).

Per closure (arrays of (N,), colours (3, N)):
    h      the offset across the strand, -1 (grazing) .. 0 (centre) .. 1: sin(gamma_o) (chiang_h)
    v, s, m0  the longitudinal variance, the logistic scale and the R lobe's variance (chiang_roughness)
    alpha  the scale tilt as the lobe uses it: -Offset (Cycles' setup negates it)
    eta    the IOR; sigma the absorption coefficient (3, N)

With theta the latitude about the strand (sin theta = x) and phi the azimuth about it, the lobe is the sum over
p = R, TT, TRT of Ap Mp Np and the residual TRRT+ term A3 M3 / (2 pi), where
    Ap     the attenuations from the Fresnel factor f = F(cos theta_o cos gamma_o) and the transmittance
           T = exp(-sigma 2 cos gamma_t / cos theta_t): A0 = f, A1 = (1 - f)^2 T, A2 = A1 T f,
           A3 = A2 T f / (1 - T f)
    Mp     d'Eon's longitudinal function with variance m0, v / 4, 4 v (4 v untilted for the residual) about
           the tilted viewer latitudes (hair_alpha_angles: -2 alpha, alpha, 4 alpha); for v <= 0.1 its
           logarithmic form (log I0 from the asymptotic expansion above 12), Cycles' low-roughness handling
    Np     the logistic of scale s trimmed to [-pi, pi], about 2 p gamma_t - 2 gamma_o + p pi
eval returns that sum as f |cos| (the cosine cancels Mp's 1 / cos theta_i) and the pdf sum Ep Mp Np (+ E3 M3 /
2 pi), with Ep = the lobes' luminances of Ap normalised to sum 1. sample picks a lobe by Ep, draws its Mp
exactly (d'Eon's sampling) and its Np by inverting the trimmed logistic, and returns weight = eval / pdf,
pdf and transmit (every lobe but R: Cycles' LABEL_TRANSMIT, a transmission bounce). As in Cycles, the sampler
draws R with variance v where the pdf says m0 (they differ only where Coat > 0), and neither looks at which
side of any surface a direction lies on (the integrator does not either: lobes.ANY_SIDE). Evaluated, the lobe
is Cycles' exactly in float32, except that its Bessel series and transcendental functions round differently
in the last bits.
"""
from __future__ import annotations

import numpy as np

from ..colorspace import RGB_TO_Y
from ..vec import F32, INV_2PI, ONE, PI, TWO_PI, ZERO, cross_xyz, dot_xyz, normalize_xyz
from .fresnel import dielectric

SQRT_PI_8 = F32(np.sqrt(np.pi / 8.0))
LN_2PI = F32(np.log(2.0 * np.pi))
# Cycles' melanin colours (bsdf_principled_hair_sigma_from_concentration).
EUMELANIN = np.array([0.506, 0.841, 1.653], F32)
PHEOMELANIN = np.array([0.343, 0.733, 1.924], F32)
# bessel_I0's denominators 4^i (i!)^2 for i = 2..9, as Cycles' integers converted to float.
_I0_DENOMINATORS = tuple(F32(4 ** i * np.prod(np.arange(1, i + 1, dtype=np.float64)) ** 2) for i in range(2, 10))


# ---------------------------------------------------------------- parametrizations (bsdf_util.h)
def albedo_roughness_scale(azimuthal_roughness):
    """bsdf_principled_hair_albedo_roughness_scale: the polynomial of Chiang et al.'s colour inversion."""
    x = np.asarray(azimuthal_roughness, F32)
    return (((((F32(0.245) * x + F32(5.574)) * x - F32(10.73)) * x + F32(2.532)) * x - F32(0.215)) * x
            + F32(5.969)).astype(F32)


def sigma_from_reflectance(color, azimuthal_roughness):
    """(3, N) absorption giving roughly `color` (3, N) as the strand's colour (Direct Coloring, Tint)."""
    with np.errstate(divide="ignore"):
        s = np.log(np.maximum(np.asarray(color, F32), ZERO)) / albedo_roughness_scale(azimuthal_roughness)
    return np.nan_to_num(s * s, posinf=np.float32(np.inf)).astype(F32)


def sigma_from_melanin(melanin, redness, random_color, random):
    """(3, N) absorption of the Melanin parametrization, as svm_node_closure_bsdf computes it: Melanin scaled by
    1 + 2 (random - 1/2) clamp01(Random Color), mapped from 0..1 to 0..inf by -log(max(1 - m, 1e-4)), split into
    eu- and pheomelanin by Melanin Redness (Bitterli's remapping), times Cycles' melanin colours. The Tint's
    absorption (sigma_from_reflectance) is added by the caller."""
    m = np.asarray(melanin, F32) * (ONE + F32(2.0) * (np.asarray(random, F32) - F32(0.5))
                                    * np.clip(np.asarray(random_color, F32), ZERO, ONE))
    m = -np.log(np.maximum(ONE - m, F32(1e-4)))
    red = np.asarray(redness, F32)
    eu, pheo = m * (ONE - red), m * red
    return (eu * EUMELANIN[:, None] + pheo * PHEOMELANIN[:, None]).astype(F32)


def chiang_roughness(roughness, radial_roughness, coat):
    """(v, s, m0) of bsdf_hair_chiang_setup from the node's Roughness and Radial Roughness (already scaled by
    Random Roughness) and Coat: clamped to [0.001, 1] (m0 = (1 - clamp01(Coat)) x roughness), then mapped to the
    logistic's variance and scale by Chiang et al.'s polynomials."""
    v = np.clip(np.asarray(roughness, F32), F32(0.001), ONE)
    s = np.clip(np.asarray(radial_roughness, F32), F32(0.001), ONE)
    m0 = np.clip((ONE - np.clip(np.asarray(coat, F32), ZERO, ONE)) * v, F32(0.001), ONE)

    def variance(r):
        return np.square(F32(0.726) * r + F32(0.812) * r * r + F32(3.700) * r ** 20).astype(F32)
    with np.errstate(under="ignore"):   # the high powers of small roughnesses
        s = ((F32(0.265) * s + F32(1.194) * s * s + F32(5.372) * s ** 22) * SQRT_PI_8).astype(F32)
        return variance(v), s, variance(m0)


def chiang_h(tangent, normal, wo):
    """(N,) the offset across the strand, Cycles' bsdf->h for a hit off a ribbon: the sine of the angle between
    the geometric normal (facing the viewer) and Z = X x (X x wo) normalised, seen along the tangent X,
    dot(normal x X, Z). tangent, normal, wo: world (x, y, z) tuples, tangent unit."""
    y = normalize_xyz(cross_xyz(tangent, wo))
    z = normalize_xyz(cross_xyz(tangent, y))
    return np.clip(dot_xyz(cross_xyz(normal, tangent), z), -ONE, ONE).astype(F32)


# ---------------------------------------------------------------- the functions of the lobes
def _cos_from_sin(s):
    return np.sqrt(np.maximum(ONE - s * s, ZERO)).astype(F32)


def _bessel_i0(x):
    """Cycles' bessel_I0: the series of I0 to its tenth term (i < 10), in float32."""
    x = (x * x).astype(F32)
    val = ONE + F32(0.25) * x
    power = x * x
    for denominator in _I0_DENOMINATORS:
        val = val + power / denominator
        power = power * x
    return val.astype(F32)


def _log_bessel_i0(x):
    """Cycles' log_bessel_I0: the asymptotic expansion above 12, else log of the series."""
    with np.errstate(divide="ignore", invalid="ignore"):
        big = x + F32(0.5) * (ONE / (F32(8.0) * x) - LN_2PI - np.log(x))
        small = np.log(_bessel_i0(np.minimum(x, F32(12.0))))
    return np.where(x > F32(12.0), big, small).astype(F32)


def longitudinal(sin_i, cos_i, sin_o, cos_o, v):
    """Mp (N,): d'Eon's longitudinal scattering with variance v, its logarithmic form for v <= 0.1."""
    inv_v = ONE / v
    cos_arg = cos_i * cos_o * inv_v
    sin_arg = sin_i * sin_o * inv_v
    with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
        low = np.exp(_log_bessel_i0(cos_arg) - sin_arg - inv_v + F32(0.6931) + np.log(F32(0.5) * inv_v))
        high = np.exp(-sin_arg) * _bessel_i0(cos_arg) / (np.sinh(np.minimum(inv_v, F32(10.0))) * F32(2.0) * v)
    return np.where(v <= F32(0.1), low, high).astype(F32)


def _logistic_cdf(x, s):
    arg = -x / s
    with np.errstate(over="ignore"):
        return np.where(arg > F32(88.0), ZERO, ONE / (ONE + np.exp(np.minimum(arg, F32(88.0))))).astype(F32)


def _trimmed_logistic(x, s):
    scale = ONE - F32(2.0) * _logistic_cdf(-PI, s)
    e = np.exp(-np.abs(x) / s)
    val = e / (s * np.square(ONE + e))
    return np.where(scale != 0, val / np.where(scale != 0, scale, ONE), ZERO).astype(F32)


def sample_trimmed_logistic(u, s):
    """The trimmed logistic's inverse cdf, clamped to [-pi, pi]."""
    c = _logistic_cdf(-PI, s)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x = -s * np.log(ONE / (u * (ONE - F32(2.0) * c) + c) - ONE)
    return np.clip(np.nan_to_num(x, nan=0.0), -PI, PI).astype(F32)


def _delta_phi(p, gamma_o, gamma_t):
    return F32(2.0 * p) * gamma_t - F32(2.0) * gamma_o + F32(p) * PI


def _wrap(a):
    return ((a + PI) - TWO_PI * np.floor((a + PI) / TWO_PI) - PI).astype(F32)


def _tilted(sin_o, cos_o, alpha):
    """hair_alpha_angles: the viewer's (sin, |cos|) latitude tilted by -2 alpha (R), alpha (TT), 4 alpha (TRT)."""
    s1 = np.sin(alpha).astype(F32)
    c1 = _cos_from_sin(s1)
    s2, c2 = F32(2.0) * s1 * c1, c1 * c1 - s1 * s1
    s4, c4 = F32(2.0) * s2 * c2, c2 * c2 - s2 * s2
    return ((sin_o * c2 - cos_o * s2, np.abs(cos_o * c2 + sin_o * s2)),
            (sin_o * c1 + cos_o * s1, np.abs(cos_o * c1 - sin_o * s1)),
            (sin_o * c4 + cos_o * s4, np.abs(cos_o * c4 - sin_o * s4)))


class _Viewer:
    """What a closure's lobes depend on besides the light's direction: the viewer's angles, the attenuations
    (Ap colour, Ep their normalised luminances) and the tilted latitudes."""

    def __init__(self, wo, h, v, s, m0, alpha, eta, sigma):
        self.v, self.s, self.m0 = v, s, m0
        self.sin_o = np.clip(wo[0], -ONE, ONE).astype(F32)
        self.cos_o = _cos_from_sin(self.sin_o)
        self.phi_o = np.arctan2(-wo[1], wo[2]).astype(F32)
        sin_t = self.sin_o / eta
        cos_t = _cos_from_sin(sin_t)
        h = np.asarray(h, F32)
        self.gamma_o = np.arcsin(np.clip(h, -ONE, ONE)).astype(F32)
        with np.errstate(divide="ignore", invalid="ignore"):
            sin_gt = h * self.cos_o / np.sqrt(eta * eta - self.sin_o * self.sin_o)
            self.gamma_t = np.arcsin(np.clip(np.nan_to_num(sin_gt), -ONE, ONE)).astype(F32)
            cos_gt = _cos_from_sin(np.nan_to_num(sin_gt))
            path = np.nan_to_num(F32(2.0) * cos_gt / cos_t, posinf=F32(3e38))
        with np.errstate(over="ignore", invalid="ignore"):
            transmittance = np.exp(-np.asarray(sigma, F32) * path).astype(F32)
        transmittance = np.nan_to_num(transmittance, nan=0.0)
        f = dielectric(self.cos_o * _cos_from_sin(h), eta)[0]
        self.ap, self.ep = _attenuation(f, transmittance)
        self.tilted = _tilted(self.sin_o, self.cos_o, np.asarray(alpha, F32))

    def lobes(self, sin_i, cos_i, phi):
        """(F (3, N), F_energy (N,)): the lobes toward the direction of latitude sin_i, cos_i and azimuth phi
        from the viewer's."""
        f = np.zeros((3, len(sin_i)), F32)
        energy = np.zeros(len(sin_i), F32)
        variances = (self.m0, F32(0.25) * self.v, F32(4.0) * self.v)
        for p in range(3):
            mp = longitudinal(sin_i, cos_i, self.tilted[p][0], self.tilted[p][1], variances[p])
            np_ = _trimmed_logistic(_wrap(phi - _delta_phi(p, self.gamma_o, self.gamma_t)), self.s)
            mn = mp * np_
            f += self.ap[p] * mn
            energy += self.ep[p] * mn
        mn = longitudinal(sin_i, cos_i, self.sin_o, self.cos_o, F32(4.0) * self.v) * INV_2PI
        f += self.ap[3] * mn
        energy += self.ep[3] * mn
        return f, energy


def _attenuation(f, transmittance):
    """hair_attenuation: the lobes' colours A0..A3 (each (3, N)) and their luminances normalised to sum 1."""
    a0 = np.broadcast_to(f, transmittance.shape).astype(F32)
    a1 = (np.square(ONE - f) * transmittance).astype(F32)
    a2 = (a1 * transmittance * f).astype(F32)
    tf = transmittance * f
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(ONE - tf != 0, tf / np.where(ONE - tf != 0, ONE - tf, ONE), ZERO)
    a3 = (a2 * ratio).astype(F32)
    ap = (a0, a1, a2, a3)
    gray = [np.asarray(f, F32).copy()] + [np.einsum("k,kn->n", RGB_TO_Y, a).astype(F32) for a in ap[1:]]
    total = gray[0] + gray[1] + gray[2] + gray[3]
    fac = np.where(total != 0, ONE / np.where(total != 0, total, ONE), ZERO).astype(F32)
    return ap, tuple((g * fac).astype(F32) for g in gray)


# ---------------------------------------------------------------- eval and sample
def chiang_eval(wo, wi, h, v, s, m0, alpha, eta, sigma):
    """(f |cos| (3, N), pdf (N,)) toward wi; see the module docstring."""
    with np.errstate(under="ignore"):   # dark hair's attenuation and narrow lobes' tails
        return _eval(wo, wi, h, v, s, m0, alpha, eta, sigma)


def _eval(wo, wi, h, v, s, m0, alpha, eta, sigma):
    viewer = _Viewer(wo, h, v, s, m0, alpha, eta, sigma)
    sin_i = np.clip(wi[0], -ONE, ONE).astype(F32)
    phi = np.arctan2(-wi[1], wi[2]).astype(F32) - viewer.phi_o
    f, pdf = viewer.lobes(sin_i, _cos_from_sin(sin_i), phi)
    return _finite(f, pdf)


def chiang_sample(wo, h, v, s, m0, alpha, eta, sigma, u1, u2, uc):
    """(wi, weight (3, N), pdf (N,), transmit (N,) bool): uc picks the lobe (then draws its latitude), u2 the
    latitude's azimuth about the tilted viewer, u1 the azimuth about the strand; see the module docstring."""
    with np.errstate(under="ignore"):   # dark hair's attenuation and narrow lobes' tails
        return _sample(wo, h, v, s, m0, alpha, eta, sigma, u1, u2, uc)


def _sample(wo, h, v, s, m0, alpha, eta, sigma, u1, u2, uc):
    viewer = _Viewer(wo, h, v, s, m0, alpha, eta, sigma)
    n = len(viewer.sin_o)
    z = np.asarray(uc, F32).copy()
    lobe = np.full(n, 3, np.int8)
    for p in range(3):
        free = lobe == 3
        take = free & (z < viewer.ep[p])
        lobe[take] = p
        z = np.where(free & ~take, z - viewer.ep[p], z)
    chosen = np.choose(lobe, viewer.ep)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(chosen > 0, z / np.where(chosen > 0, chosen, ONE), ONE)
    z = np.clip(z, F32(1e-5), ONE).astype(F32)
    var = np.where(lobe == 1, F32(0.25) * v, np.where(lobe >= 2, F32(4.0) * v, v)).astype(F32)
    sin_ot = np.choose(np.minimum(lobe, 3), [t[0] for t in viewer.tilted] + [viewer.sin_o]).astype(F32)
    cos_ot = np.choose(np.minimum(lobe, 3), [t[1] for t in viewer.tilted] + [viewer.cos_o]).astype(F32)
    with np.errstate(under="ignore"):
        fac = ONE + var * np.log(z + (ONE - z) * np.exp(-F32(2.0) / var))
    sin_i = np.clip(-fac * sin_ot + _cos_from_sin(fac) * np.cos(TWO_PI * u2) * cos_ot, -ONE, ONE).astype(F32)
    cos_i = _cos_from_sin(sin_i)
    around = sample_trimmed_logistic(np.asarray(u1, F32), viewer.s)
    phi = np.where(lobe < 3, np.choose(np.minimum(lobe, 2), [_delta_phi(p, viewer.gamma_o, viewer.gamma_t)
                                                             for p in range(3)]) + around,
                   TWO_PI * u1).astype(F32)
    f, pdf = _finite(*viewer.lobes(sin_i, cos_i, phi))
    phi_i = viewer.phi_o + phi
    wi = (sin_i, (-cos_i * np.sin(phi_i)).astype(F32), (cos_i * np.cos(phi_i)).astype(F32))
    good = pdf > 0
    weight = np.where(good, f / np.where(good, pdf, ONE), ZERO).astype(F32)
    return wi, weight, pdf, lobe > 0


def chiang_albedo(wo_x, h, v, eta, sigma):
    """(3, N) bsdf_hair_chiang_albedo: exp(-sqrt(sigma) x albedo_roughness_scale(v)) + the Fresnel factor, what
    the passes and the denoiser read (v the mapped variance, wo_x the viewer's cosine to the tangent)."""
    cos_o = _cos_from_sin(np.clip(np.asarray(wo_x, F32), -ONE, ONE))
    f = dielectric(cos_o * _cos_from_sin(np.asarray(h, F32)), eta)[0]
    return (np.exp(-np.sqrt(np.asarray(sigma, F32)) * albedo_roughness_scale(v)) + f).astype(F32)


def _finite(f, pdf):
    good = np.isfinite(pdf) & np.all(np.isfinite(f), axis=0) & (pdf >= 0)
    return np.where(good, f, ZERO).astype(F32), np.where(good, pdf, ZERO).astype(F32)
