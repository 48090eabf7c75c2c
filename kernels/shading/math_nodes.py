"""Cycles' Math, Vector Math, Map Range and Clamp nodes over arrays of hits (Blender 5.0, `kernel/svm/
math.h`, `math_util.h`, `map_range.h`, `clamp.h`).

Inputs, outputs and numerics follow the conventions of kernels.shading.cycles_math.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, PI, columns, cross_rows_fused, dot_rows, fma, length_rows, normalize_rows
from .cycles_math import as_float, as_vector, cycles_clamp, cycles_max, cycles_min, fract, is_int, safe_divide, saturate

_TO_RADIANS = PI / F32(180.0)         # M_PI_F / 180.0f, folded in float32
_TO_DEGREES = F32(180.0) / PI
_FLT_EPSILON = F32(np.finfo(F32).eps)


# ---------------------------------------------------------------- Math
def _pow(a, b):
    """Cycles' safe_powf: 0 for a negative base and a non-integer exponent, x^0 = 1, 0^y = 0."""
    out = np.power(a, b)
    out = np.where(a == 0, F32(0.0), out)
    out = np.where((a < 0) & ~is_int(b), F32(0.0), out)
    return np.where(b == 0, F32(1.0), out).astype(F32, copy=False)


def _log(a, b):
    ok = (a > 0) & (b > 0)
    la = np.log(np.where(ok, a, F32(1.0)))
    lb = np.log(np.where(ok, b, F32(1.0)))
    return np.where(ok, safe_divide(la, lb), F32(0.0))


def _wrapf(value, vmax, vmin):
    """Cycles' wrapf (Godot's): value - range * floor((value - min) / range); min where range == 0."""
    rng = vmax - vmin
    q = np.floor(safe_divide(value - vmin, rng))
    return np.where(rng != 0, fma(-rng, q, value), vmin)


def _pingpong(a, b):
    b2 = b * F32(2.0)
    f = fract(safe_divide(a - b, b2))
    return np.where(b != 0, np.abs(f * b * F32(2.0) - b), F32(0.0))


def _smooth_min(a, b, k):
    safe_k = np.where(k != 0, k, F32(1.0))
    h = np.fmax(k - np.abs(a - b), F32(0.0)) / safe_k
    m = np.fmin(a, b)
    return np.where(k != 0, fma(-(h * h * h * k), F32(1.0 / 6.0), m), m)


def _sign(a):
    return np.where(a == 0, F32(0.0), np.where(a < 0, F32(-1.0), F32(1.0)))


def _trunc(a):
    return np.where(a >= 0, np.floor(a), np.ceil(a))


