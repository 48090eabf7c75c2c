"""The triangle table: every triangle's corner, edges, normals and UVs in one row, and the barycentric
interpolation of the lecture's shading data. Shared by the integrator (hits) and the lights (points
sampled on emissive triangles)."""
from __future__ import annotations

import numpy as np

from .scene import SceneArrays

# Columns of the per-triangle table gathered for every hit (one contiguous row per component).
P0, E1, E2, NG, N0, N1, N2, UV0, UV1, UV2 = 0, 3, 6, 9, 12, 15, 18, 21, 23, 25
_COLUMNS = 27


class TriangleTable:
    """(T, 27) float32 rows: p0, e1, e2, unit geometric normal, three unit corner normals, three corner UVs.
    Gathering whole rows of a (T, 27) table is ~9x faster than columns of a (27, T) one."""

    def __init__(self, scene: SceneArrays):
        self.rows = _triangle_table(scene)
        # (T, 12) float32: per corner the tangent xyz and its sign; apart from the rows every hit gathers,
        # since only normal-mapped and anisotropic materials read it.
        self.tangent_rows = None if scene.tangents is None else \
            np.ascontiguousarray(scene.tangents.reshape(len(scene.tangents), 12), np.float32)

    def gather(self, prim: np.ndarray) -> np.ndarray:
        """(27, N) view: one row per component of the triangles prim."""
        return np.take(self.rows, prim, axis=0).T

    def tangent_frame(self, prim: np.ndarray, b1: np.ndarray, b2: np.ndarray):
        """The unnormalized interpolated tangent (x, y, z), bitangent sign and corner normal (x, y, z) at
        barycentrics (b1, b2) of triangles prim, as Cycles interpolates them for a normal map; None
        without tangents. The normal is the one the corners give, not yet flipped for back faces."""
        if self.tangent_rows is None:
            return None
        w0 = np.float32(1.0) - b1 - b2
        t = np.take(self.tangent_rows, prim, axis=0).T
        n = np.take(self.rows[:, N0:N2 + 3], prim, axis=0).T
        tangent = tuple(w0 * t[k] + b1 * t[4 + k] + b2 * t[8 + k] for k in range(3))
        sign = w0 * t[3] + b1 * t[7] + b2 * t[11]
        normal = tuple(w0 * n[k] + b1 * n[3 + k] + b2 * n[6 + k] for k in range(3))
        return tangent, sign, normal


def interpolate_uv(g: np.ndarray, w0, w1, w2):
    """Texture coordinates (u, v) at barycentrics (w0, w1, w2) of gathered rows g."""
    u = w0 * g[UV0] + w1 * g[UV1] + w2 * g[UV2]
    v = w0 * g[UV0 + 1] + w1 * g[UV1 + 1] + w2 * g[UV2 + 1]
    return u, v


def _triangle_table(scene: SceneArrays) -> np.ndarray:
    """Built column by column in float32, straight in the row layout the renderer gathers from."""
    p = scene.positions
    t = len(p)
    table = np.empty((t, _COLUMNS), np.float32)
    e1 = p[:, 1] - p[:, 0]
    e2 = p[:, 2] - p[:, 0]
    ng = np.stack(unit_rows(e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1],
                            e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2],
                            e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]), axis=1)
    table[:, P0:P0 + 3] = p[:, 0]
    table[:, E1:E1 + 3] = e1
    table[:, E2:E2 + 3] = e2
    table[:, NG:NG + 3] = ng
    for k, col in enumerate((N0, N1, N2)):
        nk = scene.normals[:, k]
        x, y, z = nk[:, 0], nk[:, 1], nk[:, 2]
        length2 = x * x + y * y + z * z
        inv = np.float32(1.0) / np.sqrt(np.maximum(length2, np.float32(1e-37)))
        # A zero-length corner normal falls back to the face normal.
        zero = length2 < np.float32(1e-30)
        for j, c in enumerate((x, y, z)):
            table[:, col + j] = np.where(zero, ng[:, j], c * inv)
    for k, col in enumerate((UV0, UV1, UV2)):
        table[:, col:col + 2] = scene.uvs[:, k]
    return table


def unit_rows(x, y, z):
    inv = np.float32(1.0) / np.sqrt(np.maximum(x * x + y * y + z * z, np.float32(1e-37)))
    return x * inv, y * inv, z * inv


def extent(positions: np.ndarray):
    """(lo, hi) corners of the geometry's bounding box, float64 (3,) each."""
    if not len(positions):
        return np.zeros(3), np.zeros(3)
    lo = np.array([positions[:, :, k].min() for k in range(3)], np.float64)
    hi = np.array([positions[:, :, k].max() for k in range(3)], np.float64)
    return lo, hi
