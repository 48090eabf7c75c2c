"""Lights whose node tree's emission varies (Cycles' light shader, kernel/light/sample.h
light_sample_shader_eval and integrator/shade_light.h): the light's program is evaluated at the point of the
light each ray reaches, and its emission multiplies the light's strength.

Cycles sets up that point as shader_setup_from_sample with light_normal_uv_from_position (kernel/light/light.h):
P the point on the light (for a sun, -D), N = Ng the light's normal there (an area light's direction, a sphere's
outward normal, else -D), the viewer direction I = -D (D from the receiver toward the light), the ray length t
(infinite for a sun), the light's object and its UV: a spot's image plane across its cone, a point's sphere map
of the normal, an area light's rectangle, a sun's disc (spot_light_uv, point_light_uv, area_light_uv,
sun_light_uv, read as the UV attribute: svm/attribute.h). Generated reads the object-space position, as Cycles
does where there is no Generated attribute.
"""
from __future__ import annotations

import numpy as np

from ..interaction import RayInfo
from ..scene.objects import object_rows
from ..shading.image_ops import map_to_sphere
from ..shading.ops import OPS
from ..shading.program import ProgramRun
from ..shading.world import DirectionInputs
from ..textures import luminance
from ..vec import F32
from .common import DISK, POINT, RECT, SPOT, SUN

# Points of a unit sphere (Fibonacci), the directions the power estimate evaluates a light's emission toward.
_ESTIMATE_POINTS = 64


class LampInputs(DirectionInputs):
    """program.HitInputs for points on lights: p, ng, wi (n, 3) world position, normal and direction toward the
    receiver, t (n,) the ray length, rows (n, OBJECT_COLUMNS) the lights' object rows, uv (n, 3) or None (0).
    As a world's directions (no mesh attributes, no barycentrics), but with an object and a position."""

    world = False
    lamp = True

    def __init__(self, scene, p, ng, wi, t, rows, uv=None):
        zeros = np.zeros(len(p), np.int32)
        super().__init__(scene, p, RayInfo(zeros, zeros, np.asarray(t, F32), emission=True, camera=False))
        self.N = self.Ng = np.ascontiguousarray(ng, F32)
        self.I = np.ascontiguousarray(wi, F32)  # noqa: E741 - Cycles' name: the direction toward the viewer
        if uv is not None:
            self.uv = uv
        self._rows = rows

    def objects(self) -> np.ndarray:
        return self._rows

    def tracing(self):
        return None   # Cycles evaluates light shaders without ray-tracing nodes