_MATH = {
    "ADD": lambda a, b, c: a + b,
    "SUBTRACT": lambda a, b, c: a - b,
    "MULTIPLY": lambda a, b, c: a * b,
    "DIVIDE": lambda a, b, c: safe_divide(a, b),
    "MULTIPLY_ADD": lambda a, b, c: fma(a, b, c),
    "POWER": lambda a, b, c: _pow(a, b),
    "LOGARITHM": lambda a, b, c: _log(a, b),
    "SQRT": lambda a, b, c: np.sqrt(cycles_max(a, F32(0.0))),
    "INVERSE_SQRT": lambda a, b, c: np.where(a > 0, safe_divide(F32(1.0), np.sqrt(cycles_max(a, F32(0.0)))),
                                             F32(0.0)),
    "ABSOLUTE": lambda a, b, c: np.abs(a),
    "EXPONENT": lambda a, b, c: np.exp(a),
    "MINIMUM": lambda a, b, c: np.fmin(a, b),
    "MAXIMUM": lambda a, b, c: np.fmax(a, b),
    "LESS_THAN": lambda a, b, c: (a < b).astype(F32),
    "GREATER_THAN": lambda a, b, c: (a > b).astype(F32),
    "SIGN": lambda a, b, c: _sign(a),
    "COMPARE": lambda a, b, c: ((a == b) | (np.abs(a - b) <= np.fmax(c, _FLT_EPSILON))).astype(F32),
    "SMOOTH_MIN": lambda a, b, c: _smooth_min(a, b, c),
    "SMOOTH_MAX": lambda a, b, c: -_smooth_min(-a, -b, c),
    "ROUND": lambda a, b, c: np.floor(a + F32(0.5)),
    "FLOOR": lambda a, b, c: np.floor(a),
    "CEIL": lambda a, b, c: np.ceil(a),
    "TRUNC": lambda a, b, c: _trunc(a),
    "FRACT": lambda a, b, c: fract(a),
    "MODULO": lambda a, b, c: np.where(b != 0, np.fmod(a, np.where(b != 0, b, F32(1.0))), F32(0.0)),
    "FLOORED_MODULO": lambda a, b, c: np.where(b != 0, fma(-np.floor(safe_divide(a, b)), b, a), F32(0.0)),
    "WRAP": lambda a, b, c: _wrapf(a, b, c),
    "SNAP": lambda a, b, c: np.floor(safe_divide(a, b)) * b,
    "PINGPONG": lambda a, b, c: _pingpong(a, b),
    "SINE": lambda a, b, c: np.sin(a),
    "COSINE": lambda a, b, c: np.cos(a),
    "TANGENT": lambda a, b, c: np.tan(a),
    "ARCSINE": lambda a, b, c: np.arcsin(cycles_clamp(a, F32(-1.0), F32(1.0))),
    "ARCCOSINE": lambda a, b, c: np.arccos(cycles_clamp(a, F32(-1.0), F32(1.0))),
    "ARCTANGENT": lambda a, b, c: np.arctan(a),
    "ARCTAN2": lambda a, b, c: np.where((a == 0) & (b == 0), F32(0.0), np.arctan2(a, b)),
    "SINH": lambda a, b, c: np.sinh(a),
    "COSH": lambda a, b, c: np.cosh(a),
    "TANH": lambda a, b, c: np.tanh(a),
    "RADIANS": lambda a, b, c: a * _TO_RADIANS,
    "DEGREES": lambda a, b, c: a * _TO_DEGREES,
}
MATH_OPERATIONS = tuple(_MATH)


def math(value=0.5, value_001=0.5, value_002=0.5, *, operation: str = "ADD", use_clamp: bool = False) -> dict:
    """Math node (`svm_math`): {"Value": (N,)}. Inputs are its three Value sockets (the third is read by
    Multiply Add, Compare, Smooth Min/Max and Wrap); use_clamp clamps to [0, 1] (a NaN to 0)."""
    a, b, c = as_float(value), as_float(value_001), as_float(value_002)
    with np.errstate(all="ignore"):
        out = _MATH[operation](a, b, c) if operation in _MATH else np.zeros(np.broadcast(a, b, c).shape, F32)
        out = np.asarray(out, F32)
        if use_clamp:
            out = saturate(out)
    return {"Value": out.astype(F32, copy=False)}


# ---------------------------------------------------------------- Vector Math
def _project(a, b):
    len2 = dot_rows(b, b)
    return np.where(columns(len2 != 0), columns(safe_divide(dot_rows(a, b), len2)) * b, F32(0.0))


def _reflect(a, b):
    n = normalize_rows(b)
    return a - F32(2.0) * n * columns(dot_rows(a, n))


def _refract(a, b, eta):
    n = normalize_rows(b)
    d = dot_rows(n, a)
    k = F32(1.0) - eta * eta * (F32(1.0) - d * d)
    r = columns(eta) * a - columns(eta * d + np.sqrt(cycles_max(k, F32(0.0)))) * n
    return np.where(columns(k < 0), F32(0.0), r)


def _vfmod(a, b):
    """Cycles' SSE fmod(): a - trunc(a / b) * b (fused), 0 where b == 0."""
    q = np.trunc(safe_divide(a, b))
    return np.where(b != 0, fma(-q, b, a), F32(0.0))


def _vfloored_mod(a, b):
    q = np.floor(safe_divide(a, b))
    return np.where(b != 0, fma(-q, b, a), F32(0.0))


