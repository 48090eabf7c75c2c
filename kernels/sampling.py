"""Warps from [0, 1)^2 to directions, each with its pdf (per unit solid angle), and local frames.

Directions in a local frame have z along the shading normal. Arrays are per component (x, y, z),
each (N,) float32: the fast layout for NumPy.
"""
from __future__ import annotations

import numpy as np

from .vec import HALF, HALF_PI, INV_4PI, INV_PI, PI, TWO_PI, cross_xyz, dot_xyz


def sample_cosine_hemisphere(ux: np.ndarray, uy: np.ndarray):
    """Cosine-weighted direction (Malley: uniform disk lifted to the hemisphere). Returns x, y, z."""
    r = np.sqrt(ux)
    phi = TWO_PI * uy
    x = r * np.cos(phi)
    y = r * np.sin(phi)
    z = np.sqrt(np.maximum(np.float32(1.0) - ux, np.float32(0.0)))
    return x, y, z


def cosine_hemisphere_pdf(cos_theta: np.ndarray) -> np.ndarray:
    return np.maximum(cos_theta, np.float32(0.0)) * INV_PI


def sample_lecture_hemisphere(ux: np.ndarray, uy: np.ndarray):
    """The slide's parametrisation: theta = pi/2 u_y, phi = 2 pi u_x - pi. Returns x, y, z, sin(theta).

    Its pdf per solid angle is 1 / (pi^2 sin(theta)), so the estimator weight is pi^2 sin(theta).
    """
    theta = HALF_PI * uy
    phi = TWO_PI * ux - PI
    sin_t = np.sin(theta)
    return np.cos(phi) * sin_t, np.sin(phi) * sin_t, np.cos(theta), sin_t


