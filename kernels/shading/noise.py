"""Cycles' Perlin noise and the texture nodes built on it, over arrays of hits: Noise, White Noise, Wave.

Sources: `kernel/svm/noise.h` (Perlin), `fractal_noise.h`, `noisetex.h`, `white_noise.h`, `wave.h`.
The results are bit-exact with Cycles' x86-64 AVX2 CPU kernel as Blender 5.0 ships it (probed: see
tests/test_nodes_noise.py); Perlin noise also as Blender 5.3's kernel rounds it (`cycles_rounding`). That kernel uses the SIMD Perlin variants (their interpolation order, fmod
as c - trunc(c / 1e5) * 1e5) and is compiled with -ffp-contract=fast and -freciprocal-math: many
multiply-adds are fused, divisions by constants are multiplications. Where a fused multiply-add changes
the rounding it is written fma(a, b, c) below; which ones the compiler fused was found by probing, not
read from the C. The one exception is the Wave's sine, within an ulp of glibc's sinf.

Perlin functions take coordinates as a sequence of d component arrays (`(x, y, z)`; a (d, N) array
unpacks the same way), like kernels.shading.hash. The node functions take sockets as the program runner
passes them: a float socket (N,) or a constant (Python float, 0-d or length-1 array), a vector (N, 3) or a
constant (3,); node options are keywords with Blender's enum identifiers (`dimensions="3D"`,
`noise_type="FBM"`, `wave_type="BANDS"`, ...). They return {output identifier: (N,) or (N, 3) float32}.

Detail is a loop count. A constant Detail runs the octaves with scalar bookkeeping; a per-hit Detail runs
to the largest count and evaluates each octave only at the hits that still need it.

How it runs (a call costs far more than a point on the waves the renderer shades): every octave's points
(and the distortion's, and the Color's channels) go to Perlin in one call; Perlin runs in blocks of
points whose corners are broadcast grids, on per-thread work arrays, replaying NumPy calls recorded once
per block size (_Tape); a large block of one frequency whose cells span a small box hashes the box once
(_perlin_box). Each is the same arithmetic point by point: the results do not change.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from functools import lru_cache

import numpy as np

from ..vec import F32, HALF, HALF_PI, I32, INV_2PI, ONE, U32, ZERO, fma
from . import hash as H

NOISE_SCALE = {1: F32(0.25), 2: F32(0.6616), 3: F32(0.9820), 4: F32(0.8344)}  # OSL's, to about [-1, 1]
WRAP_PERIOD = F32(100000.0)       # Perlin repeats every 1e5 per axis, for precision
WRAP_RECIPROCAL = F32(1e-5)       # what the compiler divides by 1e5 with (-freciprocal-math)
WRAP_FROM = F32(1000000.0)        # where the wrapped coordinate is shifted by 1/2 (off the lattice)
DIMENSIONS = {"1D": 1, "2D": 2, "3D": 3, "4D": 4}


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
    c - q * 1e5 fused (3D and 4D unfused under Blender 5.3's rounding). Only |c| >= 1e5 can change, so only those take the float64 path (where
    c - q * 1e5 is exact: q has 24 significant bits, 1e5 = 3125 * 2^5 has 12, and c is close to q 1e5)."""
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


def _perlin_wrapped(p, cuts=()):
    x = _rows(p)
    return perlin(_wrap(x, len(x)), cuts)


def snoise(p):
    """Cycles' snoise_1d .. snoise_4d: signed noise, about [-1, 1], at p = d component arrays (N,)."""
    r = _perlin_wrapped(p)
    r *= NOISE_SCALE[len(p)]
    return r


def _noise_at(jobs, scaled=True):
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
    r = _perlin_wrapped(x, cuts)
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


