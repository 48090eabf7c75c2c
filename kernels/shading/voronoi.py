"""The Voronoi Texture node over arrays of hits, as Cycles evaluates it (`kernel/svm/voronoi.h`).

    voronoi_texture(vector, w, scale, detail, ...) -> {"Distance": (N,), "Color": (N, 3), ...}

Space is cut into unit cells; each cell holds one point at a hashed offset scaled by Randomness. F1 / F2
are the nearest / second-nearest point of the 3^d neighbourhood, Smooth F1 a smooth minimum over the 5^d
neighbourhood, Distance to Edge the distance to the nearest bisector, N-Sphere Radius half the distance
from the nearest point to its own nearest point. Detail adds octaves like fBM (`fractal_voronoi_*`).

Bit-level facts this follows: 1D hashes the float bits of the cell coordinate (hash_float_to_float), 2D-4D
hash the int32 cell (PCG, hash_int*_to_float*); points are `offset + hash * randomness`; the winner is the
first cell with a strictly smaller distance, in the loop order x fastest; F1 compares a cheaper bound
(squared length, or the Minkowski sum before the root) and takes the metric of the winner afterwards;
sums over components pair up as Cycles' SIMD does ((x+y)+z, (x+y)+(z+w)). Distance to Edge and N-Sphere
Radius are always Euclidean, and 1D is always |a - b|, whatever the metric.

Cost is 3^d cells per octave (1D 3, 2D 9, 3D 27, 4D 81), Smooth F1 5^d (4D: 625 cells per octave). F1,
F2, Distance to Edge and N-Sphere Radius take all 3^d neighbours at once, as (3^d, hits) tables for
chunks of hits (_Hood, in reused work arrays: a wave's call costs tens of NumPy calls, not thousands);
when the hits' cells span a small box (a low frequency on a surface) its cells are hashed once and
gathered. Smooth F1 runs neighbour by neighbour over all hits, so memory stays O(N). For 65k hits
spread over a wide range (one thread), per octave: 3D F1 ~30 ms, F2 ~35 ms, Smooth F1 ~115 ms,
Distance to Edge ~40 ms, N-Sphere Radius ~50 ms; 4D F1 ~80 ms, Smooth F1 ~1.1 s.
"""
from __future__ import annotations

import itertools

import numpy as np

from ..vec import F32, HALF, I32, ONE, TWO, ZERO
from .hash import (hash_float_to_float, hash_float_to_float3, hash_int2_to_float2, hash_int2_to_float3,
                   hash_int3_to_float3, hash_int4_to_float4, hash_int_to_float_grid, thread_scratch)

FLT_MAX = F32(np.finfo(np.float32).max)
EDGE_EPSILON = F32(0.0001)        # bisectors of points closer than sqrt of this are skipped
FIRST_DISTANCE = F32(8.0)          # fractal Distance to Edge starts from this
_CHUNK = 1 << 16                   # neighbour values per (K, hits) array (a chunk of hits)

DIMENSIONS = {"1D": 1, "2D": 2, "3D": 3, "4D": 4}
FEATURES = ("F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE", "N_SPHERE_RADIUS")
METRICS = ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV", "MINKOWSKI")


def _offsets(d: int, reach: int) -> np.ndarray:
    """(K, d) int32 neighbour offsets in [-reach, reach]^d, in Cycles' loop order (x varies fastest)."""
    rows = [t[::-1] for t in itertools.product(range(-reach, reach + 1), repeat=d)]
    return np.array(rows, I32).reshape(-1, d)


_NEIGHBOURS = {d: _offsets(d, 1) for d in (1, 2, 3, 4)}
_SMOOTH_NEIGHBOURS = {d: _offsets(d, 2) for d in (1, 2, 3, 4)}


def available_outputs(dimensions: str = "3D", feature: str = "F1") -> tuple[str, ...]:
    """The output sockets Blender shows for these options."""
    if feature == "DISTANCE_TO_EDGE":
        return ("Distance",)
    if feature == "N_SPHERE_RADIUS":
        return ("Radius",)
    d = DIMENSIONS[dimensions]
    return ("Distance", "Color") + (("Position",) if d > 1 else ()) + (("W",) if d in (1, 4) else ())


