"""Cycles' hashes (`util/hash.h`) over arrays, bit-exact: the texture nodes' source of randomness.

- Jenkins lookup3 (`hash_uint` .. `hash_uint4`) on uint32 words; the Perlin lattice and the float hashes
  use them. `hash_uint*_to_float` maps the result to [0, 1] as float32(h) * 2^-32.
- Float hashes hash the raw bit patterns of float32 values (so -0.0 and +0.0 differ); the vector-valued
  ones hash the same key again with an extra word 1.0 / 2.0 or with the components rotated, as Cycles does.
- PCG (Jarzynski & Olano, int32-only variant) for Voronoi's cells: `hash_pcg2d_i` .. `hash_pcg4d_i` and
  `hash_int*_to_float*`, results in [0, 1] as float32(h) * 2^-31.
- Whole lattices at once, into reused work arrays (`Scratch`, one per thread and user): `hash_uint_grid`
  (Perlin's cell corners) and `hash_int_to_float_grid` (Voronoi's neighbour cells), bit-exact with the
  functions above, in a fraction of their array passes and without allocating.

Conventions: a scalar key is an array of any shape (or a Python number); a vector key (`float3`,
`int2`, ...) is a sequence of its d component arrays, e.g. `(x, y, z)` - an array of shape (d, N) such as
`p.T` for p of shape (N, d) works too, since it unpacks along its first axis. Components broadcast against
each other. Vector results are tuples of d arrays. Results have the broadcast shape of the key, at least
1-d (a 0-d key gives shape (1,)). uint32 and int32 arithmetic wraps like C.
"""
from __future__ import annotations

import threading

import numpy as np

from ..vec import F32, I32, U32

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


def _words(keys, count: int, shape=None):
    """lookup3's starting words: each key plus seed + (count << 2), as fresh uint32 arrays of the keys'
    common shape (>= 1-d) unless given; also that initial value and the shape."""
    shape = shape or np.broadcast_shapes(*(np.shape(k) for k in keys)) or (1,)
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
    shape = np.broadcast_shapes(*(np.shape(k) for k in (kx, ky, kz, kw))) or (1,)
    (a, b, c), _, shape = _words((kx, ky, kz), 4, shape)
    _mix(a, b, c)
    a += _as_u32(kw, shape)         # the fourth word goes in after the mix
    return _final(a, b, c)


# ---- Work arrays; hashes of whole lattices into them --------------------------------------------------

class Scratch:
    """Work arrays reused from call to call by name: `scratch(name, shape, dtype)` is a view of a kept
    buffer (grown when too small), so a loop over blocks allocates nothing and touches no fresh pages
    (fresh large arrays cost page faults on every call). Views of one name share memory: each use of a
    name overwrites what the last one left there."""

    def __init__(self):
        self._buffers, self._views = {}, {}
        self.generation = 0         # counts buffer growths: views taken before one may be stale

    def __call__(self, name: str, shape: tuple, dtype) -> np.ndarray:
        view = self._views.get((name, shape, dtype))
        if view is None:
            if len(self._views) > 4096:     # a view per name and block shape seen: keep the table small
                self._views.clear()
            view = self._views[(name, shape, dtype)] = self._view(name, shape, dtype)
        return view

    def _view(self, name, shape, dtype):
        size = 1
        for n in shape:
            size *= n
        buf = self._buffers.get((name, dtype))
        if buf is None or buf.size < size:
            buf = self._buffers[(name, dtype)] = np.empty(max(size, 1), dtype)
            self.generation += 1
            self._views = {k: v for k, v in self._views.items() if k[0] != name or k[2] != dtype}
        return buf[:size].reshape(shape)


_THREAD = threading.local()


def thread_scratch(owner: str) -> Scratch:
    """The calling thread's Scratch for one user (the renderer shades on a pool of threads; a user's
    arrays grow only with its own requests)."""
    scratches = getattr(_THREAD, "scratches", None)
    if scratches is None:
        scratches = _THREAD.scratches = {}
    scratch = scratches.get(owner)
    if scratch is None:
        scratch = scratches[owner] = Scratch()
    return scratch


def _broadcast_shape(x, y) -> tuple:
    """np.broadcast_shapes for a scalar or arrays of one rank whose axes are 1 or the same size."""
    sx, sy = np.shape(x), np.shape(y)
    if not sx or not sy:
        return sx or sy
    return tuple(a if a != 1 else b for a, b in zip(sx, sy))


class _GridWords:
    """lookup3's rounds over words that broadcast against each other: each result takes the broadcast
    shape of its operands, in place where the word already has that shape (and is ours to overwrite),
    else in a scratch array of its own. Every array operation goes through call(fn, *args, **kwargs)."""

    def __init__(self, scratch: Scratch, call):
        self.scratch, self.call, self.owned = scratch, call, []

    def target(self, x, y):
        shape = _broadcast_shape(x, y)
        if np.shape(x) == shape and any(x is o for o in self.owned):
            return x
        out = self.scratch(f"lookup3_word{len(self.owned)}", shape, U32)
        self.owned.append(out)
        return out

    def rot(self, y, k: int):
        shape = np.shape(y)
        out, tmp = self.scratch("lookup3_rot", shape, U32), self.scratch("lookup3_rot_tmp", shape, U32)
        self.call(np.left_shift, y, U32(k), out=out)
        self.call(np.right_shift, y, U32(32 - k), out=tmp)
        self.call(np.bitwise_or, out, tmp, out=out)
        return out

    def xor_sub(self, x, y, k: int):
        """x ^= y; x -= rot(y, k) (a line of lookup3's final)."""
        out = self.target(x, y)
        self.call(np.bitwise_xor, x, y, out=out)
        self.call(np.subtract, out, self.rot(y, k), out=out)
        return out

    def sub_xor(self, x, y, k: int):
        """x -= y; x ^= rot(y, k) (the first half of a line of lookup3's mix)."""
        out = self.target(x, y)
        self.call(np.subtract, x, y, out=out)
        self.call(np.bitwise_xor, out, self.rot(y, k), out=out)
        return out

    def add(self, x, y):
        out = self.target(x, y)
        self.call(np.add, x, y, out=out)
        return out


