"""Cycles' hashes (`util/hash.h`) over arrays, bit-exact: the texture nodes' source of randomness.

- Jenkins lookup3 (`hash_uint` .. `hash_uint4`) on uint32 words; the Perlin lattice and the float hashes
  use them. `hash_uint*_to_float` maps the result to [0, 1] as float32(h) * 2^-32.
- Float hashes hash the raw bit patterns of float32 values (so -0.0 and +0.0 differ); the vector-valued
  ones hash the same key again with an extra word 1.0 / 2.0 or with the components rotated, as Cycles does.
- PCG (Jarzynski & Olano, int32-only variant) for Voronoi's cells: `hash_pcg2d_i` .. `hash_pcg4d_i` and
  `hash_int*_to_float*`, results in [0, 1] as float32(h) * 2^-31.

Conventions: a scalar key is an array of any shape (or a Python number); a vector key (`float3`,
`int2`, ...) is a sequence of its d component arrays, e.g. `(x, y, z)` - an array of shape (d, N) such as
`p.T` for p of shape (N, d) works too, since it unpacks along its first axis. Components broadcast against
each other. Vector results are tuples of d arrays. Results have the broadcast shape of the key, at least
1-d (a 0-d key gives shape (1,)). uint32 and int32 arithmetic wraps like C.
"""
from __future__ import annotations

import numpy as np

U32, I32, F32 = np.uint32, np.int32, np.float32

_LOOKUP3_SEED = 0xDEADBEEF + 13     # a = b = c = seed + (words << 2)
_UINT_TO_UNIT = F32(2.0 ** -32)     # Cycles: 1.0f / (float)0xFFFFFFFFu, which rounds to 2^-32
_INT_TO_UNIT = F32(2.0 ** -31)      # Cycles: 1.0f / (float)0x7FFFFFFFu
_ONE_BITS, _TWO_BITS = 0x3F800000, 0x40000000   # the float words 1.0 and 2.0 some vector hashes append
_PCG_MUL, _PCG_ADD = I32(1664525), I32(1013904223)


# ---- Jenkins lookup3 ------------------------------------------------------------------------------

def _as_u32(key, shape):
    """A key as a fresh uint32 array of `shape`; int32 keys (lattice cells) wrap as C's (uint) cast."""
    a = np.asarray(key)
    w = np.empty(shape, U32)
    w[...] = a if a.dtype == U32 else a.astype(U32)
    return w


def _words(keys, count: int):
    """lookup3's starting words: each key plus seed + (count << 2), as fresh uint32 arrays of the keys'
    common shape (>= 1-d); also that initial value and the shape."""
    shape = np.broadcast_shapes(*(np.shape(k) for k in keys)) or (1,)
    init = U32((_LOOKUP3_SEED + (count << 2)) & 0xFFFFFFFF)
    words = [_as_u32(k, shape) for k in keys]
    for w in words:
        w += init
    return words, init, shape


class _Rot:
    """rot(x, k) = (x << k) | (x >> (32 - k)) into one reused scratch array (the hashes' hot loop)."""

    def __init__(self, like):
        self.out, self.tmp = np.empty_like(like), np.empty_like(like)

    def __call__(self, x, k: int):
        np.left_shift(x, U32(k), out=self.out)
        np.right_shift(x, U32(32 - k), out=self.tmp)
        self.out |= self.tmp
        return self.out


def _mix(a, b, c):
    rot = _Rot(a)
    a -= c; a ^= rot(c, 4); c += b         # noqa: E702 - lookup3's rounds read best one per line
    b -= a; b ^= rot(a, 6); a += c         # noqa: E702
    c -= b; c ^= rot(b, 8); b += a         # noqa: E702
    a -= c; a ^= rot(c, 16); c += b        # noqa: E702
    b -= a; b ^= rot(a, 19); a += c        # noqa: E702
    c -= b; c ^= rot(b, 4); b += a         # noqa: E702


def _final(a, b, c):
    rot = _Rot(a)
    c ^= b; c -= rot(b, 14)                # noqa: E702
    a ^= c; a -= rot(c, 11)                # noqa: E702
    b ^= a; b -= rot(a, 25)                # noqa: E702
    c ^= b; c -= rot(b, 16)                # noqa: E702
    a ^= c; a -= rot(c, 4)                 # noqa: E702
    b ^= a; b -= rot(a, 14)                # noqa: E702
    c ^= b; c -= rot(b, 24)                # noqa: E702
    return c


def hash_uint(kx):
    (a,), init, shape = _words((kx,), 1)
    return _final(a, np.full(shape, init), np.full(shape, init))


def hash_uint2(kx, ky):
    (a, b), init, shape = _words((kx, ky), 2)
    return _final(a, b, np.full(shape, init))


def hash_uint3(kx, ky, kz):
    (a, b, c), _, _ = _words((kx, ky, kz), 3)
    return _final(a, b, c)


def hash_uint4(kx, ky, kz, kw):
    (a, b, c), _, shape = _words((kx, ky, kz), 4)
    _mix(a, b, c)
    a += _as_u32(kw, shape)         # the fourth word goes in after the mix
    return _final(a, b, c)


def uint_to_float_incl(h):
    """uint32 -> [0, 1] float32, Cycles' uint_to_float_incl."""
    out = h.astype(F32)
    out *= _UINT_TO_UNIT
    return out


def hash_uint_to_float(kx):
    return uint_to_float_incl(hash_uint(kx))


def hash_uint2_to_float(kx, ky):
    return uint_to_float_incl(hash_uint2(kx, ky))


