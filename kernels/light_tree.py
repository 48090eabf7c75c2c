"""A light tree: per-shading-point selection among the local emitters (lights with a position and
emissive triangles), after Cycles' light tree (Estevez and Kulla's many-lights importance).

The tree is a binary BVH over the emitters' boxes, built once per scene by splitting the centroids at a
quantile along their longest extent, left-complete: with 2^D leaf slots for n emitters (D the smallest
depth with 2^D >= n), every emitter sits at depth D and empty slots have no power. Each node keeps its box,
its power (the sum of its emitters') and a cone bounding the directions its emitters emit around
(axis, spread theta_o; every emitter lights the half-space in front of its normal, theta_e = pi/2).

At a shading point P a walk from the root picks a child with probability proportional to its importance
    I(node, P) = power * cos(theta') / max(distance^2, radius^2),
    theta' = max(0, theta - theta_o - theta_u),
theta the angle between the cone axis and the direction from the box centre to P, theta_u the half angle
the box's bounding sphere subtends at P (pi inside it), the cosine 0 beyond pi/2 (every emitter of the
node faces away from P: it cannot light P) and at least COS_FLOOR before (rounding never starves an
emitter that can). The importance depends on P only, not on a normal: the MIS pdfs of BSDF rays know only
the ray origin. Where both children have no importance the walk goes by power, so every emitter with power
that can light P keeps a non-zero probability, and `pmf(e, P)`, the product of the child probabilities on
e's root path, is exactly the probability the walk chose e with.
"""
from __future__ import annotations

import numpy as np

# Below this cosine of theta' (but in front of the cone), the orientation factor is held here: a box at
# a grazing angle still lights P, and float32 rounding of the angles must not make it unreachable.
COS_FLOOR = np.float32(1e-3)
_HALF_PI = np.float32(np.pi / 2)
_PI = np.float32(np.pi)


