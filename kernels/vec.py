"""The kernels' numeric vocabulary, written once: dtype names and float32 constants, dot / cross / length /
normalize for each vector layout the kernels use, the fused multiply-add of Cycles' kernels, and products of
small matrices with long arrays of vectors.

Vector layouts. The kernels hold 3-vectors in two layouts, each where it pays:

- Components, `(x, y, z)`: three arrays of one shape, usually (N,) float32, as a tuple or stacked as a
  (3, N) array (the two index alike: v[0] is x). Everything that runs per path uses them: the path state's
  (3, N) throughput, BSDF lobes, light sampling, warps, normals. Each component is contiguous, so every
  operation is one contiguous loop and masks or np.take select lanes per component; a column of (N, 3)
  rows is a strided view, and an (N,) factor broadcast over (N, 3) rows runs inner loops three long.
  Helpers for this layout end in `_xyz`; those that return a vector return a tuple.
- Rows, (N, 3) (or (..., 3)): where vectors arrive or leave as rows. Embree takes rays as (N, 3) float32
  origins and directions, Blender's buffers and the triangle table hold (V, 3) and (T, 3) rows, and shader
  node sockets are (N, 3) vectors. Helpers for this layout end in `_rows` (and `columns`).

Data changes layout once, where it crosses such a boundary (`np.stack(xyz, axis=1)`, `rows.T`).

Rounding. Images are kept bit for bit, so each helper's arithmetic is part of its contract, and two helpers
that differ only in rounding are not interchangeable: dot_xyz and dot_rows sum the products left to
right, ((x + y) + z); the `_einsum` helpers sum with np.einsum, in the order NumPy chooses (the shading ops
are written with them); `fma` and `cross_rows_fused` round as Cycles' AVX2 kernels do (shading nodes that
reproduce Cycles bit for bit).

Why `matmul`, not `@`: NumPy hands a matrix product of float arrays to the BLAS it is linked with.
OpenBLAS (NumPy's wheels) splits a product over many vectors across its own threads, which then spin for a
while after each call on every core: beside a render's other process or thread they took a third of a core
(a textured scene's waves ran 1.5x as long beside such a process). With three or four terms to sum, a sum
of products costs about what the BLAS call did, on the calling thread alone.
"""
from __future__ import annotations

import numpy as np

F32, F64, I32, U32 = np.float32, np.float64, np.int32, np.uint32

ZERO, HALF, ONE, TWO = F32(0.0), F32(0.5), F32(1.0), F32(2.0)
# Each equals Cycles' float literal of the same constant bit for bit (M_PI_F, M_PI_2_F, M_2PI_F, M_1_PI_F,
# M_1_2PI_F, M_1_4PI_F).
PI = F32(np.pi)
HALF_PI = F32(np.pi / 2)
TWO_PI = F32(2.0 * np.pi)
INV_PI = F32(1.0 / np.pi)
INV_2PI = F32(0.5 / np.pi)
INV_4PI = F32(0.25 / np.pi)


# ---------------------------------------------------------------- components: (x, y, z)
def dot_xyz(a, b):
    """a . b of component vectors: a, b (x, y, z), arrays of shapes that broadcast (or (3, N) arrays).
    a.x b.x + a.y b.y + a.z b.z, summed left to right, in the operands' dtype."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross_xyz(a, b):
    """a x b of component vectors, as a tuple (x, y, z): (a.y b.z - a.z b.y, a.z b.x - a.x b.z,
    a.x b.y - a.y b.x), in the operands' dtype."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def length_xyz(v):
    """|v| of component vectors: sqrt(dot_xyz(v, v)), in v's dtype."""
    return np.sqrt(dot_xyz(v, v))


def normalize_xyz(v):
    """v / |v| of component vectors, as a tuple (x, y, z): each component times 1 / |v|, and times 0 where
    |v| is not positive (zero, or NaN), so a zero vector stays zero. In v's dtype."""
    length = length_xyz(v)
    ok = length > ZERO
    inv = np.where(ok, ONE / np.where(ok, length, ONE), ZERO)
    return tuple(c * inv for c in v)


def normalize_floored_xyz(v):
    """v / |v| of component vectors, as a tuple (x, y, z), with |v|^2 floored at 1e-37: each component times
    1 / sqrt(max(|v|^2, 1e-37)). Never divides by zero (a zero vector stays zero, a vector shorter than about
    3e-19 comes out shorter than 1); NaN stays NaN. float32 for float32 v."""
    inv = F32(1.0) / np.sqrt(np.maximum(dot_xyz(v, v), F32(1e-37)))
    return tuple(c * inv for c in v)


def make_orthonormals_xyz(n):
    """Cycles' make_orthonormals of unit component vectors n: a = (1, 1, 1) x n (or (-1, 1, 1) x n where n's
    components are all equal) divided by its length (floored at 1e-30), and b = n x a. Returns (a, b), each
    a tuple (x, y, z), in n's dtype. (shading.program.make_orthonormals is the same frame for (N, 3) rows.)"""
    x, y, z = n
    equal = (x == y) & (x == z)
    a = (z - y, np.where(equal, x + z, x - z), np.where(equal, -y - x, y - x))
    length = np.maximum(length_xyz(a), 1e-30)
    a = tuple(c / length for c in a)
    return a, cross_xyz(n, a)


