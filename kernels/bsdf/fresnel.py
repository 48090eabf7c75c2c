"""Fresnel models of Cycles 5.0 (`kernel/closure/bsdf_util.h`, `microfacet_fresnel` in
`kernel/closure/bsdf_microfacet.h`), and their mean values "Fss" used by the multiscatter compensation.

This module owns the formulas; it knows nothing of directions. Shapes:
    cos_i : (N,) float32, the cosine between the viewer direction and the (micro)normal;
    eta   : (N,) float32 or a scalar, the relative IOR (far side over the viewer's side);
    colour parameters (f0, f90, tints, n, k) : (3, N), (3, 1) or (3,) float32;
    a Fresnel reflectance of colour type is (3, N) float32, of scalar type (N,) float32.

The microfacet lobes take Fresnel models as callables, made by the factories at the end:
    reflection lobes : fresnel(cos_h) -> R (3, N)
    glass lobes      : fresnel(cos_h, eta) -> (R (3, N), T (3, N))
A lobe calls its callable once per call, on arrays of the full length N, with finite cos_h in [0, 1].

Thin-film iridescence (Belcour-Barla), which Cycles applies over these models when a film is thicker than
0.1 nm, is thin_film.py's.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, ONE, ZERO

# The F82 models sample Schlick's curve at cos = 1/7 (about 82 degrees), where 1 - cos = 6/7.
F82_ONE_MINUS_COS = 6.0 / 7.0
F82_COS = F32(1.0 / 7.0)


def _f32(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float32)


def color(c, n: int) -> np.ndarray:
    """A colour parameter as a (3, n) float32 array (broadcast, not copied)."""
    c = _f32(c)
    if c.ndim <= 1:
        c = c.reshape(-1, 1) if c.ndim == 1 else c.reshape(1, 1)
    return np.broadcast_to(c, (3, n))


def lerp(a, b, t):
    return a + (b - a) * t


def clamp01(x):
    return np.clip(x, ZERO, ONE)


# ---------------------------------------------------------------- IOR <-> F0
def f0_from_ior(ior):
    """Normal-incidence reflectance ((ior - 1) / (ior + 1))^2; the same for ior and 1/ior."""
    ior = _f32(ior)
    return np.square((ior - ONE) / (ior + ONE)).astype(np.float32)


def ior_from_f0(f0):
    """Inverse of f0_from_ior (the IOR >= 1 branch), with F0 clamped to [0, 0.99] as Cycles does."""
    s = np.sqrt(np.clip(_f32(f0), ZERO, F32(0.99)))
    return ((ONE + s) / (ONE - s)).astype(np.float32)


# ---------------------------------------------------------------- dielectric
def dielectric(cos_i, eta):
    """Exact unpolarised Fresnel reflectance of a dielectric interface, and the refracted cosine.

    cos_i (N,) (its sign is ignored), eta (N,) or scalar. Returns (F (N,), cos_t (N,)): cos_t is the
    magnitude of the cosine of the refracted direction, and under total internal reflection F = 1,
    cos_t = 0. Written with eta * cos_t = sqrt(eta^2 - 1 + cos_i^2), which is real exactly when there
    is a refracted ray (Cycles' `fresnel_dielectric_polarized`).
    """
    c = np.abs(_f32(cos_i))
    eta = _f32(eta)
    eta_cos_t_sq = _eta_cos_t_sq(c, eta)
    tir = eta_cos_t_sq <= 0
    eta_cos_t = np.sqrt(np.maximum(eta_cos_t_sq, ZERO))
    # Denominators vanish only together with eta_cos_t_sq (c = 0, eta = 1), i.e. under `tir`.
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (c - eta_cos_t) / (c + eta_cos_t)
        r_p = (eta * eta * c - eta_cos_t) / (eta * eta * c + eta_cos_t)
        cos_t = eta_cos_t / eta
    f = np.where(tir, ONE, F32(0.5) * (r_s * r_s + r_p * r_p)).astype(np.float32)
    return f, np.where(tir, ZERO, cos_t).astype(np.float32)


def _eta_cos_t_sq(c, eta):
    """(eta cos_t)^2 = eta^2 - 1 + c^2 by Snell's law. Every TIR test uses this one expression, so the
    Fresnel models and the lobes agree at the critical angle; it is also exact for eta = 1 (Cycles'
    generalized Schlick writes 1 - (1 - c^2) / eta^2, which reports TIR at c = 1e-4, eta = 1 in float32)."""
    return eta * eta - ONE + c * c


def refracted_cos_sq(cos_i, eta):
    """cos^2 of the refracted angle by Snell's law, <= 0 under total internal reflection."""
    eta = _f32(eta)
    return (_eta_cos_t_sq(_f32(cos_i), eta) / (eta * eta)).astype(np.float32)


# ---------------------------------------------------------------- conductor
def conductor(cos_i, n, k):
    """Exact unpolarised Fresnel reflectance from a dielectric of IOR 1 into a conductor n + ik.

    cos_i (N,); n, k colour parameters. Returns (3, N). Born & Wolf 14.4.1 with the complex IOR
    written n + ik (Cycles' `fresnel_conductor`): with u^2 - v^2 = n^2 - k^2 - sin^2, uv = nk,
        R_s = ((c - u)^2 + v^2) / ((c + u)^2 + v^2),
        R_p = (((n^2-k^2) c - u)^2 + (2nk c - v)^2) / (((n^2-k^2) c + u)^2 + (2nk c + v)^2).
    """
    c = _f32(cos_i)[None, :]
    num = c.shape[1]
    n, k = color(n, num), color(k, num)
    n2_minus_k2 = n * n - k * k
    two_nk = F32(2.0) * n * k
    t1 = n2_minus_k2 - (ONE - c * c)
    t2 = np.sqrt(t1 * t1 + two_nk * two_nk)
    u_sq = np.maximum(F32(0.5) * (t2 + t1), ZERO)
    v_sq = np.maximum(F32(0.5) * (t2 - t1), ZERO)
    u, v = np.sqrt(u_sq), np.sqrt(v_sq)
    t3, t4 = n2_minus_k2 * c, two_nk * c
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (np.square(c - u) + v_sq) / (np.square(c + u) + v_sq)
        r_p = (np.square(t3 - u) + np.square(t4 - v)) / (np.square(t3 + u) + np.square(t4 + v))
    # Cycles' safe_divide: a vanishing denominator (n = k = 0 at grazing) gives 0.
    r_s = np.where(np.isfinite(r_s), r_s, ZERO)
    r_p = np.where(np.isfinite(r_p), r_p, ZERO)
    return (F32(0.5) * (r_s + r_p)).astype(np.float32)


# ---------------------------------------------------------------- F82-tint
def f82_tint_b(f0, tint):
    """b of the F82-tint model (Kutz et al., Adobe Standard Material): the value at cos = 1/7 is
    Schlick's times `tint`. b = lerp(F0, 1, f^5) * 7 / f^6 * (1 - tint), f = 6/7. Colour in, colour out."""
    f0, tint = _f32(f0), _f32(tint)
    f5 = F82_ONE_MINUS_COS ** 5
    return (lerp(f0, ONE, F32(f5)) * F32(7.0 / (f5 * F82_ONE_MINUS_COS)) * (ONE - tint)).astype(np.float32)


def f82_b(f0, f82):
    """b of the F82 model from the reflectance F82 at cos = 1/7 (used to fit a conductor)."""
    f0, f82 = _f32(f0), _f32(f82)
    f5 = F82_ONE_MINUS_COS ** 5
    return (F32(7.0 / (f5 * F82_ONE_MINUS_COS)) * (lerp(f0, ONE, F32(f5)) - f82)).astype(np.float32)


def f82(cos_i, f0, b):
    """F82 reflectance clamp01(lerp(F0, 1, (1 - c)^5) - b c (1 - c)^6). cos_i (N,), f0 and b colour. (3, N)."""
    c = _f32(cos_i)[None, :]
    num = c.shape[1]
    s = clamp01(ONE - c)
    s5 = s * s * s * s * s
    return clamp01(lerp(color(f0, num), ONE, s5) - color(b, num) * c * s5 * s).astype(np.float32)


# ---------------------------------------------------------------- generalized Schlick
def remapped(cos_i, eta, f0, f90):
    """Cycles' generalized Schlick with a negative exponent (Principled specular/transmission, Glass):
    the exact dielectric curve remapped from [F0(eta), 1] to [f0, f90],
        s = clamp01((F(cos_i, eta) - F0(eta)) / (1 - F0(eta))),  F = lerp(f0, f90, s).
    With f0 = F0(eta), f90 = 1 this is the exact Fresnel (where it is >= F0, i.e. everywhere for
    ordinary IORs). f0 is clamped to [0, 1] first, as `bsdf_microfacet_setup_fresnel_generalized_schlick`
    does. Returns (F (3, N), cos_t (N,)); under TIR F = f90 and cos_t = 0.
    """
    f_real, cos_t = dielectric(cos_i, eta)
    num = f_real.shape[0]
    f0_real = f0_from_ior(eta)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = clamp01((f_real - f0_real) / (ONE - f0_real))
    s = np.where(np.isfinite(s), s, ONE)
    f = lerp(clamp01(color(f0, num)), color(f90, num), s[None, :])
    return f.astype(np.float32), cos_t


def generalized_schlick(cos_i, eta, f0, f90, exponent):
    """Cycles' generalized Schlick with exponent >= 0: F = lerp(f0, f90, (1 - cos)^exponent), where cos
    is cos_i, or the refracted cosine when eta < 1 (going from the denser side). TIR gives F = 1.
    exponent scalar or (N,). Returns (F (3, N), cos_t (N,))."""
    c = _f32(cos_i)
    eta = np.broadcast_to(_f32(eta), c.shape)
    num = c.shape[0]
    cos_t_sq = refracted_cos_sq(c, eta)
    tir = cos_t_sq <= 0
    cos_t = np.sqrt(np.maximum(cos_t_sq, ZERO))
    angle = np.where(eta < 1, cos_t, c)
    s = np.power(np.maximum(ONE - angle, ZERO), _f32(exponent))
    f = lerp(clamp01(color(f0, num)), color(f90, num), s[None, :])
    return np.where(tir[None, :], ONE, f).astype(np.float32), np.where(tir, ZERO, cos_t).astype(np.float32)


# ---------------------------------------------------------------- mean Fresnel "Fss"
# Fss = integral over [0, 1] of 2 cos F(cos) dcos: the cosine-weighted mean of a Fresnel curve, which the
# Kulla-Conty multiscatter term needs (section 1.3 of MATERIALS_NOTES).
def dielectric_fss(eta):
    """Fit of Kulla & Conty ("Revisiting Physically Based Shading at Imageworks") as in Cycles:
    (eta - 1) / (4.08567 + 1.00071 eta) for eta >= 1, a cubic for eta < 1. (N,) or scalar."""
    eta = _f32(eta)
    below = F32(0.997118) + eta * (F32(0.1014) - eta * (F32(0.965241) + eta * F32(0.130607)))
    above = (eta - ONE) / (F32(4.08567) + F32(1.00071) * eta)
    return np.where(eta < 1, below, above).astype(np.float32)


def f82_fss(f0, b):
    """Mean of the F82 curve, exact for its polynomial: lerp(F0, 1, 1/21) - b / 126. Colour."""
    return (lerp(_f32(f0), ONE, F32(1.0 / 21.0)) - _f32(b) * F32(1.0 / 126.0)).astype(np.float32)


def conductor_fss(n, k):
    """Cycles fits F82 to the conductor at cos = 1 and cos = 1/7 and takes that curve's mean.
    n, k colour (3, N). Returns (3, N)."""
    num = max(_f32(n).reshape(3, -1).shape[1], _f32(k).reshape(3, -1).shape[1])
    ones = np.ones(num, np.float32)
    f0 = conductor(ones, n, k)
    at_82 = conductor(ones * F82_COS, n, k)
    return clamp01(f82_fss(f0, f82_b(f0, at_82))).astype(np.float32)


def generalized_schlick_fss(f0, f90, eta, exponent, reflection_tint):
    """Fss of a reflective generalized-Schlick lobe: reflection_tint * lerp(f0, f90, s_mean), with
    s_mean = clamp01((Fss_dielectric(eta) - F0(eta)) / (1 - F0(eta))) for exponent < 0 (remap mode), else
    the exact mean 2 / ((exponent + 3) exponent + 2). For glass lobes Cycles uses the transmission tint
    instead (see microfacet.multiscatter_glass). Colour out."""
    exponent = _f32(exponent)
    f0_real = f0_from_ior(eta)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_remap = clamp01((dielectric_fss(eta) - f0_real) / (ONE - f0_real))
        s_power = F32(2.0) / ((exponent + F32(3.0)) * exponent + F32(2.0))
    s = np.where(exponent < 0, s_remap, s_power)
    return (_f32(reflection_tint) * lerp(clamp01(_f32(f0)), _f32(f90), s)).astype(np.float32)


# ---------------------------------------------------------------- callables for the lobes
def unit_reflection():
    """F = 1 (Glossy BSDF, and the tables' ggx_E)."""
    return lambda cos_h: np.ones((3, np.shape(cos_h)[0]), np.float32)


def dielectric_reflection(eta, tint=1.0):
    """Exact dielectric Fresnel times tint, for a reflection-only lobe (the Principled coat)."""
    def fresnel(cos_h):
        f, _ = dielectric(cos_h, eta)
        return (color(tint, f.shape[0]) * f[None, :]).astype(np.float32)
    return fresnel


def conductor_reflection(n, k):
    """Exact conductor Fresnel (Metallic BSDF, Physical Conductor)."""
    return lambda cos_h: conductor(cos_h, n, k)


def remapped_reflection(eta, f0, f90=1.0, tint=1.0):
    """Remapped generalized Schlick times reflection tint, for a reflection lobe (Principled specular)."""
    def fresnel(cos_h):
        f, _ = remapped(cos_h, eta, f0, f90)
        return (f * color(tint, f.shape[1])).astype(np.float32)
    return fresnel


def generalized_schlick_reflection(eta, f0, f90, exponent, tint=1.0):
    """Generalized Schlick with exponent >= 0 times reflection tint (OSL closures, the s tables)."""
    def fresnel(cos_h):
        f, _ = generalized_schlick(cos_h, eta, f0, f90, exponent)
        return (f * color(tint, f.shape[1])).astype(np.float32)
    return fresnel


def dielectric_glass(reflection_tint=1.0, transmission_tint=1.0):
    """(R, T) = (F tint_r, (1 - F) tint_t) with the exact dielectric F (the glass tables, Principled
    coat-like DIELECTRIC closures)."""
    def fresnel(cos_h, eta):
        f, _ = dielectric(cos_h, eta)
        num = f.shape[0]
        return ((color(reflection_tint, num) * f).astype(np.float32),
                (color(transmission_tint, num) * (ONE - f)).astype(np.float32))
    return fresnel


def remapped_glass(f0, f90=1.0, reflection_tint=1.0, transmission_tint=1.0):
    """(R, T) = (F tint_r, (1 - F) tint_t) with the remapped generalized Schlick F (Glass BSDF:
    f0 = F0(IOR), f90 = 1, both tints = colour; Principled transmission: f0 = F0(IOR) * specular tint,
    transmission tint = sqrt(base colour))."""
    def fresnel(cos_h, eta):
        f, _ = remapped(cos_h, eta, f0, f90)
        num = f.shape[1]
        return ((f * color(reflection_tint, num)).astype(np.float32),
                ((ONE - f) * color(transmission_tint, num)).astype(np.float32))
    return fresnel
