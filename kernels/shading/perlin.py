"""Cycles' Perlin noise over arrays of points (`kernel/svm/noise.h`): `perlin` (unscaled), `snoise`
(signed, about [-1, 1], the coordinates wrapped as Cycles wraps them) and `noise_at` (several point sets
in one call), rounded as the Cycles of a given Blender rounds them (`cycles_rounding`).

The results are bit-exact with Cycles' x86-64 AVX2 CPU kernel as Blender 5.0 ships it (probed: see
tests/test_nodes_noise.py), and as Blender 5.3's kernel rounds them. That kernel uses the SIMD Perlin
variants (their interpolation order, fmod as c - trunc(c / 1e5) * 1e5) and is compiled with
-ffp-contract=fast and -freciprocal-math: many multiply-adds are fused, divisions by constants are
multiplications. Where a fused multiply-add changes the rounding it is written fma(a, b, c); which ones
the compiler fused was found by probing, not read from the C. The fractals (kernels.shading.fractal_noise)
and the texture nodes (kernels.shading.noise) round the same way.

Coordinates are a sequence of d component arrays (`(x, y, z)`; a (d, N) array unpacks the same way), like
kernels.shading.hash.

How it runs (a call costs far more than a point on the waves the renderer shades): callers hand every
octave's points to Perlin in one call (noise_at); Perlin runs in blocks of points whose corners are
broadcast grids, on per-thread work arrays, replaying NumPy calls recorded once per block size (_Tape); a
large block of one frequency whose cells span a small box hashes the box once (_perlin_box). Each is the
same arithmetic point by point: the results do not change.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from functools import lru_cache

import numpy as np

from ..vec import F32, HALF, I32, ONE, U32, ZERO, fma
from . import hash as H

NOISE_SCALE = {1: F32(0.25), 2: F32(0.6616), 3: F32(0.9820), 4: F32(0.8344)}  # OSL's, to about [-1, 1]
WRAP_PERIOD = F32(100000.0)       # Perlin repeats every 1e5 per axis, for precision
WRAP_RECIPROCAL = F32(1e-5)       # what the compiler divides by 1e5 with (-freciprocal-math)
WRAP_FROM = F32(1000000.0)        # where the wrapped coordinate is shifted by 1/2 (off the lattice)


# ---- Which Cycles' rounding -------------------------------------------------------------------------
# Perlin's source is the same in Blender 5.0 and 5.3, its compiled rounding is not: Cycles made `mix` one
# template for every type (commit 1a3cb5e0b, in 5.3), and since then the SIMD Perlin's mixes are a
# separate multiply and add, the 3D/4D coordinate wrap subtracts q * 1e5 unfused, and the 1D mix is
# fma(u, b - a, a). Probed bit for bit against bpy 5.0.1 and 5.3.0 (docs/blender-versions.md).
UNFUSED_MIX_FROM = (5, 3)
_ROUNDING = threading.local()


@contextmanager
def cycles_rounding(version):
    """Round Perlin noise, on this thread and inside the block, as the Cycles of Blender `version`
    ((major, minor, ...)) does; None: Blender 5.0's."""
    before = getattr(_ROUNDING, "unfused", False)
    _ROUNDING.unfused = version is not None and tuple(version[:2]) >= UNFUSED_MIX_FROM
    try:
        yield
    finally:
        _ROUNDING.unfused = before


def _unfused() -> bool:
    return getattr(_ROUNDING, "unfused", False)


# ---- Perlin ---------------------------------------------------------------------------------------

def _negate_if_bit(value, h, bit: int):
    """value, negated (sign bit flipped, in place) where bit `bit` of the uint32 hash h is set."""
    value.view(U32)[...] ^= ((h >> U32(bit)) & U32(1)) << U32(31)
    return value


