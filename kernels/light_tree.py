"""A light tree: per-shading-point selection among the local emitters (lights with a position and
emissive triangles), after Cycles' light tree (Estevez and Kulla's many-lights importance). Ember's own, for
unclamped renders (less noisy than Cycles'); a clamped render chooses as Cycles' own tree
(kernels.light_tree_cycles, which walks each emissive object's triangles in this tree from the object's subtree,
unit_root).

The tree is a binary BVH over the emitters' boxes, built once per scene in two levels, as Cycles builds
its: the emitters of a group (the emissive triangles of one object, or of one instance) stand together
as one unit beside the lone emitters (lights), the units are split at their centroids' median along
the longest extent until each stands alone, and a group's unit then splits the same way over its own
emitters. A lamp beside a large emissive mesh thus competes with the mesh as a whole near the top of the
tree, not with thousands of its triangles one level after another. Leaves hold one emitter. Each node
keeps its box, its power (the sum of its emitters') and a cone bounding the directions its emitters emit
around (axis, spread theta_o) and the angle beyond it where it lights nothing (theta_e: pi/2 for surfaces).

At a shading point P a walk from the root picks a child with probability in proportion to an upper bound
of the light it can send P,
    I_max = power * cos(max(0, theta - theta_o - theta_u)) / max(d, r / 2)^2,
with d the distance from the box centre to P, r the radius of the box's bounding sphere (Cycles clamps
the distance at r / 2 too), theta the angle between the cone axis and the direction from the box centre
to P and theta_u the half angle the bounding sphere subtends at P (pi inside it); the cosine is 0 beyond
pi/2 (every emitter of the node faces away from P) and at least COS_FLOOR before (rounding never starves
an emitter that can light P); nodes whose emitters emit every way have no orientation factor.
Where the choice is between units and a group is among them, the probability is instead the mean of that
choice and the one by a lower bound,
    I_min = power * cos(theta + theta_o + theta_u) / (d + r)^2, and 0 when P is inside the sphere,
as Cycles chooses everywhere (kernel/light/tree.h; the lower bound's share goes by the upper one where
both children's lower bounds are 0): the upper bound of a mesh P stands on counts the triangles beside
P, which send it little, and alone starves a lamp next to it. Among lamps, and within a mesh, the upper
bound alone is the better guide (100 lamps over a floor: a third of the variance per sample of the
mean). Where the point's normal N is given (`facing`: the shading normal of a surface point, and whether its
closures transmit; the MIS pdfs of BSDF rays get the normal of the vertex the ray left, as Cycles keeps
mis_origin_n), both bounds take Cycles' incidence factor (light_tree_importance): with theta_i the angle
between N and the direction to the box centre (its absolute cosine where the closures transmit),
    I_max x cos(max(theta_i - theta_u, 0)),   I_min x max(cos(theta_i + theta_u), 0),
and a node wholly behind an opaque point (theta_i - theta_u beyond pi/2) gets 0: two lamps on either side of
a wall no longer share its samples. A zero normal (a point in a medium) has no such factor.
Where both children have no upper bound the walk goes by power, so every emitter with power
that can light P keeps a non-zero probability, and `pmf(e, P)`, the product of the child probabilities on
e's root path, is exactly the probability the walk chose e with.
"""
from __future__ import annotations

import numpy as np

from .vec import HALF_PI, PI

# Below this cosine of theta' (but in front of the cone), the orientation factor is held here: a box at
# a grazing angle still lights P, and float32 rounding of the angles must not make it unreachable.
COS_FLOOR = np.float32(1e-3)


