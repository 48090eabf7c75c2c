"""Area lights: rectangles sampled uniformly in the solid angle they subtend, disks uniformly in their area, as
Cycles samples them (kernel/light/area.h); sample, and intersect for BSDF rays.
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from . import area_spread
from .common import DISK, RECT, area_to_solid_angle, direction


def sample(sampler, out, idx, light, px, py, pz, u1, u2):
    """Rectangles uniformly in the solid angle they subtend, disks uniformly in their area, as Cycles
    samples them (kernel/light/area.h): the MIS weights, and so what overlapping lamps add up to
    (intersect), are Cycles'. Lamps with a Spread below pi sample the part of them that reaches each point
    (area_spread)."""
    spread = spread_rows(sampler, light)
    if len(spread):
        *sampled, delta = area_spread.sample(sampler, light[spread], px[spread], py[spread], pz[spread], u1[spread],
                                             u2[spread], spread_attenuation)
        out.set(idx[spread], *sampled, delta)
        if len(spread) == len(light):
            return
        plain = np.setdiff1d(np.arange(len(light)), spread)
        idx, light, px, py, pz, u1, u2 = (v[plain] for v in (idx, light, px, py, pz, u1, u2))
    sx, sy = sampler.size[light, 0], sampler.size[light, 1]
    disk = sampler.kind[light] == DISK
    dx_, dy_ = sampling.sample_uniform_disk(u1, u2)
    a = dx_ * np.float32(0.5) * sx
    b = dy_ * np.float32(0.5) * sy
    c = sampler.position[light].T
    xa, ya, za = sampler.axis(light, 0), sampler.axis(light, 1), sampler.axis(light, 2)
    qx = c[0] + a * xa[0] + b * ya[0]
    qy = c[1] + a * xa[1] + b * ya[1]
    qz = c[2] + a * xa[2] + b * ya[2]
    rect = np.flatnonzero(~disk)
    if len(rect):
        spherical = rectangles(sampler, light[rect], px[rect], py[rect], pz[rect])
        q = spherical.sample(u1[rect], u2[rect])
        qx[rect], qy[rect], qz[rect] = q
    wx, wy, wz, dist = direction(px, py, pz, qx, qy, qz)
    cos_l = wx * za[0] + wy * za[1] + wz * za[2]  # > 0: the point is on the emitting (-Z) side
    pdf = area_to_solid_angle(sampler.area[light], dist, cos_l)
    if len(rect):
        pdf[rect] = spherical.pdf(dist[rect], cos_l[rect])
    radiance = np.where(cos_l > 0, sampler.radiance_of[light].T, np.float32(0.0))
    out.set(idx, wx, wy, wz, dist, radiance, pdf)


def rectangles(sampler, light, px, py, pz) -> sampling.SphericalRectangle:
    """Rectangular lights as seen from points p."""
    c, xa, ya = sampler.position[light].T, sampler.axis(light, 0), sampler.axis(light, 1)
    return sampling.SphericalRectangle((px, py, pz), tuple(c), tuple(xa), tuple(ya),
                                       sampler.size[light, 0], sampler.size[light, 1])


def intersect(sampler, k, ox, oy, oz, dx, dy, dz):
    """Rays against area lights k (rectangles and disks, emitting toward their -Z)."""
    c = sampler.position[k].T
    xa, ya, za = sampler.axis(k, 0), sampler.axis(k, 1), sampler.axis(k, 2)
    denom = dx * za[0] + dy * za[1] + dz * za[2]          # > 0: travelling into the emitting face
    # The plane's distance as Cycles computes it (ray_quad_intersect): coplanar lamps meet a ray at
    # the same float wherever their centres are, and the ray steps over all but the first (intersect).
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((c[0] * za[0] + c[1] * za[1] + c[2] * za[2]) - (ox * za[0] + oy * za[1] + oz * za[2])) / denom
    hx, hy, hz = ox + t * dx - c[0], oy + t * dy - c[1], oz + t * dz - c[2]
    with np.errstate(invalid="ignore"):
        a = (hx * xa[0] + hy * xa[1] + hz * xa[2]) / sampler.size[k, 0]
        b = (hx * ya[0] + hy * ya[1] + hz * ya[2]) / sampler.size[k, 1]
    inside = np.where(sampler.kind[k] == DISK, a * a + b * b <= np.float32(0.25),
                      (np.abs(a) <= np.float32(0.5)) & (np.abs(b) <= np.float32(0.5)))
    valid = inside & (denom > 0) & np.isfinite(t)
    t = np.where(valid, t, np.float32(-1.0))
    pdf = area_to_solid_angle(sampler.area[k], np.abs(t), np.abs(denom))
    spread = np.flatnonzero(valid & spread_mask(sampler, k))
    rect = np.flatnonzero(valid & (sampler.kind[k] == RECT) & ~spread_mask(sampler, k))
    if len(rect):
        seen = rectangles(sampler, k[rect], ox[rect], oy[rect], oz[rect])
        pdf[rect] = seen.pdf(t[rect], denom[rect])
    att = np.ones(len(k), np.float32)
    if len(spread):
        # A spread lamp's pdf is its sampled part's, as seen from the ray's origin (area_spread); its grid dims it.
        pdf[spread], lit = area_spread.intersect_pdf(sampler, k[spread], ox[spread], oy[spread], oz[spread],
                                                     t[spread], denom[spread])
        att[spread] = np.where(lit, spread_attenuation(sampler, k[spread], dx[spread], dy[spread], dz[spread]), 0.0)
    return t, pdf, att


def spread_mask(sampler, k) -> np.ndarray:
    """(n,) bool: which of the area lights k have a Spread below pi."""
    if sampler.spread is None:
        return np.zeros(len(k), bool)
    return np.take(sampler.spread, k) < np.float32(np.pi)


def spread_rows(sampler, k) -> np.ndarray:
    return np.flatnonzero(spread_mask(sampler, k))


def spread_attenuation(sampler, k, dx, dy, dz) -> np.ndarray:
    """(n,) float32 the factor by which an area light k (n,) of Spread below pi dims its radiance seen along d (the
    rays' unit directions), 1 for every other lamp: Cycles' soft-box grid (kernel/light/area.h
    area_light_spread_attenuation), max((tan(s/2) - tan a) N, 0) with a the angle between -d and the light's normal
    and N = 1 / (tan(s/2) - s/2) (3 / (s/2)^3 below s/2 = 0.05), normalising the light's power
    (scene/light.cpp); spread 0: pi along the normal alone."""
    spread = np.take(sampler.spread, k).astype(np.float64)
    za = sampler.axis(k, 2)
    cos_a = np.clip((dx * za[0] + dy * za[1] + dz * za[2]).astype(np.float64), 1e-12, 1.0)
    tan_a = np.sqrt(np.maximum(1.0 - cos_a * cos_a, 0.0)) / cos_a
    half = spread / 2
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        tan_half = np.tan(half)
        normal = np.where(half > 0.05, 1.0 / (tan_half - half), 3.0 / half ** 3)
        out = np.where(half > 0, np.maximum((tan_half - tan_a) * normal, 0.0), np.where(tan_a > 1e-5, 0.0, np.pi))
    area = (np.take(sampler.kind, k) == RECT) | (np.take(sampler.kind, k) == DISK)
    return np.where(area & (spread < np.float32(np.pi)), out, 1.0).astype(np.float32)