@lru_cache(maxsize=None)
def _gradient_table(d: int) -> np.ndarray:
    """(d, 8 | 16 | 32) the gradient vector each hash (masked) selects, from Cycles' grad2/3/4 rules.

    Cycles' gradient is a sum of hash-chosen coordinates with hash-bit signs (improved noise); as a
    table of coefficients in {0, +-1, +-2} it is one dot product, with the same sum order and so the
    same float result (adding the zero terms is exact)."""
    size = {2: 8, 3: 16, 4: 32}[d]
    table = np.zeros((d, size), F32)
    for h in range(size):
        if d == 2:      # u = x, v = 2y (h < 4) or u = y, v = 2x
            picks = [(0, 1), (1, 2)] if h < 4 else [(1, 1), (0, 2)]
        elif d == 3:    # u = x | y; v = y | x (h = 12, 14) | z
            v = 1 if h < 4 else (0 if h in (12, 14) else 2)
            picks = [(0 if h < 8 else 1, 1), (v, 1)]
        else:           # u = x | y, v = y | z, s = z | w
            picks = [(0 if h < 24 else 1, 1), (1 if h < 16 else 2, 1), (2 if h < 8 else 3, 1)]
        for bit, (axis, weight) in enumerate(picks):  # term `bit` is negated by hash bit `bit`
            table[axis, h] += -weight if h >> bit & 1 else weight
    return table


_HASHES = {2: H.hash_uint2, 3: H.hash_uint3, 4: H.hash_uint4}
# The axis each interpolation step runs along, first to last (Cycles' 4D SIMD kernel mixes along w first).
_MIX_ORDER = {2: (0, 1), 3: (0, 1, 2), 4: (3, 0, 1, 2)}
# Corner values per block: large enough that the calls' own cost fades, small enough for the cache.
_BLOCK = 1 << 17
_BOX_MIN = 4096       # points in a block worth trying _perlin_box for


@lru_cache(maxsize=None)
def _corner_shapes(d: int) -> tuple:
    """Per axis, the shape its two lattice planes take in the (2,) * d grid of a cell's corners: the
    grid's first axis is the first one interpolated, so corner index bit d-1 is that axis' offset."""
    order = _MIX_ORDER[d]
    return tuple(tuple(2 if rank == order.index(axis) else 1 for rank in range(d)) for axis in range(d))


def _lattice(x, s: H.Scratch, call):
    """floor(x) (d, m) and the offsets to each axis' two lattice planes around the points, f and f - 1
    (d, 2, m): a cell's corner takes one plane per axis."""
    d, m = x.shape
    floor = call(np.floor, x, out=s("floor", (d, m), F32))
    planes = s("planes", (d, 2, m), F32)
    call(np.subtract, x, floor, out=planes[:, 0])
    call(np.subtract, planes[:, 0], ONE, out=planes[:, 1])
    return floor, planes


def _interpolate(gradients, index, planes, out, s: H.Scratch, call):
    """Perlin's corner values and their interpolation into out (m,): the corner gradients, rows of
    gradients (d, G) at index (2^d, m), dotted with the offsets to the corners in axis order (as
    _gradient_table), then faded and mixed, each mix a multiply-add fused as the kernel's (fma; unfused
    under Blender 5.3's rounding). The
    corners form a broadcast grid (2,) * d + (m,) (_corner_shapes): one call per step for all of them."""
    d, _, m = planes.shape
    shapes = [shape + (m,) for shape in _corner_shapes(d)]
    corners, grid = (2 ** d, m), (2,) * d + (m,)
    g, term = s("corner", corners, F32), s("corner_term", corners, F32)
    for k in range(d):
        dst = g if k == 0 else term
        call(np.take, gradients[k], index, out=dst, mode="wrap")    # in range: "wrap" skips the check
        call(np.multiply, dst.reshape(grid), planes[k].reshape(shapes[k]), out=dst.reshape(grid))
        if k:
            call(np.add, g, term, out=g)

    frac = planes[:, 0]
    fade, wide = s("fade", (d, m), F32), s("fade64", (d, m), np.float64)
    call(np.multiply, frac, F32(6.0), dtype=np.float64, out=wide)
    call(np.add, wide, F32(-15.0), out=wide)
    call(np.copyto, fade, wide, casting="same_kind")
    call(np.multiply, frac, fade, dtype=np.float64, out=wide)
    call(np.add, wide, F32(10.0), out=wide)
    call(np.copyto, fade, wide, casting="same_kind")
    call(np.multiply, fade, frac, out=fade)
    square = call(np.multiply, frac, frac, out=s("fade_sq", (d, m), F32))
    call(np.multiply, square, fade, out=fade)
    rows = 2 ** d
    for axis in _MIX_ORDER[d]:
        rows //= 2
        lo, hi = g[:rows], g[rows:2 * rows]
        diff = call(np.subtract, hi, lo, out=s("mix_diff", (rows, m), F32))
        if _unfused():
            call(np.multiply, fade[axis], diff, out=diff)
            call(np.add, diff, lo, out=lo if rows > 1 else out[None])
            continue
        mixed = call(np.multiply, fade[axis], diff, dtype=np.float64, out=s("mix64", (rows, m), np.float64))
        call(np.add, mixed, lo, out=mixed)
        call(np.copyto, lo if rows > 1 else out, mixed if rows > 1 else mixed[0], casting="same_kind")