_VECTOR = {
    "ADD": lambda a, b, c, s: a + b,
    "SUBTRACT": lambda a, b, c, s: a - b,
    "MULTIPLY": lambda a, b, c, s: a * b,
    "DIVIDE": lambda a, b, c, s: safe_divide(a, b),
    "MULTIPLY_ADD": lambda a, b, c, s: fma(a, b, c),
    "CROSS_PRODUCT": lambda a, b, c, s: cross_rows_fused(a, b),
    "PROJECT": lambda a, b, c, s: _project(a, b),
    "REFLECT": lambda a, b, c, s: _reflect(a, b),
    "REFRACT": lambda a, b, c, s: _refract(a, b, s),
    "FACEFORWARD": lambda a, b, c, s: np.where(columns(dot_rows(c, b) < 0), a, -a),
    "SCALE": lambda a, b, c, s: a * columns(s),
    "NORMALIZE": lambda a, b, c, s: normalize_rows(a),
    "ABSOLUTE": lambda a, b, c, s: np.abs(a),
    "POWER": lambda a, b, c, s: _pow(a, b),
    "SIGN": lambda a, b, c, s: _sign(a),
    "MINIMUM": lambda a, b, c, s: cycles_min(a, b),
    "MAXIMUM": lambda a, b, c, s: cycles_max(a, b),
    "FLOOR": lambda a, b, c, s: np.floor(a),
    "CEIL": lambda a, b, c, s: np.ceil(a),
    "FRACTION": lambda a, b, c, s: fract(a),
    "MODULO": lambda a, b, c, s: _vfmod(a, b),
    "WRAP": lambda a, b, c, s: _vfloored_mod(a - c, b - c) + c,
    "SNAP": lambda a, b, c, s: np.floor(safe_divide(a, b)) * b,
    "ROUND": lambda a, b, c, s: np.floor(a + F32(0.5)),
    "SINE": lambda a, b, c, s: np.sin(a),
    "COSINE": lambda a, b, c, s: np.cos(a),
    "TANGENT": lambda a, b, c, s: np.tan(a),
}
_VECTOR_VALUE = {
    "DOT_PRODUCT": lambda a, b: dot_rows(a, b),
    "DISTANCE": lambda a, b: length_rows(a - b),
    "LENGTH": lambda a, b: length_rows(a),
}
VECTOR_MATH_OPERATIONS = tuple(_VECTOR) + tuple(_VECTOR_VALUE)
# Operations newer than Blender 5.0, by the release that added them (Cycles' svm/math_util.h there).
OPERATIONS_SINCE = {"ROUND": (5, 2)}


def operations_in(version, operations) -> tuple:
    """The operations of `operations` that the Blender `version` ((major, minor, ...)) offers."""
    return tuple(op for op in operations if tuple(version[:2]) >= OPERATIONS_SINCE.get(op, (0, 0)))


def vector_math(vector=0.0, vector_001=0.0, vector_002=0.0, scale=1.0, *, operation: str = "ADD") -> dict:
    """Vector Math node (`svm_vector_math`): {"Vector": (N, 3), "Value": (N,)}. Inputs are its sockets
    Vector, Vector_001, Vector_002 (Multiply Add, Wrap, Faceforward) and Scale (Scale; IOR of Refract).
    The output an operation does not write is zero."""
    a, b, c, s = as_vector(vector), as_vector(vector_001), as_vector(vector_002), as_float(scale)
    n = np.broadcast_shapes(a.shape[:-1], b.shape[:-1], c.shape[:-1], s.shape)
    with np.errstate(all="ignore"):
        if operation in _VECTOR_VALUE:
            value = np.asarray(_VECTOR_VALUE[operation](a, b), F32)
            return {"Vector": np.zeros(value.shape + (3,), F32), "Value": value}
        if operation in _VECTOR:
            vec = np.asarray(_VECTOR[operation](a, b, c, s), F32)
        else:
            vec = np.zeros(n + (3,), F32)
    vec = np.broadcast_to(vec, np.broadcast_shapes(vec.shape, n + (3,))).astype(F32, copy=False)
    return {"Vector": vec, "Value": np.zeros(vec.shape[:-1], F32)}


