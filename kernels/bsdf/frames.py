"""Local frames of closures: (tangent, bitangent, normal) rows, and directions taken into and out of them."""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..vec import F32, ONE, ZERO, cross_xyz, dot_xyz, length_xyz


def frames(n: np.ndarray, t: np.ndarray | None):
    """(tangent, bitangent, normal) rows, each (3, C): t orthogonalised against n, or an arbitrary
    frame where no tangent was given (t None, or NaN rows)."""
    nx, ny, nz = n
    tx, ty, tz, bx, by, bz = sampling.orthonormal_basis(nx, ny, nz)
    given = np.isfinite(t[0]) if t is not None else None
    if given is not None and given.any():
        d = dot_xyz(t, (nx, ny, nz))
        gx, gy, gz = t[0] - d * nx, t[1] - d * ny, t[2] - d * nz
        length = length_xyz((gx, gy, gz))
        ok = given & (length > F32(1e-8))
        inv = np.where(ok, ONE / np.where(ok, length, ONE), ZERO)
        tx, ty, tz = (np.where(ok, g * inv, a) for g, a in ((gx, tx), (gy, ty), (gz, tz)))
        bx, by, bz = cross_xyz((nx, ny, nz), (tx, ty, tz))
    return np.stack([tx, ty, tz]), np.stack([bx, by, bz]), np.stack([nx, ny, nz])


def to_local(frame, w):
    t, b, n = frame
    return tuple(dot_xyz(w, a).astype(F32) for a in (t, b, n))


def to_world(frame, w):
    t, b, n = frame
    return tuple((w[0] * t[k] + w[1] * b[k] + w[2] * n[k]).astype(F32) for k in range(3))