def call_now(fn, *args, **kwargs):
    """fn(*args, **kwargs): the `call` of the functions below that take one, when nothing records."""
    return fn(*args, **kwargs)


def hash_uint_grid(keys, scratch: Scratch, call=call_now) -> np.ndarray:
    """hash_uint2 .. hash_uint4 of uint32 keys that vary along different axes of one broadcast grid,
    e.g. the corners of Perlin cells: x (2, 1, 1, N), y (1, 2, 1, N), z (1, 1, 2, N) -> (2, 2, 2, N).

    Bit-exact with hash_uint{2,3,4} of the broadcast keys; each round runs on the broadcast shape of the
    words it has read so far, so the first rounds cost a fraction of the grid (a word still depends on
    one key at the start). The result is a scratch array, overwritten by the next call. Array operations
    go through call(fn, *args, **kwargs) (a caller may record them to replay)."""
    count = len(keys)
    init = U32((_LOOKUP3_SEED + (count << 2)) & 0xFFFFFFFF)
    g = _GridWords(scratch, call)
    words = [g.add(k, init) for k in keys[:3]] + [init] * (3 - min(count, 3))
    a, b, c = words
    if count == 4:
        a = g.sub_xor(a, c, 4); c = g.add(c, b)            # noqa: E702 - lookup3's mix, as _mix
        b = g.sub_xor(b, a, 6); a = g.add(a, c)            # noqa: E702
        c = g.sub_xor(c, b, 8); b = g.add(b, a)            # noqa: E702
        a = g.sub_xor(a, c, 16); c = g.add(c, b)           # noqa: E702
        b = g.sub_xor(b, a, 19); a = g.add(a, c)           # noqa: E702
        c = g.sub_xor(c, b, 4); b = g.add(b, a)            # noqa: E702
        a = g.add(a, keys[3])
    c = g.xor_sub(c, b, 14)
    a = g.xor_sub(a, c, 11)
    b = g.xor_sub(b, a, 25)
    c = g.xor_sub(c, b, 16)
    a = g.xor_sub(a, c, 4)
    b = g.xor_sub(b, a, 14)
    return g.xor_sub(c, b, 24)


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


def _pcg_round(lanes, mul):
    """One round of pcg2d / pcg3d / pcg4d on the lanes, in place; mul(a, b) gives the products."""
    if len(lanes) == 2:
        x, y = lanes
        x += mul(y, _PCG_MUL)
        y += mul(x, _PCG_MUL)
    elif len(lanes) == 3:
        x, y, z = lanes
        x += mul(y, z)
        y += mul(z, x)
        z += mul(x, y)
    else:
        x, y, z, w = lanes
        x += mul(y, w)
        y += mul(z, x)
        z += mul(x, y)
        w += mul(y, z)


def _pcg(k):
    lanes = _int_lanes(k)
    _pcg_round(lanes, np.multiply)
    _xorshift16(lanes)
    _pcg_round(lanes, np.multiply)
    return _mask31(lanes)


def hash_pcg2d_i(k):
    return _pcg(k)


def hash_pcg3d_i(k):
    return _pcg(k)


def hash_pcg4d_i(k):
    return _pcg(k)


def hash_int_to_float_grid(keys, scratch: Scratch, name: str = "pcg") -> np.ndarray:
    """hash_int{2,3,4}_to_float{2,3,4} of d int32 keys, each given as a tuple of addends that broadcast
    together (a cell (M,) plus neighbour offsets (K, 1)): (d,) + shape float32 in [0, 1], bit-exact with
    them, computed in scratch arrays (the result is one, valid until the next call with this name)."""
    d = len(keys)
    shape = np.broadcast_shapes(*(np.shape(a) for key in keys for a in key))
    lanes = scratch(name + "_lanes", (d,) + shape, I32)
    for lane, key in zip(lanes, keys):
        if len(key) == 1:
            np.copyto(lane, key[0])
        else:
            np.add(key[0], key[1], out=lane)
    lanes *= _PCG_MUL
    lanes += _PCG_ADD
    tmp = scratch(name + "_tmp", (d,) + shape, I32)

    def mul(a, b):
        return np.multiply(a, b, out=tmp[0])

    _pcg_round(list(lanes), mul)
    np.right_shift(lanes, I32(16), out=tmp)        # arithmetic shift: Cycles' signed variant
    lanes ^= tmp
    _pcg_round(list(lanes), mul)
    lanes &= I32(0x7FFFFFFF)
    out = scratch(name + "_unit", (d,) + shape, F32)
    np.copyto(out, lanes, casting="unsafe")
    out *= _INT_TO_UNIT
    return out


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
