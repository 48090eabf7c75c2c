"""Curves, the strand primitive (Cycles' hair): how they are put into Embree and what a hit on one yields.

Embree gets each record's segments as Cycles' add_curves gives them (intern/cycles/bvh/embree.cpp): ROUND as
RTC_GEOMETRY_TYPE_ROUND_CATMULL_ROM_CURVE (a tube swept along the spline), RIBBON as FLAT_CATMULL_ROM_CURVE (a
ribbon turned to face each ray), LINEAR as ROUND_LINEAR_CURVE (cones between the keys with spheres at them), the
tessellation rate 2^Subdivisions (at most 16) + 1 (Scene::curve_subdivisions, intern/cycles/scene/scene.h). Catmull-Rom curves get their first and last key twice more
(pack_motion_verts), so that every segment k of a curve reads keys k - 1 .. k + 2, clamped to the curve; a hit's
u runs 0 to 1 along its segment.

What a hit yields is Cycles' curve_shader_setup (intern/cycles/kernel/geom/curve_intersect.h): the position
along the ray; dPdu, the spline's derivative at u (catmull_rom_basis_derivative, or the segment for linear
curves); on a tube the normal from the spline's point at u to the hit (true and shading normal alike, v = 0);
on a ribbon the true normal faces the ray and the shading normal is rounded across it as a tube's would be
(v in [-1, 1] across the ribbon, Embree's); dPdv = dPdu x Ng. Curves Info's Thickness is twice the radius
interpolated linearly along the segment (curve_thickness), its Tangent Normal the viewer direction without its
part along dPdu (curve_tangent_normal, intern/cycles/kernel/geom/curve.h).
"""
from __future__ import annotations

import numpy as np

from ..scene import Curves
from ..vec import F32

SHAPE_IDS = {"ROUND": 0, "RIBBON": 1, "LINEAR": 2}


def embree_buffers(curves: Curves) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 4) float32, indices (S,) uint32): the keys as Embree reads them (Catmull-Rom: each curve's
    first and last key repeated, V = K + 2C) and each segment's first control vertex."""
    c = curves.count
    offsets = curves.offsets.astype(np.int64)
    # Each segment's first key: every key of a curve but its last (a curve of n keys has n - 1 segments).
    last_keys = np.zeros(len(curves.keys), bool)
    last_keys[offsets[1:] - 1] = True
    first_key = np.flatnonzero(~last_keys)
    if curves.shape == "LINEAR":
        return np.ascontiguousarray(curves.keys, F32), first_key.astype(np.uint32)
    padded = np.empty((len(curves.keys) + 2 * c, 4), F32)
    key_curve = np.repeat(np.arange(c, dtype=np.int64), np.diff(offsets))
    padded_row = np.arange(1, len(curves.keys) + 1, dtype=np.int64) + 2 * key_curve
    padded[padded_row] = curves.keys
    padded[offsets[:-1] + 2 * np.arange(c)] = curves.keys[offsets[:-1]]
    padded[offsets[1:] + 2 * np.arange(c) + 1] = curves.keys[offsets[1:] - 1]
    return padded, (padded_row[first_key] - 1).astype(np.uint32)


def tessellation_rate(subdivisions: int) -> int:
    """Embree's tessellation rate of curves for the scene's Curves > Subdivisions, as Cycles sets it."""
    return min(max(1 << subdivisions, 1), 16) + 1


def segment_curves(curves: Curves, seg: np.ndarray) -> np.ndarray:
    """(n,) int64 the curve of each segment number."""
    return np.searchsorted(curves.segment_offsets(), seg, side="right") - 1


