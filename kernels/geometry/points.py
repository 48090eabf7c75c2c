"""Points, the sphere primitive (Cycles' point clouds): how they are put into Embree and what a hit on one
yields.

Embree gets the spheres as RTC_GEOMETRY_TYPE_SPHERE_POINT, reading the (P, 4) centres and radii in place, as
Cycles' add_points does (intern/cycles/bvh/embree.cpp). Embree reports t and no u, v (both zero); a ray starting
inside a sphere meets its far side. What a hit yields is Cycles' point_shader_setup
(intern/cycles/kernel/geom/point_intersect.h): the position along the ray, the true and shading normal both
from the centre to it, no UV (u = v = 0) and no dPdu. Point Info's Position and Radius are point_position and
point_radius (intern/cycles/kernel/geom/point.h): the centre in world space, and the radius, through the
instance's transform as a vector (r, r, r) / sqrt(3).
"""
from __future__ import annotations

import numpy as np

from ..scene import Points
from ..vec import F32


def embree_vertices(points: Points) -> np.ndarray:
    """(P, 4) float32 x, y, z, radius: the array Embree reads in place."""
    return np.ascontiguousarray(points.points, F32)


def centres(points: Points, local: np.ndarray, matrices: np.ndarray | None) -> np.ndarray:
    """(n, 3) float32 world centres of the points numbered `local`; matrices: (n, 3, 4) world_from_object of their
    instances, or None for points stored in world space."""
    c = np.take(points.points, local, axis=0)[:, :3]
    if matrices is None:
        return c
    return (np.einsum("nij,nj->ni", matrices[:, :, :3], c) + matrices[:, :, 3]).astype(F32)


def radii(points: Points, local: np.ndarray, matrices: np.ndarray | None) -> np.ndarray:
    """(n,) float32 Point Info's Radius: the stored radius, through the instance's transform as Cycles'
    point_radius takes it (the vector (r, r, r) / sqrt(3), its length)."""
    r = np.take(points.points[:, 3], local)
    if matrices is None:
        return r
    d = np.einsum("nij,n->ni", matrices[:, :, :3], r * F32(1.0 / np.sqrt(3.0)))
    return np.sqrt(np.einsum("ni,ni->n", d, d)).astype(F32)


def hit_geometry(centre: np.ndarray, origins: np.ndarray, dirs: np.ndarray, t: np.ndarray):
    """Cycles' point_shader_setup for n hits: (p (n, 3), normal (n, 3)) float32, the position along the ray and
    the unit normal from the sphere's centre (n, 3) to it (true and shading normal alike)."""
    p = (origins + dirs * t[:, None]).astype(F32)
    n = p - centre
    length = np.sqrt(np.einsum("ni,ni->n", n, n))
    return p, (n / np.where(length > 0, length, F32(1.0))[:, None]).astype(F32)
