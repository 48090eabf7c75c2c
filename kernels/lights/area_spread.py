"""Area lights with a Spread below 180 degrees, for the light they cast, as Cycles lights with them
(kernel/light/area.h): each shading point samples only the part of the lamp its spread can reach it from, and the
lamp's radiance is dimmed off its normal by the soft-box grid (area.spread_attenuation).

A point P at height h in front of the lamp receives light only from the lamp's points within h tan(s/2) of the foot
of P on the lamp's plane (s the spread: beyond, the grid's attenuation is 0). Cycles' area_light_spread_clamp_light
samples the smallest of three shapes covering that part: the lamp itself, the spread's circle, or a rectangle (a
rectangle lamp always keeps a rectangle, sampled in solid angle; a disk lamp's is the box of the two circles' lens,
an ellipse's the circle's box clamped to the ellipse's); the other shapes are sampled uniformly in their area. A
sample outside the lamp carries no light. A BSDF ray that hits the lamp from P gets the density of the same shape
(intersect_pdf), so light samples and BSDF rays weigh each other by MIS as in Cycles. Spread 0: the lamp lights P
only along its normal, from the foot of P, with pi times its radiance (a delta light; Cycles' pdf of 1).
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from .common import DISK, area_to_solid_angle, direction
from ..vec import F32


class Footprint:
    """The shape each point p samples on its spread lamp (area_light_spread_clamp_light): lit (n,) bool (p is in
    front of the lamp and the spread reaches p from some of it); rect (n,) bool, a rectangle (else a disk or an
    ellipse); centre, ex, ey ((3,) tuples of (n,) float32): its centre and unit axes; lu, lv its extents;
    delta (n,) bool, spread 0; foot, the foot of p on the lamp's plane; height, p's distance from it."""

    def __init__(self, sampler, light, px, py, pz):
        c = sampler.position[light].T
        xa, ya, za = sampler.axis(light, 0), sampler.axis(light, 1), sampler.axis(light, 2)
        lu, lv = sampler.size[light, 0].astype(F32), sampler.size[light, 1].astype(F32)
        half_spread = np.take(sampler.spread, light).astype(np.float64) / 2
        tan_half = np.tan(half_spread).astype(F32)
        rel = (px - c[0], py - c[1], pz - c[2])
        height = -(rel[0] * za[0] + rel[1] * za[1] + rel[2] * za[2])      # in front: the lamp emits along -Z
        su = rel[0] * xa[0] + rel[1] * xa[1] + rel[2] * xa[2]
        sv = rel[0] * ya[0] + rel[1] * ya[1] + rel[2] * ya[2]
        r_s = height * tan_half
        disk = np.take(sampler.kind, light) == DISK
        is_round = disk & (lu == lv)
        lit = height > 0
        spread_circle = r_s == 0
        n = len(light)
        rect = ~disk
        cu, cv = np.zeros(n, F32), np.zeros(n, F32)        # the shape's centre in the lamp's (u, v)
        ex, ey = tuple(xa), tuple(ya)
        out_u, out_v = lu.copy(), lv.copy()

        with np.errstate(divide="ignore", invalid="ignore"):
            # A disk lamp: the spread's circle inside it, the lamp inside the circle, or the two crossing.
            rows = is_round & ~spread_circle
            dist = np.sqrt(su * su + sv * sv)
            r = F32(0.5) * lu
            lit &= ~(rows & (dist >= r + r_s))
            inner = np.abs(r - r_s)
            spread_circle |= rows & (dist <= inner) & (r_s < r)
            crossing = rows & (dist > inner)
            len_u_ = r + r_s - dist
            chord = np.sqrt(np.maximum(F32(4.0) * r_s * r_s - (dist + (r_s * r_s - r * r) / dist) ** 2, F32(0)))
            len_v_ = np.where(np.abs(r * r - r_s * r_s) >= dist * dist, F32(2.0) * np.minimum(r, r_s), chord)
            circle_area, spread_area = F32(np.pi) * r * r, F32(np.pi) * r_s * r_s
            lens = crossing & (len_u_ * len_v_ < np.minimum(circle_area, spread_area))
            # The lens's box: u from the foot toward the lamp's centre, v across; centred between the circles' edges.
            lens_ex = [-(su * xa[k] + sv * ya[k]) / dist for k in range(3)]
            half_way = F32(0.5) * (r_s - r)
            lens_cu = F32(0.5) * su + half_way * (-su / dist)
            lens_cv = F32(0.5) * sv + half_way * (-sv / dist)
            spread_circle |= crossing & ~lens & (spread_area < circle_area)

            # A rectangle or an ellipse lamp: the spread circle's box clamped to the lamp's.
            rows = ~is_round & ~spread_circle
            min_u, max_u = np.maximum(su - r_s, F32(-0.5) * lu), np.minimum(su + r_s, F32(0.5) * lu)
            min_v, max_v = np.maximum(sv - r_s, F32(-0.5) * lv), np.minimum(sv + r_s, F32(0.5) * lv)
            lit &= ~(rows & ((min_u >= max_u) | (min_v >= max_v)))
            box_u, box_v = max_u - min_u, max_v - min_v
            ellipse_area = np.where(disk, F32(np.pi / 4) * lu * lv, F32(np.inf))
            box = rows & (~disk | (box_u * box_v < np.minimum(ellipse_area, spread_area)))
            spread_circle |= rows & ~box & (spread_area < ellipse_area)

        box &= ~spread_circle
        cu = np.where(box, F32(0.5) * (min_u + max_u), cu)
        cv = np.where(box, F32(0.5) * (min_v + max_v), cv)
        out_u, out_v = np.where(box, box_u, out_u), np.where(box, box_v, out_v)
        lens &= ~spread_circle
        cu, cv = np.where(lens, lens_cu, cu), np.where(lens, lens_cv, cv)
        out_u, out_v = np.where(lens, len_u_, out_u), np.where(lens, len_v_, out_v)
        cu, cv = np.where(spread_circle, su, cu), np.where(spread_circle, sv, cv)
        diameter = F32(2.0) * r_s
        out_u, out_v = np.where(spread_circle, diameter, out_u), np.where(spread_circle, diameter, out_v)
        self.rect = (rect | box | lens) & ~spread_circle
        # The lens's axes: u toward the lamp's centre, v = -Z x u (a quarter turn about the emitting normal).
        lens_ey = (za[2] * lens_ex[1] - za[1] * lens_ex[2], za[0] * lens_ex[2] - za[2] * lens_ex[0],
                   za[1] * lens_ex[0] - za[0] * lens_ex[1])
        self.ex = tuple(np.where(lens, lens_ex[k], ex[k]).astype(F32) for k in range(3))
        self.ey = tuple(np.where(lens, lens_ey[k], ey[k]).astype(F32) for k in range(3))
        self.centre = tuple((c[k] + cu * xa[k] + cv * ya[k]).astype(F32) for k in range(3))
        self.lu, self.lv = out_u.astype(F32), out_v.astype(F32)
        self.lit = lit & np.isfinite(self.lu) & np.isfinite(self.lv)
        self.delta = tan_half == 0
        self.foot = tuple((c[k] + su * xa[k] + sv * ya[k]).astype(F32) for k in range(3))
        self.height = height
        self.lamp = (c, xa, ya, lu, lv, disk)

    def inside_lamp(self, qx, qy, qz) -> np.ndarray:
        """Whether points q of the lamp's plane lie on the lamp, with Cycles' margin (area_light_sample)."""
        c, xa, ya, lu, lv, disk = self.lamp
        rel = (qx - c[0], qy - c[1], qz - c[2])
        u = rel[0] * xa[0] + rel[1] * xa[1] + rel[2] * xa[2]
        v = rel[0] * ya[0] + rel[1] * ya[1] + rel[2] * ya[2]
        eu = F32(0.5 + 1e-7) * lu + F32(1e-6)
        ev = F32(0.5 + 1e-7) * lv + F32(1e-6)
        return np.where(disk, (u / eu) ** 2 + (v / ev) ** 2 <= F32(1.0), (np.abs(u) <= eu) & (np.abs(v) <= ev))

    def rectangles(self, px, py, pz, rows) -> sampling.SphericalRectangle:
        return sampling.SphericalRectangle((px[rows], py[rows], pz[rows]), tuple(v[rows] for v in self.centre),
                                           tuple(v[rows] for v in self.ex), tuple(v[rows] for v in self.ey),
                                           self.lu[rows], self.lv[rows])


def sample(sampler, light, px, py, pz, u1, u2, attenuation):
    """Light samples of spread lamps `light` from points p: (wx, wy, wz, dist, radiance (3, n), pdf, delta).
    attenuation(sampler, light, wx, wy, wz): the grid's factor along the sampled directions."""
    fp = Footprint(sampler, light, px, py, pz)
    ex, ey = fp.ex, fp.ey
    dx_, dy_ = sampling.sample_uniform_disk(u1, u2)
    a, b = dx_ * F32(0.5) * fp.lu, dy_ * F32(0.5) * fp.lv
    q = [fp.centre[k] + a * ex[k] + b * ey[k] for k in range(3)]
    rect = np.flatnonzero(fp.rect & fp.lit)
    if len(rect):
        spherical = fp.rectangles(px, py, pz, rect)
        for k, v in enumerate(spherical.sample(u1[rect], u2[rect])):
            q[k][rect] = v
    delta = fp.delta
    for k in range(3):
        q[k] = np.where(delta, fp.foot[k], q[k])
    wx, wy, wz, dist = direction(px, py, pz, *q)
    za = sampler.axis(light, 2)
    cos_l = wx * za[0] + wy * za[1] + wz * za[2]
    with np.errstate(invalid="ignore", over="ignore"):
        pdf = area_to_solid_angle(F32(np.pi / 4) * fp.lu * fp.lv, dist, cos_l)
        if len(rect):
            pdf[rect] = spherical.pdf(dist[rect], cos_l[rect])
    # Spread 0: exactly along the normal, pi times the radiance (the grid's factor there).
    wx, wy, wz = (np.where(delta, za[k], w) for k, w in enumerate((wx, wy, wz)))
    dist = np.where(delta, fp.height, dist)
    pdf = np.where(delta, F32(1.0), pdf)
    factor = np.where(delta, F32(np.pi), attenuation(sampler, light, wx, wy, wz))
    keep = fp.lit & fp.inside_lamp(*q) & (cos_l > 0) & (pdf > 0)
    radiance = np.where(keep, sampler.radiance_of[light].T * factor, F32(0.0))
    return wx, wy, wz, dist, radiance, np.where(keep, pdf, F32(0.0)), delta


def intersect_pdf(sampler, k, ox, oy, oz, t, denom) -> tuple[np.ndarray, np.ndarray]:
    """For rays from o that hit spread lamps k at distance t (denom: the cosine at the lamp): the pdf per solid
    angle sample() gives the hit, and whether the lamp can light o at all (else no light: Cycles' area_light_eval
    returns false). Spread 0 lamps are delta lights: no BSDF ray gets their light."""
    fp = Footprint(sampler, k, ox, oy, oz)
    pdf = area_to_solid_angle(F32(np.pi / 4) * fp.lu * fp.lv, np.abs(t), np.abs(denom))
    rect = np.flatnonzero(fp.rect & fp.lit)
    if len(rect):
        pdf[rect] = fp.rectangles(ox, oy, oz, rect).pdf(t[rect], denom[rect])
    return pdf, fp.lit & ~fp.delta
