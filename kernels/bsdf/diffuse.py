"""The diffuse family of lobes, as Cycles 5.0 has them: Lambert, Oren-Nayar and Translucent.

Contract (see the package docstring): local frame with z along the lobe's normal; directions are
tuples (x, y, z) of (N,) float32 unit arrays; `wo` points to the viewer, `wi` to the light or the
sampled direction. `*_eval(wo, wi, ...) -> (f_cos, pdf)` gives f * |cos(theta_i)| and the pdf per unit
solid angle; `*_sample(wo, ..., u1, u2) -> (wi, weight, pdf)` with weight = f * |cos| / pdf. Lambert
and Translucent return scalar (N,) f_cos; Oren-Nayar returns (3, N) because Cycles' energy term
depends on the closure colour. None of them includes the closure weight: the caller multiplies by it.

Cycles names the viewer direction `wi` and the light direction `wo` (`bsdf_diffuse.h`,
`bsdf_oren_nayar.h`); the formulas below are written in this module's naming.

Like Cycles, the lobes only test the light side (wi.z) in `eval`: what happens when the viewer is
below the shading normal is the integrator's business (Cycles flips N to the viewer's side for
back faces). `sample` rejects directions on the wrong side of the shading normal; Cycles tests the
geometric normal there, which the integrator has and the lobe does not.
"""
from __future__ import annotations

import numpy as np

from ..sampling import cosine_hemisphere_pdf, sample_cosine_hemisphere
from ..vec import F32, HALF_PI, INV_PI, ONE, PI, ZERO

TWO_THIRDS = F32(2.0 / 3.0)
FLT_MIN = np.finfo(np.float32).tiny


def _sample_cosine(u1, u2, lower: bool):
    """Cosine-weighted direction about +z (or -z) and its pdf; pdf 0 where the warp degenerates."""
    x, y, z = sample_cosine_hemisphere(u1, u2)
    pdf = cosine_hemisphere_pdf(z)
    return (x, y, -z if lower else z), pdf


# ---------------------------------------------------------------- Lambert
def lambert_eval(wo, wi):
    """Lambert: f_cos = max(cos theta_i, 0) / pi, pdf = the same (cosine sampling is exact)."""
    f_cos = cosine_hemisphere_pdf(wi[2])
    return f_cos, f_cos.copy()


def lambert_sample(wo, u1, u2):
    """Cosine-weighted reflection. Returns (wi, weight, pdf); weight is 1 where pdf > 0."""
    wi, pdf = _sample_cosine(u1, u2, lower=False)
    weight = np.where(pdf > 0, ONE, ZERO)
    return wi, weight, np.where(pdf > 0, pdf, ZERO)


# ---------------------------------------------------------------- Translucent
def translucent_eval(wo, wi):
    """Translucent: f_cos = max(-cos theta_i, 0) / pi, pdf the same (Cycles `bsdf_translucent_eval`)."""
    f_cos = cosine_hemisphere_pdf(-wi[2])
    return f_cos, f_cos.copy()


def translucent_sample(wo, u1, u2):
    """Cosine-weighted transmission into the lower hemisphere. Returns (wi, weight, pdf)."""
    wi, pdf = _sample_cosine(u1, u2, lower=True)
    weight = np.where(pdf > 0, ONE, ZERO)
    return wi, weight, np.where(pdf > 0, pdf, ZERO)


# ---------------------------------------------------------------- Oren-Nayar
# Fujii's improved Oren-Nayar (https://mimosa-pudica.net/improved-oren-nayar.html) with the OpenPBR
# multiple-scattering term, exactly as `bsdf_oren_nayar.h`: sigma = roughness in [0, 1] (not an angle),
#   A = 1 / (pi + sigma (pi/2 - 2/3)),  B = sigma A,
#   single scattering f_ss = A + B t,  t = s / max(cos_i, cos_o) if s > 0 else s,  s = wi.wo - cos_i cos_o,
#   E(c) = A pi + B G(c), the directional albedo of f_ss (Fujii's closed form),
#   Eavg = A pi + B (2 pi - 5.6) / 3, the cosine-weighted mean of E (OpenPBR's fitted constant),
#   Ems = rho^2 Eavg / (pi (1 - Eavg) (1 - rho (1 - Eavg))), rho = clamp01(colour),
#   f_cos = cos_i [f_ss + Ems (1 - E(cos_i)) (1 - E(cos_o))].
# Cycles falls back to Lambert (no energy term) when B = 0, i.e. sigma = 0.
EAVG_G_COEFF = F32((2.0 * np.pi - 5.6) / 3.0)
G_TAYLOR_BELOW = F32(1e-6)