class LightTree:
    """Selection among n local emitters by a walk down a BVH of their boxes, power and orientation.

    lo, hi : (n, 3) float64 emitter bounding boxes; power : (n,) float64 (> 0);
    axis : (n, 3) unit emission axes; spread : (n,) float64 theta_o (pi: emits every way);
    group : (n,) int64 or None: emitters with the same non-negative group number (an emissive object's
    triangles) form a subtree of their own; -1, or None for all, stands alone.
    emission : (n,) float64 theta_e, the angle beyond the cone where the emitter no longer lights anything
    (pi / 2 for surfaces, a spot light's half angle, half an area light's Spread), or None for pi / 2 everywhere
    (Cycles' theta_e)."""

    def __init__(self, lo, hi, power, axis, spread, group=None, emission=None):
        n = len(power)
        centroid = 0.5 * (lo + hi)
        # Centroids snapped to a grid far finer than any useful split: copies of a scene that differ by
        # float rounding only (an instance and its flattened copy) build the same tree, ties by index.
        cell = max(float(np.abs(centroid).max(initial=0.0)), 1e-3) * 2.0 ** -14
        unit = _units(group, n)
        self.unit = unit                                       # (n,) each emitter's unit
        self.units = int(unit.max(initial=-1)) + 1
        unit_lo = np.full((self.units, 3), np.inf)
        unit_hi = np.full_like(unit_lo, -np.inf)
        np.minimum.at(unit_lo, unit, lo)
        np.maximum.at(unit_hi, unit, hi)
        unit_centroid = np.round(0.5 * (unit_lo + unit_hi) / cell)
        nodes = _build(np.round(centroid / cell), unit_centroid, unit)
        self.left, self.right, self.parent, self.emitter_at, level, splits_units = nodes
        self.depth = max(int(level.max(initial=0)), 1)
        count = len(self.left)
        n_lo, n_hi = np.zeros((count, 3)), np.zeros((count, 3))
        n_power, n_axis, n_spread = np.zeros(count), np.zeros((count, 3)), np.full(count, np.pi)
        n_emission = np.full(count, HALF_PI, np.float64)
        leaf = np.flatnonzero(self.emitter_at >= 0)
        e = self.emitter_at[leaf]
        n_lo[leaf], n_hi[leaf], n_power[leaf], n_axis[leaf], n_spread[leaf] = lo[e], hi[e], power[e], axis[e], spread[e]
        if emission is not None:
            n_emission[leaf] = emission[e]
        self.leaf_of = np.full(n, -1, np.int64)
        self.leaf_of[e] = leaf
        grouped = np.zeros(count, bool)                        # the subtree holds a group's emitters
        grouped[leaf] = np.bincount(unit, minlength=self.units)[unit[e]] > 1
        for depth in range(int(level.max(initial=0)) - 1, -1, -1):      # bottom-up unions
            k = np.flatnonzero((level == depth) & (self.left >= 0))
            a, b = self.left[k], self.right[k]
            n_lo[k] = np.minimum(n_lo[a], n_lo[b])
            n_hi[k] = np.maximum(n_hi[a], n_hi[b])
            n_power[k] = n_power[a] + n_power[b]
            grouped[k] = grouped[a] | grouped[b]
            n_axis[k], n_spread[k] = _merge_cones(n_axis[a], n_spread[a], n_power[a] > 0,
                                                  n_axis[b], n_spread[b], n_power[b] > 0)
            n_emission[k] = np.maximum(np.where(n_power[a] > 0, n_emission[a], 0.0),
                                       np.where(n_power[b] > 0, n_emission[b], 0.0))
        empty = n_power <= 0
        n_lo[empty], n_hi[empty] = 0.0, 0.0
        centre = 0.5 * (n_lo + n_hi)
        radius = 0.5 * np.linalg.norm(n_hi - n_lo, axis=1)
        extent = max(float(np.abs(n_hi[~empty]).max(initial=0.0)), float(np.abs(n_lo[~empty]).max(initial=0.0)), 1e-3)
        # A floor under distance^2 far below any light's size: a point on a zero-size lamp stays finite.
        floor2 = (extent * 1e-6) ** 2
        # One row per node, gathered whole: centre, cone axis, relative power, (r / 2)^2 (floored), radius,
        # spread, emits every way.
        table = np.zeros((count, 12), np.float32)
        table[:, 0:3] = centre
        table[:, 3:6] = n_axis
        table[:, 6] = n_power / max(n_power[0], 1e-300)       # relative: float32 never overflows
        table[:, 7] = np.maximum(0.25 * radius * radius, floor2)
        table[:, 8] = radius
        table[:, 9] = n_spread
        table[:, 10] = n_spread >= np.pi                       # emits every way: no orientation factor
        table[:, 11] = n_emission
        self._table = table
        # Where units of which one or more is a group are chosen between, the lower bounds count too.
        self._blend = splits_units & grouped
        inner = np.flatnonzero(self.left >= 0)
        # Each unit's own subtree: the highest node holding its emitters alone (kernels.light_tree_cycles walks
        # an emissive object's triangles from there).
        owner = np.full(count, -1, np.int64)
        owner[leaf] = unit[e]
        for depth in range(int(level.max(initial=0)) - 1, -1, -1):
            k = np.flatnonzero((level == depth) & (self.left >= 0))
            a, b = owner[self.left[k]], owner[self.right[k]]
            owner[k] = np.where((a == b) & (a >= 0), a, -1)
        parent_owner = np.where(self.parent >= 0, owner[np.maximum(self.parent, 0)], -1)
        tops = np.flatnonzero((owner >= 0) & (parent_owner != owner))
        self.unit_root = np.zeros(self.units, np.int64)
        self.unit_root[owner[tops]] = tops
        self._left_power = np.full(count, 0.5)
        with np.errstate(divide="ignore", invalid="ignore"):
            self._left_power[inner] = np.nan_to_num(n_power[self.left[inner]] / n_power[inner], nan=0.5)

    def cone_of(self, node):
        """(axis (K, 3), theta_o (K,), theta_e (K,)) float64 of nodes node (K,): the cone bounding their emitters."""
        t = self._table.take(node, axis=0).astype(np.float64)
        return t[:, 3:6], np.minimum(t[:, 9], np.pi), t[:, 11]

    # ------------------------------------------------------------------ importance
    def _bounds(self, node, px, py, pz, facing=None):
        """float32 upper and lower bounds of the light node[i] can send point i (module docstring), node (N,)
        or (K, N) (the points then stand for every row); facing: (nx, ny, nz, two_sided) of the points, or None."""
        g = self._table.take(node, axis=0)                  # rows gathered whole (far faster than by column)
        g = g.transpose(g.ndim - 1, *range(g.ndim - 1))     # (12, *node.shape) views
        vx, vy, vz = px - g[0], py - g[1], pz - g[2]
        d2 = vx * vx + vy * vy + vz * vz
        r = g[8]
        outside = d2 > r * r
        d = np.sqrt(d2)
        upper = g[6] / np.maximum(d2, g[7])
        reach = d + r
        lower = np.where(outside, g[6] / np.maximum(reach * reach, g[7]), np.float32(0.0))
        inv_d = np.float32(1.0) / np.maximum(d, np.float32(1e-30))
        if facing is not None:
            upper, lower = _incidence(upper, lower, facing, vx * inv_d, vy * inv_d, vz * inv_d, r * inv_d)
        omni = g[10] > 0
        if omni.all():
            return upper, lower
        cos_t = np.clip((vx * g[3] + vy * g[4] + vz * g[5]) * inv_d, np.float32(-1.0), np.float32(1.0))
        sin_u = r * inv_d
        theta_u = np.where(sin_u < 1, np.arcsin(np.minimum(sin_u, np.float32(1.0))), PI)
        theta = np.arccos(cos_t)
        theta_p = np.maximum(theta - g[9] - theta_u, np.float32(0.0))
        # theta_p = 0 lights P whatever theta_e (an area light of Spread 0 has theta_e = 0: Cycles' first case).
        nearest = np.where((theta_p <= 0) | (theta_p < g[11]), np.maximum(np.cos(theta_p), COS_FLOOR), np.float32(0.0))
        theta_f = theta + g[9] + theta_u
        farthest = np.where(theta_f < g[11], np.cos(np.minimum(theta_f, HALF_PI)), np.float32(0.0))
        return np.where(omni, upper, upper * nearest), np.where(omni, lower, lower * farthest)

    def _left_probability(self, node, px, py, pz, facing=None):
        """(N,) float64 probability of going to the left child of internal node[i] at point i."""
        # Both children's bounds in one pass, as (2, N) rows over which the points' own arrays broadcast
        # (elementwise: the same values as two passes, at half NumPy's per-call cost on the few points deep
        # levels hold, and what depends on the point alone is computed once).
        both = np.stack((self.left.take(node), self.right.take(node)))         # (2, N): the points broadcast
        upper, lower = (x.astype(np.float64) for x in self._bounds(both, px, py, pz, facing))
        (a_max, b_max), (a_min, b_min) = upper, lower
        total_max, total_min = a_max + b_max, a_min + b_min
        with np.errstate(divide="ignore", invalid="ignore"):
            p = a_max / total_max
            blend = self._blend.take(node) & (total_min > 0)
            p = np.where(blend, 0.5 * (p + a_min / np.where(blend, total_min, 1.0)), p)
        ok = (total_max > 0) & np.isfinite(p)
        if ok.all():
            return p
        return np.where(ok, p, self._left_power.take(node))

    # ------------------------------------------------------------------ sampling and pmf
    def sample(self, u, px, py, pz, facing=None, start=None):
        """Walk down for each point with u (N,) in [0, 1). Returns (emitter (N,) int64, pmf (N,) float64).
        facing: (nx, ny, nz, two_sided) (N,) each, the points' normals and whether they transmit, or None;
        start: (N,) the nodes the walks start from (None: the root), the pmf then the walk's below them."""
        u = np.asarray(u, np.float64).copy()
        node = np.zeros(len(u), np.int64) if start is None else np.asarray(start, np.int64).copy()
        pmf = np.ones(len(u))
        # The points still walking, compacted as points reach their leaves (each point's arithmetic is
        # the same as over the whole set; gathers shrink with the set).
        walking = np.arange(len(u))
        w_node, w_u, w_pmf = node, u, pmf
        w_points = (px, py, pz) if facing is None else (px, py, pz, *facing)
        for _ in range(self.depth):
            inner = self.left.take(w_node) >= 0
            if not inner.all():
                node[walking], u[walking], pmf[walking] = w_node, w_u, w_pmf
                keep = np.flatnonzero(inner)
                walking = walking.take(keep)
                if not len(walking):
                    break
                w_node, w_u, w_pmf = w_node.take(keep), w_u.take(keep), w_pmf.take(keep)
                w_points = tuple(c.take(keep) for c in w_points)
            p_left = self._left_probability(w_node, *w_points[:3], None if facing is None else w_points[3:])
            left = w_u < p_left
            prob = np.where(left, p_left, 1.0 - p_left)
            # Reuse u within the chosen child (float64: 53 bits last a walk of a few dozen levels).
            uw = np.where(left, w_u, w_u - p_left) / np.where(prob > 0, prob, 1.0)
            w_u = np.clip(uw, 0.0, np.nextafter(1.0, 0.0))
            w_pmf = w_pmf * prob
            w_node = np.where(left, self.left.take(w_node), self.right.take(w_node))
        else:
            node[walking], pmf[walking] = w_node, w_pmf
        return self.emitter_at.take(node), pmf

    def pmf(self, emitter, px, py, pz, facing=None, stop=None):
        """(N,) float64 probability that the walk from point i picks emitter[i] (0 for emitters not in it); stop:
        (N,) nodes (above the emitters) the walks started from (None: the root)."""
        emitter = np.asarray(emitter)
        leaf = np.where(emitter >= 0, self.leaf_of.take(np.maximum(emitter, 0)), -1)
        known = leaf >= 0
        pmf = np.ones(len(leaf))
        # The points still climbing, compacted as points reach the root (as in sample).
        climbing = np.flatnonzero(known)
        c_node = leaf.take(climbing)
        c_pmf = pmf.take(climbing)
        c_points = tuple(c.take(climbing) for c in ((px, py, pz) if facing is None else (px, py, pz, *facing)))
        c_stop = None if stop is None else np.asarray(stop, np.int64).take(climbing)
        for _ in range(self.depth):
            parent = self.parent.take(c_node)
            has = parent >= 0 if c_stop is None else (parent >= 0) & (c_node != c_stop)
            if not has.all():
                pmf[climbing] = c_pmf
                keep = np.flatnonzero(has)
                climbing = climbing.take(keep)
                if not len(climbing):
                    break
                c_node, c_pmf, parent = c_node.take(keep), c_pmf.take(keep), parent.take(keep)
                c_points = tuple(c.take(keep) for c in c_points)
                if c_stop is not None:
                    c_stop = c_stop.take(keep)
            p_left = self._left_probability(parent, *c_points[:3], None if facing is None else c_points[3:])
            c_pmf = c_pmf * np.where(self.left.take(parent) == c_node, p_left, 1.0 - p_left)
            c_node = parent
        else:
            pmf[climbing] = c_pmf
        return np.where(known, pmf, 0.0)

    def pmf_all(self, px, py, pz):
        """(N, n) probabilities of every emitter at each point (for tests: rows sum to 1)."""
        n = len(self.leaf_of)
        m = len(px)
        e = np.tile(np.arange(n), m)
        rep = (np.repeat(c, n) for c in (px, py, pz))
        return self.pmf(e, *rep).reshape(m, n)