# ---- Inputs ------------------------------------------------------------------------------------------

def _param(x) -> np.ndarray:
    """A float input as a 0-d float32 array (a constant) or an (N,) one."""
    a = np.asarray(x, F32)
    return a.reshape(()) if a.size == 1 else a.reshape(-1)


def _take(a: np.ndarray, sel):
    """A parameter restricted to some hits: constants stay as they are."""
    return a if a.ndim == 0 or sel is None else a[sel]


def _sum(parts):
    """Sum of per-component arrays in Cycles' order: (x+y)+z in 3D, pairwise (x+y)+(z+w) in 4D (SIMD)."""
    if len(parts) == 1:
        return parts[0]
    if len(parts) == 4:
        return (parts[0] + parts[1]) + (parts[2] + parts[3])
    total = parts[0] + parts[1]
    for p in parts[2:]:
        total += p
    return total


def _mix(a, b, t):
    """Cycles' mix: a + t (b - a)."""
    return a + t * (b - a)


# ---- Distances ---------------------------------------------------------------------------------------

class _Metric:
    """A distance metric over per-component difference arrays: `bound` orders candidates like `full`
    does but skips the final root, as Cycles' voronoi_distance_bound."""

    def __init__(self, d: int, metric: str, exponent):
        self.d, self.metric = d, metric if d > 1 else "ABS"
        self.exponent = exponent
        if self.metric == "MINKOWSKI":
            self.inv_exponent = ONE / exponent

    def bound(self, diff):
        m = self.metric
        if m == "ABS":
            return np.abs(diff[0])
        if m == "EUCLIDEAN":
            return _sum([c * c for c in diff])
        if m == "MANHATTAN":
            return _sum([np.abs(c) for c in diff])
        if m == "CHEBYCHEV":
            parts = [np.abs(c) for c in diff]
            if len(parts) == 4:
                return np.maximum(np.maximum(parts[0], parts[1]), np.maximum(parts[2], parts[3]))
            out = parts[0]
            for c in parts[1:]:
                out = np.maximum(out, c)
            return out
        return _sum([np.power(np.abs(c), self.exponent) for c in diff])

    def full(self, diff):
        b = self.bound(diff)
        if self.metric == "EUCLIDEAN":
            return np.sqrt(b)
        if self.metric == "MINKOWSKI":
            return np.power(b, self.inv_exponent)
        return b

    def take(self, sel):
        """The metric for some hits (a per-hit exponent is gathered)."""
        if sel is None or np.ndim(self.exponent) == 0:
            return self
        return _Metric(self.d, self.metric, self.exponent[sel])

    def max_distance(self, randomness):
        """The distance from the origin to (½ + ½ randomness)(1, ..., 1): the normalisation of F1."""
        r = HALF + HALF * randomness
        return self.full([r] * self.d) if self.d > 1 else r


def _euclidean_sq(diff):
    return _sum([c * c for c in diff])


# ---- The lattice of one octave -----------------------------------------------------------------------

