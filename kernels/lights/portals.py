"""Light portals: an area lamp marked Portal (Cycles' own setting) emits nothing and is not seen; it guides the
world's light samples through a window, as Cycles' background light samples through its portals
(kernel/light/background.h):

- A portal is possible at a shading point p on its inner side (the side its -Z faces, the side an area lamp
  lights): dot(direction, p - centre) > 1e-4 (background_portal_data_fetch_and_check_side).
- Where one or more are possible, half of the world's light samples go through them and half come from the
  world's own distribution, each method's pdf mixing both: the portal method's and the map's weights are both 1
  (scene/light.cpp device_update_background), so each has half where a portal is possible, the map all elsewhere.
- The portal method picks one of the possible portals uniformly (its second number rescaled), a rectangle's
  point uniformly in the solid angle it subtends, a disk's or an ellipse's uniformly in its area; its pdf is
  the sum, over the possible portals the direction passes through, of each one's pdf, over the number possible
  (background_portal_sample, background_portal_pdf). A disk's pdf is taken at the point the direction passes
  through, as its sample's is; Cycles' background_portal_pdf takes a disk portal's at its centre, which its
  samples do not follow (an MIS weight a little off, most where the window is near).

Table rows (Lights.portals, (P, PORTAL_COLUMNS) float32): centre (3), the edge along the lamp's x and along its y
(3 each: the axis times the lamp's Size X, Size Y, in world units), the unit direction it faces (its -Z, 3) and 1
for a disk or an ellipse, 0 for a square or a rectangle.
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..scene.lights import PORTAL_COLUMNS
from ..vec import F32
from .common import area_to_solid_angle, direction

# How far inside a portal a point must be to sample it, and how far along a ray its portal must be (Cycles').
_SIDE_EPSILON, _T_MIN = F32(1e-4), F32(1e-4)


class Portals:
    """The portals of a scene, from their table rows (P, PORTAL_COLUMNS)."""

    def __init__(self, rows: np.ndarray):
        rows = np.asarray(rows, np.float64).reshape(-1, PORTAL_COLUMNS)
        self.count = len(rows)
        self.centre = rows[:, 0:3].astype(F32)
        edge_u, edge_v = rows[:, 3:6], rows[:, 6:9]
        self.len_u = np.linalg.norm(edge_u, axis=1).astype(F32)
        self.len_v = np.linalg.norm(edge_v, axis=1).astype(F32)
        self.axis_u = (edge_u / np.maximum(self.len_u, 1e-30)[:, None]).astype(F32)
        self.axis_v = (edge_v / np.maximum(self.len_v, 1e-30)[:, None]).astype(F32)
        self.facing = rows[:, 9:12].astype(F32)
        self.round = rows[:, 12] > 0.5
        area = self.len_u.astype(np.float64) * self.len_v * np.where(self.round, np.pi / 4, 1.0)
        self.area = area.astype(F32)
        self.usable = area > 0

    def possible(self, px, py, pz) -> np.ndarray:
        """(P, n) bool: the portals whose inner side the points p are on."""
        c, f = self.centre, self.facing
        side = (f[:, 0:1] * (px[None] - c[:, 0:1]) + f[:, 1:2] * (py[None] - c[:, 1:2])
                + f[:, 2:3] * (pz[None] - c[:, 2:3]))
        return (side > _SIDE_EPSILON) & self.usable[:, None]

    def sample(self, px, py, pz, u1, u2, possible: np.ndarray):
        """Directions through one of the possible portals (possible: (P, n), at least one per point), picked
        uniformly with u2 (then rescaled). Returns (wx, wy, wz, pdf): pdf that of the portal method, every possible
        portal the direction passes through counted."""
        n = len(px)
        count = possible.sum(axis=0)
        scaled = u2 * count.astype(F32)
        pick = np.minimum(scaled.astype(np.int64), count - 1)
        u2 = np.minimum(scaled - pick.astype(F32), F32(1.0 - 2.0 ** -24))
        # The pick-th possible portal of each point.
        rank = np.cumsum(possible, axis=0) - 1
        chosen = np.argmax(possible & (rank == pick[None]), axis=0)
        wx, wy, wz, pdf = (np.zeros(n, F32) for _ in range(4))
        for k in range(self.count):
            rows = np.flatnonzero(chosen == k)
            if not len(rows):
                continue
            p = (px[rows], py[rows], pz[rows])
            if self.round[k]:
                a, b = sampling.sample_uniform_disk(u1[rows], u2[rows])
                a, b = a * (F32(0.5) * self.len_u[k]), b * (F32(0.5) * self.len_v[k])
                c, au, av = self.centre[k], self.axis_u[k], self.axis_v[k]
                q = tuple(c[j] + a * au[j] + b * av[j] for j in range(3))
                dx, dy, dz, dist = direction(*p, *q)
                pdf[rows] = self._disk_pdf(k, dx, dy, dz, dist)
            else:
                spherical = self._rectangle(k, p)
                q = spherical.sample(u1[rows], u2[rows])
                dx, dy, dz, dist = direction(*p, *q)
                pdf[rows] = spherical.pdf(dist, self._cos(k, dx, dy, dz))
            wx[rows], wy[rows], wz[rows] = dx, dy, dz
        # The other possible portals the direction passes through add theirs (Cycles' ignore_portal).
        for other in range(self.count):
            rows = np.flatnonzero(possible[other] & (chosen != other))
            if len(rows):
                pdf[rows] += self._pdf_through(other, px[rows], py[rows], pz[rows], wx[rows], wy[rows], wz[rows])
        pdf /= np.maximum(count, 1).astype(F32)
        return wx, wy, wz, pdf

    def pdf(self, px, py, pz, dx, dy, dz, possible: np.ndarray) -> np.ndarray:
        """(n,) float32 the portal method's pdf per solid angle of directions d from points p (0 where no portal is
        possible: possible (P, n))."""
        total = np.zeros(len(px), F32)
        for k in range(self.count):
            rows = np.flatnonzero(possible[k])
            if len(rows):
                total[rows] += self._pdf_through(k, px[rows], py[rows], pz[rows], dx[rows], dy[rows], dz[rows])
        return total / np.maximum(possible.sum(axis=0), 1).astype(F32)

    # ---- one portal
    def _rectangle(self, k, p) -> sampling.SphericalRectangle:
        """Rectangle portal k as seen from the points p (a tuple of three (n,) arrays)."""
        n = len(p[0])
        column = lambda value: np.full(n, value, F32)  # noqa: E731
        return sampling.SphericalRectangle(p, tuple(column(v) for v in self.centre[k]),
                                           tuple(column(v) for v in self.axis_u[k]),
                                           tuple(column(v) for v in self.axis_v[k]),
                                           column(self.len_u[k]), column(self.len_v[k]))

    def _cos(self, k, dx, dy, dz):
        """The cosine between -d and portal k's facing direction (> 0: d leaves through it from inside)."""
        f = self.facing[k]
        return -(dx * f[0] + dy * f[1] + dz * f[2])

    def _disk_pdf(self, k, dx, dy, dz, dist):
        return area_to_solid_angle(self.area[k], dist, self._cos(k, dx, dy, dz))

    def _pdf_through(self, k, px, py, pz, dx, dy, dz) -> np.ndarray:
        """Portal k's pdf of directions d from p: 0 where the ray misses it (ray_quad_intersect, either side)."""
        c, f = self.centre[k], self.facing[k]
        denom = dx * f[0] + dy * f[1] + dz * f[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((c[0] - px) * f[0] + (c[1] - py) * f[1] + (c[2] - pz) * f[2]) / denom
            hx, hy, hz = px + t * dx - c[0], py + t * dy - c[1], pz + t * dz - c[2]
            a = (hx * self.axis_u[k, 0] + hy * self.axis_u[k, 1] + hz * self.axis_u[k, 2]) / self.len_u[k]
            b = (hx * self.axis_v[k, 0] + hy * self.axis_v[k, 1] + hz * self.axis_v[k, 2]) / self.len_v[k]
        half = F32(0.5)
        inside = (a * a + b * b <= F32(0.25)) if self.round[k] else (np.abs(a) <= half) & (np.abs(b) <= half)
        hit = inside & np.isfinite(t) & (t > _T_MIN)
        if not hit.any():
            return np.zeros(len(px), F32)
        dist = np.where(hit, t, F32(1.0))
        if self.round[k]:
            pdf = self._disk_pdf(k, dx, dy, dz, dist)
        else:
            pdf = self._rectangle(k, (px, py, pz)).pdf(dist, np.abs(self._cos(k, dx, dy, dz)))
        return np.where(hit, pdf, F32(0.0)).astype(F32)
