"""Cycles 5.0's Hair BSDF lobes (`kernel/closure/bsdf_hair.h`, set up by `svm_node_closure_bsdf`): the
Reflection and Transmission components of the Kajiya-Kay-like hair model Cycles took from OSL.

Contract (see the package docstring), with one difference: the lobes turn about the hair's tangent T, a unit
vector given in the same frame as the directions (z = the closure's normal N, which only says which side
reflection is evaluated on); T need not be perpendicular to N. `wo` points to the viewer (Cycles' wi), `wi`
to the light or the sampled direction (Cycles' wo). Roughnesses r1 (along the hair) and r2 (around it) are
clamped to [0.001, 1] by the caller (Cycles' setup); offset tilts the highlight along the hair (radians).

Angles are latitudes about T: theta_r of the viewer, theta_i of wi; theta_h = (theta_i + theta_r) / 2,
t = theta_h - offset; phi is the azimuth of wi about T, from the viewer's (reflection) or its opposite
(transmission). With a = atan(((pi/2 + theta_r)/2 - offset) / r1), b = atan(((-pi/2 + theta_r)/2 - offset)
/ r1):

    theta_pdf = r1 / (2 (t^2 + r1^2) (a - b) cos theta_i)          (a Cauchy lobe in theta_h)
    reflection:    phi_pdf = cos(phi / (2 r2)) / (4 r2), |phi| <= pi r2, and 0 where |phi| > pi/2
    transmission:  phi_pdf = r2 / (c ((pi - |phi|)^2 + r2^2)),  c = 2 atan(pi / (2 r2))
    pdf = theta_pdf phi_pdf,  f_cos = pdf

so a sample's weight is 1. Evaluated, reflection is 0 where wi is below N and transmission where it is
above; sampled, neither checks a side (Cycles sends such rays on), and the reflection sampler reports
phi_pdf = cos(phi / 2) / (4 r2), not its density cos(phi / (2 r2)) / (4 r2): the MIS weights take these as
Cycles does. Directions within 0.001 rad of T are dropped. Cycles' fast_acosf, fast_atan2f and fast_cosf
are approximations (errors below 1e-4 rad); here they are exact.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, HALF_PI, ONE, PI, ZERO, dot_xyz, normalize_xyz


def _latitude(t, w):
    """(sin-like height along T, unit direction of w about T, latitude pi/2 - acos(w.T))."""
    z = dot_xyz(t, w)
    about = tuple(c.astype(F32) for c in normalize_xyz(tuple(wc - tc * z for wc, tc in zip(w, t))))
    return about, (HALF_PI - np.arccos(np.clip(z, -ONE, ONE))).astype(F32)


def _theta_range(theta_r, r1, offset):
    """Cycles' a and b: the Cauchy lobe's arctangent bounds."""
    a = np.arctan(((HALF_PI + theta_r) * F32(0.5) - offset) / r1)
    b = np.arctan(((-HALF_PI + theta_r) * F32(0.5) - offset) / r1)
    return a.astype(F32), b.astype(F32)


def _theta_pdf(t, r1, a, b, cos_theta_i):
    with np.errstate(divide="ignore", invalid="ignore"):
        return (r1 / (F32(2.0) * (t * t + r1 * r1) * (a - b) * cos_theta_i)).astype(F32)


def _eval(wo, wi, tangent, r1, r2, offset, transmission: bool):
    locy, theta_r = _latitude(tangent, wo)
    wi_about, theta_i = _latitude(tangent, wi)
    cos_phi = dot_xyz(wi_about, locy)
    a, b = _theta_range(theta_r, r1, offset)
    t = (theta_i + theta_r) * F32(0.5) - offset
    away = HALF_PI - np.abs(theta_i) >= F32(0.001)
    if transmission:
        p = PI - np.arccos(np.clip(cos_phi, -ONE, ONE))
        c = F32(2.0) * np.arctan(HALF_PI / r2)
        phi_pdf = r2 / (c * (p * p + r2 * r2))
        valid = away & (wi[2] < 0)
    else:
        phi = np.minimum(np.arccos(np.clip(cos_phi, -ONE, ONE)) / r2, PI)
        phi_pdf = np.cos(phi * F32(0.5)) * F32(0.25) / r2
        valid = away & (cos_phi >= 0) & (wi[2] >= 0)
    with np.errstate(invalid="ignore", over="ignore"):
        pdf = phi_pdf * _theta_pdf(t, r1, a, b, np.cos(theta_i))
    pdf = np.where(valid & np.isfinite(pdf), pdf, ZERO).astype(F32)
    return pdf, pdf.copy()


def hair_reflection_eval(wo, wi, tangent, r1, r2, offset):
    """(f_cos (N,), pdf (N,)) of the reflection lobe; see the module docstring."""
    return _eval(wo, wi, tangent, r1, r2, offset, transmission=False)


def hair_transmission_eval(wo, wi, tangent, r1, r2, offset):
    """(f_cos (N,), pdf (N,)) of the transmission lobe; see the module docstring."""
    return _eval(wo, wi, tangent, r1, r2, offset, transmission=True)


def _sample(wo, tangent, r1, r2, offset, u1, u2, transmission: bool):
    locy, theta_r = _latitude(tangent, wo)
    locx = (locy[1] * tangent[2] - locy[2] * tangent[1], locy[2] * tangent[0] - locy[0] * tangent[2],
            locy[0] * tangent[1] - locy[1] * tangent[0])
    a, b = _theta_range(theta_r, r1, offset)
    t = (r1 * np.tan(u1 * (a - b) + b)).astype(F32)
    theta_i = F32(2.0) * (t + offset) - theta_r
    cos_ti, sin_ti = np.cos(theta_i).astype(F32), np.sin(theta_i).astype(F32)
    if transmission:
        c = F32(2.0) * np.arctan(HALF_PI / r2)
        p = (r2 * np.tan(c * (u2 - F32(0.5)))).astype(F32)
        phi = p + PI
        phi_pdf = r2 / (c * (p * p + r2 * r2))
    else:
        phi = F32(2.0) * np.arcsin(np.clip(ONE - F32(2.0) * u2, -ONE, ONE)) * r2
        phi_pdf = np.cos(phi * F32(0.5)) * F32(0.25) / r2
    cos_phi, sin_phi = np.cos(phi).astype(F32), np.sin(phi).astype(F32)
    wi = tuple(((cos_phi * cos_ti) * y - (sin_phi * cos_ti) * x + sin_ti * tc).astype(F32)
               for y, x, tc in zip(locy, locx, tangent))
    with np.errstate(invalid="ignore", over="ignore"):
        pdf = np.abs(phi_pdf * _theta_pdf(t, r1, a, b, cos_ti))
    pdf = np.where((HALF_PI - np.abs(theta_i) >= F32(0.001)) & np.isfinite(pdf), pdf, ZERO).astype(F32)
    return wi, np.where(pdf > 0, ONE, ZERO).astype(F32), pdf


def hair_reflection_sample(wo, tangent, r1, r2, offset, u1, u2):
    """(wi, weight (N,), pdf (N,)) of the reflection lobe; see the module docstring."""
    return _sample(wo, tangent, r1, r2, offset, u1, u2, transmission=False)


def hair_transmission_sample(wo, tangent, r1, r2, offset, u1, u2):
    """(wi, weight (N,), pdf (N,)) of the transmission lobe; see the module docstring."""
    return _sample(wo, tangent, r1, r2, offset, u1, u2, transmission=True)
