"""Cycles' colour, maths and converter nodes over arrays of hits (Blender 5.0, `kernel/svm/*.h`).

One function per node: Math, Vector Math, Mix (and the legacy MixRGB), Map Range, Clamp, Separate/Combine
Color and XYZ, Hue/Saturation/Value, Bright/Contrast, Gamma, Invert, RGB to BW, Blackbody, Wavelength,
Mapping, Vector Rotate, Color Ramp, RGB Curves, Vector Curves, Float Curve; plus the socket conversions
Cycles inserts on links (colour -> float by luminance, vector -> float by the average).

Conventions (the node program runner depends on them):
- Inputs are the node's input sockets in Blender's order, as snake_case parameters: a float socket (N,)
  float32, a vector or colour socket (N, 3) float32 (alpha is not carried). Any input may instead be a
  constant: a Python float or 0-d/length-1 array for a float socket, a float or a (3,) array for a vector
  socket; constants broadcast. Node options are keyword arguments named and spelt as Blender's RNA
  properties (operation="MULTIPLY", blend_type="OVERLAY", ...).
- Each function returns {output socket name as Blender shows it: array}, float32; (N,) or (N, 3) (length 1
  when every input was a constant).
- Numerics are Cycles' float32 arithmetic, its guards included: safe divide (x/0 = 0), safe pow/log/sqrt,
  C's truncating float->int and fmod, its NaN-blind min/max/clamp (`a > b ? a : b`). Cycles' CPU kernels
  are built with -ffp-contract=fast (fused multiply-add on AVX2) and -freciprocal-math: where that decides
  the result beyond rounding noise (a product cancelling against a sum) the fused form is reproduced
  (kernels.vec.fma); elsewhere results agree to a few ulp.
- Colour-space constants (luminance weights, XYZ -> RGB, Rec.709 -> RGB) default to Blender's own OCIO
  config (scene linear = Linear Rec.709); engine/export/node_tables.color_constants() reads them from the
  config in use.
- Ramps and curves take the baked tables of engine/export/node_tables.py (Cycles' Blender sync samples
  them: RAMP_TABLE_SIZE + 1 = 257 entries).
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, PI, columns, cross_rows_fused, dot_rows, fma, length_rows, normalize_rows

# ---------------------------------------------------------------- colour-space constants
# Luminance of scene-linear RGB (Cycles' kernel_data.film.rgb_to_y): row Y of (Cycles' ACES AP0 -> XYZ D65
# matrix, scene/shader.cpp) x (OCIO's scene_linear -> aces_interchange). For Blender's config this is
# Rec.709's luminance: float32 values exactly as Cycles 5.0 holds them (probed: RGB to BW of unit colours).
RGB_TO_Y = np.array([0.21263912, 0.71516913, 0.07219276], F32)
# CIE XYZ (D65) -> scene-linear RGB (kernel_data.film.xyz_to_r/g/b), the same derivation in float64 for
# Blender's config (Cycles' own float32 arithmetic may differ in the last digit; Wavelength agrees to 3e-7).
XYZ_TO_RGB = np.array([[3.2409700, -1.5373843, -0.49861140],
                       [-0.96924340, 1.8759667, 0.041554690],
                       [0.055629883, -0.20397648, 1.0569712]], F32)
# Rec.709 -> scene linear: None when the scene-linear space is Rec.709 (Cycles' film.is_rec709).
REC709_TO_RGB = None

# ---------------------------------------------------------------- Cycles' tables (kernel/tables.h)
# Blackbody: 800 K..12000 K piecewise fit, R, G = a/t + b t + c, B = ((a t + b) t + c) t + d, Rec.709.
_BLACKBODY_EDGES = np.array([965.0, 1167.0, 1449.0, 1902.0, 3315.0, 6365.0], F32)
_BLACKBODY_R = np.array([
    [1.61919106e+03, -2.05010916e-03, 5.02995757e+00],
    [2.48845471e+03, -1.11330907e-03, 3.22621544e+00],
    [3.34143193e+03, -4.86551192e-04, 1.76486769e+00],
    [4.09461742e+03, -1.27446582e-04, 7.25731635e-01],
    [4.67028036e+03, 2.91258199e-05, 1.26703442e-01],
    [4.59509185e+03, 2.87495649e-05, 1.50345020e-01],
    [3.78717450e+03, 9.35907826e-06, 3.99075871e-01]], F32)
_BLACKBODY_G = np.array([
    [-4.88999748e+02, 6.04330754e-04, -7.55807526e-02],
    [-7.55994277e+02, 3.16730098e-04, 4.78306139e-01],
    [-1.02363977e+03, 1.20223470e-04, 9.36662319e-01],
    [-1.26571316e+03, 4.87340896e-06, 1.27054498e+00],
    [-1.42529332e+03, -4.01150431e-05, 1.43972784e+00],
    [-1.17554822e+03, -2.16378048e-05, 1.30408023e+00],
    [-5.00799571e+02, -4.59832026e-06, 1.09098763e+00]], F32)
_BLACKBODY_B = np.array([
    [5.96945309e-11, -4.85742887e-08, -9.70622247e-05, -4.07936148e-03],
    [2.40430366e-11, 5.55021075e-08, -1.98503712e-04, 2.89312858e-02],
    [-1.40949732e-11, 1.89878968e-07, -3.56632824e-04, 9.10767778e-02],
    [-3.61460868e-11, 2.84822009e-07, -4.93211319e-04, 1.56723440e-01],
    [-1.97075738e-11, 1.75359352e-07, -2.50542825e-04, -2.22783266e-02],
    [-1.61997957e-13, -1.64216008e-08, 3.86216271e-04, -7.38077418e-01],
    [6.72650283e-13, -2.73078809e-08, 4.24098264e-04, -7.52335691e-01]], F32)
_BLACKBODY_HOT = np.array([0.8262954810464208, 0.9945080501520986, 1.566307710274283], F32)    # t >= 12000 K
_BLACKBODY_COLD = np.array([5.413294490189271, -0.20319390035873933, -0.0822535242887164], F32)  # t < 800 K

# CIE 1931 colour matching functions, 380..780 nm in 5 nm steps (81 rows of x, y, z).
_CIE_XYZ = np.array([
    [0.0014, 0.0000, 0.0065], [0.0022, 0.0001, 0.0105], [0.0042, 0.0001, 0.0201],
    [0.0076, 0.0002, 0.0362], [0.0143, 0.0004, 0.0679], [0.0232, 0.0006, 0.1102],
    [0.0435, 0.0012, 0.2074], [0.0776, 0.0022, 0.3713], [0.1344, 0.0040, 0.6456],
    [0.2148, 0.0073, 1.0391], [0.2839, 0.0116, 1.3856], [0.3285, 0.0168, 1.6230],
    [0.3483, 0.0230, 1.7471], [0.3481, 0.0298, 1.7826], [0.3362, 0.0380, 1.7721],
    [0.3187, 0.0480, 1.7441], [0.2908, 0.0600, 1.6692], [0.2511, 0.0739, 1.5281],
    [0.1954, 0.0910, 1.2876], [0.1421, 0.1126, 1.0419], [0.0956, 0.1390, 0.8130],
    [0.0580, 0.1693, 0.6162], [0.0320, 0.2080, 0.4652], [0.0147, 0.2586, 0.3533],
    [0.0049, 0.3230, 0.2720], [0.0024, 0.4073, 0.2123], [0.0093, 0.5030, 0.1582],
    [0.0291, 0.6082, 0.1117], [0.0633, 0.7100, 0.0782], [0.1096, 0.7932, 0.0573],
    [0.1655, 0.8620, 0.0422], [0.2257, 0.9149, 0.0298], [0.2904, 0.9540, 0.0203],
    [0.3597, 0.9803, 0.0134], [0.4334, 0.9950, 0.0087], [0.5121, 1.0000, 0.0057],
    [0.5945, 0.9950, 0.0039], [0.6784, 0.9786, 0.0027], [0.7621, 0.9520, 0.0021],
    [0.8425, 0.9154, 0.0018], [0.9163, 0.8700, 0.0017], [0.9786, 0.8163, 0.0014],
    [1.0263, 0.7570, 0.0011], [1.0567, 0.6949, 0.0010], [1.0622, 0.6310, 0.0008],
    [1.0456, 0.5668, 0.0006], [1.0026, 0.5030, 0.0003], [0.9384, 0.4412, 0.0002],
    [0.8544, 0.3810, 0.0002], [0.7514, 0.3210, 0.0001], [0.6424, 0.2650, 0.0000],
    [0.5419, 0.2170, 0.0000], [0.4479, 0.1750, 0.0000], [0.3608, 0.1382, 0.0000],
    [0.2835, 0.1070, 0.0000], [0.2187, 0.0816, 0.0000], [0.1649, 0.0610, 0.0000],
    [0.1212, 0.0446, 0.0000], [0.0874, 0.0320, 0.0000], [0.0636, 0.0232, 0.0000],
    [0.0468, 0.0170, 0.0000], [0.0329, 0.0119, 0.0000], [0.0227, 0.0082, 0.0000],
    [0.0158, 0.0057, 0.0000], [0.0114, 0.0041, 0.0000], [0.0081, 0.0029, 0.0000],
    [0.0058, 0.0021, 0.0000], [0.0041, 0.0015, 0.0000], [0.0029, 0.0010, 0.0000],
    [0.0020, 0.0007, 0.0000], [0.0014, 0.0005, 0.0000], [0.0010, 0.0004, 0.0000],
    [0.0007, 0.0002, 0.0000], [0.0005, 0.0002, 0.0000], [0.0003, 0.0001, 0.0000],
    [0.0002, 0.0001, 0.0000], [0.0002, 0.0001, 0.0000], [0.0001, 0.0000, 0.0000],
    [0.0001, 0.0000, 0.0000], [0.0001, 0.0000, 0.0000], [0.0000, 0.0000, 0.0000]], F32)

_TO_RADIANS = PI / F32(180.0)         # M_PI_F / 180.0f, folded in float32
_TO_DEGREES = F32(180.0) / PI
_FLT_EPSILON = F32(np.finfo(F32).eps)
_INT_MIN = F32(-2147483648.0)         # what x86 makes of an out-of-range float -> int cast


# ---------------------------------------------------------------- inputs and Cycles' scalar helpers
def _f(x) -> np.ndarray:
    """A float input as a float32 array of at least one dimension ((N,) or (1,))."""
    a = np.asarray(x, F32)
    return a.reshape(1) if a.ndim == 0 else a


def _v(x) -> np.ndarray:
    """A vector/colour input as a float32 (N, 3) or (1, 3) array."""
    a = np.asarray(x, F32)
    if a.ndim == 0 or a.shape == (1,):
        return np.broadcast_to(a.reshape(1, 1), (1, 3))
    return a.reshape(1, 3) if a.ndim == 1 else a


def _max(a, b):
    """Cycles' max(): `a > b ? a : b` (a NaN a gives b)."""
    return np.where(a > b, a, b)