def _snoise_plus(live, p, offset, raw=None):
    """snoise(p) + offset at the hits in `live`, with the scale's multiply fused into the add as
    Cycles' inlined snoise is compiled. raw: the wrapped unscaled Perlin there if already computed."""
    if raw is None:
        raw = _on(live, p, _perlin_wrapped)
    return fma(NOISE_SCALE[len(p)], raw, offset)


# ---- Fractals (fractal_noise.h) -------------------------------------------------------------------

class _Octaves:
    """Detail as a loop: `count` octaves (Cycles: i = 0 ..= int(detail)) and the fractional remainder.

    Uniform detail: count is an int, `live(i)` is None (every hit) and rmd a scalar. Per-hit detail:
    live(i) is the mask of hits that run octave i, rmd an array."""

    def __init__(self, detail, n: int):
        d = np.asarray(detail, F32)
        if d.size == 1 or d.min() == d.max():
            d = F32(d.flat[0])
            self.counts = None
            self.count = max(int(np.trunc(d)) + 1, 0)
            self.rmd = d - np.floor(d)
        else:
            d = np.broadcast_to(d, (n,))
            self.counts = np.trunc(d).astype(I32) + I32(1)
            self.count = max(int(self.counts.max()), 0)
            self.rmd = d - np.floor(d)

    def live(self, i: int):
        return None if self.counts is None else self.counts > i

    def remainder(self):
        """Mask of hits with a fractional octave (None: all), or False when no hit has one."""
        if self.counts is None:
            return None if self.rmd != 0 else False
        has = self.rmd != 0
        return has if has.any() else False


def _on(live, p, fn=snoise):
    """fn(p) at the hits in mask `live` (None: all); 0 elsewhere."""
    if live is None:
        return fn(p)
    out = np.zeros(p[0].shape, F32)
    if live.any():
        out[live] = fn(tuple(c[live] for c in p))
    return out


def _keep(live, new, old):
    return new if live is None else np.where(live, new, old)


def _both(a, b):
    """Intersection of two masks where None means all hits."""
    if a is None:
        return b
    return a if b is None else a & b


def _scaled(p, s):
    return tuple(c * s for c in p)


def _prepare(p, detail, *params):
    """A fractal's arguments: p's components as float32 arrays of one 1-d shape, the octave plan, and
    the parameters as float32 (scalars or per-hit arrays), so that the bookkeeping rounds in float32."""
    comps = np.broadcast_arrays(*(np.atleast_1d(np.asarray(c, F32)) for c in p))
    p = tuple(np.ascontiguousarray(c) for c in comps)
    return p, _Octaves(detail, len(p[0])), tuple(np.asarray(x, F32) for x in params)


def _progression(p, lives, lacunarity):
    """The octaves' points when each octave scales the last one's by lacunarity (at its live hits):
    len(lives) + 1 coordinate tuples, the first p itself."""
    points = [p]
    for live in lives:
        points.append(tuple(_keep(live, c * lacunarity, c) for c in points[-1]))
    return points


def fbm(p, detail, roughness, lacunarity, normalize=True):
    """Fractal Brownian motion: octaves of snoise(lacunarity^i p) with amplitudes roughness^i."""
    p, octaves, (roughness, lacunarity) = _prepare(p, detail, roughness, lacunarity)
    lives = [octaves.live(i) for i in range(octaves.count)]
    has = octaves.remainder()
    fscales = [ONE]
    for live in lives:
        fscales.append(_keep(live, fscales[-1] * lacunarity, fscales[-1]))
    jobs = [(live, _scaled(p, fscale)) for live, fscale in zip(lives, fscales)]
    if has is not False:
        jobs.append((has, _scaled(p, fscales[-1])))
    noise = _noise_at(jobs) if jobs else []
    amp, maxamp, total = ONE, ZERO, ZERO
    for live, t in zip(lives, noise):
        total = _keep(live, fma(t, amp, total), total)
        maxamp = _keep(live, maxamp + amp, maxamp)
        amp = _keep(live, amp * roughness, amp)
    total = np.broadcast_to(np.asarray(total, F32), p[0].shape)
    with np.errstate(divide="ignore", invalid="ignore"):     # detail < 0: Cycles divides 0 by 0 too
        out = HALF * total / maxamp + HALF if normalize else total
        if has is not False:
            total2 = fma(noise[-1], amp, total)
            if normalize:
                extra = HALF * total2 / (maxamp + amp) + HALF
            else:
                extra = total2
            out = _keep(has, fma(octaves.rmd, extra - out, out), out)
    return np.asarray(out, F32)