class _Cells:
    """The cells around coordinates (d arrays (M,)): floor, local position, and hashes of neighbours."""

    def __init__(self, coords, randomness):
        self.d = len(coords)
        self.floor = [np.floor(c) for c in coords]
        self.local = [c - f for c, f in zip(coords, self.floor)]
        self.randomness = randomness
        if self.d == 1:
            self.key = self.floor[0]        # 1D hashes the float's bits
        else:
            with np.errstate(invalid="ignore"):   # beyond int32: C's cvttps gives INT_MIN, as numpy does
                self.key = [f.astype(I32) for f in self.floor]

    def _cell(self, offset):
        if self.d == 1:
            return self.key + _as_f32(offset[0])
        return [k + (I32(o) if np.ndim(o) == 0 else o) for k, o in zip(self.key, offset)]

    def hash(self, offset):
        """The unit hash of the neighbour at `offset` (d ints or d int32 arrays): d arrays in [0, 1]."""
        cell = self._cell(offset)
        if self.d == 1:
            return (hash_float_to_float(cell),)
        if self.d == 2:
            return hash_int2_to_float2(cell)
        if self.d == 3:
            return hash_int3_to_float3(cell)
        return hash_int4_to_float4(cell)

    def color(self, offset, point_hash=None):
        """The neighbour's colour: 3 arrays (the point hash itself in 3D and 4D, as Cycles' hashes are)."""
        if self.d >= 3:
            return tuple((point_hash or self.hash(offset))[:3])
        if self.d == 1:
            return hash_float_to_float3(self._cell(offset))
        return hash_int2_to_float3(self._cell(offset))

    def point(self, offset, h):
        """The neighbour's point relative to this cell: offset + hash * randomness (d arrays)."""
        return [_as_f32(o) + c * self.randomness for o, c in zip(offset, h)]

    def part(self, lo: int, hi: int) -> "_Cells":
        """The same cells for hits lo:hi."""
        part = _Cells.__new__(_Cells)
        part.d, part.randomness = self.d, _take(self.randomness, slice(lo, hi))
        part.floor, part.local = [f[lo:hi] for f in self.floor], [c[lo:hi] for c in self.local]
        part.key = self.key[lo:hi] if self.d == 1 else [k[lo:hi] for k in self.key]
        return part

    def around(self, table: np.ndarray) -> "_Hood":
        """Every neighbour of an offset table at once (kept: several passes read the same table)."""
        if getattr(self, "_hood_table", None) is not table:
            self._hood, self._hood_table = _Hood(self, table), table
        return self._hood


class _Hood:
    """The K neighbours of an offset table (K, d) for all M hits, as d arrays (K, M): hashes `hash`,
    points `point` relative to the hit's cell, and `diff` = point - local. One array operation per
    step for all neighbours, computed as the per-neighbour scan computes each (offset (K, 1) broadcast
    against the hits), so every value is the same bit for bit.

    2D-4D keep them in the thread's scratch arrays: valid until the next _Hood (one is read at a time)."""

    def __init__(self, cells: _Cells, table: np.ndarray):
        self.table = table
        offset = [np.ascontiguousarray(table[:, k, None]) for k in range(cells.d)]
        if cells.d == 1:
            self.hash = cells.hash(offset)
            self.point = cells.point(offset, self.hash)
            self.diff = [pc - lc for pc, lc in zip(self.point, cells.local)]
            return
        scratch = thread_scratch("voronoi")
        shape = (cells.d, len(table), len(cells.local[0]))
        self.hash = _box_hashes(cells.key, table, scratch)
        if self.hash is None:
            self.hash = hash_int_to_float_grid([(k, o) for k, o in zip(cells.key, offset)], scratch, "voronoi")
        self.point = scratch("voronoi_point", shape, F32)
        self.diff = scratch("voronoi_diff", shape, F32)
        for h, p, diff, o, local in zip(self.hash, self.point, self.diff, offset, cells.local):
            np.multiply(h, cells.randomness, out=p)
            p += o.astype(F32)                          # o + h r, as Cells.point
            np.subtract(p, local, out=diff)

    def offsets(self, k: np.ndarray):
        """The offsets of rows k (M,) as d int32 arrays."""
        return _columns(self.table, k)


