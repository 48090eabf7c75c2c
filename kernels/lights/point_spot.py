"""Point and spot lights: a sized one lights a point as a uniform disk of its radius facing it, as Cycles does;
a zero-size one is a delta light. sample, intersect (BSDF rays against the disk) and the spot cone.
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
    out.set(idx, wx, wy, wz, dist, radiance, pdf, delta)


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
    return t, pdf, att