# ---------------------------------------------------------------- Map Range, Clamp
def _smoothstep(edge0, edge1, x):
    t = safe_divide(x - edge0, edge1 - edge0)
    mid = (F32(3.0) - F32(2.0) * t) * (t * t)
    return np.where(x < edge0, F32(0.0), np.where(x >= edge1, F32(1.0), mid))


def _smootherstep(edge0, edge1, x):
    x = saturate(safe_divide(x - edge0, edge1 - edge0))
    return x * x * x * (x * (x * F32(6.0) - F32(15.0)) + F32(10.0))


def _range_clamp(value, lo, hi):
    """Clamp to the range between lo and hi, whichever is larger (Clamp node, RANGE)."""
    return np.where(lo > hi, cycles_clamp(value, hi, lo), cycles_clamp(value, lo, hi))


def map_range(value=1.0, from_min=0.0, from_max=1.0, to_min=0.0, to_max=1.0, steps=4.0, *,
              data_type: str = "FLOAT", interpolation_type: str = "LINEAR", clamp: bool = True) -> dict:
    """Map Range node: FLOAT {"Result": (N,)} (`svm_node_map_range`, then Cycles' Clamp node in RANGE
    mode to [To Min, To Max] when clamp); FLOAT_VECTOR {"Vector": (N, 3)} (`svm_node_vector_map_range`:
    safe divides, no clamping for the smooth types). For FLOAT_VECTOR every input is a vector (the
    sockets Vector, From_Min_FLOAT3, ..., Steps_FLOAT3)."""
    with np.errstate(all="ignore"):
        if data_type == "FLOAT_VECTOR":
            vectors = (as_vector(v) for v in (value, from_min, from_max, to_min, to_max, steps))
            return {"Vector": _vector_map_range(*vectors, interpolation_type, clamp)}
        x, f0, f1, t0, t1, n = (as_float(v) for v in (value, from_min, from_max, to_min, to_max, steps))
        span = f1 - f0
        if interpolation_type == "SMOOTHSTEP":
            factor = np.where(f0 > f1, F32(1.0) - _smoothstep(f1, f0, x), _smoothstep(f0, f1, x))
        elif interpolation_type == "SMOOTHERSTEP":
            factor = np.where(f0 > f1, F32(1.0) - _smootherstep(f1, f0, x), _smootherstep(f0, f1, x))
        else:
            factor = safe_divide(x - f0, span)
            if interpolation_type == "STEPPED":
                factor = np.where(n > 0, safe_divide(np.floor(factor * (n + F32(1.0))), n), F32(0.0))
        result = np.where(span != 0, t0 + factor * (t1 - t0), F32(0.0))
        if clamp:
            result = _range_clamp(result, t0, t1)
    return {"Result": result.astype(F32, copy=False)}


def _vector_map_range(x, f0, f1, t0, t1, n, interpolation_type, clamp):
    factor = safe_divide(x - f0, f1 - f0)
    if interpolation_type == "STEPPED":
        factor = np.where(n > 0, safe_divide(np.floor(factor * (n + F32(1.0))), n), F32(0.0))
    elif interpolation_type == "SMOOTHSTEP":
        factor = saturate(factor)
        factor = (F32(3.0) - F32(2.0) * factor) * (factor * factor)
    elif interpolation_type == "SMOOTHERSTEP":
        factor = saturate(factor)
        factor = factor * factor * factor * (factor * (factor * F32(6.0) - F32(15.0)) + F32(10.0))
    result = t0 + factor * (t1 - t0)
    if clamp and interpolation_type not in ("SMOOTHSTEP", "SMOOTHERSTEP"):
        result = _range_clamp(result, t0, t1)
    return result.astype(F32, copy=False)


def clamp(value=1.0, min=0.0, max=1.0, *, clamp_type: str = "MINMAX") -> dict:  # noqa: A002 - socket names
    """Clamp node: {"Result": (N,)}; MINMAX = Cycles' min(max(v, min), max); RANGE swaps min > max."""
    v, lo, hi = as_float(value), as_float(min), as_float(max)
    out = _range_clamp(v, lo, hi) if clamp_type == "RANGE" else cycles_clamp(v, lo, hi)
    return {"Result": np.asarray(out, F32)}
