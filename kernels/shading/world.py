"""World node programs: the radiance of a world's node tree (a gradient or sky, a Mix of two backgrounds,
Light Path tricks) evaluated per escaped ray, as Cycles evaluates its background shader.

In a world Cycles' shading point is the ray direction D: P = D, N = Ng = -D, the viewer direction
wi = -D, no object (Generated and Object coordinates are D itself), UV zero. A bake of the program on an
equirectangular grid gives the importance map for sampling the world as a light.
"""
from __future__ import annotations

import numpy as np

from ..environment import equirect_to_direction
from ..interaction import RayInfo
from ..scene import World, object_row
from ..vec import F32
from .ops import OPS
from .program import ProgramRun


class _Directions:
    """The SurfaceHit fields input ops read, for escaped rays: the path state, no curves or points."""
    __slots__ = ("ray", "shapes")

    def __init__(self, ray):
        self.ray, self.shapes = ray, None


class DirectionInputs:
    """program.HitInputs for world directions d (n, 3)."""

    world = True

    def __init__(self, scene, d: np.ndarray, ray: RayInfo | None):
        self.scene = scene
        self.n = len(d)
        self.idx = np.arange(self.n)
        self.hit = _Directions(ray)
        self.P = np.ascontiguousarray(d, F32)
        self.N = self.Ng = self.I = -self.P
        self.backfacing = np.zeros(self.n, bool)
        self.uv = np.zeros((self.n, 3), F32)
        self.dp = np.zeros(self.n, F32)
        self._cache = {}

    def memo(self, key, compute):
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]

    def attribute(self, name, interpolate: bool = True):
        return None   # no object, no mesh: every attribute reads zero, as in Cycles' background

    def objects(self) -> np.ndarray:
        return np.broadcast_to(_IDENTITY_OBJECT, (self.n, len(_IDENTITY_OBJECT)))

    def barycentrics(self):
        zero = np.zeros(self.n, F32)
        return zero, zero


_IDENTITY_OBJECT = object_row(np.eye(4))


class WorldShader:
    """A world's program, ready to evaluate: radiance(d, ray) and the importance bake."""

    def __init__(self, world: World, data):
        self.program, self.output, self.data = world.program, world.output, data

    def radiance(self, dx, dy, dz, ray: RayInfo | None = None) -> np.ndarray:
        """(3, n) float32 radiance arriving from unit world directions d."""
        d = np.stack([dx, dy, dz], axis=1).astype(F32, copy=False)
        if ray is None:  # a light sample: Cycles evaluates it as emission, not as a camera ray
            zeros = np.zeros(len(d), np.int32)
            ray = RayInfo(zeros, zeros, emission=True, camera=False)
        value = ProgramRun(self.program, DirectionInputs(self.data, d, ray), OPS).value(self.output)  # (n, 3)
        # Light cannot be negative or non-finite in a sampling distribution; Cycles clamps nothing here,
        # but a NaN radiance would poison the film.
        return np.ascontiguousarray(np.nan_to_num(value, nan=0.0, posinf=0.0, neginf=0.0).T, F32)

    def bake(self, width: int, height: int) -> np.ndarray:
        """(H, W, 3) float32 radiance at the texel centres of an equirectangular map (row 0 at the bottom,
        environment.direction_to_equirect's layout), for importance sampling."""
        v, u = np.meshgrid((np.arange(height, dtype=F32) + F32(0.5)) / F32(height),
                           (np.arange(width, dtype=F32) + F32(0.5)) / F32(width), indexing="ij")
        dx, dy, dz, _ = equirect_to_direction(u.ravel(), v.ravel())
        out = np.empty((height * width, 3), F32)
        step = 1 << 16
        for s in range(0, len(dx), step):
            out[s:s + step] = self.radiance(dx[s:s + step], dy[s:s + step], dz[s:s + step]).T
        return np.maximum(out, F32(0.0)).reshape(height, width, 3)