def _min(a, b):
    """Cycles' min(): `a < b ? a : b`."""
    return np.where(a < b, a, b)


def _clamp(a, lo, hi):
    return _min(_max(a, lo), hi)


def _saturate(a):
    return _clamp(a, F32(0.0), F32(1.0))


def _safe_divide(a, b) -> np.ndarray:
    """a / b, 0 where b == 0."""
    out = np.zeros(np.broadcast_shapes(np.shape(a), np.shape(b)), F32)
    np.divide(a, b, out=out, where=(b != 0))
    return out


def _is_int(b: np.ndarray) -> np.ndarray:
    """`b == (float)(int)b` with C's truncating cast on x86 (out of range and NaN -> INT_MIN)."""
    small = np.abs(b) < F32(2147483648.0)
    return np.where(small, b == np.trunc(np.where(small, b, F32(0.0))), b == _INT_MIN)


def _fract(x):
    return x - np.floor(x)


def _interp(a, b, t):
    return a + t * (b - a)


# ---------------------------------------------------------------- Math
def _pow(a, b):
    """Cycles' safe_powf: 0 for a negative base and a non-integer exponent, x^0 = 1, 0^y = 0."""
    out = np.power(a, b)
    out = np.where(a == 0, F32(0.0), out)
    out = np.where((a < 0) & ~_is_int(b), F32(0.0), out)
    return np.where(b == 0, F32(1.0), out).astype(F32, copy=False)