def multi_fractal(p, detail, roughness, lacunarity):
    """Multifractal: the product of (1 + roughness^i snoise(lacunarity^i p))."""
    p, octaves, (roughness, lacunarity) = _prepare(p, detail, roughness, lacunarity)
    lives = [octaves.live(i) for i in range(octaves.count)]
    has = octaves.remainder()
    points = _progression(p, lives, lacunarity)
    jobs = list(zip(lives, points)) + ([(has, points[-1])] if has is not False else [])
    noise = _noise_at(jobs) if jobs else []
    value, pwr = ONE, ONE
    for live, t in zip(lives, noise):
        value = _keep(live, value * fma(pwr, t, ONE), value)
        pwr = _keep(live, pwr * roughness, pwr)
    if has is not False:
        value = _keep(has, value * fma(octaves.rmd * pwr, noise[-1], ONE), value)
    return np.broadcast_to(np.asarray(value, F32), p[0].shape).copy()


def hetero_terrain(p, detail, roughness, lacunarity, offset):
    """Heterogeneous terrain: octaves scaled by the value so far."""
    p, octaves, (roughness, lacunarity, offset) = _prepare(p, detail, roughness, lacunarity, offset)
    lives = [octaves.live(i) for i in range(1, octaves.count)]
    has = octaves.remainder()
    points = [p] + _progression(_scaled(p, lacunarity), lives, lacunarity)
    jobs = [(None, p)] + list(zip(lives, points[1:])) + ([(has, points[-1])] if has is not False else [])
    raw = _noise_at(jobs, scaled=False)
    pwr = roughness
    value = _snoise_plus(None, p, offset, raw[0])
    for live, q, r in zip(lives, points[1:], raw[1:]):
        value = _keep(live, fma(_snoise_plus(live, q, offset, r) * pwr, value, value), value)
        pwr = _keep(live, pwr * roughness, pwr)
    if has is not False:
        increment = _snoise_plus(has, points[-1], offset, raw[-1]) * pwr * value
        value = _keep(has, fma(octaves.rmd, increment, value), value)
    return np.asarray(value, F32)


def hybrid_multi_fractal(p, detail, roughness, lacunarity, offset, gain):
    """Hybrid additive/multiplicative multifractal: octaves weighted by gain times the last signal,
    stopping where the weight falls to 0.001."""
    p, octaves, (roughness, lacunarity, offset, gain) = _prepare(p, detail, roughness, lacunarity, offset, gain)
    n = len(p[0])
    pwr = np.full(n, ONE)
    value = np.zeros(n, F32)
    weight = np.full(n, ONE)
    threshold = F32(0.001)
    for i in range(octaves.count):
        live = _both(octaves.live(i), weight > threshold)
        if not live.any():
            break
        weight = _keep(live, np.minimum(weight, ONE), weight)
        signal = _snoise_plus(live, p, offset) * pwr
        pwr = _keep(live, pwr * roughness, pwr)
        value = _keep(live, fma(weight, signal, value), value)
        weight = _keep(live, weight * (gain * signal), weight)
        p = tuple(_keep(live, c * lacunarity, c) for c in p)
    has = octaves.remainder()
    if has is not False:
        has = _both(has, weight > threshold)
        w = np.minimum(weight, ONE)
        signal = _snoise_plus(has, p, offset) * pwr
        value = _keep(has, fma(octaves.rmd * w, signal, value), value)
    return value


