"""The ops of the nodes that read curves and points: Curves Info and Point Info (Cycles' svm_node_hair_info and
svm_node_point_info, intern/cycles/kernel/svm/geometry.h), and what the Generated coordinates and the Geometry
node's Tangent are on them.

On triangles and in scenes without curves or points, every output is zero (Is Strand 0), as in Cycles.
Generated coordinates: particle hair's root in the emitter's texture space, other curves and points the object-space
position (they have no Generated attribute: svm_node_attr's fallback, intern/cycles/kernel/svm/attribute.h). On curves
(Cycles' curve.h): Intercept, Length and Random are attributes the export makes (ATTR_STD_CURVE_INTERCEPT per key,
interpolated along the segment, _LENGTH and _RANDOM per curve); Thickness is twice the radius interpolated along
the segment, the stored one (an instance's object-space radius, a world-space copy's scaled); Tangent Normal the
viewer direction without its part along dPdu. On points (point.h): Position the centre, Radius the radius through
the instance's transform, Random an attribute (ATTR_STD_POINT_RANDOM).
"""
from __future__ import annotations

import numpy as np

from ..vec import F32

CURVE, POINT = 1, 2
# The attributes the export makes for these nodes (engine/export/curves.py, points.py).
CURVE_ATTRIBUTES = {"Intercept": "std:intercept", "Length": "std:length", "Random": "std:curve_random"}
POINT_ATTRIBUTES = {"Random": "std:point_random"}
# Particle hair's Generated coordinates: its root, in object space, and 1 (Cycles' sync gives each strand the
# Generated of its first key, blender/curves.cpp).
ROOT = "std:root"


def _kind(hits) -> np.ndarray | None:
    """(n,) int8 the primitive kind of each hit (0 triangle), None in a scene without curves and points."""
    shapes = getattr(getattr(hits, "hit", None), "shapes", None)
    return None if shapes is None else np.take(shapes.kind, hits.idx)


def _float_attribute(hits, name: str) -> np.ndarray:
    """(n,) a one-channel attribute made at export, interpolated; zero where the primitive has none."""
    values = hits.attribute(name)
    return np.zeros(hits.n, F32) if values is None else np.ascontiguousarray(values[:, 0], F32)


def _shape_rows(hits, name: str) -> np.ndarray:
    """(n, 3) float32 of a ShapeHits field at the hits."""
    return np.take(getattr(hits.hit.shapes, name), hits.idx, axis=0)


def curves_info(hits, inputs, op):
    n = hits.n
    kind = _kind(hits)
    zero = np.zeros(n, F32)
    out = {"Is Strand": zero, "Thickness": zero, "Tangent Normal": np.zeros((n, 3), F32)}
    for socket, name in CURVE_ATTRIBUTES.items():
        out[socket] = _float_attribute(hits, name)
    if kind is None:
        return out
    curve = kind == CURVE
    if not curve.any():
        return out
    out["Is Strand"] = curve.astype(F32)
    out["Thickness"] = np.where(curve, F32(2.0) * _shape_rows(hits, "radius"), zero).astype(F32)
    normal = _tangent_normal(hits.I, _shape_rows(hits, "dpdu"))
    out["Tangent Normal"] = np.where(curve[:, None], normal, F32(0.0)).astype(F32)
    return out


def _tangent_normal(wi: np.ndarray, dpdu: np.ndarray) -> np.ndarray:
    """Cycles' curve_tangent_normal: the viewer direction wi (n, 3) without its part along dPdu, normalised."""
    along = np.einsum("ni,ni->n", dpdu, wi) / np.maximum(np.einsum("ni,ni->n", dpdu, dpdu), F32(1e-30))
    t = wi - dpdu * along[:, None]
    length = np.sqrt(np.einsum("ni,ni->n", t, t))
    return (t / np.where(length > 0, length, F32(1.0))[:, None]).astype(F32)


def point_info(hits, inputs, op):
    n = hits.n
    kind = _kind(hits)
    out = {"Position": np.zeros((n, 3), F32), "Radius": np.zeros(n, F32),
           "Random": _float_attribute(hits, POINT_ATTRIBUTES["Random"])}
    if kind is None:
        return out
    point = kind == POINT
    if point.any():
        out["Position"] = np.where(point[:, None], _shape_rows(hits, "centre"), F32(0.0)).astype(F32)
        out["Radius"] = np.where(point, _shape_rows(hits, "radius"), F32(0.0)).astype(F32)
    return out


def shape_generated(hits, generated: np.ndarray, local: np.ndarray, texture_space) -> np.ndarray:
    """Generated coordinates where some hits are on curves or points: Cycles gives particle hair its root's in
    the emitter's texture space (texture_space(hits, (n, 3) object points)), and other curves and points, which
    have no Generated attribute, the object-space position (local, (n, 3): svm_node_attr's fallback)."""
    kind = _kind(hits)
    if kind is None or not kind.any():
        return generated
    out = np.where((kind != 0)[:, None], local, generated).astype(F32)
    root = hits.attribute(ROOT)
    if root is not None:
        rooted = np.flatnonzero((kind == CURVE) & (root[:, 3] > 0))
        if len(rooted):
            out[rooted] = texture_space(hits, root[:, :3])[rooted]
    return out


def shape_tangent(hits, tangent: np.ndarray) -> np.ndarray:
    """The Geometry node's Tangent where some hits are on curves or points: dPdu normalised (Cycles'
    primitive_tangent; zero on points, which have none)."""
    kind = _kind(hits)
    if kind is None or not kind.any():
        return tangent
    dpdu = _shape_rows(hits, "dpdu")
    length = np.sqrt(np.einsum("ni,ni->n", dpdu, dpdu))
    along = dpdu / np.where(length > 0, length, F32(1.0))[:, None]
    return np.where((kind != 0)[:, None], along, tangent).astype(F32)
