"""Cycles' Color Ramp, RGB Curves, Vector Curves and Float Curve nodes over arrays of hits (Blender 5.0,
`kernel/svm/ramp.h`).

They read the tables that engine/export/node_tables.py bakes, as Cycles' Blender sync samples them
(RAMP_TABLE_SIZE + 1 = 257 entries). Inputs, outputs and numerics follow the conventions of
kernels.shading.cycles_math.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, columns
from .cycles_math import as_float, as_vector, saturate


# ---------------------------------------------------------------- Color Ramp and curves (ramp.h)
def ramp_lookup(table: np.ndarray, f, interpolate: bool, extrapolate: bool) -> np.ndarray:
    """Cycles' rgb/float_ramp_lookup over a baked (K,) or (K, C) table at positions f (N,): (N,) or (N, C).

    Inside [0, 1]: entry floor(f (K - 1)), lerped to the next when interpolate. Outside, with
    extrapolate: the end segment's line, t0 + (t0 - t1) |excess| (K - 1); without: the end entry."""
    table = np.asarray(table, F32)
    size = table.shape[0]
    cols = table.T if table.ndim == 2 else table[None]        # (C, K): the lookups run along N
    f = as_float(f)
    x = saturate(f) * F32(size - 1)
    i = np.minimum(x.astype(np.intp), size - 1)
    out = np.take(cols, i, axis=1)
    if interpolate:
        t = x - i.astype(F32)
        # Cycles skips the lerp where t == 0; (1 - 0) a + 0 b is a exactly for the finite tables.
        out = (F32(1.0) - t) * out + t * np.take(cols, np.minimum(i + 1, size - 1), axis=1)
    if extrapolate:
        below, above = f < 0, f > 1
        if below.any() or above.any():
            t0 = np.where(below, cols[:, :1], cols[:, -1:])
            dy = t0 - np.where(below, cols[:, 1:2], cols[:, -2:-1])
            excess = np.where(below, -f, f - F32(1.0))
            out = np.where(below | above, t0 + dy * excess * F32(size - 1), out)
    return np.ascontiguousarray(out.T) if table.ndim == 2 else out[0]


def color_ramp(fac=0.5, *, table: np.ndarray, interpolate: bool = True) -> dict:
    """Color Ramp node (`svm_node_rgb_ramp`): {"Color": (N, 3), "Alpha": (N,)} from the (K, 4) RGBA
    table baked by node_tables.color_ramp_table; interpolate False for Constant ramps."""
    rgba = ramp_lookup(table, fac, interpolate, False)
    return {"Color": rgba[..., :3], "Alpha": rgba[..., 3]}


def _curves(fac, v, table, min_x, max_x, extrapolate):
    table = np.asarray(table, F32)
    rng = F32(max_x) - F32(min_x)
    with np.errstate(all="ignore"):
        rel = (v - F32(min_x)) / rng
        out = np.stack([ramp_lookup(table[:, k], rel[..., k], True, extrapolate) for k in range(3)], -1)
        fac = columns(as_float(fac))
        return ((F32(1.0) - fac) * v + fac * out).astype(F32, copy=False)


def rgb_curves(fac=1.0, color=1.0, *, table: np.ndarray, min_x: float = 0.0, max_x: float = 1.0,
               extrapolate: bool = True) -> dict:
    """RGB Curves node (`svm_node_curves`): {"Color": (N, 3)}: each channel looked up in its column of the
    (K, 3) table (node_tables.rgb_curves_table: the C curve already applied) at (c - min_x) / (max_x -
    min_x), then mixed with the input by Fac."""
    return {"Color": _curves(fac, as_vector(color), table, min_x, max_x, extrapolate)}


def vector_curves(fac=1.0, vector=0.0, *, table: np.ndarray, min_x: float = -1.0, max_x: float = 1.0,
                  extrapolate: bool = True) -> dict:
    """Vector Curves node: {"Vector": (N, 3)}, as RGB Curves over the X, Y, Z curves' table."""
    return {"Vector": _curves(fac, as_vector(vector), table, min_x, max_x, extrapolate)}


def float_curve(factor=1.0, value=1.0, *, table: np.ndarray, min_x: float = 0.0, max_x: float = 1.0,
                extrapolate: bool = True) -> dict:
    """Float Curve node (`svm_node_curve`): {"Value": (N,)} from the (K,) table of node_tables.float_curve_table."""
    x = as_float(value)
    rng = F32(max_x) - F32(min_x)
    with np.errstate(all="ignore"):
        y = ramp_lookup(table, (x - F32(min_x)) / rng, True, extrapolate)
        f = as_float(factor)
        return {"Value": ((F32(1.0) - f) * x + f * y).astype(F32, copy=False)}