def control_points(curves: Curves, seg: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """(n, 4, 4) float32 the keys k - 1, k, k + 1, k + 2 around each segment (clamped to its curve): Cycles'
    P_curve, x, y, z and radius."""
    k0 = seg + curve
    first = curves.offsets[curve].astype(np.int64)
    last = curves.offsets[curve + 1].astype(np.int64) - 1
    rows = np.stack([np.maximum(k0 - 1, first), k0, k0 + 1, np.minimum(k0 + 2, last)], axis=1)
    return np.take(curves.keys, rows, axis=0)


def placed(points: np.ndarray, matrices: np.ndarray | None) -> np.ndarray:
    """(n, 4, 4) control points into world space by (n, 3, 4) world_from_object (None: stored in world space).
    Radii stay the object's (Cycles' curve_thickness reads them so on instances)."""
    if matrices is None:
        return points
    out = points.copy()
    out[:, :, :3] = np.einsum("nij,nkj->nki", matrices[:, :, :3], points[:, :, :3]) + matrices[:, None, :, 3]
    return out


def basis(u: np.ndarray, linear: np.ndarray):
    """(n, 4) weights of the four control points for the spline's point and its derivative at u: Catmull-Rom
    (catmull_rom_basis_eval / _derivative), or for linear curves the segment's two keys."""
    t, s = u, F32(1.0) - u
    w = F32(0.5) * np.stack([-t * s * s, F32(2.0) + t * t * (F32(3.0) * t - F32(5.0)),
                             F32(2.0) + s * s * (F32(3.0) * s - F32(5.0)), -s * t * t], axis=1)
    dw = F32(0.5) * np.stack([-s * s + F32(2.0) * s * t, F32(2.0) * t * (F32(3.0) * t - F32(5.0)) + F32(3.0) * t * t,
                              F32(2.0) * s * (F32(3.0) * t + F32(2.0)) - F32(3.0) * s * s,
                              F32(-2.0) * s * t + t * t], axis=1)
    if linear.any():
        zero = np.zeros_like(u)
        one = np.ones_like(u)
        w = np.where(linear[:, None], np.stack([zero, s, t, zero], axis=1), w)
        dw = np.where(linear[:, None], np.stack([zero, -one, one, zero], axis=1), dw)
    return w.astype(F32), dw.astype(F32)


def hit_geometry(points: np.ndarray, shape: np.ndarray, u: np.ndarray, v: np.ndarray, origins: np.ndarray,
                 dirs: np.ndarray, t: np.ndarray):
    """Cycles' curve_shader_setup for n hits on segments with world control points (n, 4, 4), shape (n,) int
    (SHAPE_IDS) and Embree's (u, v): (p, ng, ns, dpdu) (n, 3) float32 and v (n,) (kept across ribbons, 0 on
    tubes). ng is not yet turned toward the viewer."""
    linear = shape == SHAPE_IDS["LINEAR"]
    w, dw = basis(u, linear)
    xyz = points[:, :, :3]
    centre = np.einsum("nk,nki->ni", w, xyz)
    dpdu = np.einsum("nk,nki->ni", dw, xyz).astype(F32)
    p = (origins + dirs * t[:, None]).astype(F32)
    ribbon = shape == SHAPE_IDS["RIBBON"]
    # A tube: from the spline's point to the hit (the view direction where they coincide).
    n = p - centre
    length = np.sqrt(np.einsum("ni,ni->n", n, n))
    tube = np.where((length > 0)[:, None], n / np.where(length > 0, length, F32(1.0))[:, None], dirs)
    ns = tube
    ng = tube
    v_out = np.zeros_like(v)
    if ribbon.any():
        tangent = _unit(dpdu)
        bitangent = _unit(np.cross(tangent, -dirs))
        cosine = np.sqrt(np.maximum(F32(1.0) - v * v, F32(0.0)))
        rounded = _unit(v[:, None] * bitangent - cosine[:, None] * _unit(np.cross(tangent, bitangent)))
        ns = np.where(ribbon[:, None], rounded, tube)
        ng = np.where(ribbon[:, None], -dirs, tube)
        v_out = np.where(ribbon, v, v_out)
    return p, ng.astype(F32), ns.astype(F32), dpdu, v_out.astype(F32)


def object_space_hits(points: np.ndarray, matrices: np.ndarray, shape: np.ndarray, u: np.ndarray, v: np.ndarray,
                      origins: np.ndarray, dirs: np.ndarray, t: np.ndarray):
    """hit_geometry for n hits on curves kept in object space under (n, 3, 4) world_from_object transforms, as
    Cycles' curve_shader_setup works where the transform is not applied: the ray taken into object space, the
    normals set up there and turned into world space by the inverse transpose (object_normal_transform), the
    position and dPdu by the transform; a ribbon's Ng is the world ray's reverse, a tube's its normal. points:
    (n, 4, 4) object-space control points; origins, dirs (n, 3) and t (n,) the world rays."""
    m = matrices[:, :, :3].astype(np.float64)
    inverse = np.linalg.inv(m)
    o = np.einsum("nij,nj->ni", inverse, origins - matrices[:, :, 3])
    step = np.einsum("nij,nj->ni", inverse, dirs * t[:, None])
    t_object = np.sqrt(np.einsum("ni,ni->n", step, step))
    d = step / np.where(t_object > 0, t_object, 1.0)[:, None]
    p, ng, ns, dpdu, v_out = hit_geometry(points, shape, u, v, o.astype(F32), d.astype(F32), t_object.astype(F32))
    p = (np.einsum("nij,nj->ni", m, p) + matrices[:, :, 3]).astype(F32)
    ns = _unit(np.einsum("nji,nj->ni", inverse, ns).astype(F32))
    dpdu = np.einsum("nij,nj->ni", m, dpdu).astype(F32)
    ng = np.where((shape == SHAPE_IDS["RIBBON"])[:, None], -dirs, ns).astype(F32)
    return p, ng, ns, dpdu, v_out


def radius_along(points: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(n,) the radius interpolated linearly between the segment's keys at u (Cycles' curve_thickness is twice it)."""
    return (points[:, 2, 3] - points[:, 1, 3]) * u + points[:, 1, 3]


def tangent_normal(wi: np.ndarray, dpdu: np.ndarray) -> np.ndarray:
    """(n, 3) Cycles' curve_tangent_normal: the viewer direction wi without its part along dPdu, normalised."""
    along = np.einsum("ni,ni->n", dpdu, wi) / np.maximum(np.einsum("ni,ni->n", dpdu, dpdu), F32(1e-30))
    return _unit(wi - dpdu * along[:, None])


def _unit(a: np.ndarray) -> np.ndarray:
    length = np.sqrt(np.einsum("ni,ni->n", a, a))
    return (a / np.where(length > 0, length, F32(1.0))[:, None]).astype(F32)
