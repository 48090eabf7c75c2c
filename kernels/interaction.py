"""The surface-interaction record of a wave: what shading needs at every hit, built once per bounce."""
from __future__ import annotations

import numpy as np

from .geometry import E1, E2, N0, N1, N2, NG, P0, TriangleTable, interpolate_uv


class SurfaceHit:
    """Shading data at N hits, per component (x, y, z) tuples of (N,) float32 arrays.

    p : position (the slide's barycentric interpolation of the corners).
    ng : unit geometric normal, facing the side the ray came from.
    ns : unit shading normal (interpolated corner normals), flipped with ng as Cycles does for back faces.
    u, v : render UV (None when no material reads UVs).
    d : the incoming ray direction; wo = -d points toward the viewer.
    mat : (N,) int32 material row; prim : (N,) triangle index.
    backfacing : (N,) bool, the ray hit the triangle's back (normals were flipped).
    tangent_frame(idx) : the tangents of some hits, computed on demand.
    """
    __slots__ = ("p", "ng", "ns", "u", "v", "d", "mat", "prim", "backfacing", "_table", "_b1", "_b2")

    def __init__(self, table: TriangleTable, material_ids: np.ndarray, prim, b1, b2, d, need_uv: bool):
        g = table.gather(prim)
        w0 = np.float32(1.0) - b1 - b2
        self.p = tuple(g[P0 + k] + b1 * g[E1 + k] + b2 * g[E2 + k] for k in range(3))
        ns = [w0 * g[N0 + k] + b1 * g[N1 + k] + b2 * g[N2 + k] for k in range(3)]
        gx, gy, gz = g[NG], g[NG + 1], g[NG + 2]
        len2 = ns[0] * ns[0] + ns[1] * ns[1] + ns[2] * ns[2]
        inv = np.float32(1.0) / np.sqrt(np.maximum(len2, np.float32(1e-12)))
        ns = [c * inv for c in ns]
        degenerate = len2 < np.float32(1e-12)
        if degenerate.any():  # opposing corner normals cancel: use the face normal
            ns = [np.where(degenerate, gk, c) for c, gk in zip(ns, (gx, gy, gz))]
        dx, dy, dz = d
        # Face the geometric normal towards the side the ray came from, and the shading normal with
        # it (as Cycles does for back-facing hits): near a smooth object's silhouette the shading
        # normal may lean away from the viewer while the face looks at it, and stays so.
        self.backfacing = gx * dx + gy * dy + gz * dz > 0
        sign = np.where(self.backfacing, np.float32(-1.0), np.float32(1.0))
        self.ng = (gx * sign, gy * sign, gz * sign)
        self.ns = (ns[0] * sign, ns[1] * sign, ns[2] * sign)
        self.u, self.v = interpolate_uv(g, w0, b1, b2) if need_uv else (None, None)
        self.d = d
        self.mat = np.take(material_ids, prim)
        self.prim = prim
        self._table, self._b1, self._b2 = table, b1, b2

    def tangent_frame(self, idx: np.ndarray):
        """At hits idx: the interpolated, unnormalized tangent (x, y, z) and bitangent sign (n,), and the
        unnormalized interpolated corner normal (x, y, z), not flipped for back faces: what Cycles'
        normal map reads. None when the scene has no tangents."""
        return self._table.tangent_frame(np.take(self.prim, idx), np.take(self._b1, idx), np.take(self._b2, idx))

    def __len__(self) -> int:
        return len(self.mat)