def hash_uint3_to_float(kx, ky, kz):
    return uint_to_float_incl(hash_uint3(kx, ky, kz))


def hash_uint4_to_float(kx, ky, kz, kw):
    return uint_to_float_incl(hash_uint4(kx, ky, kz, kw))


# ---- Float keys: hashes of the bit patterns ---------------------------------------------------------

def float_bits(x):
    """float32 value(s) -> their uint32 bit patterns (Cycles' __float_as_uint)."""
    return np.asarray(x, F32).view(U32)


def hash_float_to_float(k):
    return hash_uint_to_float(float_bits(k))


def hash_float2_to_float(k):
    x, y = k
    return hash_uint2_to_float(float_bits(x), float_bits(y))


def hash_float3_to_float(k):
    x, y, z = k
    return hash_uint3_to_float(float_bits(x), float_bits(y), float_bits(z))


def hash_float4_to_float(k):
    x, y, z, w = k
    return hash_uint4_to_float(float_bits(x), float_bits(y), float_bits(z), float_bits(w))


def hash_float_to_float2(k):
    x = float_bits(k)
    return hash_uint_to_float(x), hash_uint2_to_float(x, _ONE_BITS)


def hash_float_to_float3(k):
    x = float_bits(k)
    return hash_uint_to_float(x), hash_uint2_to_float(x, _ONE_BITS), hash_uint2_to_float(x, _TWO_BITS)


def hash_float2_to_float2(k):
    x, y = (float_bits(c) for c in k)
    return hash_uint2_to_float(x, y), hash_uint3_to_float(x, y, _ONE_BITS)


def hash_float2_to_float3(k):
    x, y = (float_bits(c) for c in k)
    return (hash_uint2_to_float(x, y), hash_uint3_to_float(x, y, _ONE_BITS),
            hash_uint3_to_float(x, y, _TWO_BITS))


def hash_float3_to_float2(k):
    x, y, z = (float_bits(c) for c in k)
    return hash_uint3_to_float(x, y, z), hash_uint3_to_float(z, x, y)


def hash_float3_to_float3(k):
    x, y, z = (float_bits(c) for c in k)
    return (hash_uint3_to_float(x, y, z), hash_uint4_to_float(x, y, z, _ONE_BITS),
            hash_uint4_to_float(x, y, z, _TWO_BITS))


def hash_float4_to_float2(k):
    x, y, z, w = (float_bits(c) for c in k)
    return hash_uint4_to_float(x, y, z, w), hash_uint4_to_float(z, x, w, y)


def hash_float4_to_float3(k):
    x, y, z, w = (float_bits(c) for c in k)
    return (hash_uint4_to_float(x, y, z, w), hash_uint4_to_float(z, x, w, y),
            hash_uint4_to_float(w, z, y, x))


def hash_float4_to_float4(k):
    x, y, z, w = (float_bits(c) for c in k)
    return (hash_uint4_to_float(x, y, z, w), hash_uint4_to_float(w, x, y, z),
            hash_uint4_to_float(z, w, x, y), hash_uint4_to_float(y, z, w, x))


# ---- PCG on int32 (Voronoi) -------------------------------------------------------------------------

def _int_lanes(k):
    """A vector key as fresh int32 arrays of the common shape (>= 1-d), already through v*M + A."""
    arrays = [np.asarray(c) for c in k]
    shape = np.broadcast_shapes(*(a.shape for a in arrays)) or (1,)
    out = []
    for a in arrays:
        v = np.empty(shape, I32)
        v[...] = a.astype(I32, copy=False) if a.dtype != I32 else a
        v *= _PCG_MUL
        v += _PCG_ADD
        out.append(v)
    return out


def _xorshift16(lanes):
    for v in lanes:
        v ^= v >> I32(16)           # arithmetic shift: Cycles' signed variant


def _mask31(lanes):
    for v in lanes:
        v &= I32(0x7FFFFFFF)
    return tuple(lanes)


def hash_pcg2d_i(k):
    x, y = _int_lanes(k)
    x += y * _PCG_MUL
    y += x * _PCG_MUL
    _xorshift16((x, y))
    x += y * _PCG_MUL
    y += x * _PCG_MUL
    return _mask31([x, y])


def _pcg3_round(x, y, z):
    x += y * z
    y += z * x
    z += x * y


def hash_pcg3d_i(k):
    x, y, z = _int_lanes(k)
    _pcg3_round(x, y, z)
    _xorshift16((x, y, z))
    _pcg3_round(x, y, z)
    return _mask31([x, y, z])


def _pcg4_round(x, y, z, w):
    x += y * w
    y += z * x
    z += x * y
    w += y * z


def hash_pcg4d_i(k):
    x, y, z, w = _int_lanes(k)
    _pcg4_round(x, y, z, w)
    _xorshift16((x, y, z, w))
    _pcg4_round(x, y, z, w)
    return _mask31([x, y, z, w])


def _unit31(h):
    out = h.astype(F32)
    out *= _INT_TO_UNIT
    return out


def hash_int2_to_float2(k):
    return tuple(_unit31(h) for h in hash_pcg2d_i(k))


def hash_int3_to_float3(k):
    return tuple(_unit31(h) for h in hash_pcg3d_i(k))


def hash_int4_to_float4(k):
    return tuple(_unit31(h) for h in hash_pcg4d_i(k))


def hash_int2_to_float3(k):
    x, y = k
    return hash_int3_to_float3((x, y, 0))


def hash_int4_to_float3(k):
    return hash_int4_to_float4(k)[:3]