def ridged_multi_fractal(p, detail, roughness, lacunarity, offset, gain):
    """Ridged multifractal: squared (offset - |snoise|) ridges, each octave weighted by the last.
    No fractional octave: Cycles ignores the fraction of Detail here."""
    p, octaves, (roughness, lacunarity, offset, gain) = _prepare(p, detail, roughness, lacunarity, offset, gain)
    lives = [octaves.live(i) for i in range(1, octaves.count)]
    points = _progression(p, lives, lacunarity)
    noise = _noise_at([(None, p)] + list(zip(lives, points[1:])))
    pwr = roughness
    signal = offset - np.abs(noise[0])
    signal = signal * signal
    value = signal
    for live, t in zip(lives, noise[1:]):
        weight = np.clip(signal * gain, ZERO, ONE)
        s = offset - np.abs(t)
        s = s * s * weight
        signal = _keep(live, s, signal)
        value = _keep(live, fma(s, pwr, value), value)
        pwr = _keep(live, pwr * roughness, pwr)
    return np.asarray(value, F32)


def fractal(p, detail, roughness, lacunarity, offset, gain, noise_type="FBM", normalize=True):
    """Cycles' noise_select: the Noise node's fractal by Blender's noise_type identifier."""
    if noise_type == "FBM":
        return fbm(p, detail, roughness, lacunarity, normalize)
    if noise_type == "MULTIFRACTAL":
        return multi_fractal(p, detail, roughness, lacunarity)
    if noise_type == "HYBRID_MULTIFRACTAL":
        return hybrid_multi_fractal(p, detail, roughness, lacunarity, offset, gain)
    if noise_type == "RIDGED_MULTIFRACTAL":
        return ridged_multi_fractal(p, detail, roughness, lacunarity, offset, gain)
    if noise_type == "HETERO_TERRAIN":
        return hetero_terrain(p, detail, roughness, lacunarity, offset)
    raise ValueError(f"unknown noise_type {noise_type!r}")


# ---- Noise Texture node (noisetex.h) --------------------------------------------------------------

@lru_cache(maxsize=None)
def random_offset(seed: float, d: int) -> tuple:
    """Cycles' random_float{,2,3,4}_offset(seed): a constant per-axis shift in [100, 200]."""
    if d == 1:
        h = (H.hash_float_to_float(F32(seed))[0],)
    else:
        h = tuple(H.hash_float2_to_float((F32(seed), F32(axis)))[0] for axis in range(d))
    return tuple(F32(100.0) + x * F32(100.0) for x in h)


def _shift(p, seed: float):
    return tuple(c + o for c, o in zip(p, random_offset(seed, len(p))))


def _vector(v):
    """A vector socket as (x, y, z) component arrays."""
    v = np.asarray(v, F32).reshape(-1, 3)
    return v[:, 0], v[:, 1], v[:, 2]


def _hit_count(vector, *floats) -> int:
    """N: the hits the node runs at, from whichever input is per hit (1 when all are constants)."""
    sizes = {len(np.asarray(vector).reshape(-1, 3))} | {np.size(f) for f in floats}
    per_hit = sizes - {1}
    return per_hit.pop() if per_hit else 1


def _coords(vector, w, d: int, n: int):
    """The node's coordinates for its dimension count, each component a float32 (n,) array."""
    x, y, z = _vector(vector)
    w = np.asarray(w, F32)
    comps = {1: (w,), 2: (x, y), 3: (x, y, z), 4: (x, y, z, w)}[d]
    return tuple(np.ascontiguousarray(np.broadcast_to(c, (n,))) for c in comps)


# Which axes' p + snoise * distortion Cycles' compiled kernel fuses (found by probing it bit-exactly):
# 1D is scalar code; 2D's float2 is scalar too but only x contracts; 3D and 4D add a SIMD vector.
_FUSED_DISTORTION = {1: (True,), 2: (True, False), 3: (False,) * 3, 4: (False,) * 4}