def rows_of(facing, idx):
    """The facing tuple of the points idx only (None stays None)."""
    return None if facing is None else tuple(np.take(c, idx) for c in facing)


def _incidence(upper, lower, facing, tx, ty, tz, sin_u):
    """The bounds times Cycles' incidence factor (module docstring): (tx, ty, tz) the unit direction from the box
    centre to the points, sin_u the sine of the half angle the box's sphere subtends (1 or more inside it)."""
    nx, ny, nz, two_sided = facing
    cos_i = -(tx * nx + ty * ny + tz * nz)
    cos_i = np.where(two_sided, np.abs(cos_i), cos_i)
    sin_i = np.sqrt(np.maximum(np.float32(1.0) - cos_i * cos_i, np.float32(0.0)))
    cos_u = np.where(sin_u < 1, np.sqrt(np.maximum(np.float32(1.0) - sin_u * sin_u, np.float32(0.0))),
                     np.float32(-1.0))
    sin_u = np.minimum(sin_u, np.float32(1.0))
    cc, ss = cos_i * cos_u, sin_i * sin_u
    c_min = np.where(cos_i >= cos_u, np.float32(1.0), cc + ss)
    c_max = np.maximum(cc - ss, np.float32(0.0))
    # A zero normal (a point in a medium) has no incidence factor.
    free = (nx == 0) & (ny == 0) & (nz == 0)
    c_min = np.where(free, np.float32(1.0), np.maximum(c_min, np.float32(0.0)))
    c_max = np.where(free, np.float32(1.0), c_max)
    return upper * c_min, lower * c_max