# ---------------------------------------------------------------- rows: (..., 3)
def dot_rows(a, b):
    """a . b over the last axis of (..., 3) arrays (shapes that broadcast): (...,), summed left to right,
    a[..., 0] b[..., 0] + a[..., 1] b[..., 1] + a[..., 2] b[..., 2] (Cycles' SSE4 dot: every product and
    sum rounded), in the operands' dtype."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def length_rows(v):
    """|v| over the last axis of a (..., 3) array: (...,) sqrt(dot_rows(v, v)), in v's dtype."""
    return np.sqrt(dot_rows(v, v))


def normalize_rows(v):
    """Cycles' safe_normalize of (..., 3) rows: v times 1 / |v| (in float32) where |v| != 0, v itself where
    it is 0. (..., 3), float32 for float32 v."""
    length = length_rows(v)
    nonzero = length != 0
    inv = np.zeros(np.shape(length), F32)
    np.divide(F32(1.0), length, out=inv, where=nonzero)
    return np.where(columns(nonzero), v * columns(inv), v)


def columns(x):
    """A (...,) array as three equal columns (..., 3), to combine with (..., 3) rows; a one-element x as
    (..., 1). Repeated in full, since NumPy broadcasting (N, 1) against (N, 3) runs inner loops three long,
    some 20x slower than arrays of the same shape."""
    x = x[..., None]
    return np.repeat(x, 3, -1) if x.size > 1 else x


def cross_rows_fused(a, b):
    """a x b over the last axis of (..., 3) rows, as Cycles' SSE cross() compiles on AVX2: each component
    one fused msub, fma(a.y, b.z, -(a.z * b.y)). (..., 3) float32."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([fma(ay, bz, -(az * by)), fma(az, bx, -(ax * bz)), fma(ax, by, -(ay * bx))], -1)


def dot_rows_fused(a, b):
    """a . b over the last axis of (..., 3) rows as Embree's dot (common/math/vec3.h) compiles with FMA:
    fma(a.x, b.x, fma(a.y, b.y, a.z * b.z)). (...,) float32."""
    return fma(a[..., 0], b[..., 0], fma(a[..., 1], b[..., 1], a[..., 2] * b[..., 2]))


def dot_rows_einsum(a, b):
    """a . b of (N, 3) rows summed by np.einsum("ij,ij->i") (NumPy's order of summation): (N,), in the
    operands' dtype. The shading ops and the hit record use it; new code takes dot_rows."""
    return np.einsum("ij,ij->i", a, b)


def normalize_rows_einsum(v):
    """(N, 3) rows divided by their length from dot_rows_einsum (a division, not a product with 1 / |v|);
    rows whose length is not positive are left as they are. (N, 3), in v's dtype."""
    length = np.sqrt(dot_rows_einsum(v, v))
    return v / np.where(length > 0, length, ONE)[:, None]


# ---------------------------------------------------------------- rounding as Cycles' kernels round
def fma(a, b, c):
    """a * b + c rounded once to float32, as the fused multiply-add Cycles' AVX2 kernels compile to.
    Operands broadcast (arrays or numbers); the result is float32. The product of two float32 is exact in
    float64; rounding the float64 sum and then to float32 differs from one rounding only when the first
    lands exactly halfway between two float32 (roughly one case in 2^28)."""
    r = np.multiply(a, b, dtype=F64)
    if isinstance(r, np.ndarray) and (np.ndim(c) == 0 or np.shape(c) == r.shape):
        r += c
    else:
        r = r + c
    return r.astype(F32)


# ---------------------------------------------------------------- small matrices times many vectors
def matmul(a, b) -> np.ndarray:
    """a @ b for 1-D and 2-D operands whose shared dimension is short (3 or 4: vectors and their matrices),
    as a sum of products over it, in the dtype a @ b would have."""
    a, b = np.asarray(a), np.asarray(b)
    dtype = np.result_type(a, b)
    a, b = a.astype(dtype, copy=False), b.astype(dtype, copy=False)
    if not 1 <= a.ndim <= 2 or not 1 <= b.ndim <= 2 or a.shape[-1] != b.shape[0]:
        raise ValueError(f"matmul: shapes {a.shape} and {b.shape} do not chain")
    if a.ndim == 2 and b.ndim == 2 and a.shape[0] > b.shape[1]:
        # Rows of vectors times a matrix: the transposed product, term by term along the long axis (a
        # broadcast over the short one would be strided), handed back as its transpose (a view).
        return _sum_of_products(b.T, a.T).T
    return _sum_of_products(a, b)


def _sum_of_products(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = None
    for k in range(b.shape[0]):
        left = a[:, k, None] if a.ndim == 2 and b.ndim == 2 else a[..., k]
        term = left * b[k]
        out = term if out is None else out + term
    return out