def _log(a, b):
    ok = (a > 0) & (b > 0)
    la = np.log(np.where(ok, a, F32(1.0)))
    lb = np.log(np.where(ok, b, F32(1.0)))
    return np.where(ok, _safe_divide(la, lb), F32(0.0))


def _wrapf(value, vmax, vmin):
    """Cycles' wrapf (Godot's): value - range * floor((value - min) / range); min where range == 0."""
    rng = vmax - vmin
    q = np.floor(_safe_divide(value - vmin, rng))
    return np.where(rng != 0, fma(-rng, q, value), vmin)


def _pingpong(a, b):
    b2 = b * F32(2.0)
    f = _fract(_safe_divide(a - b, b2))
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
    "DIVIDE": lambda a, b, c: _safe_divide(a, b),
    "MULTIPLY_ADD": lambda a, b, c: fma(a, b, c),
    "POWER": lambda a, b, c: _pow(a, b),
    "LOGARITHM": lambda a, b, c: _log(a, b),
    "SQRT": lambda a, b, c: np.sqrt(_max(a, F32(0.0))),
    "INVERSE_SQRT": lambda a, b, c: np.where(a > 0, _safe_divide(F32(1.0), np.sqrt(_max(a, F32(0.0)))),
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
    "FRACT": lambda a, b, c: _fract(a),
    "MODULO": lambda a, b, c: np.where(b != 0, np.fmod(a, np.where(b != 0, b, F32(1.0))), F32(0.0)),
    "FLOORED_MODULO": lambda a, b, c: np.where(b != 0, fma(-np.floor(_safe_divide(a, b)), b, a), F32(0.0)),
    "WRAP": lambda a, b, c: _wrapf(a, b, c),
    "SNAP": lambda a, b, c: np.floor(_safe_divide(a, b)) * b,
    "PINGPONG": lambda a, b, c: _pingpong(a, b),
    "SINE": lambda a, b, c: np.sin(a),
    "COSINE": lambda a, b, c: np.cos(a),
    "TANGENT": lambda a, b, c: np.tan(a),
    "ARCSINE": lambda a, b, c: np.arcsin(_clamp(a, F32(-1.0), F32(1.0))),
    "ARCCOSINE": lambda a, b, c: np.arccos(_clamp(a, F32(-1.0), F32(1.0))),
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
    a, b, c = _f(value), _f(value_001), _f(value_002)
    with np.errstate(all="ignore"):
        out = _MATH[operation](a, b, c) if operation in _MATH else np.zeros(np.broadcast(a, b, c).shape, F32)
        out = np.asarray(out, F32)
        if use_clamp:
            out = _saturate(out)
    return {"Value": out.astype(F32, copy=False)}


# ---------------------------------------------------------------- Vector Math
def _project(a, b):
    len2 = dot_rows(b, b)
    return np.where(columns(len2 != 0), columns(_safe_divide(dot_rows(a, b), len2)) * b, F32(0.0))


def _reflect(a, b):
    n = normalize_rows(b)
    return a - F32(2.0) * n * columns(dot_rows(a, n))


def _refract(a, b, eta):
    n = normalize_rows(b)
    d = dot_rows(n, a)
    k = F32(1.0) - eta * eta * (F32(1.0) - d * d)
    r = columns(eta) * a - columns(eta * d + np.sqrt(_max(k, F32(0.0)))) * n
    return np.where(columns(k < 0), F32(0.0), r)


def _vfmod(a, b):
    """Cycles' SSE fmod(): a - trunc(a / b) * b (fused), 0 where b == 0."""
    q = np.trunc(_safe_divide(a, b))
    return np.where(b != 0, fma(-q, b, a), F32(0.0))


def _vfloored_mod(a, b):
    q = np.floor(_safe_divide(a, b))
    return np.where(b != 0, fma(-q, b, a), F32(0.0))


_VECTOR = {
    "ADD": lambda a, b, c, s: a + b,
    "SUBTRACT": lambda a, b, c, s: a - b,
    "MULTIPLY": lambda a, b, c, s: a * b,
    "DIVIDE": lambda a, b, c, s: _safe_divide(a, b),
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
    "MINIMUM": lambda a, b, c, s: _min(a, b),
    "MAXIMUM": lambda a, b, c, s: _max(a, b),
    "FLOOR": lambda a, b, c, s: np.floor(a),
    "CEIL": lambda a, b, c, s: np.ceil(a),
    "FRACTION": lambda a, b, c, s: _fract(a),
    "MODULO": lambda a, b, c, s: _vfmod(a, b),
    "WRAP": lambda a, b, c, s: _vfloored_mod(a - c, b - c) + c,
    "SNAP": lambda a, b, c, s: np.floor(_safe_divide(a, b)) * b,
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
    a, b, c, s = _v(vector), _v(vector_001), _v(vector_002), _f(scale)
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


# ---------------------------------------------------------------- colour models (util/color.h)
_HSV_PICK = np.array([  # hsv_to_rgb's sextants (i = 0..4, anything else): which of (v, p, q, t) per channel
    [0, 2, 1, 1, 3, 0],       # r: v q p p t v
    [3, 0, 0, 2, 1, 1],       # g: t v v q p p
    [1, 1, 3, 0, 0, 2]],      # b: p p t v v q
    np.intp)


def _channels(rgb: np.ndarray):
    return rgb[..., 0], rgb[..., 1], rgb[..., 2]


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """(N, 3) RGB -> HSV as Cycles' rgb_to_hsv (hue in [0, 1), no clamping of negative colours)."""
    r, g, b = _channels(rgb)
    cmax = np.fmax(r, np.fmax(g, b))
    delta = cmax - _min(r, _min(g, b))
    s = _safe_divide(delta, cmax)
    cr, cg, cb = (_safe_divide(cmax - c, delta) for c in (r, g, b))
    h = np.where(r == cmax, cb - cg, np.where(g == cmax, (F32(2.0) + cr) - cb, (F32(4.0) + cg) - cr))
    h *= F32(1.0 / 6.0)  # h /= 6.0f under -freciprocal-math
    h = np.where(h < 0, h + F32(1.0), h)
    return np.stack(np.broadcast_arrays(np.where(s != 0, h, F32(0.0)), s, cmax), -1)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """(N, 3) HSV -> RGB as Cycles' hsv_to_rgb (hue 1 -> 0; a hue outside [0, 1) takes the last sextant)."""
    h, s, v = _channels(hsv)
    h = np.where(h == 1, F32(0.0), h) * F32(6.0)
    i = np.floor(h)
    # Saturation 0 is grey, (v, v, v): with f = 0, p = q = t = v exactly, whatever the hue.
    f = np.where(s != 0, h - i, F32(0.0))
    p = v * (F32(1.0) - s)
    q = v * (F32(1.0) - s * f)
    t = v * (F32(1.0) - s * (F32(1.0) - f))
    sextant = np.where((i >= 0) & (i <= 4), i, F32(5.0)).astype(np.intp)
    cols = np.stack(np.broadcast_arrays(v, p, q, t), -1)
    flat = cols.reshape(-1)
    base = np.arange(0, flat.size, 4, dtype=np.intp).reshape(cols.shape[:-1])
    return np.stack([np.take(flat, base + np.take(_HSV_PICK[k], sextant)) for k in range(3)], -1)


def rgb_to_hsl(rgb: np.ndarray) -> np.ndarray:
    """(N, 3) RGB -> HSL as Cycles' rgb_to_hsl."""
    r, g, b = _channels(rgb)
    cmax = np.fmax(r, np.fmax(g, b))
    cmin = _min(r, _min(g, b))
    l = _min(F32(1.0), (cmax + cmin) * F32(0.5))
    delta = cmax - cmin
    grey = cmax == cmin
    s = np.where(l > 0.5, _safe_divide(delta, F32(2.0) - cmax - cmin), _safe_divide(delta, cmax + cmin))
    h = np.where(cmax == r, _safe_divide(g - b, delta) + np.where(g < b, F32(6.0), F32(0.0)),
                 np.where(cmax == g, _safe_divide(b - r, delta) + F32(2.0), _safe_divide(r - g, delta) + F32(4.0)))
    h = np.where(grey, F32(0.0), h) * F32(1.0 / 6.0)
    return np.stack(np.broadcast_arrays(h, np.where(grey, F32(0.0), s), l), -1)


def hsl_to_rgb(hsl: np.ndarray) -> np.ndarray:
    """(N, 3) HSL -> RGB as Cycles' hsl_to_rgb."""
    h, s, l = _channels(hsl)
    h6 = h * F32(6.0)
    nr = _saturate(np.abs(h6 - F32(3.0)) - F32(1.0))
    ng = _saturate(F32(2.0) - np.abs(h6 - F32(2.0)))
    nb = _saturate(F32(2.0) - np.abs(h6 - F32(4.0)))
    chroma = (F32(1.0) - np.abs(F32(2.0) * l - F32(1.0))) * s
    return np.stack(np.broadcast_arrays((nr - F32(0.5)) * chroma + l, (ng - F32(0.5)) * chroma + l,
                                        (nb - F32(0.5)) * chroma + l), -1)


# ---------------------------------------------------------------- Mix
def _per_channel_dodge(c1, c2, t):
    tmp = F32(1.0) - t * c2
    q = _safe_divide(c1, tmp)
    out = np.where(tmp <= 0, F32(1.0), np.where(q > 1, F32(1.0), q))
    return np.where(c1 != 0, out, c1)


def _per_channel_burn(c1, c2, t, tm):
    tmp = tm + t * c2
    q = F32(1.0) - _safe_divide(F32(1.0) - c1, tmp)
    return np.where(tmp <= 0, F32(0.0), np.where(q < 0, F32(0.0), np.where(q > 1, F32(1.0), q)))


def _blend_hue(t, c1, c2):
    hsv2 = rgb_to_hsv(c2)
    hsv = rgb_to_hsv(c1)
    hsv = np.stack(np.broadcast_arrays(hsv2[..., 0], hsv[..., 1], hsv[..., 2]), -1)
    return np.where(columns(hsv2[..., 1] != 0), _interp(c1, hsv_to_rgb(hsv), t), c1)


def _blend_saturation(t, tm, c1, c2):
    hsv = rgb_to_hsv(c1)
    hsv2 = rgb_to_hsv(c2)
    s = tm[..., 0] * hsv[..., 1] + t[..., 0] * hsv2[..., 1]
    out = hsv_to_rgb(np.stack(np.broadcast_arrays(hsv[..., 0], s, hsv[..., 2]), -1))
    return np.where(columns(hsv[..., 1] != 0), out, c1)


def _blend_value(t, tm, c1, c2):
    hsv = rgb_to_hsv(c1)
    hsv2 = rgb_to_hsv(c2)
    v = tm[..., 0] * hsv[..., 2] + t[..., 0] * hsv2[..., 2]
    return hsv_to_rgb(np.stack(np.broadcast_arrays(hsv[..., 0], hsv[..., 1], v), -1))


def _blend_color(t, c1, c2):
    hsv2 = rgb_to_hsv(c2)
    hsv = rgb_to_hsv(c1)
    hsv = np.stack(np.broadcast_arrays(hsv2[..., 0], hsv2[..., 1], hsv[..., 2]), -1)
    return np.where(columns(hsv2[..., 1] != 0), _interp(c1, hsv_to_rgb(hsv), t), c1)


def _blend_overlay(t, tm, c1, c2):
    low = c1 * (tm + F32(2.0) * t * c2)
    high = F32(1.0) - (tm + F32(2.0) * t * (F32(1.0) - c2)) * (F32(1.0) - c1)
    return np.where(c1 < 0.5, low, high)


def _blend_soft_light(t, tm, c1, c2):
    one = F32(1.0)
    scr = one - (one - c2) * (one - c1)
    return tm * c1 + t * ((one - c1) * c2 * c1 + c1 * scr)


_BLEND = {  # blend_type -> f(t, tm, c1, c2); t and tm are the factor and 1 - factor as columns()
    "MIX": lambda t, tm, a, b: _interp(a, b, t),
    "ADD": lambda t, tm, a, b: _interp(a, a + b, t),
    "MULTIPLY": lambda t, tm, a, b: _interp(a, a * b, t),
    "SCREEN": lambda t, tm, a, b: F32(1.0) - (tm + t * (F32(1.0) - b)) * (F32(1.0) - a),
    "OVERLAY": _blend_overlay,
    "SUBTRACT": lambda t, tm, a, b: _interp(a, a - b, t),
    "DIVIDE": lambda t, tm, a, b: np.where(b != 0, tm * a + t * _safe_divide(a, b), a),
    "DIFFERENCE": lambda t, tm, a, b: _interp(a, np.abs(a - b), t),
    "EXCLUSION": lambda t, tm, a, b: _max(_interp(a, a + b - F32(2.0) * a * b, t), F32(0.0)),
    "DARKEN": lambda t, tm, a, b: _interp(a, _min(a, b), t),
    "LIGHTEN": lambda t, tm, a, b: _interp(a, _max(a, b), t),
    "DODGE": lambda t, tm, a, b: _per_channel_dodge(a, b, t),
    "BURN": lambda t, tm, a, b: _per_channel_burn(a, b, t, tm),
    "HUE": lambda t, tm, a, b: _blend_hue(t, a, b),
    "SATURATION": _blend_saturation,
    "VALUE": _blend_value,
    "COLOR": lambda t, tm, a, b: _blend_color(t, a, b),
    "SOFT_LIGHT": _blend_soft_light,
    "LINEAR_LIGHT": lambda t, tm, a, b: a + t * (F32(2.0) * b + F32(-1.0)),
}
BLEND_TYPES = tuple(_BLEND)


def mix_color(factor, a, b, *, blend_type: str = "MIX", clamp_factor: bool = True,
              clamp_result: bool = False) -> np.ndarray:
    """Cycles' svm_mix over (N, 3) colours with an (N,) factor: (N, 3)."""
    t = _f(factor)
    if clamp_factor:
        t = _saturate(t)
    t = columns(t)
    c1, c2 = _v(a), _v(b)
    with np.errstate(all="ignore"):
        out = _BLEND[blend_type](t, F32(1.0) - t, c1, c2)
        out = np.broadcast_to(out, np.broadcast_shapes(out.shape, c1.shape, c2.shape, t.shape))
        if clamp_result:
            out = _saturate(out)
    return out.astype(F32, copy=False)


def mix(factor=0.5, a=0.0, b=0.0, *, data_type: str = "FLOAT", factor_mode: str = "UNIFORM",
        blend_type: str = "MIX", clamp_factor: bool = True, clamp_result: bool = False) -> dict:
    """Mix node (ShaderNodeMix): {"Result": (N,) for FLOAT, (N, 3) for VECTOR and RGBA}.

    factor: Factor_Float, or Factor_Vector for VECTOR with factor_mode NON_UNIFORM; a, b: A_*/B_* of the
    data type. FLOAT and VECTOR lerp a (1 - t) + b t; RGBA blends by blend_type (`svm_mix`), clamp_result
    saturating the colour. clamp_factor clamps the factor to [0, 1] first."""
    if data_type == "RGBA":
        return {"Result": mix_color(factor, a, b, blend_type=blend_type, clamp_factor=clamp_factor,
                                    clamp_result=clamp_result)}
    if data_type == "VECTOR":
        t = _v(factor) if factor_mode == "NON_UNIFORM" else columns(_f(factor))
        a, b = _v(a), _v(b)
    else:
        t, a, b = _f(factor), _f(a), _f(b)
    if clamp_factor:
        t = _saturate(t)
    return {"Result": (a * (F32(1.0) - t) + b * t).astype(F32, copy=False)}


def mix_rgb(fac=0.5, color1=0.5, color2=0.5, *, blend_type: str = "MIX", use_clamp: bool = False) -> dict:
    """Legacy MixRGB node: {"Color": (N, 3)}; its factor is always clamped, use_clamp saturates the result."""
    return {"Color": mix_color(fac, color1, color2, blend_type=blend_type, clamp_factor=True,
                               clamp_result=use_clamp)}


# ---------------------------------------------------------------- Map Range, Clamp
def _smoothstep(edge0, edge1, x):
    t = _safe_divide(x - edge0, edge1 - edge0)
    mid = (F32(3.0) - F32(2.0) * t) * (t * t)
    return np.where(x < edge0, F32(0.0), np.where(x >= edge1, F32(1.0), mid))


def _smootherstep(edge0, edge1, x):
    x = _saturate(_safe_divide(x - edge0, edge1 - edge0))
    return x * x * x * (x * (x * F32(6.0) - F32(15.0)) + F32(10.0))


def _range_clamp(value, lo, hi):
    """Clamp to the range between lo and hi, whichever is larger (Clamp node, RANGE)."""
    return np.where(lo > hi, _clamp(value, hi, lo), _clamp(value, lo, hi))


def map_range(value=1.0, from_min=0.0, from_max=1.0, to_min=0.0, to_max=1.0, steps=4.0, *,
              data_type: str = "FLOAT", interpolation_type: str = "LINEAR", clamp: bool = True) -> dict:
    """Map Range node: FLOAT {"Result": (N,)} (`svm_node_map_range`, then Cycles' Clamp node in RANGE
    mode to [To Min, To Max] when clamp); FLOAT_VECTOR {"Vector": (N, 3)} (`svm_node_vector_map_range`:
    safe divides, no clamping for the smooth types). For FLOAT_VECTOR every input is a vector (the
    sockets Vector, From_Min_FLOAT3, ..., Steps_FLOAT3)."""
    with np.errstate(all="ignore"):
        if data_type == "FLOAT_VECTOR":
            return {"Vector": _vector_map_range(_v(value), _v(from_min), _v(from_max), _v(to_min), _v(to_max),
                                                _v(steps), interpolation_type, clamp)}
        x, f0, f1, t0, t1, n = (_f(v) for v in (value, from_min, from_max, to_min, to_max, steps))
        span = f1 - f0
        if interpolation_type == "SMOOTHSTEP":
            factor = np.where(f0 > f1, F32(1.0) - _smoothstep(f1, f0, x), _smoothstep(f0, f1, x))
        elif interpolation_type == "SMOOTHERSTEP":
            factor = np.where(f0 > f1, F32(1.0) - _smootherstep(f1, f0, x), _smootherstep(f0, f1, x))
        else:
            factor = _safe_divide(x - f0, span)
            if interpolation_type == "STEPPED":
                factor = np.where(n > 0, _safe_divide(np.floor(factor * (n + F32(1.0))), n), F32(0.0))
        result = np.where(span != 0, t0 + factor * (t1 - t0), F32(0.0))
        if clamp:
            result = _range_clamp(result, t0, t1)
    return {"Result": result.astype(F32, copy=False)}


def _vector_map_range(x, f0, f1, t0, t1, n, interpolation_type, clamp):
    factor = _safe_divide(x - f0, f1 - f0)
    if interpolation_type == "STEPPED":
        factor = np.where(n > 0, _safe_divide(np.floor(factor * (n + F32(1.0))), n), F32(0.0))
    elif interpolation_type == "SMOOTHSTEP":
        factor = _saturate(factor)
        factor = (F32(3.0) - F32(2.0) * factor) * (factor * factor)
    elif interpolation_type == "SMOOTHERSTEP":
        factor = _saturate(factor)
        factor = factor * factor * factor * (factor * (factor * F32(6.0) - F32(15.0)) + F32(10.0))
    result = t0 + factor * (t1 - t0)
    if clamp and interpolation_type not in ("SMOOTHSTEP", "SMOOTHERSTEP"):
        result = _range_clamp(result, t0, t1)
    return result.astype(F32, copy=False)


def clamp(value=1.0, min=0.0, max=1.0, *, clamp_type: str = "MINMAX") -> dict:  # noqa: A002 - socket names
    """Clamp node: {"Result": (N,)}; MINMAX = Cycles' min(max(v, min), max); RANGE swaps min > max."""
    v, lo, hi = _f(value), _f(min), _f(max)
    out = _range_clamp(v, lo, hi) if clamp_type == "RANGE" else _clamp(v, lo, hi)
    return {"Result": np.asarray(out, F32)}


# ---------------------------------------------------------------- colour converters
def separate_color(color=0.8, *, mode: str = "RGB") -> dict:
    """Separate Color node: {"Red", "Green", "Blue": (N,)} (H, S, V or H, S, L for those modes)."""
    c = _v(color)
    with np.errstate(all="ignore"):
        c = rgb_to_hsv(c) if mode == "HSV" else rgb_to_hsl(c) if mode == "HSL" else c
    return {"Red": c[..., 0].copy(), "Green": c[..., 1].copy(), "Blue": c[..., 2].copy()}


def combine_color(red=0.0, green=0.0, blue=0.0, *, mode: str = "RGB") -> dict:
    """Combine Color node: {"Color": (N, 3)}."""
    c = np.stack(np.broadcast_arrays(_f(red), _f(green), _f(blue)), -1)
    with np.errstate(all="ignore"):
        c = hsv_to_rgb(c) if mode == "HSV" else hsl_to_rgb(c) if mode == "HSL" else c
    return {"Color": c.astype(F32, copy=False)}


def separate_xyz(vector=0.0) -> dict:
    """Separate XYZ node: {"X", "Y", "Z": (N,)}."""
    v = _v(vector)
    return {"X": v[..., 0].copy(), "Y": v[..., 1].copy(), "Z": v[..., 2].copy()}


def combine_xyz(x=0.0, y=0.0, z=0.0) -> dict:
    """Combine XYZ node: {"Vector": (N, 3)}."""
    return {"Vector": np.stack(np.broadcast_arrays(_f(x), _f(y), _f(z)), -1)}


def hue_saturation(hue=0.5, saturation=1.0, value=1.0, fac=1.0, color=0.8) -> dict:
    """Hue/Saturation/Value node (`svm_node_hsv`): {"Color": (N, 3)}: hue shifted by Hue - 1/2 and wrapped,
    saturation scaled and clamped to [0, 1], value scaled, mixed with the input by Fac, negatives -> 0."""
    c = _v(color)
    fac = columns(_f(fac))
    with np.errstate(all="ignore"):
        hsv = rgb_to_hsv(c)
        h = _fract(hsv[..., 0] + _f(hue) + F32(0.5))
        s = _saturate(hsv[..., 1] * _f(saturation))
        v = hsv[..., 2] * _f(value)
        out = hsv_to_rgb(np.stack(np.broadcast_arrays(h, s, v), -1))
        out = fac * out + (F32(1.0) - fac) * c
    return {"Color": _max(out, F32(0.0)).astype(F32, copy=False)}


def bright_contrast(color=1.0, bright=0.0, contrast=0.0) -> dict:
    """Bright/Contrast node: {"Color": max((1 + contrast) c + bright - contrast / 2, 0)}."""
    c = _v(color)
    contrast = _f(contrast)
    a = columns(F32(1.0) + contrast)
    b = columns(_f(bright) - contrast * F32(0.5))
    return {"Color": _max(fma(a, c, b), F32(0.0))}


def gamma(color=1.0, gamma=1.0) -> dict:  # noqa: A002
    """Gamma node: {"Color": c ** gamma for positive channels (others kept); all 1 when gamma == 0}."""
    c = _v(color)
    g = columns(_f(gamma))
    with np.errstate(all="ignore"):
        out = np.where(c > 0, np.power(np.where(c > 0, c, F32(1.0)), g), c)
    return {"Color": np.where(g == 0, F32(1.0), out).astype(F32, copy=False)}


def invert(fac=1.0, color=0.0) -> dict:
    """Invert node: {"Color": fac (1 - c) + (1 - fac) c}."""
    c = _v(color)
    f = columns(_f(fac))
    return {"Color": (f * (F32(1.0) - c) + (F32(1.0) - f) * c).astype(F32, copy=False)}


def color_to_float(color, rgb_to_y=RGB_TO_Y) -> np.ndarray:
    """Colour -> float as Cycles converts on a link and RGB to BW computes: luminance, (N,)."""
    return dot_rows(_v(color), np.asarray(rgb_to_y, F32))


def vector_to_float(vector) -> np.ndarray:
    """Vector -> float as Cycles converts on a link: the average of the components, (N,)."""
    v = _v(vector)
    return (v[..., 0] + v[..., 1] + v[..., 2]) * F32(1.0 / 3.0)


def rgb_to_bw(color=0.5, *, rgb_to_y=RGB_TO_Y) -> dict:
    """RGB to BW node: {"Val": (N,)} the scene-linear luminance (RGB_TO_Y)."""
    return {"Val": color_to_float(color, rgb_to_y)}


def blackbody(temperature=6500.0, *, rec709_to_rgb=REC709_TO_RGB) -> dict:
    """Blackbody node: {"Color": (N, 3)}: Cycles' piecewise fit (800..12000 K, constant beyond), in
    Rec.709 then scene linear (rec709_to_rgb, a 3x3 matrix; None = identity), negatives -> 0."""
    t = _f(temperature)
    with np.errstate(all="ignore"):
        i = np.searchsorted(_BLACKBODY_EDGES, t, side="right")
        r, g, b = _BLACKBODY_R[i], _BLACKBODY_G[i], _BLACKBODY_B[i]
        t_inv = _safe_divide(F32(1.0), t)
        red = fma(r[..., 0], t_inv, r[..., 1] * t) + r[..., 2]
        green = fma(g[..., 0], t_inv, g[..., 1] * t) + g[..., 2]
        blue = fma(fma(fma(b[..., 0], t, b[..., 1]), t, b[..., 2]), t, b[..., 3])
        rgb = np.stack([red, green, blue], -1)
        rgb = np.where(columns(t >= 12000), _BLACKBODY_HOT, np.where(columns(t < 800), _BLACKBODY_COLD, rgb))
        if rec709_to_rgb is not None:
            m = np.asarray(rec709_to_rgb, F32)
            rgb = np.stack([dot_rows(rgb, m[k]) for k in range(3)], -1)
    return {"Color": _max(rgb, F32(0.0)).astype(F32, copy=False)}


def wavelength(wavelength=500.0, *, xyz_to_rgb=XYZ_TO_RGB) -> dict:  # noqa: A002
    """Wavelength node: {"Color": (N, 3)}: the CIE table lerped at (nm - 380) / 5 (C's truncating index,
    so 375..380 nm extrapolate the first interval), black outside, XYZ -> scene linear, / 2.52, negatives
    -> 0."""
    lam = _f(wavelength)
    with np.errstate(all="ignore"):
        ii = (lam - F32(380.0)) * F32(1.0 / 5.0)
        small = np.abs(ii) < F32(2147483648.0)
        i = np.where(small, np.trunc(np.where(small, ii, F32(0.0))), _INT_MIN)
        valid = (i >= 0) & (i < 80)
        k = np.where(valid, i, F32(0.0)).astype(np.intp)
        frac = columns(ii - np.where(valid, i, F32(0.0)))
        xyz = _interp(_CIE_XYZ[k], _CIE_XYZ[k + 1], frac)
        m = np.asarray(xyz_to_rgb, F32)
        rgb = np.stack([dot_rows(xyz, m[c]) for c in range(3)], -1) * F32(1.0 / 2.52)
        rgb = np.where(columns(valid), rgb, F32(0.0))
    return {"Color": _max(rgb, F32(0.0)).astype(F32, copy=False)}


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
    v, loc, rot, s = _v(vector), _v(location), _v(rotation), _v(scale)
    with np.errstate(all="ignore"):
        m = _euler_rows(rot)
        if vector_type == "POINT":
            out = _rotate(m, v * s) + loc
        elif vector_type == "TEXTURE":
            out = _safe_divide(_rotate_transposed(m, v - loc), s)
        elif vector_type == "VECTOR":
            out = _rotate(m, v * s)
        elif vector_type == "NORMAL":
            out = normalize_rows(_rotate(m, _safe_divide(v, s)))
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
    v, ctr = _v(vector), _v(center)
    with np.errstate(all="ignore"):
        if rotation_type == "EULER_XYZ":
            m = _euler_rows(_v(rotation))
            d = v - ctr
            out = (_rotate_transposed(m, d) if invert else _rotate(m, d)) + ctr
        else:
            if rotation_type in _AXES:
                ax = np.asarray(_AXES[rotation_type], F32)[None]
                length = np.ones(1, F32)
            else:
                ax = _v(axis)
                length = length_rows(ax)
            a = _f(angle)
            a = -a if invert else a
            unit = _safe_divide(ax, columns(length))
            out = np.where(columns(length != 0), _rotate_around_axis(v - ctr, unit, columns(a)[..., 0]) + ctr, v)
    return {"Vector": out.astype(F32, copy=False)}


# ---------------------------------------------------------------- Color Ramp and curves (ramp.h)
def ramp_lookup(table: np.ndarray, f, interpolate: bool, extrapolate: bool) -> np.ndarray:
    """Cycles' rgb/float_ramp_lookup over a baked (K,) or (K, C) table at positions f (N,): (N,) or (N, C).

    Inside [0, 1]: entry floor(f (K - 1)), lerped to the next when interpolate. Outside, with
    extrapolate: the end segment's line, t0 + (t0 - t1) |excess| (K - 1); without: the end entry."""
    table = np.asarray(table, F32)
    size = table.shape[0]
    cols = table.T if table.ndim == 2 else table[None]        # (C, K): the lookups run along N
    f = _f(f)
    x = _saturate(f) * F32(size - 1)
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
        fac = columns(_f(fac))
        return ((F32(1.0) - fac) * v + fac * out).astype(F32, copy=False)


def rgb_curves(fac=1.0, color=1.0, *, table: np.ndarray, min_x: float = 0.0, max_x: float = 1.0,
               extrapolate: bool = True) -> dict:
    """RGB Curves node (`svm_node_curves`): {"Color": (N, 3)}: each channel looked up in its column of the
    (K, 3) table (node_tables.rgb_curves_table: the C curve already applied) at (c - min_x) / (max_x -
    min_x), then mixed with the input by Fac."""
    return {"Color": _curves(fac, _v(color), table, min_x, max_x, extrapolate)}


def vector_curves(fac=1.0, vector=0.0, *, table: np.ndarray, min_x: float = -1.0, max_x: float = 1.0,
                  extrapolate: bool = True) -> dict:
    """Vector Curves node: {"Vector": (N, 3)}, as RGB Curves over the X, Y, Z curves' table."""
    return {"Vector": _curves(fac, _v(vector), table, min_x, max_x, extrapolate)}


def float_curve(factor=1.0, value=1.0, *, table: np.ndarray, min_x: float = 0.0, max_x: float = 1.0,
                extrapolate: bool = True) -> dict:
    """Float Curve node (`svm_node_curve`): {"Value": (N,)} from the (K,) table of node_tables.float_curve_table."""
    x = _f(value)
    rng = F32(max_x) - F32(min_x)
    with np.errstate(all="ignore"):
        y = ramp_lookup(table, (x - F32(min_x)) / rng, True, extrapolate)
        f = _f(factor)
        return {"Value": ((F32(1.0) - f) * x + f * y).astype(F32, copy=False)}