class LampShaders:
    """The varying lights of a scene (Lights.shader >= 0) and what their programs need: the shading's scene data
    (textures, camera) and each light's object row (its position and rotation)."""

    def __init__(self, lights, data):
        self.shader = lights.shader
        self.shaders = lights.shaders
        self.data = data
        self.kind = lights.kind
        self.position = lights.position.astype(F32)
        self.axes = lights.frame.astype(F32)
        self.size = lights.size.astype(F32)
        cos_half = np.clip(lights.spot_cos[:, 0].astype(np.float64), -1.0, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            # Cycles' half_cot_half_spot_angle (0.5 / tan of half the spot's angle) and the sun's
            # half_inv_sin_half_angle (0.5 / sin of half its half angle, 0 for a sharp sun: scene/light.cpp).
            self.half_cot = np.nan_to_num(0.5 * cos_half / np.sqrt(np.maximum(1.0 - cos_half ** 2, 0.0))).astype(F32)
            half = lights.sun_half_angle.astype(np.float64)
            self.half_inv_sin = np.where(half > 0, 0.5 / np.sin(0.5 * np.maximum(half, 1e-30)), 0.0).astype(F32)
        m = np.zeros((lights.count, 4, 4))
        m[:, :3, :3], m[:, :3, 3], m[:, 3, 3] = lights.frame, lights.position, 1.0
        count = lights.count
        self.rows = object_rows(m, np.zeros((count, 3)), np.ones((count, 3)), np.ones((count, 4)),
                                np.zeros(count), np.zeros(count)) if count else np.zeros((0, 1), F32)

    def varying(self, light: np.ndarray) -> np.ndarray:
        """Indices of the lights `light` (n,) whose emission varies."""
        return np.flatnonzero(np.take(self.shader, light) >= 0)

    def uv(self, light, p, ng, w) -> np.ndarray:
        """(n, 3) the lights' UV (u, v, 0) at points p with normals ng, reached along w (toward the light), as
        Cycles' *_light_uv give them and its UV attribute reads them (1 - u - v, u)."""
        out = np.zeros((len(light), 3), F32)
        kind = np.take(self.kind, light)
        axes = self.axes[light]                                          # (n, 3, 3), columns x, y, z

        def local(d, rows):
            """World directions d of the lights `rows` (indices into light) in those lights' frames."""
            return np.einsum("nji,nj->ni", axes[rows], d)

        spot = np.flatnonzero(kind == SPOT)
        if len(spot):
            ray = local(-w[spot], spot)
            ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), F32(1e-30))
            with np.errstate(divide="ignore", invalid="ignore"):
                f = self.half_cot[light[spot]] / -ray[:, 2]
            out[spot, 0], out[spot, 1] = F32(0.5) + ray[:, 0] * f, F32(0.5) + ray[:, 1] * f
        point = np.flatnonzero(kind == POINT)
        if len(point):
            out[point] = map_to_sphere(local(ng[point], point))
        area = np.flatnonzero((kind == RECT) | (kind == DISK))
        if len(area):
            inplane = local(p[area] - self.position[light[area]], area)
            size = np.maximum(self.size[light[area]], F32(1e-30))
            out[area, :2] = np.clip(inplane[:, :2] / size, F32(-0.5), F32(0.5)) + F32(0.5)
        sun = np.flatnonzero(kind == SUN)
        if len(sun):
            k = light[sun]
            with np.errstate(divide="ignore", invalid="ignore"):
                fac = self.half_inv_sin[k] / np.linalg.norm(w[sun] + axes[sun, :, 2], axis=1)
            d = local(w[sun], sun)
            out[sun, 0], out[sun, 1] = F32(0.5) + d[:, 0] * fac, F32(0.5) + d[:, 1] * fac
        return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0).astype(F32)

    def emission(self, light, p, ng, wi, t, uv=None) -> np.ndarray:
        """(3, n) float32 emission of the varying lights `light` (n,) at points p with normals ng, seen along wi
        (each (n, 3)), t (n,) ray lengths: their programs' value, negative and non-finite parts read 0 (Ember's
        lights emit no negative light)."""
        out = np.zeros((3, len(light)), F32)
        which = np.take(self.shader, light)
        for s in np.unique(which):
            rows = np.flatnonzero(which == s)
            program, output = self.shaders[s]
            inputs = LampInputs(self.data, p[rows], ng[rows], wi[rows], np.asarray(t, F32)[rows],
                                np.take(self.rows, np.take(light, rows), axis=0), None if uv is None else uv[rows])
            value = ProgramRun(program, inputs, OPS).value(output)
            out[:, rows] = np.maximum(np.nan_to_num(value, nan=0.0, posinf=0.0, neginf=0.0), 0.0).T
        return out

    def at_sample(self, light, px, py, pz, wx, wy, wz, dist, sphere=None) -> np.ndarray:
        """emission() where light samples from points p went along w (toward the light) for dist. sphere: (n,)
        bool, the lights that are spheres (their normal is the sphere's), or None."""
        w = np.stack([wx, wy, wz], axis=1).astype(F32)
        far = ~np.isfinite(dist)
        p = np.stack([px, py, pz], axis=1) + w * np.where(far, F32(0.0), dist)[:, None]
        p = np.where(far[:, None], -w, p).astype(F32)
        kind = np.take(self.kind, light)
        ng = -w
        area = (kind == RECT) | (kind == DISK)
        if area.any():
            ng = np.where(area[:, None], -self.axes[light, :, 2], ng)
        if sphere is not None and sphere.any():
            out = p - self.position[light]
            out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), F32(1e-30))
            ng = np.where(sphere[:, None], out, ng)
        t = np.where(kind == SUN, F32(np.inf), dist).astype(F32)
        ng = ng.astype(F32)
        return self.emission(light, p, ng, -w, t, self.uv(light, p, ng, w))

    def estimate(self, light: int) -> float:
        """The light's mean emission (luminance) toward a sphere of directions at unit distance from its centre,
        for its power in the light selection: 1 where it reads 0 there (the selection needs power wherever the
        light may emit; only noise depends on it)."""
        k = np.arange(_ESTIMATE_POINTS) + 0.5
        z = 1.0 - 2.0 * k / _ESTIMATE_POINTS
        phi = np.pi * (1.0 + 5.0 ** 0.5) * k
        r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
        d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).astype(F32)
        if self.kind[light] in (RECT, DISK):   # toward the side it lights
            d[:, 2] = -np.abs(d[:, 2])
            d = d @ self.axes[light].T
        rows = np.full(len(d), light)
        t = np.full(len(d), F32(np.inf) if self.kind[light] == SUN else F32(1.0))
        p = np.where(np.isfinite(t)[:, None], self.position[light] + d, -d).astype(F32)
        value = self.emission(rows, p, d, d, t)
        mean = float(luminance(value.T.astype(np.float64)).mean())
        return mean if mean > 0 and np.isfinite(mean) else 1.0