def _distort(c, s, distortion, d: int, axis: int):
    """Distortion along one axis: c + s * distortion, rounded as Cycles rounds it."""
    return fma(s, distortion, c) if _FUSED_DISTORTION[d][axis] else c + s * distortion


def noise_texture(vector, w=0.0, scale=5.0, detail=2.0, roughness=0.5, lacunarity=2.0, offset=0.0,
                  gain=1.0, distortion=0.0, *, dimensions="3D", noise_type="FBM", normalize=True,
                  outputs=("Fac", "Color"), cycles_version=None):
    """The Noise Texture node: {"Fac": (N,), "Color": (N, 3)} (Color costs two more fractals), rounded as
    the Cycles of Blender `cycles_version` (cycles_rounding)."""
    with cycles_rounding(cycles_version):
        return _noise_texture(vector, w, scale, detail, roughness, lacunarity, offset, gain, distortion,
                              dimensions, noise_type, normalize, outputs)


def _noise_texture(vector, w, scale, detail, roughness, lacunarity, offset, gain, distortion, dimensions,
                   noise_type, normalize, outputs):
    d = DIMENSIONS[dimensions]
    n = _hit_count(vector, w, scale, detail, roughness, lacunarity, offset, gain, distortion)
    if n == 0:
        return {"Fac": np.zeros(0, F32), "Color": np.zeros((0, 3), F32)}
    scale = np.asarray(scale, F32)
    p = tuple(c * scale for c in _coords(vector, w, d, n))
    detail = np.clip(np.asarray(detail, F32), ZERO, F32(15.0))
    roughness = np.maximum(np.asarray(roughness, F32), ZERO)
    lacunarity, offset, gain = (np.asarray(x, F32) for x in (lacunarity, offset, gain))
    distortion = np.asarray(distortion, F32)
    if distortion.any():
        # Cycles skips this where distortion is 0; adding 0 * snoise leaves p unchanged all the same.
        shifted = _noise_at([(None, _shift(p, axis)) for axis in range(d)])
        p = tuple(_distort(c, s, distortion, d, axis) for axis, (c, s) in enumerate(zip(p, shifted)))
    params = (detail, roughness, lacunarity, offset, gain)
    options = (noise_type, normalize)
    if "Color" not in outputs:
        return {"Fac": fractal(p, *params, *options)} if "Fac" in outputs else {}
    # The colour's channels are the Fac and two more fractals at shifted points (the distortion used
    # seeds 0 .. d-1, the colour takes the next two): one fractal over the three point sets end to end.
    seed = d
    points = [p, _shift(p, seed), _shift(p, seed + 1)]
    stacked = tuple(np.concatenate(axis) for axis in zip(*points))
    params = tuple(np.tile(x, 3) if x.size > 1 else x for x in params)
    channels = fractal(stacked, *params, *options).reshape(3, n)
    result = {"Fac": channels[0]} if "Fac" in outputs else {}
    result["Color"] = np.ascontiguousarray(channels.T)
    return result


# ---- White Noise Texture node (white_noise.h) -----------------------------------------------------

_WHITE_VALUE = {1: lambda k: H.hash_float_to_float(k[0]), 2: H.hash_float2_to_float,
                3: H.hash_float3_to_float, 4: H.hash_float4_to_float}
_WHITE_COLOR = {1: lambda k: H.hash_float_to_float3(k[0]), 2: H.hash_float2_to_float3,
                3: H.hash_float3_to_float3, 4: H.hash_float4_to_float3}


