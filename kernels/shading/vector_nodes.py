"""Cycles' vector nodes over arrays of hits: Mapping, Vector Rotate, Separate/Combine XYZ (Blender 5.0,
`kernel/svm/mapping.h`, `vector_rotate.h`, `sepcomb_vector.h`).

Inputs, outputs and numerics follow the conventions of kernels.shading.cycles_math.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, columns, dot_rows, fma, length_rows, normalize_rows
from .cycles_math import as_float, as_vector, safe_divide


# ---------------------------------------------------------------- Separate XYZ, Combine XYZ
def separate_xyz(vector=0.0) -> dict:
    """Separate XYZ node: {"X", "Y", "Z": (N,)}."""
    v = as_vector(vector)
    return {"X": v[..., 0].copy(), "Y": v[..., 1].copy(), "Z": v[..., 2].copy()}


def combine_xyz(x=0.0, y=0.0, z=0.0) -> dict:
    """Combine XYZ node: {"Vector": (N, 3)}."""
    return {"Vector": np.stack(np.broadcast_arrays(as_float(x), as_float(y), as_float(z)), -1)}


# ---------------------------------------------------------------- Mapping, Vector Rotate
def _euler_rows(rotation: np.ndarray) -> np.ndarray:
    """Cycles' euler_to_transform (XYZ Euler, R = Rz Ry Rx): (N, 3, 3) rows."""
    cx, cy, cz = (np.cos(rotation[..., k]) for k in range(3))
    sx, sy, sz = (np.sin(rotation[..., k]) for k in range(3))
    return np.stack([
        np.stack([cy * cz, sy * sx * cz - cx * sz, sy * cx * cz + sx * sz], -1),
        np.stack([cy * sz, sy * sx * sz + cx * cz, sy * cx * sz - sx * cz], -1),
        np.stack([-sy, cy * sx, cy * cx], -1)], -2)


def _rotate(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """transform_direction: fused multiply-adds, z first (SSE madd chain on AVX2)."""
    out = []
    for k in range(3):
        row = m[..., k, :]
        acc = v[..., 2] * row[..., 2]
        acc = fma(v[..., 1], row[..., 1], acc)
        out.append(fma(v[..., 0], row[..., 0], acc))
    return np.stack(out, -1)


def _rotate_transposed(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """transform_direction_transposed: dot products with the columns."""
    return np.stack([dot_rows(m[..., :, k], v) for k in range(3)], -1)


def mapping(vector=0.0, location=0.0, rotation=0.0, scale=1.0, *, vector_type: str = "POINT") -> dict:
    """Mapping node (`svm_mapping`): {"Vector": (N, 3)}. POINT R(S v) + L; TEXTURE R^T (v - L) / S
    (safe); VECTOR R(S v); NORMAL normalize(R (v / S)) (safe)."""
    v, loc, rot, s = as_vector(vector), as_vector(location), as_vector(rotation), as_vector(scale)
    with np.errstate(all="ignore"):
        m = _euler_rows(rot)
        if vector_type == "POINT":
            out = _rotate(m, v * s) + loc
        elif vector_type == "TEXTURE":
            out = safe_divide(_rotate_transposed(m, v - loc), s)
        elif vector_type == "VECTOR":
            out = _rotate(m, v * s)
        elif vector_type == "NORMAL":
            out = normalize_rows(_rotate(m, safe_divide(v, s)))
        else:
            out = np.zeros(np.broadcast_shapes(v.shape, loc.shape, rot.shape, s.shape), F32)
    return {"Vector": out.astype(F32, copy=False)}


def _rotate_around_axis(p, axis, angle):
    c, s = np.cos(angle), np.sin(angle)
    oc = F32(1.0) - c
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    px, py, pz = p[..., 0], p[..., 1], p[..., 2]
    rx = (c + oc * x * x) * px + (oc * x * y - z * s) * py + (oc * x * z + y * s) * pz
    ry = (oc * x * y + z * s) * px + (c + oc * y * y) * py + (oc * y * z - x * s) * pz
    rz = (oc * x * z - y * s) * px + (oc * y * z + x * s) * py + (c + oc * z * z) * pz
    return np.stack([rx, ry, rz], -1)


_AXES = {"X_AXIS": (1.0, 0.0, 0.0), "Y_AXIS": (0.0, 1.0, 0.0), "Z_AXIS": (0.0, 0.0, 1.0)}


def vector_rotate(vector=0.0, center=0.0, axis=(0.0, 0.0, 1.0), angle=0.0, rotation=0.0, *,
                  rotation_type: str = "AXIS_ANGLE", invert: bool = False) -> dict:
    """Vector Rotate node (`svm_node_vector_rotate`): {"Vector": (N, 3)} rotated about Center: by the XYZ
    Euler Rotation (EULER_XYZ; invert = the transpose), else by Angle about the X/Y/Z axis or the
    normalised Axis (AXIS_ANGLE; a zero axis leaves the vector as it is; invert negates the angle)."""
    v, ctr = as_vector(vector), as_vector(center)
    with np.errstate(all="ignore"):
        if rotation_type == "EULER_XYZ":
            m = _euler_rows(as_vector(rotation))
            d = v - ctr
            out = (_rotate_transposed(m, d) if invert else _rotate(m, d)) + ctr
        else:
            if rotation_type in _AXES:
                ax = np.asarray(_AXES[rotation_type], F32)[None]
                length = np.ones(1, F32)
            else:
                ax = as_vector(axis)
                length = length_rows(ax)
            a = as_float(angle)
            a = -a if invert else a
            unit = safe_divide(ax, columns(length))
            out = np.where(columns(length != 0), _rotate_around_axis(v - ctr, unit, columns(a)[..., 0]) + ctr, v)
    return {"Vector": out.astype(F32, copy=False)}