def _oren_nayar_ab(roughness):
    sigma = np.clip(np.asarray(roughness, np.float32), ZERO, ONE)
    a = ONE / (PI + sigma * (HALF_PI - TWO_THIRDS))
    return a, sigma * a


def _oren_nayar_g(cos_theta):
    """Fujii's G(theta), so that E(cos) = A pi + B G(cos). Below cos = 1e-6 Cycles switches to the
    first-order expansion because tan(theta) blows up; we keep its switch point."""
    c = np.maximum(cos_theta, G_TAYLOR_BELOW)
    s = np.sqrt(np.maximum(ONE - c * c, ZERO))
    theta = np.arccos(np.minimum(c, ONE))
    g = s * (theta - TWO_THIRDS - s * c) + TWO_THIRDS * (s / c) * (ONE - s * s * s)
    return np.where(cos_theta < G_TAYLOR_BELOW, (HALF_PI - TWO_THIRDS) - cos_theta, g).astype(np.float32)


def oren_nayar_single_scatter_albedo(cos_theta, roughness):
    """E(cos) = A pi + B G(cos): the directional albedo of the single-scattering term, (N,) float32.

    Cycles uses it only inside the lobe (the energy term). It does not use any Oren-Nayar albedo for
    layering or sample weights: the diffuse closure is the bottom layer and `bsdf_albedo` returns its
    plain weight."""
    a, b = _oren_nayar_ab(roughness)
    return (a * PI + b * _oren_nayar_g(np.maximum(cos_theta, ZERO))).astype(np.float32)


def _oren_nayar_multiscatter(a, b, color):
    """Ems of the energy term, (3, N). 0 where Eavg rounds to 1 (sigma below ~1e-6; Cycles would
    divide by zero there, but its nodes switch to Lambert below 1e-5): the term vanishes like sigma."""
    rho = np.clip(np.asarray(color, np.float32), ZERO, ONE)
    eavg = a * PI + EAVG_G_COEFF * b
    ok = eavg < ONE
    one_minus = np.where(ok, ONE - eavg, F32(0.5))
    ems = INV_PI * rho * rho * (eavg / one_minus) / (ONE - rho * one_minus)
    return np.where(ok, ems, ZERO).astype(np.float32)


def _oren_nayar_f_cos(wo, wi, roughness, color):
    a, b = _oren_nayar_ab(roughness)
    cos_i = np.maximum(wi[2], ZERO)
    cos_o = np.maximum(wo[2], ZERO)
    s = wi[0] * wo[0] + wi[1] * wo[1] + wi[2] * wo[2] - cos_i * cos_o
    # FLT_MIN as in Cycles: s > 0 implies max(cos) > 0 except for rounding.
    t = np.where(s > 0, s / (np.maximum(cos_i, cos_o) + FLT_MIN), s)
    single = a + b * t
    e_i = a * PI + b * _oren_nayar_g(cos_i)
    e_o = a * PI + b * _oren_nayar_g(cos_o)
    multi = _oren_nayar_multiscatter(a, b, color) * ((ONE - e_o) * (ONE - e_i))
    f_cos = cos_i * (single + multi)
    lambert = cos_i * INV_PI
    return np.where(b > 0, f_cos, lambert).astype(np.float32)


def oren_nayar_eval(wo, wi, roughness, color):
    """Cycles' Oren-Nayar. roughness (N,) or scalar in [0, 1]; color (3, N) or (3, 1), clamped to [0, 1]
    for the energy term only. Returns (f_cos (3, N), pdf (N,)); both 0 below the surface."""
    f_cos = _oren_nayar_f_cos(wo, wi, roughness, color)
    pdf = cosine_hemisphere_pdf(wi[2])
    return np.where(pdf > 0, f_cos, ZERO).astype(np.float32), pdf


def oren_nayar_sample(wo, roughness, color, u1, u2):
    """Cosine-weighted sample of Oren-Nayar. Returns (wi, weight (3, N), pdf (N,))."""
    wi, pdf = _sample_cosine(u1, u2, lower=False)
    f_cos = _oren_nayar_f_cos(wo, wi, roughness, color)
    ok = pdf > 0
    weight = np.where(ok, f_cos / np.where(ok, pdf, ONE), ZERO).astype(np.float32)
    return wi, weight, np.where(ok, pdf, ZERO)