def lecture_hemisphere_pdf(sin_theta: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.float32(1.0 / np.pi**2) / sin_theta


def sample_uniform_cone(ux: np.ndarray, uy: np.ndarray, cos_max: np.ndarray):
    """Uniform direction in the cone around +z with half-angle acos(cos_max). Returns x, y, z."""
    z = np.float32(1.0) - ux * (np.float32(1.0) - cos_max)
    r = np.sqrt(np.maximum(np.float32(1.0) - z * z, np.float32(0.0)))
    phi = TWO_PI * uy
    return r * np.cos(phi), r * np.sin(phi), z


def sample_uniform_cone_precise(ux: np.ndarray, uy: np.ndarray, one_minus_cos_max):
    """sample_uniform_cone given 1 - cos of the half-angle, which keeps cones narrower than float32's
    cosines (half-angles below about 3e-4 rad) apart from a single direction. Returns x, y, z."""
    t = ux * np.asarray(one_minus_cos_max, np.float32)
    z = np.float32(1.0) - t
    r = np.sqrt(np.maximum(t * (np.float32(2.0) - t), np.float32(0.0)))
    phi = TWO_PI * uy
    return r * np.cos(phi), r * np.sin(phi), z


def uniform_cone_pdf(cos_max) -> np.ndarray:
    return np.float32(1.0) / (TWO_PI * (np.float32(1.0) - cos_max))


def sample_uniform_disk(ux: np.ndarray, uy: np.ndarray):
    """Uniform point in the unit disk (polar map). Returns x, y."""
    r = np.sqrt(ux)
    phi = TWO_PI * uy
    return r * np.cos(phi), r * np.sin(phi)


def sample_uniform_disk_concentric(ux: np.ndarray, uy: np.ndarray):
    """Uniform point in the unit disk by Shirley's concentric map (Cycles' sample_uniform_disk,
    kernel/sample/mapping.h): squares to rings, keeping stratification. Returns x, y."""
    one, zero = np.float32(1.0), np.float32(0.0)
    a = np.float32(2.0) * ux - one
    b = np.float32(2.0) * uy - one
    wide = a * a > b * b
    r = np.where(wide, a, b)
    quarter_pi = HALF_PI * HALF
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(wide, quarter_pi * (b / a), HALF_PI - quarter_pi * (a / b))
    centre = (a == zero) & (b == zero)
    phi = np.where(centre, zero, phi)
    r = np.where(centre, zero, r)
    return (r * np.cos(phi)).astype(np.float32), (r * np.sin(phi)).astype(np.float32)


UNIFORM_SPHERE_PDF = INV_4PI


def sample_uniform_sphere(ux: np.ndarray, uy: np.ndarray):
    z = np.float32(1.0) - np.float32(2.0) * ux
    r = np.sqrt(np.maximum(np.float32(1.0) - z * z, np.float32(0.0)))
    phi = TWO_PI * uy
    return r * np.cos(phi), r * np.sin(phi), z


def orthonormal_basis(nx: np.ndarray, ny: np.ndarray, nz: np.ndarray):
    """Tangent frame (t, b) around unit n, branchless (Duff et al. 2017). Returns tx, ty, tz, bx, by, bz."""
    sign = np.where(nz >= 0, np.float32(1.0), np.float32(-1.0))
    a = np.float32(-1.0) / (sign + nz)
    b = nx * ny * a
    tx = np.float32(1.0) + sign * nx * nx * a
    ty = sign * b
    tz = -sign * nx
    bx = b
    by = sign + ny * ny * a
    bz = -ny
    return tx, ty, tz, bx, by, bz


def local_to_world(lx, ly, lz, nx, ny, nz):
    """Rotate a local direction (z along n) into world space."""
    tx, ty, tz, bx, by, bz = orthonormal_basis(nx, ny, nz)
    return (lx * tx + ly * bx + lz * nx,
            lx * ty + ly * by + lz * ny,
            lx * tz + ly * bz + lz * nz)


class SphericalRectangle:
    """A rectangle seen from points p, for directions uniform in the solid angle it subtends: the
    area-preserving parametrisation of Urena, Fajardo and King (2013), with the internal angles written
    as arcsines, which keeps the solid angle of a small or distant rectangle accurate in float32 (as Cycles
    does, kernel/light/area.h).

    Built from points p, the rectangle's centre c and unit edge directions ex, ey (each (x, y, z) of (N,)
    float32) and edge lengths lu, lv (N,). solid_angle (N,) is S; `usable` marks where S is large enough to
    be computed in float32 (elsewhere sample and pdf fall back to uniform area sampling, as Cycles' pdf
    does below S = 1e-5 or at grazing angles)."""

    def __init__(self, p, c, ex, ey, lu, lv):
        ez = cross_xyz(ex, ey)
        d = tuple(ci - pi for ci, pi in zip(c, p))
        z0 = dot_xyz(d, ez)
        # The frame's z away from the rectangle: the rectangle lies at z0 <= 0.
        flip = np.where(z0 > 0, np.float32(-1.0), np.float32(1.0))
        self.ez = tuple(e * flip for e in ez)
        self.z0 = z0 * flip
        xc, yc = dot_xyz(d, ex), dot_xyz(d, ey)
        half_u, half_v = np.float32(0.5) * lu, np.float32(0.5) * lv
        self.x0, self.x1, self.y0, self.y1 = xc - half_u, xc + half_u, yc - half_v, yc + half_v
        z2 = self.z0 * self.z0
        # z components of the unit normals of the four planes through p and the edges.
        nz = [v / np.sqrt(np.maximum(v * v + z2, np.float32(1e-37))) for v in (-self.y0, self.x1, self.y1, -self.x0)]
        g = [np.arcsin(np.clip(-nz[i] * nz[(i + 1) % 4], np.float32(-1.0), np.float32(1.0))) for i in range(4)]
        self.solid_angle = -(g[0] + g[1] + g[2] + g[3])
        self._offset = g[2] + g[3]
        self._b0, self._b1 = nz[0], nz[2]
        self.usable = (self.solid_angle >= np.float32(1e-5)) & ~np.all(
            [v * v > np.float32(0.99999) for v in nz], axis=0)
        self.p, self.ex, self.ey, self.lu, self.lv = p, ex, ey, lu, lv

    def sample(self, u1, u2):
        """Points (x, y, z) on the rectangle whose directions from p are uniform in its solid angle (where
        usable; uniform in its area elsewhere)."""
        au = u1 * self.solid_angle + self._offset
        sin_au = np.sin(au)
        with np.errstate(divide="ignore", invalid="ignore"):
            fu = np.where(sin_au != 0, (np.cos(au) * self._b0 + self._b1) / sin_au, np.float32(0.0))
            cu = np.clip(np.copysign(np.float32(1.0) / np.sqrt(fu * fu + self._b0 * self._b0), fu),
                         np.float32(-1.0), np.float32(1.0))
            xu = np.clip(-(cu * self.z0) / np.maximum(np.sqrt(np.float32(1.0) - cu * cu), np.float32(1e-7)),
                         self.x0, self.x1)
            d2 = xu * xu + self.z0 * self.z0
            h0 = self.y0 / np.sqrt(d2 + self.y0 * self.y0)
            h1 = self.y1 / np.sqrt(d2 + self.y1 * self.y1)
            hv = h0 + u2 * (h1 - h0)
            hv2 = hv * hv
            yv = np.where(hv2 < np.float32(1 - 1e-6), hv * np.sqrt(d2 / np.maximum(np.float32(1.0) - hv2, np.float32(1e-37))),
                          self.y1)
        # Uniform in the area where the solid angle cannot be trusted.
        xa = self.x0 + u1 * (self.x1 - self.x0)
        ya = self.y0 + u2 * (self.y1 - self.y0)
        xu, yv = np.where(self.usable, xu, xa), np.where(self.usable, yv, ya)
        return tuple(self.p[k] + xu * self.ex[k] + yv * self.ey[k] + self.z0 * self.ez[k] for k in range(3))

    def pdf(self, dist, cos_light):
        """pdf per solid angle of sample()'s directions, given the distance to the sampled point and the
        cosine at the rectangle (only used where the area fallback applies)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            spherical = np.float32(1.0) / self.solid_angle
            area = dist * dist / (self.lu * self.lv * cos_light)
        pdf = np.where(self.usable, spherical, area)
        return np.where((cos_light > 0) & np.isfinite(pdf), pdf, np.float32(0.0)).astype(np.float32)


def balance_heuristic(pdf_a: np.ndarray, pdf_b: np.ndarray) -> np.ndarray:
    """MIS weight of the strategy with pdf_a (beta = 1). Infinite pdf_a (a delta) gets weight 1. The world's
    light samples and BSDF rays use it when the world's distribution is compensated (environment.Environment.
    mis_balance): MIS compensation is derived for it, so the compensated world is less noisy with it than
    with the power heuristic; many small lamps are noisier with it and keep the power heuristic
    (docs/architecture.md, Next-event estimation)."""
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        w = pdf_a / (pdf_a + pdf_b)
    return np.where(np.isfinite(w), w, np.where(pdf_a > 0, np.float32(1.0), np.float32(0.0))).astype(np.float32)


def power_heuristic(pdf_a: np.ndarray, pdf_b: np.ndarray) -> np.ndarray:
    """MIS weight of the strategy with pdf_a (beta = 2). Infinite pdf_a (a delta) gets weight 1."""
    a2 = pdf_a * pdf_a
    b2 = pdf_b * pdf_b
    with np.errstate(invalid="ignore", over="ignore"):
        w = a2 / (a2 + b2)
    return np.where(np.isfinite(w), w, np.where(pdf_a > 0, np.float32(1.0), np.float32(0.0))).astype(np.float32)


class GuidedCdf:
    """np.searchsorted(cdf, x, side="right") for many x, through a guide table (Devroye's index search).

    cdf: sorted float64 values, one or more concatenated segments each offset by its number (segment s
    covers [s, s + 1)), so that x = s + u searches segment s alone. The guide holds, for K buckets per
    segment, the answer at each bucket's start; a query starts there and steps forward over the few
    entries of its bucket. On a 512 x 1024 HDRI map this is 4-5x faster than the binary search, whose
    ~20 random reads per query miss the cache. Answers are exactly searchsorted's.
    """

    STEPS = 3  # forward steps taken in NumPy; the rare queries still short are finished by searchsorted

    def __init__(self, cdf: np.ndarray, segments: int = 1, buckets: int = 0):
        self.cdf = np.ascontiguousarray(cdf, np.float64)
        self.segments = int(segments)
        self.buckets = int(buckets) or max(1, len(self.cdf) // self.segments)
        starts = np.arange(self.segments, dtype=np.float64)[:, None] + \
            np.arange(self.buckets, dtype=np.float64)[None, :] / self.buckets
        self.guide = np.searchsorted(self.cdf, starts.ravel(), side="right").astype(np.int64)

    def search(self, segment: np.ndarray | int, u: np.ndarray) -> np.ndarray:
        """searchsorted(cdf, segment + u) for u in [0, 1) (float32 or float64), as int64."""
        u = np.asarray(u, np.float64)
        x = u + segment
        k = self.buckets
        bucket = np.minimum((u * k).astype(np.int64), k - 1)
        if self.segments > 1:
            bucket += np.asarray(segment, np.int64) * k
        pos = np.take(self.guide, bucket)
        # Rounding of u * k can start a query one bucket late: step back where the entry before is above x.
        back = (pos > 0) & (np.take(self.cdf, np.maximum(pos - 1, 0)) > x)
        pos -= back
        n = len(self.cdf)
        todo, p, xs = np.arange(len(x)), pos, x
        for _ in range(self.STEPS):
            more = (p < n) & (np.take(self.cdf, np.minimum(p, n - 1)) <= xs)
            if not more.any():
                return pos
            todo, p, xs = todo[more], p[more] + 1, xs[more]
            pos[todo] = p
        pos[todo] = np.searchsorted(self.cdf, xs, side="right")
        return pos


def channel_mean(rgb: np.ndarray) -> np.ndarray:
    """(n,) mean of a (3, n) colour array's rows: rgb.mean(axis=0) bit for bit (the same float sums in the
    same order, then / 3), without NumPy's strided reduction, which costs 1.6x as much on 20k columns."""
    return (rgb[0] + rgb[1] + rgb[2]) / np.asarray(3, rgb.dtype)


# Columns of (k, n) arrays (colours, frames) at integer indices: NumPy's 2-D fancy index a[:, idx] costs about
# 3.7x np.take(a, idx, axis=1) when gathering 100k columns, and about 3x a row-by-row index when scattering.
def put_columns(a: np.ndarray, idx, value) -> None:
    """a[:, idx] = value, row by row (value (k, m), or broadcastable to it)."""
    value = np.broadcast_to(value, (a.shape[0], len(idx)))
    for k in range(a.shape[0]):
        row = a[k]
        row[idx] = value[k]


def scale_columns(a: np.ndarray, idx, factor) -> None:
    """a[:, idx] *= factor, row by row (factor (m,) or (k, m))."""
    factor = np.asarray(factor)
    for k in range(a.shape[0]):
        row = a[k]
        row[idx] *= factor[k] if factor.ndim == 2 else factor
