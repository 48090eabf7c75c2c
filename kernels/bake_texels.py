"""Where a bake's paths start: the texels Blender hands over (BakeTexels), their triangles among the scene's
(object_triangles), the paths of some texels and their numbers (BakePaths), and each path's first hit on the
surface as Cycles makes it (first_hits, after kernel/integrator/init_from_bake.h): the texel's barycentrics
jittered inside the texel by its differentials (sample 0 at its centre; a try that leaves the triangle is hashed
and tried again), nudged inwards where they fall exactly on a vertex, converted to Embree's convention
(Blender's (u, v) weigh corners 0 and 1, Embree's corners 1 and 2), and seen from 1 above the surface along the
smooth normal or from the camera. kernels/bake.py bakes them."""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .accel import Hits
from .geometry import E1, E2, P0
from .interaction import SurfaceHit
from .rays import Rays
from .rng import PathRng, seed_paths
from .samples import sample_strata
from .scene import SceneArrays
from .scene.triangles import usable_triangles
from .shading.hash import hash_float2_to_float2
from .vec import F32

# Cycles' tries at a jittered point inside the texel's triangle before it keeps the centre (bake_jitter_barycentric).
_JITTER_TRIES = 10


@dataclass(frozen=True)
class BakeTexels:
    """The texels of one bake image, P = width x height, row 0 at the bottom (Blender's order).

    prim : (P,) int64 scene triangle numbers (what ray hits report), -1 where the texel is not the object's.
    u, v : (P,) float32 Blender's barycentrics: the weights of the triangle's corners 0 and 1.
    differentials : (P, 4) float32 du/dx, du/dy, dv/dx, dv/dy across the texel.
    seed : (P,) uint32 Blender's seeds (the vertex of a colour attribute's corner), or None: the texel's own."""
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    differentials: np.ndarray
    width: int
    height: int
    seed: np.ndarray | None = None


def object_triangles(exported: SceneArrays, scene: SceneArrays, row: int) -> np.ndarray:
    """(t,) int64 scene triangle numbers of object row `row`'s triangles in its mesh's order (Blender's loop
    triangles, which a bake's primitive ids count), -1 for those validate() dropped; empty when the row has
    none. exported: the scene as exported, scene: as validated (Renderer.scene)."""
    if exported.object_ids is not None and len(exported.object_ids):
        plain = np.flatnonzero(exported.object_ids == row)
        if len(plain):
            keep = usable_triangles(exported.positions[plain[0]:plain[-1] + 1])
            out = np.full(len(plain), -1, np.int64)
            out[keep] = np.flatnonzero(scene.object_ids == row)
            return out
    placed = exported.instances
    if placed is None or placed.object_ids is None:
        return np.zeros(0, np.int64)
    k = np.flatnonzero(placed.object_ids == row)
    kept = np.flatnonzero(scene.instances.object_ids == row) if scene.instances is not None else k[:0]
    if not len(k) or not len(kept):
        return np.zeros(0, np.int64)
    keep = usable_triangles(placed.prototypes[placed.prototype[k[0]]].positions)
    out = np.full(len(keep), -1, np.int64)
    out[keep] = scene.instances.bases(scene.triangle_count)[kept[0]] + np.arange(int(keep.sum()))
    return out


class FirstHits(NamedTuple):
    """Where a bake's paths start: hits (accel.Hits, t = 1) of rays (Rays from 1 above the surface toward it);
    dp (n,) the texel's footprint; p (n, 3) the points and normal (n, 3) their smooth normals."""
    hits: Hits
    rays: Rays
    dp: np.ndarray
    p: np.ndarray
    normal: np.ndarray

    def take(self, rows: np.ndarray) -> "FirstHits":
        h = self.hits
        return FirstHits(Hits(h.prim[rows], h.t[rows], h.u[rows], h.v[rows]), Rays(*(r[rows] for r in self.rays)),
                         self.dp[rows], self.p[rows], self.normal[rows])


