"""The world: constant radiance or an equirectangular HDRI looked up in Cycles' convention.

Cycles' equirectangular map: u = 0.5 - atan2(d.y, d.x) / (2 pi), v = 1 - acos(d.z) / pi, with the
image's row 0 at the bottom (v = 0 looks straight down). d is the world direction taken to the
map's frame by env_from_world.
"""
from __future__ import annotations

import numpy as np

from .scene import World
from .textures import Texture

INV_2PI = np.float32(0.5 / np.pi)
INV_PI = np.float32(1.0 / np.pi)


def direction_to_equirect(dx, dy, dz):
    """World-frame unit direction components -> (u, v) in [0, 1]."""
    u = np.float32(0.5) - np.arctan2(dy, dx) * INV_2PI
    v = np.float32(1.0) - np.arccos(np.clip(dz, np.float32(-1.0), np.float32(1.0))) * INV_PI
    return u, v


def equirect_to_direction(u, v):
    """Inverse of direction_to_equirect. Returns dx, dy, dz and sin(theta)."""
    phi = (np.float32(0.5) - u) * np.float32(2.0 * np.pi)
    theta = (np.float32(1.0) - v) * np.float32(np.pi)
    sin_t = np.sin(theta)
    return np.cos(phi) * sin_t, np.sin(phi) * sin_t, np.cos(theta), sin_t


class Environment:
    """World radiance for escaped rays."""

    def __init__(self, world: World):
        self.world = world
        self.strength = np.float32(world.strength)
        self.rotation = np.asarray(world.env_from_world, np.float32)
        self.texture = Texture(world.hdri) if world.hdri is not None else None
        self.constant = (np.asarray(world.color, np.float32) * self.strength)[:, None]

    @property
    def is_constant(self) -> bool:
        return self.texture is None

    def to_env(self, dx, dy, dz):
        r = self.rotation
        return (r[0, 0] * dx + r[0, 1] * dy + r[0, 2] * dz,
                r[1, 0] * dx + r[1, 1] * dy + r[1, 2] * dz,
                r[2, 0] * dx + r[2, 1] * dy + r[2, 2] * dz)

    def to_world(self, ex, ey, ez):
        r = self.rotation
        return (r[0, 0] * ex + r[1, 0] * ey + r[2, 0] * ez,
                r[0, 1] * ex + r[1, 1] * ey + r[2, 1] * ez,
                r[0, 2] * ex + r[1, 2] * ey + r[2, 2] * ez)

    def radiance(self, dx, dy, dz) -> np.ndarray:
        """(3, N) float32 radiance arriving from world directions d (unit)."""
        n = len(dx)
        if self.texture is None:
            return np.broadcast_to(self.constant, (3, n))
        u, v = direction_to_equirect(*self.to_env(dx, dy, dz))
        return self.texture.lookup(u, v, wrap_v=False) * self.strength
