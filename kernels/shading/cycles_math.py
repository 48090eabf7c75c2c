"""Cycles' float32 scalar helpers over arrays (`util/math_float.h`), and how the colour, maths and
converter nodes take their inputs: the conventions of math_nodes, color_nodes, mix_nodes, vector_nodes
and curve_nodes, which the node program runner depends on.

- Inputs are the node's input sockets in Blender's order, as snake_case parameters: a float socket (N,)
  float32, a vector or colour socket (N, 3) float32 (alpha is not carried). Any input may instead be a
  constant: a Python float or 0-d/length-1 array for a float socket, a float or a (3,) array for a vector
  socket; constants broadcast (as_float, as_vector). Node options are keyword arguments named and spelt as
  Blender's RNA properties (operation="MULTIPLY", blend_type="OVERLAY", ...).
- Each function returns {output socket name as Blender shows it: array}, float32; (N,) or (N, 3) (length 1
  when every input was a constant).
- Numerics are Cycles' float32 arithmetic, its guards included: safe divide (x/0 = 0), safe pow/log/sqrt,
  C's truncating float->int and fmod, its NaN-blind min/max/clamp (`a > b ? a : b`). Cycles' CPU kernels
  are built with -ffp-contract=fast (fused multiply-add on AVX2) and -freciprocal-math: where that decides
  the result beyond rounding noise (a product cancelling against a sum) the fused form is reproduced
  (kernels.vec.fma); elsewhere results agree to a few ulp.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32

INT_MIN = F32(-2147483648.0)          # what x86 makes of an out-of-range float -> int cast


def as_float(x) -> np.ndarray:
    """A float input as a float32 array of at least one dimension ((N,) or (1,))."""
    a = np.asarray(x, F32)
    return a.reshape(1) if a.ndim == 0 else a


def as_vector(x) -> np.ndarray:
    """A vector/colour input as a float32 (N, 3) or (1, 3) array."""
    a = np.asarray(x, F32)
    if a.ndim == 0 or a.shape == (1,):
        return np.broadcast_to(a.reshape(1, 1), (1, 3))
    return a.reshape(1, 3) if a.ndim == 1 else a


def cycles_max(a, b):
    """Cycles' max(): `a > b ? a : b` (a NaN a gives b)."""
    return np.where(a > b, a, b)


def cycles_min(a, b):
    """Cycles' min(): `a < b ? a : b`."""
    return np.where(a < b, a, b)


def cycles_clamp(a, lo, hi):
    return cycles_min(cycles_max(a, lo), hi)


def saturate(a):
    return cycles_clamp(a, F32(0.0), F32(1.0))


def safe_divide(a, b) -> np.ndarray:
    """a / b, 0 where b == 0."""
    out = np.zeros(np.broadcast_shapes(np.shape(a), np.shape(b)), F32)
    np.divide(a, b, out=out, where=(b != 0))
    return out


def is_int(b: np.ndarray) -> np.ndarray:
    """`b == (float)(int)b` with C's truncating cast on x86 (out of range and NaN -> INT_MIN)."""
    small = np.abs(b) < F32(2147483648.0)
    return np.where(small, b == np.trunc(np.where(small, b, F32(0.0))), b == INT_MIN)


def fract(x):
    return x - np.floor(x)


def interp(a, b, t):
    return a + t * (b - a)
