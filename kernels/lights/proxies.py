"""Bounding shapes of the lights with a surface in an Embree scene of their own, so that BSDF rays test only the
lights they may hit.
"""
from __future__ import annotations

import numpy as np

from ..accel import Accel
from .common import DISK, RECT

# With more lights with a surface than this, BSDF rays find the lights they cross through Embree
# (LightProxies) instead of testing every light.
PROXY_MIN_LIGHTS = 8
# A ray crosses at most this many proxy faces (two per light it passes): a ray along which more than
# half this many lights overlap misses the rest.
MAX_PROXY_CROSSINGS = 1024


class LightProxies:
    """Bounding shapes of the lights with a surface, in an Embree scene of their own: an octahedron
    around each light's bounding sphere (a sized point light's own sphere, an area light's circumscribed
    one). BSDF rays collect every proxy they cross (lights are transparent to each other), so the exact
    tests run only on the few (ray, light) pairs that may hit."""

    def __init__(self, ids, kind, position, radius, size):
        area = (kind[ids] == RECT) | (kind[ids] == DISK)
        bound = np.where(area, 0.5 * np.hypot(size[ids, 0], size[ids, 1]), radius[ids]).astype(np.float64)
        # |x| + |y| + |z| <= r sqrt(3) holds the ball of radius r, widened a little for rounding.
        a = bound * np.sqrt(3.0) * 1.01
        # Each octahedron turned its own way: lights on a grid would otherwise share face planes, and
        # of two faces at the same distance a ray would step past the second.
        axes = _random_rotations(len(a)) * a[:, None, None]
        c = position[ids].astype(np.float64)[:, None, :]
        corners = [np.stack([sx * axes[:, :, 0], sy * axes[:, :, 1], sz * axes[:, :, 2]], axis=1) + c
                   for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
        self.owner = np.tile(ids, 8)
        positions = np.concatenate(corners).astype(np.float32)
        self.accel = Accel(positions, threads=1)
        extent = max(float(np.abs(positions).max()), 1e-3)
        # Step past a face just crossed: far below any light's size, far above float32 rounding.
        self.step = np.float32(max(1e-4 * float(np.min(bound[bound > 0], initial=1.0)), extent * 1e-6))

    def candidates(self, ox, oy, oz, dx, dy, dz, t_max):
        """(ray, light) pairs, each once, for every proxy a ray crosses before t_max."""
        n = len(ox)
        live = np.arange(n)
        travelled = np.zeros(n, np.float32)
        dirs = np.stack([dx, dy, dz], axis=1).astype(np.float32)
        rays, lights = [], []
        for _ in range(MAX_PROXY_CROSSINGS):
            if not len(live):
                break
            t0 = travelled[live]
            origins = np.stack([ox[live] + dx[live] * t0, oy[live] + dy[live] * t0, oz[live] + dz[live] * t0],
                               axis=1).astype(np.float32)
            remaining = (t_max[live] - t0).astype(np.float32)
            hits = self.accel.intersect(origins, dirs[live], np.where(remaining > 0, remaining, np.float32(0)),
                                        split=False)
            got = np.flatnonzero((hits.prim >= 0) & (remaining > 0))
            rays.append(live[got])
            lights.append(np.take(self.owner, hits.prim[got]))
            live = live[got]
            travelled[live] += hits.t[got] + self.step
        if not rays:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        ray, light = np.concatenate(rays), np.concatenate(lights)
        key = np.unique(light.astype(np.int64) * n + ray)  # each pair once, grouped by light
        return key % n, key // n


def _random_rotations(n: int) -> np.ndarray:
    """(n, 3, 3) rotation matrices (columns are the rotated axes) from a fixed seed."""
    q = np.random.default_rng(0x5EED).normal(size=(n, 4))
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=1),
        np.stack([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], axis=1),
        np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=1)], axis=2)
