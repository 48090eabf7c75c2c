"""Point and spot lights: a sized one lights a point as a uniform disk of its radius facing it, as Cycles does with
Soft Falloff on (Blender's default), or as a true sphere of that radius with it off; a zero-size one is a delta
light. sample, intersect (BSDF rays against the disk or the sphere) and the spot cone.
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..vec import PI
from .common import SPOT, area_to_solid_angle, direction


def smoothstep01(x):
    x = np.clip(x, np.float32(0.0), np.float32(1.0))
    return x * x * (np.float32(3.0) - np.float32(2.0) * x)


def sample(sampler, out, idx, light, px, py, pz, u1, u2):
    """Point and spot lights. With a radius, Cycles lights a point as a uniform disk of that radius
    facing it (checked against Cycles 5.0.1 on and off axis); without, they are delta lights."""
    c = sampler.position[light].T
    dx, dy, dz = c[0] - px, c[1] - py, c[2] - pz
    d2 = dx * dx + dy * dy + dz * dz
    inv = np.float32(1.0) / np.sqrt(np.maximum(d2, np.float32(1e-30)))
    ax, ay, az = dx * inv, dy * inv, dz * inv            # from the point toward the light
    r = sampler.radius[light]
    delta = r <= 0
    # A uniform point on the disk through c, perpendicular to the axis.
    ex, ey = sampling.sample_uniform_disk(u1, u2)
    tx, ty, tz, bx, by, bz = sampling.orthonormal_basis(ax, ay, az)
    qx = c[0] + r * (ex * tx + ey * bx)
    qy = c[1] + r * (ex * ty + ey * by)
    qz = c[2] + r * (ex * tz + ey * bz)
    wx, wy, wz, dist = direction(px, py, pz, qx, qy, qz)
    cos_l = wx * ax + wy * ay + wz * az
    pdf = area_to_solid_angle(PI * r * r, dist, cos_l)
    # The spot cone is evaluated along the sampled ray, as Cycles does (this softens its edge).
    radiance = sampler.radiance_of[light].T * attenuation(sampler, light, -wx, -wy, -wz)[None, :]
    # Delta lights: the exact direction, radiance becomes intensity / distance^2.
    dist_c = np.sqrt(d2)
    wx, wy, wz = np.where(delta, ax, wx), np.where(delta, ay, wy), np.where(delta, az, wz)
    dist = np.where(delta, dist_c, dist)
    radiance = np.where(delta[None, :], radiance / np.maximum(d2, np.float32(1e-30))[None, :], radiance)
    pdf = np.where(delta, np.float32(1.0), pdf)
    balls = sphere_rows(sampler, light)
    if len(balls):
        sw = sphere_sample(sampler, light[balls], px[balls], py[balls], pz[balls], u1[balls], u2[balls])
        for column, value in zip((wx, wy, wz, dist, pdf), sw[:5]):
            column[balls] = value
        radiance[:, balls] = sw[5]
    out.set(idx, wx, wy, wz, dist, radiance, pdf, delta)


def sphere_rows(sampler, k) -> np.ndarray:
    """Indices of the lights k that are spheres (Soft Falloff off and a radius: Cycles' is_sphere && radius != 0)."""
    if sampler.sphere is None:
        return np.zeros(0, np.int64)
    return np.flatnonzero(np.take(sampler.sphere, k) & (np.take(sampler.radius, k) > 0))


def _one_minus_cos(r2, d2):
    """1 - cos of the half angle a sphere of squared radius r2 subtends from squared distance d2 (> r2), in float64
    (Cycles' sin_sqr_to_one_minus_cos keeps small spheres' cones accurate the same way)."""
    s2 = r2.astype(np.float64) / d2.astype(np.float64)
    return (s2 / (1.0 + np.sqrt(np.maximum(1.0 - s2, 0.0)))).astype(np.float32)


def sphere_sample(sampler, light, px, py, pz, u1, u2):
    """Sphere lamps (Cycles' point_light_sample / spot_light_sample with is_sphere, kernel/light/point.h, spot.h):
    from outside, directions uniform in the cone the sphere subtends; from inside, uniform over all directions
    (Cycles takes a cosine hemisphere about the normal there, or the sphere where the surface transmits: only the
    noise differs). The spot's cone is evaluated along the sampled ray, outside the sphere only.
    Returns (wx, wy, wz, dist, pdf, radiance (3, n))."""
    c, r = sampler.position[light].T, sampler.radius[light]
    lx, ly, lz = c[0] - px, c[1] - py, c[2] - pz
    d2 = lx * lx + ly * ly + lz * lz
    r2 = r * r
    outside = d2 > r2
    d = np.sqrt(d2)
    inv = np.float32(1.0) / np.maximum(d, np.float32(1e-30))
    ax, ay, az = lx * inv, ly * inv, lz * inv            # from the point toward the centre
    one_minus = np.where(outside, _one_minus_cos(r2, np.where(outside, d2, r2 + 1)), np.float32(2.0))
    sx, sy, sz = sampling.sample_uniform_cone_precise(u1, u2, one_minus)
    tx, ty, tz, bx, by, bz = sampling.orthonormal_basis(ax, ay, az)
    wx, wy, wz = sx * tx + sy * bx + sz * ax, sx * ty + sy * by + sz * ay, sx * tz + sy * bz + sz * az
    pdf = np.where(outside, np.float32(1.0) / (np.float32(2 * np.pi) * one_minus), np.float32(1 / (4 * np.pi)))
    # The law of cosines: the near side from outside, the far side from inside.
    cos_t = sz
    root = np.sqrt(np.maximum(r2 - d2 + d2 * cos_t * cos_t, np.float32(0.0)))
    dist = d * cos_t - np.where(outside, root, -root)
    att = np.where(outside, attenuation(sampler, light, -wx, -wy, -wz), np.float32(1.0))
    return wx, wy, wz, dist.astype(np.float32), pdf.astype(np.float32), sampler.radiance_of[light].T * att[None, :]


def sphere_intersect(sampler, k, ox, oy, oz, dx, dy, dz):
    """Rays against sphere lamps k (Cycles' ray_sphere_intersect: from outside, the near side only; from inside,
    the far side), with sphere_sample's pdf."""
    c, r = sampler.position[k].T, sampler.radius[k]
    lx, ly, lz = c[0] - ox, c[1] - oy, c[2] - oz
    d2 = lx * lx + ly * ly + lz * lz
    r2 = r * r
    outside = d2 > r2
    along = lx * dx + ly * dy + lz * dz
    px_, py_, pz_ = lx - along * dx, ly - along * dy, lz - along * dz
    miss2 = px_ * px_ + py_ * py_ + pz_ * pz_
    root = np.sqrt(np.maximum(r2 - miss2, np.float32(0.0)))
    t = along - np.where(outside, root, -root)
    # Cycles' spot_light_intersect also turns away the rays leaving a spot's centre, which only matters for
    # points inside its sphere, where its light samples do not: Ember keeps them, as its samples do.
    hit = (miss2 <= r2) & ~(outside & (along < 0)) & (r > 0)
    t = np.where(hit, t, np.float32(-1.0))
    one_minus = np.where(outside, _one_minus_cos(r2, np.where(outside, d2, r2 + 1)), np.float32(2.0))
    pdf = np.where(outside, np.float32(1.0) / (np.float32(2 * np.pi) * one_minus), np.float32(1 / (4 * np.pi)))
    att = np.where(outside, attenuation(sampler, k, -dx, -dy, -dz), np.float32(1.0))
    return t, pdf.astype(np.float32), att.astype(np.float32)


def attenuation(sampler, light, vx, vy, vz):
    """Cycles' spot cone: smoothstep of (cos - cos_half) / (blend width); 1 for point lights.
    v is the unit direction from the light toward the point."""
    is_spot = sampler.kind[light] == SPOT
    zx, zy, zz = sampler.axis(light, 2)
    cos = -(vx * zx + vy * zy + vz * zz)
    cos_half, width = sampler.spot[light, 0], sampler.spot[light, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        soft = smoothstep01((cos - cos_half) / width)
    att = np.where(width > 0, soft, (cos > cos_half).astype(np.float32))
    return np.where(is_spot, att, np.float32(1.0)).astype(np.float32)


def intersect(sampler, k, ox, oy, oz, dx, dy, dz):
    """Rays against sized point lights k: the disk through each centre facing the ray origin."""
    c, r = sampler.position[k].T, sampler.radius[k]
    lx, ly, lz = c[0] - ox, c[1] - oy, c[2] - oz
    d2 = lx * lx + ly * ly + lz * lz
    inv = np.float32(1.0) / np.sqrt(np.maximum(d2, np.float32(1e-30)))
    nx, ny, nz = lx * inv, ly * inv, lz * inv
    denom = dx * nx + dy * ny + dz * nz
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (lx * nx + ly * ny + lz * nz) / denom
    hx, hy, hz = ox + t * dx - c[0], oy + t * dy - c[1], oz + t * dz - c[2]
    inside = (hx * hx + hy * hy + hz * hz <= r * r) & (denom > 0) & np.isfinite(t)
    t = np.where(inside, t, np.float32(-1.0))
    pdf = area_to_solid_angle(PI * r * r, np.abs(t), np.abs(denom))
    att = attenuation(sampler, k, -dx, -dy, -dz)
    balls = sphere_rows(sampler, k)
    if len(balls):
        t[balls], pdf[balls], att[balls] = sphere_intersect(sampler, k[balls], ox[balls], oy[balls], oz[balls],
                                                            dx[balls], dy[balls], dz[balls])
    return t, pdf, att
