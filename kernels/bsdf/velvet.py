"""Cycles' Ashikhmin velvet lobe (`kernel/closure/bsdf_ashikhmin_velvet.h`, the Sheen BSDF's "Ashikhmin"
distribution, Blender's Velvet BSDF before 4.0): Ashikhmin, Premoze and Shirley's 2000 microfacet sheen, its
distribution of half vectors

    D(h) = exp(-cot^2 theta_h / sigma^2) / (pi sigma^2 sin^4 theta_h),

with the shadowing G = min(1, 2 cos_h / cos_hi cos_i, 2 cos_h / cos_hi cos_o) and no Fresnel, f cos = D G / (4 cos_v)
(cos_v toward the viewer), sigma the closure's roughness clamped to [0.01, 1]. Directions are sampled uniformly over
the hemisphere (pdf 1 / 2 pi), as Cycles samples it.

Contract as in the package docstring: local frame with z along the lobe's normal, directions (x, y, z) tuples of
(N,) float32 arrays, `wo` toward the viewer, `wi` toward the light or the sampled direction; the closure weight is
the caller's. Cycles files the closure as glossy for the light passes (CLOSURE_IS_BSDF_GLOSSY) and labels its
samples diffuse (bounce counts), which lobes.py records.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, INV_PI, ONE, ZERO

SIGMA_MIN = F32(0.01)          # bsdf_ashikhmin_velvet_setup: sigma at least this
UNIFORM_PDF = F32(0.5 / np.pi)  # the uniform hemisphere's density
EDGE = F32(1e-5)               # Cycles' limits on cos(N, H) near 1, on cos(H, viewer) and on the ratio


def _velvet(wo, wi, sigma, cos_v_min: F32):
    """(f cos (N,), valid (N,)) of the lobe for viewer wo and light wi, valid where Cycles evaluates it."""
    inv_sigma2 = ONE / np.square(np.maximum(np.asarray(sigma, F32), SIGMA_MIN))
    cos_v, cos_l = wo[2], wi[2]
    hx, hy, hz = wo[0] + wi[0], wo[1] + wi[1], wo[2] + wi[2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        length = np.sqrt(hx * hx + hy * hy + hz * hz)
        hx, hy, hz = hx / length, hy / length, hz / length
        cos_h = hz
        cos_hv = np.abs(wo[0] * hx + wo[1] * hy + wo[2] * hz)
        valid = (cos_v > cos_v_min) & (cos_l > 0) & (np.abs(cos_h) < ONE - EDGE) & (cos_hv > EDGE)
        ratio = np.maximum(cos_h / cos_hv, EDGE)
        shadowing = np.minimum(ONE, np.minimum(np.abs(2 * ratio * cos_v), np.abs(2 * ratio * cos_l)))
        sin2 = ONE - cos_h * cos_h
        cot2 = cos_h * cos_h / sin2
        d = np.exp(-cot2 * inv_sigma2) * inv_sigma2 * INV_PI / (sin2 * sin2)
        value = F32(0.25) * d * shadowing / cos_v
    return np.where(valid, value, ZERO).astype(F32), valid


def velvet_eval(wo, wi, sigma):
    """f cos and the pdf (1 / 2 pi where Cycles evaluates the lobe, else 0) of light direction wi."""
    value, valid = _velvet(wo, wi, sigma, ZERO)
    return value, np.where(valid, UNIFORM_PDF, ZERO).astype(F32)


def velvet_sample(wo, sigma, u1, u2):
    """A direction uniform over the upper hemisphere: (wi, weight = f cos / pdf, pdf)."""
    z = np.asarray(u1, F32)
    r = np.sqrt(np.maximum(ONE - z * z, ZERO))
    phi = F32(2.0 * np.pi) * np.asarray(u2, F32)
    wi = ((r * np.cos(phi)).astype(F32), (r * np.sin(phi)).astype(F32), z)
    value, valid = _velvet(wo, wi, sigma, EDGE)
    pdf = np.where(valid, UNIFORM_PDF, ZERO).astype(F32)
    return wi, (value / UNIFORM_PDF).astype(F32), pdf