class BakePaths:
    """The paths of some texels (their numbers `texels` in the image), spp samples each from sample `first`,
    texel-major as a wave's pixels are: path k is sample first + k % spp of texel texels[k // spp]."""

    def __init__(self, image: BakeTexels, texels: np.ndarray, first: int, spp: int, settings):
        self.image, self.texels, self.first, self.spp, self.settings = image, texels, first, spp, settings

    def __len__(self) -> int:
        return len(self.texels) * self.spp

    def batch(self, start: int, end: int):
        """(texel numbers, sample numbers, PathRng, strata) of the paths [start, end)."""
        k = np.arange(start, end, dtype=np.int64)
        texel = np.take(self.texels, k // self.spp)
        sample = (self.first + k % self.spp).astype(np.uint32)
        image, settings = self.image, self.settings
        # Blender's seed, where it gives one, makes the corners of one vertex see the same numbers (Cycles).
        key = texel if image.seed is None else np.take(image.seed, texel).astype(np.int64)
        row, col = (key // image.width).astype(np.int32), (key % image.width).astype(np.int32)
        pixel_index = key.astype(np.uint32)
        rng = PathRng(*seed_paths(pixel_index, sample, settings.seed))
        whole = start % self.spp == 0 and (end - start) % self.spp == 0
        strata = sample_strata(settings.sampling_pattern, settings.seed, image.width, max(image.height, 1),
                               int(settings.samples), row, col, pixel_index, sample,
                               repeats=self.spp if whole else 1)
        return texel, sample, rng, strata


def first_hits(tables, image: BakeTexels, texel: np.ndarray, jx: np.ndarray, jy: np.ndarray,
               use_camera: bool) -> FirstHits:
    """The first hits of paths on texels `texel` with filter numbers (jx, jy) (0.5 at a texel's centre), as
    init_from_bake.h makes them."""
    prim = np.take(image.prim, texel)
    u, v = np.take(image.u, texel).astype(F32), np.take(image.v, texel).astype(F32)
    d = np.take(image.differentials, texel, axis=0).astype(F32)
    g = tables.triangles.gather(prim)
    corner = np.flatnonzero(((u == 0) | (u == 1)) & ((v == 0) | (v == 1)))
    if len(corner):   # exactly on a vertex: nudged towards the centre, off the edges a ray would graze
        u[corner], v[corner] = _towards_centre(tuple(c[corner] for c in g), u[corner], v[corner])
    u, v = _jitter(u, v, jx, jy, d)
    b1, b2 = v, F32(1.0) - u - v            # Embree's weights of corners 1 and 2
    du = (d[:, 2], d[:, 3])                 # the same differentials in Embree's convention
    dv = (-d[:, 0] - d[:, 2], -d[:, 1] - d[:, 3])
    e1 = np.stack([g[E1 + k] for k in range(3)])
    e2 = np.stack([g[E2 + k] for k in range(3)])
    dp = F32(0.5) * (np.linalg.norm(e1 * du[0] + e2 * dv[0], axis=0) + np.linalg.norm(e1 * du[1] + e2 * dv[1], axis=0))
    n = len(prim)
    surface = SurfaceHit(tables.triangles, prim, b1, b2, (np.zeros(n, F32),) * 3, False)
    p = np.stack(surface.p, axis=1)
    normal = np.stack(surface.ns, axis=1)
    toward = _from_camera(tables, p, normal, np.stack(surface.ng, axis=1)) if use_camera else normal
    rays = Rays((p + toward).astype(F32), np.ascontiguousarray(-toward, F32), np.full(n, np.inf, F32))
    return FirstHits(Hits(prim, np.ones(n, F32), b1, b2), rays, dp.astype(F32), p, normal)


def _jitter(u, v, jx, jy, d):
    """Cycles' bake_jitter_barycentric: (u, v) moved by the texel's differentials times (j - 0.5), tried again
    with hashed numbers where that leaves the triangle, kept where every try does."""
    out_u, out_v = u.copy(), v.copy()
    todo = np.arange(len(u))
    for _ in range(_JITTER_TRIES):
        ju = u[todo] + (jx - F32(0.5)) * d[todo, 0] + (jy - F32(0.5)) * d[todo, 1]
        jv = v[todo] + (jx - F32(0.5)) * d[todo, 2] + (jy - F32(0.5)) * d[todo, 3]
        inside = (ju > 0) & (jv > 0) & (ju + jv < 1)
        out_u[todo[inside]], out_v[todo[inside]] = ju[inside], jv[inside]
        todo, jx, jy = todo[~inside], jx[~inside], jy[~inside]
        if not len(todo):
            break
        jx, jy = (np.asarray(c, F32) for c in hash_float2_to_float2((jx, jy)))
    return out_u, out_v


def _towards_centre(g, u, v):
    """Cycles' bake_offset_towards_center: a point at a vertex moved towards the triangle's centre by 1e-4 of
    its coordinates' size (at least 1e-4), as barycentrics clamped to [1e-5, 1 - 1e-5]."""
    p0 = np.stack([g[P0 + k] for k in range(3)]).astype(np.float64)
    v1, v2 = p0 + np.stack([g[E1 + k] for k in range(3)]), p0 + np.stack([g[E2 + k] for k in range(3)])
    w = 1.0 - u - v
    p = u * p0 + v * v1 + w * v2
    to_centre = (p0 + v1 + v2) / 3.0 - p
    length = np.linalg.norm(to_centre, axis=0)
    step = np.minimum(length, np.maximum(np.abs(p).max(axis=0), 1.0) * 1e-4)
    q = p + to_centre / np.where(length > 0, length, 1.0) * step
    a, b, c = v1 - p0, v2 - p0, q - p0
    d11, d12, d22 = (a * a).sum(axis=0), (a * b).sum(axis=0), (b * b).sum(axis=0)
    d1, d2 = (c * a).sum(axis=0), (c * b).sum(axis=0)
    denom = d11 * d22 - d12 * d12
    ok = denom != 0
    safe = np.where(ok, denom, 1.0)
    ov = np.clip((d22 * d1 - d12 * d2) / safe, 1e-5, 1 - 1e-5)
    ow = np.clip((d11 * d2 - d12 * d1) / safe, 1e-5, 1 - 1e-5)
    ou = np.clip(1.0 - ov - ow, 1e-5, 1 - 1e-5)
    return np.where(ok, ou, 0.0).astype(F32), np.where(ok, ov, 0.0).astype(F32)


def _from_camera(tables, p, normal, ng):
    """Cycles' view from the active camera: the direction toward the camera (its backward axis for an
    orthographic one), kept 0.2 above the smooth normal, turned toward the normal on the surface's back and
    never below the true surface (init_from_bake.h)."""
    eye, rotation = tables.camera_frame
    if tables.scene.camera.kind == "ORTHO":
        d = np.broadcast_to(np.asarray(rotation[:, 2], F32), p.shape).copy()
    else:
        d = np.asarray(eye, F32)[None] - p
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), F32(1e-30))
    dn = (d * normal).sum(axis=1, keepdims=True)
    low = dn <= F32(0.2)
    d = np.where(low, d - normal * (dn - F32(0.2)), d)
    d = np.where(low, d / np.linalg.norm(d, axis=1, keepdims=True), d)
    back = dn <= 0
    mixed = d + (normal - d) * -dn
    d = np.where(back, mixed / np.maximum(np.linalg.norm(mixed, axis=1, keepdims=True), F32(1e-30)), d)
    dg = (d * ng).sum(axis=1, keepdims=True)
    under = dg <= F32(1e-5)
    d = np.where(under, d - ng * (dg - F32(1e-5)), d)
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(F32)
