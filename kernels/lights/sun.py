"""Suns: directions in the cone of the sun's disc (a delta light when the cone rounds to one direction), and
the discs that rays leaving the scene look into.
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..light_tree import rows_of
from .links import reaches


def sample(sampler, out, idx, light, px, py, pz, u1, u2):
    zx, zy, zz = sampler.axis(light, 2)  # toward the sun
    cos_max = sampler.sun_cos[light]
    delta = cos_max >= np.float32(1.0)
    lx, ly, lz = sampling.sample_uniform_cone(u1, u2, cos_max)
    wx, wy, wz = sampling.local_to_world(lx, ly, lz, zx, zy, zz)
    wx, wy, wz = np.where(delta, zx, wx), np.where(delta, zy, wy), np.where(delta, zz, wz)
    pdf = np.where(delta, np.float32(1.0), sampling.uniform_cone_pdf(np.minimum(cos_max, np.float32(1 - 1e-7))))
    out.set(idx, wx, wy, wz, np.float32(np.inf), sampler.sun_radiance[light].T, pdf, delta)


def seen(sampler, dx, dy, dz, bsdf_pdf=None, receiver=None, shadow_linked: bool = False, parts=None, types=None,
         points=None):
    """(3, n) radiance of the sun discs that rays leaving the scene along d (x, y, z of (n,)) look into, each
    weighed by MIS (power heuristic) against its own light samples given the pdf of the BSDF sample that
    chose d (None: not weighed, as after a singular bounce), as Cycles' escaped rays see suns; None when
    the scene has no sun with a disc. receiver: (n,) uint8 the light sets of the objects the rays left
    (Light Linking), or None: a ray sees only the suns that reach its set, and not the shadow-linked ones
    (dedicated rays count those, kernels/shadow_linking.py) unless shadow_linked, as Cycles'
    integrate_sun_lights (kernel/integrator/shade_background.h). parts: a list, or None: each sun's share is
    appended to it, (sun, columns (m,), (3, m) radiance), for its light group's pass. types: (n,) uint8 the
    rays' types, or None: a sun that does not see a ray's type gives it nothing (kernels/lights/ray_visibility.py).
    points: (px, py, pz, facing) of the vertices the rays left, where the choice weighs distant emitters per point
    (sampler.weighs_distant)."""
    if not len(sampler.sun_discs):
        return None
    out = np.zeros((3, len(dx)), np.float32)
    links = sampler.links if receiver is not None else None
    for k in sampler.sun_discs:
        zx, zy, zz = sampler.axes[k, :, 2]
        facing = dx * zx + dy * zy + dz * zz >= sampler.sun_cos[k]
        if links is not None:
            if links.shadow_linked[k] and not shadow_linked:
                continue
            facing &= reaches(links.light[k], receiver)
        if types is not None and sampler.visibility is not None:
            facing &= (types & sampler.visibility[k]) != 0
        inside = np.flatnonzero(facing)
        if not len(inside):
            continue
        weight = np.ones(len(inside), np.float32)
        if links is not None:
            if bsdf_pdf is not None:   # the pmf of the receivers' own choice (0: weight 1)
                light_pdf = links.pmf(k, receiver[inside]) * sampling.uniform_cone_pdf(sampler.sun_cos[k])
                weight = sampling.power_heuristic(np.take(bsdf_pdf, inside), light_pdf)
        elif bsdf_pdf is not None and sampler.select_pmf[k] > 0:
            if sampler.weighs_distant:
                px, py, pz, fac = points
                pmf = sampler.distant_pmf(int(k), len(inside), None, px[inside], py[inside], pz[inside],
                                          rows_of(fac, inside))
            else:
                pmf = np.full(len(inside), sampler.select_pmf[k], np.float32)
            light_pdf = (pmf * sampling.uniform_cone_pdf(sampler.sun_cos[k])).astype(np.float32)
            weight = sampling.power_heuristic(np.take(bsdf_pdf, inside), light_pdf)
        share = sampler.sun_radiance[k][:, None] * weight * _shaded(sampler, k, dx, dy, dz, inside)
        out[:, inside] += share
        if parts is not None:
            parts.append((int(k), inside, share))
    return out


def seen_by_camera(sampler, dx, dy, dz, parts=None):
    """(3, n) radiance of the sun discs that camera rays leaving the scene along d look into, of the suns whose
    Ray Visibility > Camera is on (sampler.camera); None when there is none. As Cycles' integrate_sun_lights
    (kernel/integrator/shade_background.h): unweighed (a camera ray skips MIS, PATH_RAY_MIS_SKIP), whatever the
    light linking (camera rays are no receivers), and never a shadow-linked sun (it skips those for every ray).
    parts: as seen's."""
    if sampler.camera is None:
        return None
    suns = [k for k in sampler.sun_discs if sampler.camera[k]
            and not (sampler.links is not None and sampler.links.shadow_linked[k])]
    if not suns:
        return None
    out = np.zeros((3, len(dx)), np.float32)
    for k in suns:
        zx, zy, zz = sampler.axes[k, :, 2]
        inside = np.flatnonzero(dx * zx + dy * zy + dz * zz >= sampler.sun_cos[k])
        if not len(inside):
            continue
        share = np.repeat(sampler.sun_radiance[k][:, None], len(inside), axis=1) * _shaded(sampler, k, dx, dy, dz, inside)
        out[:, inside] += share
        if parts is not None:
            parts.append((int(k), inside, share))
    return out


def _shaded(sampler, k, dx, dy, dz, inside):
    """(3, m) the emission of sun k's node program toward the rays `inside` leaving along d, where it varies
    (kernels/lights/shaders.py); else 1."""
    shaders = sampler.lamp_shaders
    if shaders is None or shaders.shader[k] < 0:
        return np.float32(1.0)
    m = len(inside)
    light = np.full(m, k)
    zeros = np.zeros(m, np.float32)
    return shaders.at_sample(light, zeros, zeros, zeros, np.take(dx, inside), np.take(dy, inside),
                             np.take(dz, inside), np.full(m, np.inf, np.float32))