def _units(group, n: int) -> np.ndarray:
    """(n,) int64 unit of each emitter: one per group of two or more emitters, one per lone emitter."""
    if group is None:
        return np.arange(n, dtype=np.int64)
    group = np.asarray(group, np.int64)
    keys, inverse, counts = np.unique(group, return_inverse=True, return_counts=True)
    alone = (keys[inverse] < 0) | (counts[inverse] < 2)
    key = np.where(alone, -1 - np.arange(n), inverse)                  # lone emitters: keys of their own
    return np.unique(key, return_inverse=True)[1].astype(np.int64)


def _build(centroid, unit_centroid, unit):
    """The tree's nodes, top-down, a level at a time: (left, right, parent, emitter_at, level) (K,) int64
    each, -1 for none, and (K,) bool: the node splits units; node 0 is the root. A node holding several
    units splits them (whole) at the median of their centroids along those centroids' longest extent; a
    node holding one unit of several emitters splits the emitters likewise at theirs; a node of one emitter
    is a leaf."""
    n = len(centroid)
    perm = np.lexsort((np.arange(n), unit))                            # each unit's emitters side by side
    size = max(2 * n - 1, 1)                                           # a binary tree of n leaves
    left, right, parent, emitter_at = (np.full(size, -1, np.int64) for _ in range(4))
    level = np.zeros(size, np.int64)
    splits_units = np.zeros(size, bool)
    start, count, node = np.zeros(1, np.int64), np.full(1, n, np.int64), np.zeros(1, np.int64)
    made, depth = 1, 0
    while len(start) and n:
        single = count == 1
        emitter_at[node[single]] = perm[start[single]]
        start, count, node = start[~single], count[~single], node[~single]
        if not len(start):
            break
        seg = np.repeat(np.arange(len(start)), count)
        first = np.cumsum(count) - count
        pos = np.arange(int(count.sum())) - np.repeat(first, count) + np.repeat(start, count)
        e = perm[pos]
        u = unit[e]
        units = np.add.reduceat(_starts(u, seg).astype(np.int64), first)
        by_unit = units > 1
        c = np.where(by_unit[seg][:, None], unit_centroid[u], centroid[e])
        axis = np.argmax(np.maximum.reduceat(c, first, axis=0) - np.minimum.reduceat(c, first, axis=0), axis=1)
        key = c[np.arange(len(pos)), axis[seg]]
        order = np.lexsort((np.arange(len(pos)), u, key, seg))          # stable; a unit stays whole
        perm[pos] = e[order]
        starts = np.cumsum(_starts(u[order], seg))
        rank = starts - np.repeat(starts[first], count)                  # each position's unit, 0 first
        in_left_units = np.add.reduceat((rank < np.repeat((units + 1) // 2, count)).astype(np.int64), first)
        left_count = np.where(by_unit, in_left_units, (count + 1) // 2)
        depth += 1
        a = made + 2 * np.arange(len(start))
        made += 2 * len(start)
        left[node], right[node] = a, a + 1
        splits_units[node] = by_unit
        parent[a], parent[a + 1] = node, node
        level[a], level[a + 1] = depth, depth
        start = np.stack([start, start + left_count], axis=1).ravel()
        count = np.stack([left_count, count - left_count], axis=1).ravel()
        node = np.stack([a, a + 1], axis=1).ravel()
    return left, right, parent, emitter_at, level, splits_units


def _starts(u, seg) -> np.ndarray:
    """(m,) bool: where a new unit begins in the segments' concatenated positions."""
    new = np.ones(len(u), bool)
    new[1:] = (u[1:] != u[:-1]) | (seg[1:] != seg[:-1])
    return new


def _merge_cones(axis_a, spread_a, has_a, axis_b, spread_b, has_b):
    """Cone bounding two cones (per row): the axis halfway (power-blind), the spread the larger of
    angle(axis, child axis) + child spread; a missing child leaves the other's cone as it is."""
    mean = axis_a + axis_b
    norm = np.linalg.norm(mean, axis=1)
    ok = norm > 1e-6
    axis = np.where(ok[:, None], mean / np.where(ok, norm, 1.0)[:, None], axis_a)
    angle_a = np.arccos(np.clip(np.sum(axis * axis_a, axis=1), -1.0, 1.0)) + spread_a
    angle_b = np.arccos(np.clip(np.sum(axis * axis_b, axis=1), -1.0, 1.0)) + spread_b
    spread = np.where(ok, np.maximum(angle_a, angle_b), np.pi)
    spread = np.minimum(spread, np.pi)
    axis = np.where((has_a & ~has_b)[:, None], axis_a, np.where((has_b & ~has_a)[:, None], axis_b, axis))
    spread = np.where(has_a & ~has_b, spread_a, np.where(has_b & ~has_a, spread_b, spread))
    return axis, spread