class LightTree:
    """Selection among n local emitters by a walk down a BVH of their boxes, power and orientation.

    lo, hi : (n, 3) float64 emitter bounding boxes; power : (n,) float64 (> 0);
    axis : (n, 3) unit emission axes; spread : (n,) float64 theta_o (pi: emits every way)."""

    def __init__(self, lo, hi, power, axis, spread):
        n = len(power)
        depth = max(int(np.ceil(np.log2(max(n, 1)))), 1)
        self.depth = depth
        centroid = 0.5 * (lo + hi)
        # Centroids snapped to a grid far finer than any useful split: copies of a scene that differ by
        # float rounding only (an instance and its flattened copy) build the same tree, ties by index.
        cell = max(float(np.abs(centroid).max(initial=0.0)), 1e-3) * 2.0 ** -14
        order = _split_order(np.round(centroid / cell), depth)  # (2^depth,) emitter per leaf slot, -1 empty
        leaves = 1 << depth
        first_leaf = leaves - 1                                # heap layout: children of k are 2k+1, 2k+2
        nodes = 2 * leaves - 1
        n_lo = np.full((nodes, 3), np.inf)
        n_hi = np.full((nodes, 3), -np.inf)
        n_power = np.zeros(nodes)
        n_axis = np.zeros((nodes, 3))
        n_spread = np.full(nodes, np.pi)
        full = order >= 0
        slots = first_leaf + np.flatnonzero(full)
        e = order[full]
        n_lo[slots], n_hi[slots], n_power[slots] = lo[e], hi[e], power[e]
        n_axis[slots], n_spread[slots] = axis[e], spread[e]
        self.leaf_of = np.full(n, -1, np.int64)
        self.leaf_of[e] = slots
        self.emitter_at = np.full(nodes, -1, np.int64)
        self.emitter_at[slots] = e
        for level in range(depth - 1, -1, -1):                 # bottom-up unions
            k = np.arange((1 << level) - 1, (1 << (level + 1)) - 1)
            a, b = 2 * k + 1, 2 * k + 2
            n_lo[k] = np.minimum(n_lo[a], n_lo[b])
            n_hi[k] = np.maximum(n_hi[a], n_hi[b])
            n_power[k] = n_power[a] + n_power[b]
            n_axis[k], n_spread[k] = _merge_cones(n_axis[a], n_spread[a], n_power[a] > 0,
                                                  n_axis[b], n_spread[b], n_power[b] > 0)
        empty = n_power <= 0
        n_lo[empty], n_hi[empty] = 0.0, 0.0
        centre = 0.5 * (n_lo + n_hi)
        radius = 0.5 * np.linalg.norm(n_hi - n_lo, axis=1)
        extent = max(float(np.abs(n_hi[~empty]).max(initial=0.0)), float(np.abs(n_lo[~empty]).max(initial=0.0)), 1e-3)
        # A floor under distance^2 far below any light's size: a point on a zero-size lamp stays finite.
        floor2 = (extent * 1e-6) ** 2
        # One row per node, gathered whole: centre, cone axis, relative power, radius^2 (floored), radius,
        # spread, emits every way.
        table = np.zeros((nodes, 12), np.float32)
        table[:, 0:3] = centre
        table[:, 3:6] = n_axis
        table[:, 6] = n_power / max(n_power[0], 1e-300)       # relative: float32 never overflows
        table[:, 7] = np.maximum(radius * radius, floor2)
        table[:, 8] = radius
        table[:, 9] = n_spread
        table[:, 10] = n_spread >= np.pi                       # emits every way: no orientation factor
        self._table = table
        internal = np.arange(leaves - 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            self._left_power = np.nan_to_num(n_power[2 * internal + 1] / n_power[internal], nan=0.5)

    # ------------------------------------------------------------------ importance
    def _importance(self, node, px, py, pz):
        """(N,) float32 importance of node[i] at point i."""
        g = np.take(self._table, node, axis=0).T
        vx, vy, vz = px - g[0], py - g[1], pz - g[2]
        d2 = vx * vx + vy * vy + vz * vz
        unoriented = g[6] / np.maximum(d2, g[7])
        omni = g[10] > 0
        if omni.all():
            return unoriented
        inv_d = np.float32(1.0) / np.sqrt(np.maximum(d2, np.float32(1e-30)))
        cos_t = np.clip((vx * g[3] + vy * g[4] + vz * g[5]) * inv_d, np.float32(-1.0), np.float32(1.0))
        sin_u = g[8] * inv_d
        theta_u = np.where(sin_u < 1, np.arcsin(np.minimum(sin_u, np.float32(1.0))), _PI)
        theta_p = np.maximum(np.arccos(cos_t) - g[9] - theta_u, np.float32(0.0))
        orient = np.where(theta_p < _HALF_PI, np.maximum(np.cos(theta_p), COS_FLOOR), np.float32(0.0))
        return np.where(omni, unoriented, unoriented * orient)

    def _left_probability(self, node, px, py, pz):
        """(N,) float64 probability of going to the left child of internal node[i] at point i."""
        ia = self._importance(2 * node + 1, px, py, pz).astype(np.float64)
        ib = self._importance(2 * node + 2, px, py, pz).astype(np.float64)
        total = ia + ib
        with np.errstate(divide="ignore", invalid="ignore"):
            by_importance = ia / total
        ok = (total > 0) & np.isfinite(by_importance)
        if ok.all():
            return by_importance
        return np.where(ok, by_importance, np.take(self._left_power, node))

    # ------------------------------------------------------------------ sampling and pmf
    def sample(self, u, px, py, pz):
        """Walk down for each point with u (N,) in [0, 1). Returns (emitter (N,) int64, pmf (N,) float64)."""
        u = np.asarray(u, np.float64).copy()
        node = np.zeros(len(u), np.int64)
        pmf = np.ones(len(u))
        for _ in range(self.depth):
            p_left = self._left_probability(node, px, py, pz)
            left = u < p_left
            prob = np.where(left, p_left, 1.0 - p_left)
            # Reuse u within the chosen child (float64: depth ~20 halvings keep 30 bits).
            u = np.where(left, u, u - p_left) / np.where(prob > 0, prob, 1.0)
            u = np.clip(u, 0.0, np.nextafter(1.0, 0.0))
            pmf *= prob
            node = np.where(left, 2 * node + 1, 2 * node + 2)
        emitter = np.take(self.emitter_at, node)
        # Rounding could in principle land on an empty slot (probability 0): report no emitter then.
        pmf = np.where(emitter >= 0, pmf, 0.0)
        return np.maximum(emitter, 0), pmf

    def pmf(self, emitter, px, py, pz):
        """(N,) float64 probability that the walk from point i picks emitter[i] (0 for emitters not in it)."""
        emitter = np.asarray(emitter)
        leaf = np.where(emitter >= 0, np.take(self.leaf_of, np.maximum(emitter, 0)), -1)
        known = leaf >= 0
        node = np.where(known, leaf, 0)
        pmf = np.ones(len(node))
        for _ in range(self.depth):
            parent = (node - 1) // 2
            p_left = self._left_probability(parent, px, py, pz)
            pmf *= np.where(node == 2 * parent + 1, p_left, 1.0 - p_left)
            node = parent
        return np.where(known, pmf, 0.0)

    def pmf_all(self, px, py, pz):
        """(N, n) probabilities of every emitter at each point (for tests: rows sum to 1)."""
        n = len(self.leaf_of)
        m = len(px)
        e = np.tile(np.arange(n), m)
        rep = (np.repeat(c, n) for c in (px, py, pz))
        return self.pmf(e, *rep).reshape(m, n)


def _split_order(centroid, depth):
    """(2^depth,) emitter index per leaf slot (-1 empty): at each level every node's emitters are sorted
    along their centroids' longest extent and the left child takes as many as its subtree holds (at most
    half), so the tree is left-complete and spatially coherent."""
    n = len(centroid)
    perm = np.arange(n)
    starts, counts = np.zeros(1, np.int64), np.full(1, n, np.int64)  # per node of the level
    for level in range(depth):
        cap = 1 << (depth - level - 1)                         # leaves under each child
        seg = np.repeat(np.arange(len(starts)), counts)
        c = centroid[perm]
        nonempty = counts > 0
        s = starts[nonempty]
        lo = np.minimum.reduceat(c, s, axis=0)
        hi = np.maximum.reduceat(c, s, axis=0)
        axis_of = np.zeros(len(starts), np.int64)
        axis_of[nonempty] = np.argmax(hi - lo, axis=1)
        key = c[np.arange(n), axis_of[seg]]
        perm = perm[np.lexsort((np.arange(n), key, seg))]      # stable: ties keep their order
        left = np.minimum(counts, cap)
        starts = np.stack([starts, starts + left], axis=1).ravel()
        counts = np.stack([left, counts - left], axis=1).ravel()
    order = np.full(1 << depth, -1, np.int64)
    filled = counts > 0                                        # every leaf holds 0 or 1 emitter now
    order[np.flatnonzero(filled)] = perm[starts[filled]]
    return order


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
