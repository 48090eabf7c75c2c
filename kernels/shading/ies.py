"""The IES Texture node: a light's photometric profile (an IES LM-63 file) looked up by direction, as Cycles'
svm_node_ies and kernel_ies_interp (kernel/svm/ies.h, kernel/util/ies.h).

The table (IesTable, read by engine/export/ies.py as Cycles' util/ies.cpp reads the file) holds horizontal angles
(about the light's axis) and vertical angles (from straight down), both in radians and increasing, and an
intensity per pair in W/sr-per-unit-strength. A direction v gives the vertical angle acos(-v.z) and the horizontal
one atan2(v.x, v.y) + pi; outside the table's range the profile is 0. Inside, Catmull-Rom cubics interpolate
along the vertical angles, then across the horizontal ones, wrapping where the table spans the whole circle (or
reaches a pole), else repeating the edge value as Cycles does; negative results read 0. A node without a usable
profile gives 100 x Strength, as Cycles' kernel does for an invalid slot.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..vec import F32, PI, TWO_PI
from .program import full

INVALID_PROFILE = F32(100.0)   # kernel_ies_interp's value for a slot without a profile


@dataclass(frozen=True, eq=False)
class IesTable:
    """h_angles (H,) and v_angles (V,) float32 radians, increasing; intensity (H, V) float32."""
    h_angles: np.ndarray
    v_angles: np.ndarray
    intensity: np.ndarray


def cubic(a, b, c, d, x):
    """Cycles' cubic_interp: the Catmull-Rom cubic between b and c (a and d their outer neighbours) at x in [0, 1]."""
    return F32(0.5) * (((d + F32(3.0) * (b - c) - a) * x + (F32(2.0) * a - F32(5.0) * b + F32(4.0) * c - d)) * x
                       + (c - a)) * x + b


def profile(table: IesTable | None, h: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(n,) float32 the profile at horizontal angles h and vertical angles v (radians)."""
    if table is None:
        return np.full(len(h), INVALID_PROFILE, F32)
    ha, va, values = table.h_angles, table.v_angles, table.intensity
    h_num, v_num = len(ha), len(va)
    out = np.zeros(len(h), F32)
    inside = np.flatnonzero((v >= va[0]) & (v < va[-1]) & (h >= ha[0]) & (h < ha[-1]))
    if not len(inside) or h_num < 2 or v_num < 2:
        return out
    h, v = h[inside], v[inside]
    wrap_h = bool(ha[0] < F32(1e-7) and ha[-1] > TWO_PI - F32(1e-7))
    wrap_low, wrap_high = bool(va[0] < F32(1e-7)), bool(va[-1] > PI - F32(1e-7))
    # Cycles walks up from index 0 while the next angle is below the lookup's.
    hi = np.searchsorted(ha[1:], h, side="left")
    vi = np.searchsorted(va[1:], v, side="left")
    h_frac = ((h - ha[hi]) / (ha[hi + 1] - ha[hi])).astype(F32)
    v_frac = ((v - va[vi]) / (va[vi + 1] - va[vi])).astype(F32)

    def vertical(column):
        """Interpolation along the vertical angles in the columns `column` (n,) of the table."""
        row = values[column]                                          # (n, V)
        take = lambda k: np.take_along_axis(row, k[:, None], axis=1)[:, 0]   # noqa: E731
        b, c = take(vi), take(vi + 1)
        a = np.where(vi > 0, take(np.maximum(vi - 1, 0)), take(np.full_like(vi, min(1, v_num - 1))) if wrap_low else b)
        d = np.where(vi + 2 < v_num, take(np.minimum(vi + 2, v_num - 1)),
                     take(np.full_like(vi, max(v_num - 2, 0))) if wrap_high else c)
        return cubic(a, b, c, d, v_frac)

    b, c = vertical(hi), vertical(hi + 1)
    first = vertical(np.maximum(hi - 1, 0))
    a = np.where(hi > 0, first, vertical(np.full_like(hi, h_num - 2)) if wrap_h else b)
    last = vertical(np.minimum(hi + 2, h_num - 1))
    # Past the last column Cycles repeats the second point (b), not the third.
    d = np.where(hi + 2 < h_num, last, vertical(np.full_like(hi, 1)) if wrap_h else b)
    out[inside] = np.maximum(cubic(a, b, c, d, h_frac), F32(0.0))
    return out


def ies_node(hits, inputs, op):
    """The IES Texture node's Fac: Strength x the profile toward the Vector (normalized)."""
    vector = np.array(full(inputs["Vector"], hits.n, 3), F32)
    strength = np.asarray(full(inputs["Strength"], hits.n), F32)
    length = np.sqrt(np.einsum("ij,ij->i", vector, vector))
    with np.errstate(divide="ignore", invalid="ignore"):
        unit = vector / length[:, None]
    unit = np.where(length[:, None] > 0, unit, F32(0.0))
    v_angle = np.arccos(np.clip(-unit[:, 2], F32(-1.0), F32(1.0))).astype(F32)
    h_angle = (np.arctan2(unit[:, 0], unit[:, 1]) + PI).astype(F32)
    return {"Fac": (strength * profile(op.option("table"), h_angle, v_angle)).astype(F32)}
