"""The surface-interaction record of a wave: what shading needs at every hit, built once per bounce."""
from __future__ import annotations

import numpy as np

from .geometry import E1, E2, N0, N1, N2, NG, P0, TriangleTable, interpolate_uv
from .geometry.deform import replace_rows
from .geometry.primitives import ShapeHits
from .vec import dot_rows_einsum


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
    ray : the path state the Light Path node reads (RayInfo), None outside the integrator's loop.
    shapes : None in a scene of triangles alone; else kernels.geometry.primitives.ShapeHits of every hit (zeros on
        triangles) with kind (N,) int8 (0 triangle, 1 curve, 2 point); its dpdu turned with the normals.
    side_ng : the normal a sampled direction's side is tested against: ng, but on curves the shading normal
        (Cycles' bsdf_sample tests curves against the closure's normal).
    """
    __slots__ = ("p", "ng", "ns", "u", "v", "d", "mat", "prim", "backfacing", "ray", "programs", "normal_set", "_table",
                 "_b1", "_b2", "_moved", "shapes", "side_ng")

    def __init__(self, table: TriangleTable, prim, b1, b2, d, need_uv: bool, motion=None, ray=None, deform=None):
        """motion : None, or (rows, (m, 3, 4) matrices, (m, 3, 3) normal matrices) for hits on moving
        objects (motion blur): each takes its triangle from where it is stored to where it was at the
        path's time. ray : (origins (N, 3), t (N,)[, times (N,) or None]) of the rays that found the hits: hits on
        curves and points (a table with them, kernels.geometry.primitives.PrimitiveTable) are placed along them,
        moving ones where they are at the rays' shutter times. deform : None, or kernels.geometry.deform's
        deformed_corners of the hits on deforming triangles (deformation motion blur): they take the place of the
        stored corners and normals, before motion moves them."""
        g = table.gather(prim)
        if deform is not None:
            g = np.array(g)
            replace_rows(g, deform)
        w0 = np.float32(1.0) - b1 - b2
        self.p = tuple(g[P0 + k] + b1 * g[E1 + k] + b2 * g[E2 + k] for k in range(3))
        ns = [w0 * g[N0 + k] + b1 * g[N1 + k] + b2 * g[N2 + k] for k in range(3)]
        gx, gy, gz = g[NG], g[NG + 1], g[NG + 2]
        self._moved = None
        if motion is not None:
            # Normals move by the inverse transpose (the same rotation for rigid motion), renormalised.
            rows, matrices, normal_matrices = motion
            self._moved = (np.full(len(prim), -1, np.int64), matrices, normal_matrices)
            self._moved[0][rows] = np.arange(len(rows))
            self.p = _moved_points(self.p, rows, matrices)
            ns = list(_moved_vectors(ns, rows, normal_matrices))
            gx, gy, gz = _unit(_moved_vectors((gx, gy, gz), rows, normal_matrices))
        len2 = ns[0] * ns[0] + ns[1] * ns[1] + ns[2] * ns[2]
        inv = np.float32(1.0) / np.sqrt(np.maximum(len2, np.float32(1e-12)))
        ns = [c * inv for c in ns]
        degenerate = len2 < np.float32(1e-12)
        if degenerate.any():  # opposing corner normals cancel: use the face normal
            ns = [np.where(degenerate, gk, c) for c, gk in zip(ns, (gx, gy, gz))]
        self.shapes = None
        if getattr(table, "layout", None) is not None:
            ns, (gx, gy, gz), b1, b2 = self._shape_hits(table, prim, b1, b2, d, ray, ns, (gx, gy, gz))
            w0 = np.float32(1.0) - b1 - b2
        dx, dy, dz = d
        # Face the geometric normal towards the side the ray came from, and the shading normal with
        # it (as Cycles does for back-facing hits): near a smooth object's silhouette the shading
        # normal may lean away from the viewer while the face looks at it, and stays so.
        self.backfacing = gx * dx + gy * dy + gz * dz > 0
        sign = np.where(self.backfacing, np.float32(-1.0), np.float32(1.0))
        self.ng = (gx * sign, gy * sign, gz * sign)
        self.ns = (ns[0] * sign, ns[1] * sign, ns[2] * sign)
        self.side_ng = self.ng
        if self.shapes is not None:
            self.shapes.dpdu *= sign[:, None]
            curve = self.shapes.kind == 1
            if curve.any():
                self.side_ng = tuple(np.where(curve, a, b) for a, b in zip(self.ns, self.ng))
        self.u, self.v = interpolate_uv(g, w0, b1, b2) if need_uv else (None, None)
        self.d = d
        self.mat = table.materials(prim)
        self.prim = prim
        self.ray = None
        self.programs = {}  # material -> (hit indices, ProgramRun): node programs run once per wave
        self.normal_set = False  # ns holds the materials' set normals (Shading.surface, Shader.set_normal)
        self._table, self._b1, self._b2 = table, b1, b2

    def _shape_hits(self, table, prim, b1, b2, d, ray, ns, g):
        """The hits on curves and points (table.shape_hits) put in place of what the triangle rows gave them:
        position, normals, and barycentrics (u along a curve's segment, 0 on a point: the weights of
        PrimitiveTable.attribute's corners)."""
        n = len(prim)
        self.shapes = ShapeHits(n)
        sel = np.flatnonzero(prim >= table.triangle_count)
        if not len(sel):
            return ns, g, b1, b2
        if ray is None:
            raise ValueError("SurfaceHit: hits on curves and points need the rays that found them")
        origins, t = ray[:2]
        times = ray[2] if len(ray) > 2 and ray[2] is not None else None   # shutter times: moving curves, points
        dirs = np.stack([np.take(c, sel) for c in d], axis=1)
        got = table.shape_hits(np.take(prim, sel), np.take(b1, sel), np.take(b2, sel),
                               np.take(origins, sel, axis=0), dirs, np.take(t, sel),
                               None if times is None else np.take(times, sel))
        for name in ShapeHits.__slots__:
            getattr(self.shapes, name)[sel] = getattr(got, name)
        self.shapes.kind[sel] = np.where(got.curve, np.int8(1), np.int8(2))
        p = [np.array(c, np.float32, copy=True) for c in self.p]
        ns = [np.array(c, np.float32, copy=True) for c in ns]
        g = [np.array(c, np.float32, copy=True) for c in g]
        for k in range(3):
            p[k][sel], ns[k][sel], g[k][sel] = got.p[:, k], got.ns[:, k], got.ng[:, k]
        self.p = tuple(p)
        b1, b2 = np.array(b1, np.float32, copy=True), np.array(b2, np.float32, copy=True)
        b1[sel], b2[sel] = got.b1, 0.0
        return ns, tuple(g), b1, b2

    @property
    def barycentrics(self):
        """(b1, b2): the weights of each hit's triangle corners 1 and 2 (corner 0 has 1 - b1 - b2)."""
        return self._b1, self._b2

    def uv_at(self, idx: np.ndarray, b1=None, b2=None):
        """Render UV (u, v) of the hits idx (at other barycentrics b1, b2 of their triangles if given)."""
        if self.u is not None and b1 is None:
            return np.take(self.u, idx), np.take(self.v, idx)
        if b1 is None:
            b1, b2 = np.take(self._b1, idx), np.take(self._b2, idx)
        g = self._table.gather(np.take(self.prim, idx))
        return interpolate_uv(g, np.float32(1.0) - b1 - b2, b1, b2)

    def edges(self, idx: np.ndarray):
        """(E1, E2): the (n, 3) edges p1 - p0 and p2 - p0 of the hits' triangles."""
        rows = self._table.rows_of(np.take(self.prim, idx))
        return self._move(idx, rows[:, E1:E1 + 3], False), self._move(idx, rows[:, E2:E2 + 3], False)

    def corners(self, idx: np.ndarray):
        """(p0, p1, p2): the (n, 3) corners of the hits' triangles."""
        rows = self._table.rows_of(np.take(self.prim, idx))
        p0 = rows[:, P0:P0 + 3]
        return tuple(self._move(idx, c, True) for c in (p0, p0 + rows[:, E1:E1 + 3], p0 + rows[:, E2:E2 + 3]))

    def smooth_offset(self, idx: np.ndarray, ng) -> np.ndarray:
        """(n, 3) float32: how far Cycles lifts the start of a shadow ray off the hits idx to the smooth surface
        their corner normals describe (shadow_ray_smooth_surface_offset, kernel/light/sample.h, after Hanika's
        "Hacking the shadow terminator"): a parabola through the corners along their normals, bounded by each
        corner's tangent plane. ng (x, y, z of (n,)): the side the ray leaves on. Hits on moving triangles
        are not lifted."""
        rows = self._table.rows_of(np.take(self.prim, idx)).astype(np.float64)
        v0 = rows[:, P0:P0 + 3]
        v1, v2 = v0 + rows[:, E1:E1 + 3], v0 + rows[:, E2:E2 + 3]
        # Unit corner normals (an object interpolating its normals in object space keeps their lengths' ratios
        # in its rows; Cycles lifts its rays in object space, which Ember approximates in world space).
        n0, n1, n2 = (c / np.maximum(np.linalg.norm(c, axis=1, keepdims=True), 1e-300)
                      for c in (rows[:, N0:N0 + 3], rows[:, N1:N1 + 3], rows[:, N2:N2 + 3]))
        b1, b2 = np.take(self._b1, idx).astype(np.float64)[:, None], np.take(self._b2, idx).astype(np.float64)[:, None]
        b0 = 1.0 - b1 - b2
        p = v0 * b0 + v1 * b1 + v2 * b2
        n = n0 * b0 + n1 * b1 + n2 * b2            # the interpolated normal, not normalised (as Cycles)

        u, v = b0[:, 0], b1[:, 0]
        a, b, c = (dot_rows_einsum(n2 - n0, v0 - v2), dot_rows_einsum(n2 - n1, v1 - v2),
                   dot_rows_einsum(n1 - n0, v1 - v0))
        h = a * u * (u - 1) + (a + b + c) * u * v + b * v * (v - 1)
        front = dot_rows_einsum(n, np.stack(ng, axis=1)) > 0
        # Each corner's tangent plane bounds the lift (its local linear envelope), on the side the ray leaves.
        out_of = [np.maximum(np.maximum(dot_rows_einsum(vj - vi, ni), dot_rows_einsum(vk - vi, ni)), 0.0)
                  for vi, ni, vj, vk in ((v0, n0, v1, v2), (v1, n1, v0, v2), (v2, n2, v0, v1))]
        above = [np.maximum(dot_rows_einsum(vi - p, ni) + e, 0.0)
                 for vi, ni, e in zip((v0, v1, v2), (n0, n1, n2), out_of)]
        into = [np.maximum(np.maximum(dot_rows_einsum(vi - vj, ni), dot_rows_einsum(vi - vk, ni)), 0.0)
                for vi, ni, vj, vk in ((v0, n0, v1, v2), (v1, n1, v0, v2), (v2, n2, v0, v1))]
        below = [np.maximum(dot_rows_einsum(p - vi, ni) + e, 0.0)
                 for vi, ni, e in zip((v0, v1, v2), (n0, n1, n2), into)]
        h = np.where(front, np.maximum(np.minimum.reduce(above), 0.5 * h),
                     np.minimum(-np.minimum.reduce(below), 0.5 * h))
        offset = (n * h[:, None]).astype(np.float32)
        if self._moved is not None:
            offset[np.take(self._moved[0], idx) >= 0] = 0.0
        if self.shapes is not None:   # Cycles lifts shadow rays off smooth triangles only
            offset[np.take(self.shapes.kind, idx) != 0] = 0.0
        return offset

    def tangent_frame(self, idx: np.ndarray):
        """At hits idx: the interpolated, unnormalized tangent (x, y, z) and bitangent sign (n,), and the
        unnormalized interpolated corner normal (x, y, z), not flipped for back faces: what Cycles'
        normal map reads. None when the scene has no tangents."""
        frame = self._table.tangent_frame(np.take(self.prim, idx), np.take(self._b1, idx), np.take(self._b2, idx))
        if frame is None or self._moved is None:
            return frame
        tangent, sign, normal = frame
        slot = np.take(self._moved[0], idx)
        rows = np.flatnonzero(slot >= 0)
        if len(rows):
            tangent = _moved_vectors(tangent, rows, self._moved[1][slot[rows], :, :3])
            normal = _moved_vectors(normal, rows, self._moved[2][slot[rows]])
        return tangent, sign, normal

    def _move(self, idx, values: np.ndarray, points: bool) -> np.ndarray:
        """(n, 3) points or vectors of the hits idx, moved to the hits' times where their objects move."""
        if self._moved is None:
            return values
        slot = np.take(self._moved[0], idx)
        rows = np.flatnonzero(slot >= 0)
        if not len(rows):
            return values
        m = self._moved[1][slot[rows]]
        values = values.astype(np.float32, copy=True)
        moved = np.einsum("nij,nj->ni", m[:, :, :3], values[rows].astype(np.float64))
        values[rows] = moved + m[:, :, 3] if points else moved
        return values

    def __len__(self) -> int:
        return len(self.mat)


def _moved_points(p, rows, matrices):
    """Components (x, y, z) of points with the entries `rows` moved by (m, 3, 4) affine matrices."""
    out = tuple(c.copy() for c in p)
    xyz = np.stack([c[rows] for c in p], axis=1).astype(np.float64)
    moved = np.einsum("nij,nj->ni", matrices[:, :, :3], xyz) + matrices[:, :, 3]
    for k in range(3):
        out[k][rows] = moved[:, k]
    return out


def _moved_vectors(v, rows, linear):
    """Components (x, y, z) of vectors with the entries `rows` multiplied by (m, 3, 3) matrices."""
    out = tuple(np.array(c, np.float32, copy=True) for c in v)
    xyz = np.stack([np.asarray(c)[rows] for c in v], axis=1).astype(np.float64)
    moved = np.einsum("nij,nj->ni", linear[:, :3, :3], xyz)
    for k in range(3):
        out[k][rows] = moved[:, k]
    return out


def _unit(v):
    length = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    inv = np.float32(1.0) / np.maximum(length, np.float32(1e-30))
    return tuple((c * inv).astype(np.float32) for c in v)


class RayInfo:
    """The path state behind a wave's hits, for the Light Path node: per hit (N,) arrays of scattering
    events so far (depth) and transparent surfaces passed (transparent), the ray's length (or None), and
    whether these are shadow rays; dp, the rays' position spread at the hits (Cycles' compact
    differential sd->dP, for the Bump node), None for none. emission: the world or a light is evaluated
    (Cycles' PATH_RAY_EMISSION: one bounce further); camera=False: not a camera ray whatever the depth
    (a light sample of the world). lobes: (4, N) paths.PathState.lobes (label bits, diffuse, glossy and
    transmission bounces) or None when no Light Path node reads them. caustics: None, or the render's
    (reflective, refractive) caustics switches when one is off (RenderSettings.caustics_*; lobes is then
    tracked): closures of that kind are not made where the ray comes from a diffuse bounce. portal: (N,) Ray
    Portals passed so far, or None for none. keys: the paths' (x, y) keys (paths.ray_keys) where shader nodes
    may trace rays (a path's surface vertex, as Cycles' shade_surface_raytrace), else None; with them time
    (accel.RayTimes or None), min_ray_pdf ((N,) or None: PathState.min_ray_pdf) and split (the wave's)."""
    __slots__ = ("depth", "transparent", "length", "shadow", "dp", "emission", "camera", "lobes", "caustics",
                 "portal", "keys", "time", "min_ray_pdf", "split")

    def __init__(self, depth, transparent, length=None, shadow: bool = False, dp=None, emission: bool = False,
                 camera: bool = True, lobes=None, caustics=None, portal=None, keys=None, time=None,
                 min_ray_pdf=None, split: bool = True):
        self.depth, self.transparent, self.length, self.shadow, self.dp = depth, transparent, length, shadow, dp
        self.emission, self.camera, self.lobes, self.caustics = emission, camera, lobes, caustics
        self.portal = portal
        self.keys, self.time, self.min_ray_pdf, self.split = keys, time, min_ray_pdf, split


def spawn_offset(epsilon, px, py, pz):
    """Distance to move a spawned ray's origin along the normal: the scene's scale (epsilon, the renderer's
    ray_epsilon) plus float32 ulps."""
    return epsilon + np.float32(2.0 ** -16) * np.maximum(np.maximum(np.abs(px), np.abs(py)), np.abs(pz))
