"""Equiangular distance sampling toward a point (Kulla and Fajardo 2012, "Importance Sampling Techniques for
Path Tracing in Participating Media"), as Cycles samples where along a ray in a medium to take a light
sample (volume_equiangular_sample and volume_equiangular_pdf, kernel/integrator/shade_volume.h): the
distance's density is proportional to 1 / (squared distance to the point), over the range [t_min, t_max)
of the ray; uniform where the range subtends almost no angle."""
from __future__ import annotations

import numpy as np

THETA_MIN = 1e-6    # below this angle the range is sampled uniformly (Cycles)


def _frame(origins, dirs, point):
    """(delta, D): the distance along each ray to the point's foot, and the point's distance from the ray."""
    rel = point - origins
    delta = np.einsum("ij,ij->i", rel, dirs)
    foot = rel - dirs * delta[:, None]
    return delta, np.sqrt(np.einsum("ij,ij->i", foot, foot))


def sample(origins, dirs, point, t_min, t_max, u):
    """(t, pdf) float64 (n,): distances in [t_min, t_max) (t_max may be inf) drawn toward point (n, 3); pdf 0
    where the ray passes through the point."""
    delta, d = _frame(origins.astype(np.float64), dirs.astype(np.float64), point.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        theta_a = np.arctan2(t_min - delta, d)
        theta_b = np.arctan2(t_max - delta, d)
        theta_d = theta_b - theta_a
        flat = theta_d < THETA_MIN
        t_ = d * np.tan(u * theta_b + (1 - u) * theta_a)
        pdf = d / (theta_d * (d * d + t_ * t_))
        t = np.clip(delta + t_, t_min, t_max)
        span = t_max - t_min
        t = np.where(flat, t_min + u * np.where(np.isfinite(span), span, 0.0), t)
        pdf = np.where(flat, np.where(np.isfinite(span) & (span > 0), 1.0 / span, 0.0), pdf)
    ok = (d > 0) & np.isfinite(pdf) & np.isfinite(t)
    return np.where(ok, t, t_min), np.where(ok, pdf, 0.0)


def pdf(origins, dirs, point, t_min, t_max, t):
    """The density of distances t (n,) under sample()."""
    delta, d = _frame(origins.astype(np.float64), dirs.astype(np.float64), point.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        theta_d = np.arctan2(t_max - delta, d) - np.arctan2(t_min - delta, d)
        t_ = t - delta
        out = np.where(theta_d < THETA_MIN, 1.0 / (t_max - t_min), d / (theta_d * (d * d + t_ * t_)))
    return np.where((d > 0) & np.isfinite(out), out, 0.0)


def cone_range(origins, dirs, apex, axis, cos_half, end):
    """(t0, t1, hit) float64, float64, bool (n,): the part of each ray [0, end) inside a cone (apex, unit axis,
    cosine of its half angle, at least 0) where a spot light shines, as Cycles narrows equiangular sampling to
    it (spot_light_valid_ray_segment); a solid cone of half angle up to 90 degrees is convex, so the part is
    one interval."""
    v = origins.astype(np.float64) - apex
    d = dirs.astype(np.float64)
    a = axis.astype(np.float64)
    c2 = cos_half.astype(np.float64) ** 2
    da, va = np.einsum("ij,ij->i", d, a), np.einsum("ij,ij->i", v, a)
    dv, vv = np.einsum("ij,ij->i", d, v), np.einsum("ij,ij->i", v, v)
    qa, qb, qc = da * da - c2, 2 * (da * va - c2 * dv), va * va - c2 * vv
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = qb * qb - 4 * qa * qc
        root = np.sqrt(np.maximum(disc, 0.0))
        r1, r2 = (-qb - root) / (2 * qa), (-qb + root) / (2 * qa)
    lo_r, hi_r = np.fmin(r1, r2), np.fmax(r1, r2)
    lo_r = np.where(disc >= 0, lo_r, np.inf)
    hi_r = np.where(disc >= 0, hi_r, np.inf)
    fin = np.where(np.isfinite(end), end, np.maximum(np.where(np.isfinite(hi_r), hi_r, 0.0), 0.0) * 2 + 1e6)
    bounds = np.stack([np.zeros_like(fin), np.clip(lo_r, 0, fin), np.clip(hi_r, 0, fin), fin])

    def inside(t):
        x = v + d * t[:, None]
        return np.einsum("ij,ij->i", x, a) >= np.sqrt(c2) * np.sqrt(np.einsum("ij,ij->i", x, x))

    t0, t1 = np.zeros_like(fin), np.zeros_like(fin)
    hit = np.zeros(len(fin), bool)
    for k in range(3):
        a0, a1 = bounds[k], bounds[k + 1]
        ok = ~hit & (a1 > a0) & inside((a0 + a1) / 2)
        t0, t1, hit = np.where(ok, a0, t0), np.where(ok, a1, t1), hit | ok
    t1 = np.where(hit & ~np.isfinite(end) & (t1 == fin) , np.inf, t1)
    return t0, t1, hit
