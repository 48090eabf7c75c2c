"""The C library's float functions as Cycles calls them, over float32 arrays.

sinf and cosf reproduce glibc's (>= 2.28) bit for bit; the others (exp, log, pow, acos, atan2...) are
evaluated in float64 and rounded to float32 (`libm`), which agrees with glibc's float functions in all but
about 0.1% of arguments, by one unit in the last place.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, F64, ONE, U32


# ---- glibc's sinf / cosf -----------------------------------------------------------------------
# Cycles calls the C library's sinf/cosf. NumPy's float32 sin/cos differ from glibc's in the last bit
# for ~15% of arguments, and the Magic texture feeds sines into sines, so at Distortion > 1 such 1-ulp
# differences grow into visible ones. These reproduce glibc's (>= 2.28) algorithm - ARM's optimized
# routines: a double-precision polynomial after reduction by pi/2 (its coefficients and the 4/pi bits
# are the library's data) - bit for bit on the million arguments checked against glibc 2.36, near
# multiples of pi/2 included. About 1-3 ms per 65k values (NumPy's float32 sin: 0.1 ms).
_U64, _I64 = np.uint64, np.int64
_HPI_INV_2P24 = float.fromhex("0x1.45f306dc9c883p+23")    # 2/pi, scaled by 2^24
_HPI = float.fromhex("0x1.921fb54442d18p0")               # pi/2
_PI_2P_M62 = float.fromhex("0x1.921fb54442d18p-62")       # 2pi * 2^-64
_COS_POLY = tuple(float.fromhex(h) for h in ("0x1p0", "-0x1.ffffffd0c621cp-2", "0x1.55553e1068f19p-5",
                                               "-0x1.6c087e89a359dp-10", "0x1.99343027bf8c3p-16"))
_SIN_POLY = tuple(float.fromhex(h) for h in ("-0x1.555545995a603p-3", "0x1.1107605230bc4p-7",
                                               "-0x1.994eb3774cf24p-13"))
_INV_PIO4 = np.array([  # 4/pi to 192 bits, 8 new bits per entry
    0xa2, 0xa2f9, 0xa2f983, 0xa2f9836e, 0xf9836e4e, 0x836e4e44, 0x6e4e4415, 0x4e441529, 0x441529fc,
    0x1529fc27, 0x29fc2757, 0xfc2757d1, 0x2757d1f5, 0x57d1f534, 0xd1f534dd, 0xf534ddc0, 0x34ddc0db,
    0xddc0db62, 0xc0db6295, 0xdb629599, 0x6295993c, 0x95993c43, 0x993c4390, 0x3c439041], _U64)


def _reduce_large(bits: np.ndarray):
    """|y| >= 120: y mod pi/2 from an exact fixed-point product with 4/pi; (remainder, quadrant)."""
    idx = ((bits >> U32(26)) & U32(15)).astype(np.intp)
    shift = ((bits >> U32(23)) & U32(7)).astype(_U64)
    m = (((bits.astype(_U64) & _U64(0xFFFFFF)) | _U64(0x800000)) << shift) & _U64(0xFFFFFFFF)
    low = (m * _INV_PIO4[idx]) & _U64(0xFFFFFFFF)            # a 32-bit product in C
    mid = m * _INV_PIO4[idx + 4]
    high = m * _INV_PIO4[idx + 8]
    acc = ((high >> _U64(32)) | (low << _U64(32))) + mid
    quadrant = (acc + (_U64(1) << _U64(61))) >> _U64(62)
    acc = acc - (quadrant << _U64(62))
    return acc.view(_I64).astype(F64) * _PI_2P_M62, quadrant.astype(_I64)


_QUADRANT_SIGN = np.array([1.0, -1.0, -1.0, 1.0])      # glibc's sign[n & 3] for the reduced argument
_COS_SIGN = np.array([1.0, 1.0, -1.0, -1.0])           # its second table entry negates the cosine


# pi/2 in three parts of 33 bits (fdlibm's): n * part is exact for n < 2^20.
_PIO2_PARTS = (1.57079632673412561417e+00, 6.07710050630396597660e-11, 2.02226624871116645580e-21)
_MEDIUM_TOP = U32(0x48F)                                # |y| < 2^18


def _sincosf(y, cosine: bool) -> np.ndarray:
    y = np.asarray(y, F32)
    x = y.astype(F64)
    # |y| < 120: glibc's one multiply-subtract by pi/2, rounded as it does (below pi/4 glibc skips it,
    # which is the same: n = 0).
    with np.errstate(invalid="ignore"):
        n = (np.asarray(x * _HPI_INV_2P24).astype(_I64) + 0x800000) >> 24
    xr = x - n * _HPI
    turn = n
    top = (y.view(U32) & U32(0x7FFFFFFF)) >> U32(20)
    large = top >= U32(0x42F)
    if large.any():
        # Beyond, glibc reduces exactly (a fixed-point product with 4/pi's bits). Up to 2^18 a
        # three-part pi/2 is as accurate (error ~1e-16 of the remainder), so the float results agree
        # bar a tie within 1e-16: a cheaper route to the same bits.
        medium = large & (top < _MEDIUM_TOP)
        xm = x[medium]
        nm = (np.asarray(xm * _HPI_INV_2P24).astype(_I64) + 0x800000) >> 24
        fm = nm.astype(F64)
        xr[medium] = ((xm - fm * _PIO2_PARTS[0]) - fm * _PIO2_PARTS[1]) - fm * _PIO2_PARTS[2]
        n[medium] = nm
        huge = large & ~medium
        if huge.any():
            xl, nl = _reduce_large(y[huge].view(U32))
            xr[huge] = xl
            n[huge] = nl
            turn = n.copy()
            turn[huge] += (y[huge].view(U32) >> U32(31)).astype(_I64)   # glibc folds y's sign in here
    quarter = turn & 3
    xs = xr * _QUADRANT_SIGN[quarter]
    x2 = xr * xr
    if cosine:
        n = n ^ 1
    x3 = xs * x2
    sin_val = (xs + x3 * _SIN_POLY[0]) + (x3 * x2) * (_SIN_POLY[1] + x2 * _SIN_POLY[2])
    x4 = x2 * x2
    cos_val = ((_COS_POLY[0] + x2 * _COS_POLY[1]) + x4 * _COS_POLY[2]) + \
        (x4 * x2) * (_COS_POLY[3] + x2 * _COS_POLY[4])
    out = np.where(n & 1, cos_val * _COS_SIGN[quarter], sin_val).astype(F32)
    tiny = top < U32(0x398)                           # |y| < 2^-12: sin y = y, cos y = 1
    if tiny.any():
        out[tiny] = ONE if cosine else y[tiny]
    if large.any():
        out[top >= U32(0x7F8)] = np.nan
    return out


def sinf(y) -> np.ndarray:
    """glibc's sinf over a float32 array, bit-exact."""
    return _sincosf(y, False)


def cosf(y) -> np.ndarray:
    """glibc's cosf over a float32 array, bit-exact."""
    return _sincosf(y, True)


# ---- the others: float64, rounded --------------------------------------------------------------
def libm(fn, x) -> np.ndarray:
    """A float function of the C library: float64 evaluation rounded to float32."""
    return fn(np.asarray(x, F32).astype(F64)).astype(F32)


def expf(x):
    return libm(np.exp, x)


def tanf(x):
    return libm(np.tan, x)


def atanf(x):
    return libm(np.arctan, x)


def atan2f(y, x) -> np.ndarray:
    """atan2f(y, x): signed zeros as C's (atan2f(-0, -1) = -pi)."""
    return np.arctan2(np.asarray(y, F32).astype(F64), np.asarray(x, F32).astype(F64)).astype(F32)