def _perlin_block(x, out, s: H.Scratch, call):
    """Perlin noise at the m points x (d, m) float32 into out (m,), in work arrays from s; every array
    operation goes through call(fn, *args, **kwargs) (a _Tape). Hashes every cell corner."""
    d, m = x.shape
    floor, planes = _lattice(x, s, call)
    keys = s("keys", (d, 2, m), U32)                  # the two planes' lattice coordinates per axis
    call(np.copyto, keys[:, 0].view(I32), floor, casting="unsafe")   # beyond int32: INT_MIN, as Cycles sees
    call(np.add, keys[:, 0], U32(1), out=keys[:, 1])
    shapes = [shape + (m,) for shape in _corner_shapes(d)]
    h = H.hash_uint_grid([keys[k].reshape(shapes[k]) for k in range(d)], s, call)
    table = _gradient_table(d)
    index = s("grad_index", (2 ** d, m), np.intp)
    call(np.bitwise_and, h.reshape(2 ** d, m), U32(table.shape[1] - 1), out=index)
    _interpolate(table, index, planes, out, s, call)


def _perlin_box(x, out) -> bool:
    """Perlin noise at the m points x (d, m) into out (m,) by hashing once the box of lattice points
    their cells span, when it has at most a quarter as many points as the cells have corners (points
    on a surface at a low frequency share most corners); the corner gradients are then gathered from
    the box's. Same values as _perlin_block. False, with nothing done, when the box is too large."""
    d, m = x.shape
    s = H.thread_scratch("perlin_box")
    floor, planes = _lattice(x, s, H.call_now)
    lo, hi = floor.min(axis=1).astype(np.float64), floor.max(axis=1).astype(np.float64)
    if not (np.all(lo >= -2.0 ** 31) and np.all(hi < 2.0 ** 31 - 1)):     # NaN, or cells int32 can't hold
        return False
    dims = (hi - lo + 2).astype(np.int64)             # the cells' lattice points, far corners included
    if np.prod(dims.astype(np.float64)) > (2 ** d * m) // 4:
        return False
    size, lo = int(np.prod(dims)), lo.astype(np.int64)
    strides = np.ones(d, np.int64)
    for k in range(d - 2, -1, -1):
        strides[k] = strides[k + 1] * dims[k + 1]
    keys = [((lo[k] + np.arange(dims[k])) & 0xFFFFFFFF).astype(U32).reshape([-1 if a == k else 1 for a in range(d)])
            for k in range(d)]
    table = _gradient_table(d)
    box_index = _HASHES[d](*keys).reshape(size) & U32(table.shape[1] - 1)
    gradients = [row.take(box_index.astype(np.intp)) for row in table]

    cells = np.empty((d, m), np.int64)
    np.copyto(cells, floor, casting="unsafe")
    cells -= lo[:, None]
    cells *= strides[:, None]
    corner_offsets = np.zeros((2,) * d, np.int64)
    for k, shape in enumerate(_corner_shapes(d)):
        corner_offsets += np.array([0, strides[k]]).reshape(shape)
    index = s("box_index", (2 ** d, m), np.intp)
    np.add(cells.sum(axis=0), corner_offsets.reshape(-1, 1), out=index)
    _interpolate(gradients, index, planes, out, s, H.call_now)
    return True


