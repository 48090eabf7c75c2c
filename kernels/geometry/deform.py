"""Deformation motion blur of triangles: where a deforming triangle's corners and corner normals are at a ray's
time, as Cycles' motion triangles give them (intern/cycles/kernel/geom/motion_triangle.h:
motion_triangle_compute_info, motion_triangle_vertices, motion_triangle_normals): of S steps evenly spread over
the shutter, the two around the time, step = min(floor(time (S - 1)), S - 2), mixed linearly by the rest.
Embree interpolates its time steps so for the ray queries (kernels.embree, kernels.accel); shading reads the same
interpolation here (SceneArrays.deform_ids, deform_positions, deform_normals)."""
from __future__ import annotations

import numpy as np

from ..vec import F32
from .triangles import E1, E2, N0, NG, P0


def deformed_corners(scene, prim: np.ndarray, times: np.ndarray | None):
    """(rows, (m, 3, 3) corners, (m, 3, 3) corner normals) of the hits prim on deforming triangles at their times
    (n,) (None: 0.5), rows their places among prim; None when no hit is on one."""
    ids = scene.deform_ids
    if ids is None:
        return None
    columns = np.where(prim < len(ids), np.take(ids, np.clip(prim, 0, len(ids) - 1)), -1)
    rows = np.flatnonzero(columns >= 0)
    if not len(rows):
        return None
    columns = columns[rows]
    steps = scene.deform_positions.shape[0]
    t = np.full(len(rows), 0.5, F32) if times is None else np.take(times, rows).astype(F32)
    scaled = t * F32(steps - 1)
    step = np.minimum(scaled.astype(np.int64), steps - 2)
    f = (scaled - step).astype(F32)[:, None, None]
    positions = scene.deform_positions
    normals = scene.deform_normals
    p = (F32(1) - f) * positions[step, columns] + f * positions[step + 1, columns]
    n = (F32(1) - f) * normals[step, columns] + f * normals[step + 1, columns]
    return rows, p.astype(F32), n.astype(F32)


def replace_rows(g: np.ndarray, deformed) -> None:
    """Write deformed corners (deformed_corners) into gathered rows g (27, N) in place: the corner, the edges,
    the unit geometric normal (turned as the stored one where the object mirrors) and the unit corner normals (the
    geometric one where a corner's is zero), as the triangle table builds them."""
    rows, p, n = deformed
    old_cross = np.cross(g[E1:E1 + 3, rows].T, g[E2:E2 + 3, rows].T)
    turned = np.einsum("ij,ij->i", old_cross, g[NG:NG + 3, rows].T) < 0
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    ng = np.cross(e1, e2)
    ng = ng / np.sqrt(np.maximum(np.einsum("ij,ij->i", ng, ng), F32(1e-37)))[:, None]
    ng[turned] *= F32(-1)
    g[P0:P0 + 3, rows] = p[:, 0].T
    g[E1:E1 + 3, rows] = e1.T
    g[E2:E2 + 3, rows] = e2.T
    g[NG:NG + 3, rows] = ng.T
    length2 = np.einsum("ijk,ijk->ij", n, n)
    unit = n / np.sqrt(np.maximum(length2, F32(1e-37)))[:, :, None]
    unit = np.where((length2 < F32(1e-30))[:, :, None], ng[:, None, :], unit)
    for c in range(3):
        g[N0 + 3 * c:N0 + 3 * c + 3, rows] = unit[:, c].T
