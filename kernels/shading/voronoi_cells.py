"""One octave of Cycles' Voronoi texture over arrays of hits (`kernel/svm/voronoi.h`): the unit cells
around the hits (Cells), their hashed points, and the features over them (f1, f2, smooth_f1,
distance_to_edge, n_sphere_radius) under a distance Metric. kernels.shading.voronoi sums the octaves
and is the node.

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
gathered. Smooth F1 runs neighbour by neighbour over all hits, so memory stays O(N): its 5^d
neighbourhood as one table would be 625 rows per hit in 4D.
"""
from __future__ import annotations

import itertools

import numpy as np

from ..vec import F32, HALF, I32, ONE, TWO, ZERO
from .cycles_math import interp
from .hash import (hash_float_to_float, hash_float_to_float3, hash_int2_to_float2, hash_int2_to_float3,
                   hash_int3_to_float3, hash_int4_to_float4, hash_int_to_float_grid, thread_scratch)

FLT_MAX = F32(np.finfo(np.float32).max)
EDGE_EPSILON = F32(0.0001)        # bisectors of points closer than sqrt of this are skipped
_CHUNK = 1 << 16                   # neighbour values per (K, hits) array (a chunk of hits)


def _offsets(d: int, reach: int) -> np.ndarray:
    """(K, d) int32 neighbour offsets in [-reach, reach]^d, in Cycles' loop order (x varies fastest)."""
    rows = [t[::-1] for t in itertools.product(range(-reach, reach + 1), repeat=d)]
    return np.array(rows, I32).reshape(-1, d)


_NEIGHBOURS = {d: _offsets(d, 1) for d in (1, 2, 3, 4)}
_SMOOTH_NEIGHBOURS = {d: _offsets(d, 2) for d in (1, 2, 3, 4)}


# ---- Parameters and sums -----------------------------------------------------------------------------

def take(a: np.ndarray, sel):
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


# ---- Distances ---------------------------------------------------------------------------------------

class Metric:
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
        return Metric(self.d, self.metric, self.exponent[sel])

    def max_distance(self, randomness):
        """The distance from the origin to (½ + ½ randomness)(1, ..., 1): the normalisation of F1."""
        r = HALF + HALF * randomness
        return self.full([r] * self.d) if self.d > 1 else r


def _euclidean_sq(diff):
    return _sum([c * c for c in diff])


# ---- The lattice of one octave -----------------------------------------------------------------------

class Cells:
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

    def part(self, lo: int, hi: int) -> "Cells":
        """The same cells for hits lo:hi."""
        part = Cells.__new__(Cells)
        part.d, part.randomness = self.d, take(self.randomness, slice(lo, hi))
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

    def __init__(self, cells: Cells, table: np.ndarray):
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


def in_chunks(fn, cells: Cells, *args):
    """fn(cells, *args) for chunks of the hits small enough that its neighbour tables (3^d, chunk) stay
    in cache, the results joined (a Metric among args is cut with the hits)."""
    m, step = len(cells.local[0]), max(_CHUNK // 3 ** cells.d, 1)
    if m <= step:
        return fn(cells, *args)
    parts = [fn(cells.part(lo, lo + step), *(a.take(slice(lo, lo + step)) if isinstance(a, Metric) else a
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

def _nearest(cells: Cells, distance_of):
    """Each hit's nearest neighbour cell under distance_of (per-component point - local -> (K, M)) as
    its row in the neighbour table: the first of equals, as Cycles' strict-< scan in its loop order."""
    hood = cells.around(_NEIGHBOURS[cells.d])
    return hood, _first_min(distance_of(hood.diff))


def f1(cells: Cells, metric: Metric, want_color: bool):
    hood, k = _nearest(cells, metric.bound)
    return _winner(cells, metric, hood, k, want_color, None)


def _winner(cells: Cells, metric: Metric, hood: _Hood, k, want_color: bool, distance):
    """Distance (unless given), colour and position of each hit's neighbour at row k of the hood."""
    p = _pick(hood.point, k)
    if distance is None:
        distance = metric.full(_pick(hood.diff, k))
    color = None
    if want_color:
        color = tuple(_pick(hood.hash[:3], k)) if cells.d >= 3 else cells.color(hood.offsets(k))
    position = [pc + fc for pc, fc in zip(p, cells.floor)]
    return distance, color, position


def f2(cells: Cells, metric: Metric, want_color: bool):
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


def smooth_f1(cells: Cells, metric: Metric, smoothness, want_color: bool):
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
        dist_sm = interp(dist_sm, dist, w) - correction
        correction /= color_correction
        color_sm = [interp(a, b, w) - correction for a, b in zip(color_sm, color)]
        pos_sm = [interp(a, b, w) - correction for a, b in zip(pos_sm, p)]
    position = [fc + pc for fc, pc in zip(cells.floor, pos_sm)]
    return dist_sm, (tuple(color_sm) if want_color else None), position


def distance_to_edge(cells: Cells):
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


def _distance_to_edge_1d(cells: Cells):
    r, x, local = cells.randomness, cells.key, cells.local[0]
    mid = hash_float_to_float(x) * r
    left = -ONE + hash_float_to_float(x - ONE) * r
    right = ONE + hash_float_to_float(x + ONE) * r
    to_left = np.abs((mid + left) / TWO - local)
    to_right = np.abs((mid + right) / TWO - local)
    return np.where(to_right < to_left, to_right, to_left)


def n_sphere_radius(cells: Cells):
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