class _Tape:
    """NumPy calls recorded once and replayed. A Perlin block of one size is the same ~80 calls on the
    same work arrays every time; replaying them skips the Python that chose them (shapes, views,
    names), which costs more than the calls themselves on small blocks."""

    def __init__(self):
        self.steps = []

    def __call__(self, fn, *args, **kwargs):
        self.steps.append((fn, args, kwargs))
        return fn(*args, **kwargs)

    def replay(self):
        for fn, args, kwargs in self.steps:
            fn(*args, **kwargs)


_PLANS = threading.local()


@lru_cache(maxsize=None)
def _block_sizes(step: int) -> tuple:
    """The block sizes tapes are recorded for: steps of sqrt(2) from 32 to `step` (a block of m points
    runs on the next size up, so padding costs at most 41% on the last, partial block of a call)."""
    sizes, size = {step}, 32.0
    while size < step:
        sizes.add(min(int(np.ceil(size / 16)) * 16, step))
        size *= 2 ** 0.5
    return tuple(sorted(sizes))


def _plan(d: int, m: int):
    """(tape, input (d, M), output (M,)) of the recorded Perlin block that runs m points, per thread.
    Tapes hold views of the thread's scratch arrays, sized by the largest block, recorded first; should
    the arrays grow all the same, the tapes recorded before are dropped (and recorded again when next
    needed), so that none keeps a superseded array alive."""
    s = H.thread_scratch("perlin")
    if getattr(_PLANS, "generation", None) != s.generation:
        _PLANS.plans, _PLANS.generation = {}, s.generation
    sizes = _block_sizes(_BLOCK >> d)
    size = next(b for b in sizes if b >= m)
    unfused = _unfused()      # the tape records one rounding's calls
    plan = _PLANS.plans.get((d, size, unfused))
    if plan is None:
        if (d, sizes[-1], unfused) not in _PLANS.plans:
            _PLANS.plans[(d, sizes[-1], unfused)] = _record(d, sizes[-1], s)
        plan = _PLANS.plans[(d, size, unfused)] = _record(d, size, s)
        if _PLANS.generation != s.generation:
            _PLANS.plans, _PLANS.generation = {(d, size, unfused): plan}, s.generation
    return plan


def _record(d: int, size: int, s: H.Scratch):
    x = s("perlin_in", (d, size), F32)
    x[...] = ZERO
    out = s("perlin_out", (size,), F32)
    tape = _Tape()
    _perlin_block(x, out, s, tape)
    return tape, x, out


def _floorfrac(x):
    """(x - floor(x), int(floor(x)) as uint32 bits): Cycles' floorfrac."""
    f = np.floor(x)
    with np.errstate(invalid="ignore"):        # beyond int32: x86 gives INT_MIN, as Cycles sees
        i = f.astype(I32)
    return x - f, i.view(U32)


def _grad1(h):
    """The 1D gradient chosen by hash h: +-(1 .. 8)."""
    g = (U32(1) + (h & U32(7))).astype(F32)
    return _negate_if_bit(g, h, 3)


def _perlin_1d(x):
    fx, cell = _floorfrac(x)
    g0, g1 = _grad1(H.hash_uint(np.stack([cell, cell + U32(1)])))    # both neighbours in one hash
    # The scalar kernel's fade, ((t t) t) b, and its contraction of mix(g0 fx, g1 (fx - 1), u).
    u = fma(fx, fma(fx, F32(6.0), F32(-15.0)), F32(10.0))
    u *= (fx * fx) * fx
    if _unfused():
        a = g0 * fx
        return fma(u, g1 * (fx - ONE) - a, a)
    return fma(g0, fx, u * fma(-g0, fx, g1 * (fx - ONE)))


def _rows(p) -> np.ndarray:
    """Coordinates as one (d, N) float32 array (a copy unless p already is one)."""
    if isinstance(p, np.ndarray) and p.ndim == 2 and p.dtype == F32:
        return p
    return np.stack([np.asarray(c, F32) for c in p])


