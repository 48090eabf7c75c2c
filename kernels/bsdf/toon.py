"""Cycles 5.0's Toon BSDF lobes (`kernel/closure/bsdf_toon.h`, set up by `svm_node_closure_bsdf`): the
diffuse and the glossy component.

Contract (see the package docstring): local frame z = the closure's normal; `wo` toward the viewer
(Cycles' wi), `wi` toward the light or the sampled direction (Cycles' wo). Size and Smooth are angles
already set up (toon_angles): size = clamp(Size, 1e-5, 1) pi/2, smooth = clamp01(Smooth) pi/2.

Both lobes are a uniform cone of half-angle A = min(size + smooth, pi/2) about an axis: the normal
(diffuse) or the viewer's mirror direction R = (-wo.x, -wo.y, wo.z) (glossy). With theta the angle
between wi and the axis,

    pdf   = 1 / (2 pi (1 - cos A))                         for theta < A, else 0
    f_cos = pdf * I(theta)                                  (the cosine is not applied: Cycles' lobe)
    I     = 1 below size, 1 - (theta - size) / smooth up to size + smooth, 0 beyond

so a sample's weight f_cos / pdf is I(theta): a Toon closure scatters at most its weight. The diffuse
lobe only asks wi.z >= 0; the glossy one wo.z > 0 and wi.z > 0 (eval and sample). 1 - cos A is Cycles'
one_minus_cos (a Taylor expansion below 0.02 rad), so a Size of 0 gives a cone of 1.6e-5 rad, not a
division by zero. theta is acos of a float32 cosine, as in Cycles: the eval of such a narrow cone is 0
almost everywhere, while its sampler reports theta = 0 (the closure table keeps the sampler's value for
the lobe that sampled, lobes.SELF_EVALUATED).
"""
from __future__ import annotations

import numpy as np

from ..sampling import local_to_world, sample_uniform_cone_precise
from ..vec import F32, HALF_PI, INV_2PI, ONE, ZERO


def toon_angles(size, smooth):
    """Cycles' bsdf_toon_setup_common: the node's Size and Smooth as angles (size, smooth), (n,) float32."""
    size = np.clip(np.asarray(size, F32), F32(1e-5), ONE) * HALF_PI
    smooth = np.clip(np.nan_to_num(np.asarray(smooth, F32)), ZERO, ONE) * HALF_PI
    return size.astype(F32), smooth.astype(F32)


def _one_minus_cos(angle):
    """1 - cos(angle), exact enough for small angles (Cycles' one_minus_cos)."""
    return np.where(angle > F32(0.02), ONE - np.cos(angle), F32(0.5) * angle * angle).astype(F32)


def _cone(size, smooth):
    """(A, 1 - cos A, pdf inside the cone): the cone every toon direction lies in."""
    angle = np.minimum(size + smooth, HALF_PI)
    omc = _one_minus_cos(angle)
    return angle, omc, (INV_2PI / omc).astype(F32)


def _intensity(size, smooth, theta):
    """Cycles' bsdf_toon_get_intensity: 1 inside size, a linear ramp over smooth, 0 beyond."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ramp = ONE - (theta - size) / smooth
    ramped = (theta < size + smooth) & (smooth != 0)
    return np.where(theta < size, ONE, np.where(ramped, ramp, ZERO)).astype(F32)


def _about_axis(cos_theta, size, smooth, valid):
    """(f_cos, pdf) of a direction at cos_theta from the cone's axis, where valid."""
    theta = np.arccos(np.clip(np.maximum(cos_theta, ZERO), -ONE, ONE)).astype(F32)
    angle, _, pdf = _cone(size, smooth)
    inside = valid & (theta < angle)
    pdf = np.where(inside, pdf, ZERO).astype(F32)
    return (pdf * _intensity(size, smooth, theta)).astype(F32), pdf


def _mirror(wo):
    return (-wo[0], -wo[1], wo[2])


def diffuse_toon_eval(wo, wi, size, smooth):
    """(f_cos (N,), pdf (N,)) of the diffuse toon lobe, a cone about the normal."""
    return _about_axis(wi[2], size, smooth, wi[2] >= 0)


def glossy_toon_eval(wo, wi, size, smooth):
    """(f_cos (N,), pdf (N,)) of the glossy toon lobe, a cone about the mirror direction."""
    r = _mirror(wo)
    cos_r = r[0] * wi[0] + r[1] * wi[1] + r[2] * wi[2]
    return _about_axis(cos_r, size, smooth, (wo[2] > 0) & (wi[2] > 0))


def _sample_cone(axis, size, smooth, u1, u2):
    """A uniform direction in the cone about axis: (wi, weight = I(theta), pdf)."""
    _, omc, pdf = _cone(size, smooth)
    lx, ly, lz = sample_uniform_cone_precise(u1, u2, omc)
    wi = tuple(c.astype(F32) for c in local_to_world(lx, ly, lz, *axis))
    theta = np.arccos(np.minimum(lz, ONE)).astype(F32)
    return wi, _intensity(size, smooth, theta), np.broadcast_to(pdf, np.shape(u1)).astype(F32)


def diffuse_toon_sample(wo, size, smooth, u1, u2):
    """(wi, weight (N,), pdf (N,)): a uniform direction in the cone about the normal."""
    n = np.shape(u1)
    axis = (np.zeros(n, F32), np.zeros(n, F32), np.ones(n, F32))
    return _sample_cone(axis, size, smooth, u1, u2)


def glossy_toon_sample(wo, size, smooth, u1, u2):
    """(wi, weight (N,), pdf (N,)): a uniform direction in the cone about the mirror direction; weight and
    pdf 0 where the viewer or the direction is below the surface."""
    wi, weight, pdf = _sample_cone(tuple(np.asarray(c, F32) for c in _mirror(wo)), size, smooth, u1, u2)
    ok = (wo[2] > 0) & (wi[2] > 0)
    return wi, np.where(ok, weight, ZERO).astype(F32), np.where(ok, pdf, ZERO).astype(F32)