def _box_hashes(keys, table: np.ndarray, scratch):
    """The neighbours' cell hashes (d, K, M) gathered from the hashes of the box of cells around the
    hits, computed once, if that box has at most a quarter as many cells as there are neighbours
    (hits on a surface at a low frequency share most of them); None otherwise."""
    d, k, m = len(keys), len(table), len(keys[0])
    reach = int(table.max())
    lo = np.array([key.min() for key in keys], np.int64) - reach
    dims = np.array([key.max() for key in keys], np.int64) + reach - lo + 1
    if np.prod(dims.astype(np.float64)) * 4 > k * m:
        return None
    lattice = [(lo[a] + np.arange(dims[a])).astype(I32).reshape([-1 if b == a else 1 for b in range(d)])
               for a in range(d)]             # int32 wraps as the cell + offset sums do
    box = hash_int_to_float_grid([(c,) for c in lattice], scratch, "voronoi_box").reshape(d, -1)
    strides = np.ones(d, np.int64)
    for a in range(d - 2, -1, -1):
        strides[a] = strides[a + 1] * dims[a + 1]
    base = sum((key.astype(np.int64) - lo[a]) * strides[a] for a, key in enumerate(keys))
    index = np.add.outer(table.astype(np.int64) @ strides, base)
    out = scratch("voronoi_box_gather", (d, k, m), F32)
    for a in range(d):
        np.take(box[a], index, out=out[a], mode="wrap")         # in range: "wrap" skips the check
    return out