def perlin(p, cuts=()):
    """Unscaled signed Perlin noise at p = (x,) .. (x, y, z, w), each (N,) float32 -> (N,) float32
    (or p a (d, N) float32 array). Blocks start at the offsets `cuts` too (where a set of points at one
    frequency begins: see _perlin_box)."""
    x = _rows(p)
    d, n = x.shape
    if d == 1:
        return _perlin_1d(x[0])
    out = np.empty(n, F32)
    step = _BLOCK >> d
    bounds = sorted({0, n, *(c for c in cuts if 0 < c < n)})
    starts = [a for lo, hi in zip(bounds, bounds[1:]) for a in range(lo, hi, step)]
    with np.errstate(invalid="ignore"):
        for a, b in zip(starts, starts[1:] + [n]):
            m = b - a
            if m >= _BOX_MIN and _perlin_box(x[:, a:b], out[a:b]):
                continue
            tape, block_in, block_out = _plan(d, m)
            block_in[:, :m] = x[:, a:b]
            block_in[:, m:] = ZERO
            tape.replay()
            out[a:b] = block_out[:m]
    return out


def _wrap(c, d: int):
    """A coordinate as snoise feeds it to Perlin: fmod(c, 1e5), plus 1/2 where |c| >= 1e6.

    1D calls fmodf (exact). 2D-4D use the SIMD fmod as compiled: q = trunc(c * float32(1e-5)), then
    c - q * 1e5 fused (3D and 4D unfused under Blender 5.3's rounding). Only |c| >= 1e5 can change, so
    only those take the float64 path (where c - q * 1e5 is exact: q has 24 significant bits, 1e5 =
    3125 * 2^5 has 12, and c is close to q 1e5)."""
    big = np.abs(c) >= WRAP_PERIOD
    if not big.any():
        return c
    out = c.copy()
    cb = c[big]
    if d == 1:
        wrapped = np.fmod(cb, WRAP_PERIOD)
    elif d >= 3 and _unfused():
        wrapped = cb - np.trunc(cb * WRAP_RECIPROCAL) * WRAP_PERIOD
    else:
        q = np.trunc(cb * WRAP_RECIPROCAL)
        wrapped = (cb.astype(np.float64) - q.astype(np.float64) * float(WRAP_PERIOD)).astype(F32)
    out[big] = wrapped + np.where(np.abs(cb) >= WRAP_FROM, HALF, ZERO)
    return out


def perlin_wrapped(p, cuts=()):
    x = _rows(p)
    return perlin(_wrap(x, len(x)), cuts)


def snoise(p):
    """Cycles' snoise_1d .. snoise_4d: signed noise, about [-1, 1], at p = d component arrays (N,)."""
    r = perlin_wrapped(p)
    r *= NOISE_SCALE[len(p)]
    return r


def noise_at(jobs, scaled=True):
    """Noise at several point sets in one Perlin call (its cost per call is far above its cost per
    point): jobs = [(live, p)], p d component arrays (N,), live a mask of the hits to evaluate (None: all).
    Per job (N,) float32: snoise(p), or the wrapped unscaled Perlin if not `scaled`; 0 off `live`."""
    d = len(jobs[0][1])
    picked = [p if live is None else tuple(c[live] for c in p) for live, p in jobs]
    sizes = [len(p[0]) for p in picked]
    x = np.empty((d, sum(sizes)), F32)
    for k in range(d):
        np.concatenate([p[k] for p in picked], out=x[k])
    ends = np.cumsum(sizes)
    cuts = [c for size, end in zip(sizes, ends) if size >= _BOX_MIN for c in (end - size, end)]
    r = perlin_wrapped(x, cuts)
    if scaled:
        r *= NOISE_SCALE[d]
    out, start = [], 0
    for (live, p), q in zip(jobs, picked):
        part = r[start:start + len(q[0])]
        start += len(q[0])
        if live is not None:
            part, values = np.zeros(p[0].shape, F32), part
            part[live] = values
        out.append(part)
    return out