def white_noise_texture(vector, w=0.0, *, dimensions="3D", outputs=("Value", "Color")):
    """The White Noise node: hashes of the input's float bits. {"Value": (N,), "Color": (N, 3)}."""
    d = DIMENSIONS[dimensions]
    k = _coords(vector, w, d, _hit_count(vector, w))
    result = {}
    if "Value" in outputs:
        result["Value"] = _WHITE_VALUE[d](k)
    if "Color" in outputs:
        result["Color"] = np.stack(_WHITE_COLOR[d](k), axis=1)
    return result


# ---- Wave Texture node (wave.h) -------------------------------------------------------------------

_RING_AXES = {"X": (1, 2), "Y": (0, 2), "Z": (0, 1), "SPHERICAL": (0, 1, 2)}
_BAND_AXIS = {"X": 0, "Y": 1, "Z": 2}


def _sinf(x):
    """float32 sine via float64, correctly rounded: within an ulp of the glibc sinf Cycles calls."""
    return np.sin(x.astype(np.float64)).astype(F32)


def wave(vector, scale, distortion, detail, detail_scale, detail_roughness, phase, *, wave_type="BANDS",
         bands_direction="X", rings_direction="X", wave_profile="SIN"):
    """Cycles' svm_wave(co * scale, ...) at vector = (x, y, z) -> Fac (N,).

    Rounded as Cycles' kernel is compiled: co * scale + 1e-6 and the distortion's multiply-add are
    fused, the division by 2 pi is a multiplication by its reciprocal (-freciprocal-math)."""
    scale, distortion, detail_scale, detail_roughness, phase = (
        np.asarray(x, F32) for x in (scale, distortion, detail_scale, detail_roughness, phase))
    # Cycles nudges p off unit coordinates, where the bands would sit on their discontinuities.
    p = tuple(fma(c, scale, F32(0.000001)) * F32(0.999999) for c in vector)
    if wave_type == "BANDS":
        if bands_direction == "DIAGONAL":
            n = (p[0] + p[1] + p[2]) * F32(10.0)
        else:
            n = p[_BAND_AXIS[bands_direction]] * F32(20.0)
    elif wave_type == "RINGS":
        squares = [p[a] * p[a] for a in _RING_AXES[rings_direction]]
        n = np.sqrt(sum(squares[1:], squares[0])) * F32(20.0)
    else:
        raise ValueError(f"unknown wave_type {wave_type!r}")
    n += phase
    if distortion.any():
        f = fbm(_scaled(p, detail_scale), detail, detail_roughness, F32(2.0), True)
        n = fma(distortion, f * F32(2.0) - ONE, n)
    if wave_profile == "SIN":
        return HALF + HALF * _sinf(n - HALF_PI)
    n *= INV_2PI
    if wave_profile == "SAW":
        return n - np.floor(n)
    if wave_profile == "TRI":
        return np.abs(n - np.floor(n + HALF)) * F32(2.0)
    raise ValueError(f"unknown wave_profile {wave_profile!r}")


def wave_texture(vector, scale=5.0, distortion=0.0, detail=2.0, detail_scale=1.0, detail_roughness=0.5,
                 phase_offset=0.0, *, wave_type="BANDS", bands_direction="X", rings_direction="X",
                 wave_profile="SIN", cycles_version=None):
    """The Wave Texture node: {"Color": (N, 3) grey, "Fac": (N,)}, its noise rounded as the Cycles of
    Blender `cycles_version` (cycles_rounding)."""
    n = _hit_count(vector, scale, distortion, detail, detail_scale, detail_roughness, phase_offset)
    if n == 0:
        return {"Color": np.zeros((0, 3), F32), "Fac": np.zeros(0, F32)}
    with cycles_rounding(cycles_version):
        fac = wave(_coords(vector, 0.0, 3, n), scale, distortion, detail, detail_scale, detail_roughness,
                   phase_offset, wave_type=wave_type, bands_direction=bands_direction,
                   rings_direction=rings_direction, wave_profile=wave_profile)
    return {"Color": np.repeat(fac[:, None], 3, axis=1), "Fac": fac}