def _in_chunks(fn, cells: _Cells, *args):
    """fn(cells, *args) for chunks of the hits small enough that its neighbour tables (3^d, chunk) stay
    in cache, the results joined (a _Metric among args is cut with the hits)."""
    m, step = len(cells.local[0]), max(_CHUNK // 3 ** cells.d, 1)
    if m <= step:
        return fn(cells, *args)
    parts = [fn(cells.part(lo, lo + step), *(a.take(slice(lo, lo + step)) if isinstance(a, _Metric) else a
                                             for a in args))
             for lo in range(0, m, step)]
    return _join(parts)


def _join(parts):
    """Per-hit results of chunks, end to end: arrays, or tuples and lists of them (None stays None)."""
    if parts[0] is None:
        return None
    if isinstance(parts[0], (tuple, list)):
        return type(parts[0])(_join(list(p)) for p in zip(*parts))
    return np.concatenate(parts)


def _pick(rows, k: np.ndarray):
    """Row k[m] of each (K, M) array at each hit m: d arrays (M,)."""
    return [np.take_along_axis(a, k[None, :], axis=0)[0] for a in rows]


def _first_min(values: np.ndarray) -> np.ndarray:
    """(M,) the row of each column's smallest of values (K, M), the first of equals, as Cycles' scan
    `if (d < best)` from best = FLT_MAX finds it: NaN and values >= FLT_MAX never win, and a column
    without a winner gives row 0."""
    return np.argmin(np.where(values < FLT_MAX, values, F32(np.inf)), axis=0)


def _as_f32(o):
    return F32(o) if np.ndim(o) == 0 else o.astype(F32)


def _columns(table: np.ndarray, idx: np.ndarray):
    """Per-hit offsets: the rows idx of an offset table as d int32 arrays."""
    rows = table[idx]
    return [np.ascontiguousarray(rows[:, k]) for k in range(table.shape[1])]


# ---- One octave --------------------------------------------------------------------------------------

def _nearest(cells: _Cells, distance_of):
    """Each hit's nearest neighbour cell under distance_of (per-component point - local -> (K, M)) as
    its row in the neighbour table: the first of equals, as Cycles' strict-< scan in its loop order."""
    hood = cells.around(_NEIGHBOURS[cells.d])
    return hood, _first_min(distance_of(hood.diff))


def _f1(cells: _Cells, metric: _Metric, want_color: bool):
    hood, k = _nearest(cells, metric.bound)
    return _winner(cells, metric, hood, k, want_color, None)


def _winner(cells: _Cells, metric: _Metric, hood: _Hood, k, want_color: bool, distance):
    """Distance (unless given), colour and position of each hit's neighbour at row k of the hood."""
    p = _pick(hood.point, k)
    if distance is None:
        distance = metric.full(_pick(hood.diff, k))
    color = None
    if want_color:
        color = tuple(_pick(hood.hash[:3], k)) if cells.d >= 3 else cells.color(hood.offsets(k))
    position = [pc + fc for pc, fc in zip(p, cells.floor)]
    return distance, color, position


def _f2(cells: _Cells, metric: _Metric, want_color: bool):
    """The second nearest: Cycles' scan keeps (d1, d2), a new nearest pushing d1 down to d2, so the
    second is the first smallest among the rows other than the nearest's (FLT_MAX if none)."""
    hood = cells.around(_NEIGHBOURS[cells.d])
    dist = metric.full(hood.diff)
    key = np.where(dist < FLT_MAX, dist, F32(np.inf))
    k1 = np.argmin(key, axis=0)
    np.put_along_axis(key, k1[None, :], F32(np.inf), axis=0)
    k2 = np.argmin(key, axis=0)
    d2 = np.take_along_axis(key, k2[None, :], axis=0)[0]
    d2 = np.where(d2 < np.inf, d2, FLT_MAX)
    return _winner(cells, metric, hood, k2, want_color, d2)


def _smooth_f1(cells: _Cells, metric: _Metric, smoothness, want_color: bool):
    """Smooth minimum over the 5^d neighbourhood, blending distance, colour and position alike."""
    color_correction = ONE + F32(3.0) * smoothness
    dist_sm = color_sm = pos_sm = None
    for off in _SMOOTH_NEIGHBOURS[cells.d]:
        off = tuple(int(o) for o in off)
        h = cells.hash(off)
        p = cells.point(off, h)
        dist = metric.full([pc - lc for pc, lc in zip(p, cells.local)])
        color = cells.color(off, h) if want_color else ()
        if dist_sm is None:         # the first cell takes h = 1: the values themselves
            dist_sm, color_sm, pos_sm = dist, list(color), p
            continue
        t = np.clip(HALF + HALF * (dist_sm - dist) / smoothness, ZERO, ONE)
        w = (F32(3.0) - TWO * t) * (t * t)               # smoothstep(0, 1, x)
        correction = smoothness * w * (ONE - w)
        dist_sm = _mix(dist_sm, dist, w) - correction
        correction /= color_correction
        color_sm = [_mix(a, b, w) - correction for a, b in zip(color_sm, color)]
        pos_sm = [_mix(a, b, w) - correction for a, b in zip(pos_sm, p)]
    position = [fc + pc for fc, pc in zip(cells.floor, pos_sm)]
    return dist_sm, (tuple(color_sm) if want_color else None), position


def _distance_to_edge(cells: _Cells):
    if cells.d == 1:
        return _distance_to_edge_1d(cells)
    hood, k = _nearest(cells, _euclidean_sq)
    closest = _pick(hood.diff, k)
    v = hood.diff                                   # every neighbour's point - local, (K, M) each
    perp = [a - b for a, b in zip(v, closest)]
    perp_sq = _euclidean_sq(perp)
    length = np.sqrt(perp_sq)
    with np.errstate(invalid="ignore", divide="ignore"):
        dist = _sum([((c + a) / TWO) * (p / length) for c, a, p in zip(closest, v, perp)])
    valid = perp_sq > EDGE_EPSILON
    edge = np.full(cells.local[0].shape, FLT_MAX, F32)
    for row, ok in zip(dist, valid):               # Cycles' strict-< scan, first of equals kept
        np.copyto(edge, row, where=ok & (row < edge))
    return edge


def _distance_to_edge_1d(cells: _Cells):
    r, x, local = cells.randomness, cells.key, cells.local[0]
    mid = hash_float_to_float(x) * r
    left = -ONE + hash_float_to_float(x - ONE) * r
    right = ONE + hash_float_to_float(x + ONE) * r
    to_left = np.abs((mid + left) / TWO - local)
    to_right = np.abs((mid + right) / TWO - local)
    return np.where(to_right < to_left, to_right, to_left)


def _n_sphere_radius(cells: _Cells):
    """Half the distance from the nearest point to its own nearest point (Euclidean; 1D |a - b|)."""
    dist_sq = _euclidean_sq if cells.d > 1 else (lambda diff: np.abs(diff[0]))
    hood, k = _nearest(cells, dist_sq)
    centre = hood.offsets(k)
    closest = _pick(hood.point, k)

    # Then the point nearest to that one among the 3^d - 1 cells around its cell (all at once, (K, M)),
    # found as Cycles' strict-< scan from FLT_MAX finds it; 0 if none is nearer than that.
    offsets = _NEIGHBOURS[cells.d][_NEIGHBOURS[cells.d].any(axis=1)]
    around = [c + o[:, None] for c, o in zip(centre, offsets.T)]
    p = cells.point(around, cells.hash(around))
    dist = dist_sq([a - b for a, b in zip(closest, p)])
    row = _first_min(dist)
    found = np.take_along_axis(dist, row[None, :], axis=0)[0] < FLT_MAX
    nearest = [np.where(found, c, ZERO) for c in _pick(p, row)]
    diff = [a - b for a, b in zip(nearest, closest)]
    radius = np.sqrt(_euclidean_sq(diff)) if cells.d > 1 else np.abs(diff[0])
    return radius / TWO


# ---- Fractal sums ------------------------------------------------------------------------------------

def _octaves(detail, roughness):
    """Yield (i, sel) for the octaves of a fractal sum: sel indexes the hits that take octave i (None:
    all of them). Every hit takes octave 0; zero input (detail or roughness 0) stops there, others go on
    to ceil(detail)."""
    more = ~((detail == 0) | (roughness == 0))
    ceil_detail = np.ceil(detail)
    for i in range(int(np.max(ceil_detail)) + 1):
        if i == 0:
            yield i, None
            continue
        mask = more & (i <= ceil_detail)
        if np.ndim(mask) == 0:
            if not mask:
                return
            yield i, None
            continue
        if not mask.any():
            return
        yield i, (None if mask.all() else np.flatnonzero(mask))


def _store(acc, sel, value):
    if sel is None:
        acc[...] = value
    else:
        acc[sel] = value


def _fractal_fx(feature, coords, params, metric, want_color, want_position):
    """F1 / F2 / Smooth F1 summed over octaves (`fractal_voronoi_x_fx`): distance and colour add up
    with amplitude roughness^i, position lerps toward each octave's; returns them and max_amplitude."""
    n, d = len(coords[0]), len(coords)
    detail, roughness, lacunarity = params["detail"], params["roughness"], params["lacunarity"]
    distance = np.zeros(n, F32)
    color = [np.zeros(n, F32) for _ in range(3)] if want_color else None
    position = [np.zeros(n, F32) for _ in range(d)] if want_position else None
    max_amplitude = np.zeros(n, F32)
    amplitude = np.ones(n, F32)
    scale = np.ones(n, F32)
    for i, sel in _octaves(detail, roughness):
        s = _take(scale, sel)
        cells = _Cells([_take(c, sel) * s for c in coords], _take(params["randomness"], sel))
        m = metric.take(sel)
        if feature == "F2":
            od, oc, op = _in_chunks(_f2, cells, m, want_color)
        elif feature == "SMOOTH_F1":
            od, oc, op = _smooth_f1(cells, m, _take(params["smoothness"], sel), want_color)
        else:
            od, oc, op = _in_chunks(_f1, cells, m, want_color)
        amp = _take(amplitude, sel)
        sub_detail = _take(detail, sel)
        full = i <= sub_detail
        # The octave past floor(detail) enters with weight frac(detail): a lerp toward the full sum.
        rem = None if np.all(full) else sub_detail - np.floor(sub_detail)

        def blend(acc, new):
            if rem is not None:
                new = np.where(full, new, _mix(_take(acc, sel), new, rem))
            _store(acc, sel, new)

        blend(max_amplitude, _take(max_amplitude, sel) + amp)
        blend(distance, _take(distance, sel) + od * amp)
        if want_color:
            for acc, c in zip(color, oc):
                blend(acc, _take(acc, sel) + c * amp)
        if want_position:
            for acc, c in zip(position, op):
                blend(acc, _mix(_take(acc, sel), c / s, amp))
        _store(scale, sel, s * _take(lacunarity, sel))
        _store(amplitude, sel, amp * _take(roughness, sel))
    return distance, color, position, max_amplitude


def _fractal_edge(coords, params):
    """Distance to Edge over octaves (`fractal_voronoi_distance_to_edge`): a running minimum of
    distance / scale, lerped by amplitude; returns it and the max_amplitude to normalise by."""
    n = len(coords[0])
    detail, roughness, lacunarity = params["detail"], params["roughness"], params["lacunarity"]
    max_distance = params["max_distance"]
    distance = np.full(n, FIRST_DISTANCE, F32)
    max_amplitude = np.empty(n, F32)
    max_amplitude[...] = max_distance
    amplitude = np.ones(n, F32)
    scale = np.ones(n, F32)
    zero_input = (detail == 0) | (roughness == 0)
    for i, sel in _octaves(detail, roughness):
        s = _take(scale, sel)
        od = _in_chunks(_distance_to_edge, _Cells([_take(c, sel) * s for c in coords],
                                                  _take(params["randomness"], sel)))
        amp = _take(amplitude, sel)
        old_dist, old_max = _take(distance, sel), _take(max_amplitude, sel)
        new_max = _mix(old_max, _take(max_distance, sel) / s, amp)
        scaled = od / s
        new_dist = _mix(old_dist, np.where(scaled < old_dist, scaled, old_dist), amp)
        sub_detail = _take(detail, sel)
        full = i <= sub_detail
        if not np.all(full):
            rem = sub_detail - np.floor(sub_detail)
            new_max = np.where(full, new_max, _mix(old_max, new_max, rem))
            new_dist = np.where(full, new_dist,
                                _mix(old_dist, np.where(new_dist < old_dist, new_dist, old_dist), rem))
        if i == 0 and np.any(zero_input):
            new_dist = np.where(zero_input, od, new_dist)       # zero input: the octave as it is
            new_max = np.where(zero_input, old_max, new_max)
        _store(max_amplitude, sel, new_max)
        _store(distance, sel, new_dist)
        _store(scale, sel, s * _take(lacunarity, sel))
        _store(amplitude, sel, amp * _take(roughness, sel))
    return distance, max_amplitude


# ---- The node ----------------------------------------------------------------------------------------

def voronoi_texture(vector=0.0, w=0.0, scale=5.0, detail=0.0, roughness=0.5, lacunarity=2.0,
                    smoothness=1.0, exponent=0.5, randomness=1.0, *, dimensions: str = "3D",
                    feature: str = "F1", distance: str = "EUCLIDEAN", normalize: bool = False,
                    outputs=None) -> dict:
    """Cycles' Voronoi Texture at N hits.

    vector : (N, 3) float32 (or a constant (3,)); w, scale, detail, roughness, lacunarity, smoothness,
        exponent, randomness : (N,) float32 or constants. Defaults are Blender's.
    dimensions "1D".."4D", feature (FEATURES), distance (METRICS), normalize: the node's options.
    outputs : names to compute (default: the sockets Blender shows, `available_outputs`); a name the
        feature does not produce comes back as zeros, as Cycles writes it.
    Returns {"Distance": (N,), "Color": (N, 3), "Position": (N, 3), "W": (N,), "Radius": (N,)} (those
    asked for), float32.
    """
    d = DIMENSIONS[dimensions]
    if feature not in FEATURES or distance not in METRICS:
        raise ValueError(f"unknown Voronoi option {feature!r} / {distance!r}")
    wanted = set(available_outputs(dimensions, feature) if outputs is None else outputs)

    vec = np.asarray(vector, F32)
    vec = np.broadcast_to(vec, (1, 3)) if vec.size == 1 else vec.reshape(-1, 3)
    w, scale = _param(w), _param(scale)
    params = {"detail": np.clip(_param(detail), ZERO, F32(15.0)),
              "roughness": np.clip(_param(roughness), ZERO, ONE),
              "lacunarity": _param(lacunarity),
              "smoothness": np.clip(_param(smoothness) / TWO, ZERO, HALF),
              "randomness": np.clip(_param(randomness), ZERO, ONE)}
    exponent = _param(exponent)
    lengths = [len(a) for a in (vec, w, scale, exponent, *params.values()) if a.ndim > 0 and a.size != 1]
    n = max(lengths, default=1)
    if n == 0:
        return {name: np.zeros((0, 3) if name in ("Color", "Position") else 0, F32) for name in wanted}

    # Coordinates: x, y, z scaled (2D uses x, y), then w for 1D and 4D.
    coords = [np.broadcast_to(vec[:, k] * scale, (n,)) for k in range(min(d, 3))] if d > 1 else []
    if d in (1, 4):
        coords.append(np.broadcast_to(w * scale, (n,)))
    coords = [np.ascontiguousarray(c, F32) for c in coords]

    result = {}
    if feature == "DISTANCE_TO_EDGE":
        params["max_distance"] = HALF + HALF * params["randomness"]
        if "Distance" in wanted:
            dist, max_amplitude = _fractal_edge(coords, params)
            result["Distance"] = dist / max_amplitude if normalize else dist
    elif feature == "N_SPHERE_RADIUS":
        if "Radius" in wanted:
            result["Radius"] = _in_chunks(_n_sphere_radius, _Cells(coords, params["randomness"]))
    else:
        metric = _Metric(d, distance, exponent)
        want_color = "Color" in wanted
        want_position = bool(wanted & {"Position", "W"})
        if feature == "SMOOTH_F1" and np.any(params["smoothness"] == 0):
            dist, color, position, max_amplitude = _smooth_split(coords, params, metric, want_color,
                                                                 want_position)
        else:
            dist, color, position, max_amplitude = _fractal_fx(feature, coords, params, metric,
                                                               want_color, want_position)
        if normalize:
            max_distance = metric.max_distance(params["randomness"]) * (TWO if feature == "F2" else ONE)
            dist = dist / (max_amplitude * max_distance)
            if want_color:
                color = [c / max_amplitude for c in color]
        if "Distance" in wanted:
            result["Distance"] = dist
        if want_color:
            result["Color"] = np.stack(color, axis=1)
        if want_position:
            with np.errstate(invalid="ignore", divide="ignore"):
                position = [np.where(scale != 0, c / scale, ZERO).astype(F32, copy=False)
                            for c in position]
            if "Position" in wanted:
                xyz_out = position[:3] if d > 1 else []
                xyz_out = xyz_out[:3] + [np.zeros(n, F32)] * (3 - len(xyz_out[:3]))
                result["Position"] = np.stack(xyz_out, axis=1)
            if "W" in wanted:
                result["W"] = position[-1] if d in (1, 4) else np.zeros(n, F32)

    for name in wanted - set(result):
        result[name] = np.zeros((n, 3) if name in ("Color", "Position") else n, F32)
    return result


def _smooth_split(coords, params, metric, want_color, want_position):
    """Smooth F1 where some hits have smoothness 0: those hits take F1 (as Cycles does), the rest
    Smooth F1; each group runs on its own hits and the results are scattered back."""
    n = len(coords[0])
    smooth = params["smoothness"] != 0
    outs = None
    for feature, mask in (("SMOOTH_F1", smooth), ("F1", ~smooth)):
        sel = np.flatnonzero(np.broadcast_to(mask, (n,)))
        if len(sel) == 0:
            continue
        sub = {k: _take(v, sel) for k, v in params.items()}
        part = _fractal_fx(feature, [c[sel] for c in coords], sub, metric.take(sel), want_color,
                           want_position)
        if outs is None:
            outs = [None if p is None else ([np.zeros(n, F32) for _ in p] if isinstance(p, list)
                                            else np.zeros(n, F32)) for p in part]
        for acc, p in zip(outs, part):
            if isinstance(p, list):
                for a, c in zip(acc, p):
                    a[sel] = c
            elif p is not None:
                acc[sel] = p
    return tuple(outs)
