"""Cycles' light tree over lamps and emissive objects, for clamped renders.

Unclamped, how a shading point chooses a light changes only the noise, and Ember's own tree (kernels.light_tree)
is the less noisy. Clamped (Light Paths > Clamping), each sample's value, and so what the clamp cuts, depends on
the probability its light was chosen with: a scene whose lamps sit inside rough glass read 11% bright with Ember's
tree at Clamp Indirect 10. There, light samples are shared as Cycles' tree shares them (all facts from Cycles'
scene/light_tree.cpp and kernel/light/tree.h, point.h, spot.h, area.h):

- The units are the lamps and the emissive objects (an object's, or an instance's, emissive triangles, Cycles' mesh
  emitters), each with Cycles' energy (the mean of |R|, |G|, |B|; a point or spot lamp's strength over 4 pi, an area
  lamp's over pi, an object's the sum of its triangles' areas times its material's emission estimate,
  Shader.emission_estimate, where a linked colour counts as white: every triangle, those a texture leaves dark
  too, as Cycles keeps them, though light samples go to the emitting ones only), box and cone of emission (axis,
  theta_o, theta_e).
- The tree over them is built as Cycles builds it: at each node the units' centroids go into 12 buckets along
  each axis, each split between buckets costs the two sides' energy x box surface area x cone measure (its
  orientation measure; the box's diagonal where the area is 0), times the node's largest centroid extent over this
  axis'; a node splits at the cheapest split if it costs less than the node whole, or if it holds more than 8 units,
  else it is a leaf. Cones merge as Cycles' merge() does.
- A walk goes left with the mean of the left child's share of the two upper bounds and of the two lower bounds
  (get_left_probability; where neither has a lower bound, that half is even between the children with an upper
  one), a node's bounds being Cycles' light_tree_node_importance (one distance, the centre's, at least half the
  box's bounding radius, for both), and a child holding a single unit bounded as that unit
  (light_tree_child_importance).
- In a leaf, one unit is chosen by the upper bounds or by the lower bounds, each half the time (Cycles' two
  reservoirs; uniformly among units with an upper bound where no lower bound is above 0), with each unit's own
  bounds: a point or spot lamp's by its radius (point_light_tree_parameters, spot_light_tree_parameters with the
  spot's blend), an area lamp's by its corners (area_light_tree_parameters), an emissive object's as a node's.
- Within an emissive object the triangles are chosen by Ember's tree (kernels.light_tree, walked from the object's
  own subtree): Cycles builds that level the same way, and clamped images depend far less on the share of each
  triangle of one object than on the shares of lamps and objects.

`pmf(slot, P)` is exactly the probability `sample` chose slot with at P (the walk's, the leaf's and the object's
tree's); where the walk meets a leaf none of whose units can light P, as in Cycles, no light is chosen (pmf 0).
Distant lights (suns, the world) stay outside, with their fixed share (kernels.lights.selection), and points in a
medium take the surface bounds without the incidence factor (Cycles bounds a volume segment along the ray).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from .light_tree import LightTree

# Cycles' scene/light.cpp builds its tree with at most this many emitters in a leaf, light_tree.h 12 buckets.
MAX_IN_LEAF = 8
BUCKETS = 12

POINT, SPOT, AREA, MESH = 0, 1, 2, 3


@functools.lru_cache(maxsize=4096)
def cone_measure(theta_o: float, theta_e: float) -> float:
    """Cycles' OrientationBounds::calculate_measure."""
    theta_w = min(math.pi, theta_o + theta_e)
    c, s = math.cos(theta_o), math.sin(theta_o)
    return (2 * math.pi * (1 - c)
            + 0.5 * math.pi * (2 * theta_w * s - math.cos(theta_o - 2 * theta_w) - 2 * theta_o * s + c))


def merge_cones(a, b):
    """Cycles' merge() of two cones (axis (x, y, z), theta_o, theta_e); None is the empty cone."""
    if a is None:
        return b
    if b is None:
        return a
    if b[1] > a[1]:
        a, b = b, a
    (ax, ay, az), (bx, by, bz) = a[0], b[0]
    cos_ab = min(max(ax * bx + ay * by + az * bz, -1.0), 1.0)
    theta_d = math.acos(cos_ab)
    theta_e = max(a[2], b[2])
    if a[1] + 5e-4 >= min(math.pi, theta_d + b[1]):
        return a[0], a[1], theta_e
    theta_o = (theta_d + a[1] + b[1]) * 0.5
    if theta_o >= math.pi:
        return a[0], math.pi, theta_e
    if cos_ab < -0.9995:
        w = np.cross(a[0], (1.0, 0.0, 0.0) if abs(ax) < 0.9 else (0.0, 1.0, 0.0))
        axis = tuple(float(x) for x in w / np.linalg.norm(w))
    else:
        ox, oy, oz = bx - ax * cos_ab, by - ay * cos_ab, bz - az * cos_ab
        norm = math.sqrt(ox * ox + oy * oy + oz * oz)
        if norm > 0:
            ox, oy, oz = ox / norm, oy / norm, oz / norm
        c, s = math.cos(theta_o - a[1]), math.sin(theta_o - a[1])
        axis = (ax * c + ox * s, ay * c + oy * s, az * c + oz * s)
    return axis, theta_o, theta_e


class _Measure:
    """A node's or a bucket's box, cone and energy, grown as Cycles' LightTreeMeasure::add grows them (plain floats:
    the build handles a few values at a time)."""
    __slots__ = ("lo", "hi", "cone", "energy")

    def __init__(self, lo=None, hi=None, cone=None, energy=0.0):
        self.lo, self.hi, self.cone, self.energy = lo, hi, cone, energy

    def add(self, lo, hi, cone, energy):
        if energy == 0:
            return
        if self.lo is None:
            self.lo, self.hi = lo, hi
        else:
            self.lo = (min(self.lo[0], lo[0]), min(self.lo[1], lo[1]), min(self.lo[2], lo[2]))
            self.hi = (max(self.hi[0], hi[0]), max(self.hi[1], hi[1]), max(self.hi[2], hi[2]))
        self.cone = merge_cones(self.cone, cone)
        self.energy += energy

    def join(self, other: "_Measure") -> "_Measure":
        m = _Measure(self.lo, self.hi, self.cone, self.energy)
        m.add(other.lo, other.hi, other.cone, other.energy)
        return m

    def cost(self) -> float:
        if self.energy == 0:
            return 0.0
        sx, sy, sz = self.hi[0] - self.lo[0], self.hi[1] - self.lo[1], self.hi[2] - self.lo[2]
        area = 2.0 * (sx * sy + sy * sz + sz * sx)
        size = area if area != 0 else math.sqrt(sx * sx + sy * sy + sz * sz)
        return self.energy * size * cone_measure(self.cone[1], self.cone[2])


class Units:
    """The units a CyclesLightTree chooses among, (U,) arrays: kind (POINT, SPOT, AREA, MESH), energy, lo and hi
    (U, 3) boxes, centroid (U, 3), axis (U, 3), theta_o, theta_e; for lamps their radius, sphere (Soft Falloff off),
    spot_smooth (1 / ((1 - cos half angle) x blend), inf without blend); for area lamps their edge vectors eu, ev
    (U, 3)."""

    def __init__(self, kind, energy, lo, hi, centroid, axis, theta_o, theta_e, radius=None, sphere=None,
                 spot_smooth=None, eu=None, ev=None):
        u = len(kind)
        self.kind = np.asarray(kind, np.int64)
        self.energy = np.asarray(energy, np.float64)
        self.lo, self.hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        self.centroid, self.axis = np.asarray(centroid, np.float64), np.asarray(axis, np.float64)
        self.theta_o, self.theta_e = np.asarray(theta_o, np.float64), np.asarray(theta_e, np.float64)
        self.radius = np.zeros(u) if radius is None else np.asarray(radius, np.float64)
        self.sphere = np.zeros(u, bool) if sphere is None else np.asarray(sphere, bool)
        self.spot_smooth = np.full(u, np.inf) if spot_smooth is None else np.asarray(spot_smooth, np.float64)
        self.eu = np.zeros((u, 3)) if eu is None else np.asarray(eu, np.float64)
        self.ev = np.zeros((u, 3)) if ev is None else np.asarray(ev, np.float64)

    def as_float32(self) -> "Units":
        """The same units in float32, as the walks evaluate them (half the memory traffic of float64)."""
        out = Units.__new__(Units)
        for name, value in vars(self).items():
            setattr(out, name, value.astype(np.float32) if value.dtype == np.float64 else value)
        return out


def build(units: Units):
    """Cycles' recursive_build over the units: (nodes, order) with nodes a dict of (K,) arrays (left, right -1 in
    leaves; first, count: the leaf's units order[first:first + count]; lo, hi, axis, theta_o, theta_e, energy)."""
    order = np.arange(len(units.energy))
    rows = []
    items = [(tuple(lo), tuple(hi), (tuple(axis), float(o), float(e)), float(energy)) for lo, hi, axis, o, e, energy
             in zip(units.lo.tolist(), units.hi.tolist(), units.axis.tolist(), units.theta_o, units.theta_e,
                    units.energy)]

    def measure_of(idx) -> _Measure:
        m = _Measure()
        for i in idx.tolist():
            m.add(*items[i])
        return m

    stack = [(0, len(order), -1, 0)]
    while stack:
        start, end, parent, side = stack.pop()
        node = len(rows)
        idx = order[start:end]
        whole = measure_of(idx)
        rows.append([whole, -1, -1, start, end - start])
        if parent >= 0:
            rows[parent][1 + side] = node
        middle, dim = _split(units, items, idx, whole)
        if middle is None:
            continue
        if dim >= 0:
            key = units.centroid[idx, dim]
            order[start:end] = idx[np.argsort(key, kind="stable")]
        stack.append((start + middle, end, node, 1))
        stack.append((start, start + middle, node, 0))
    k = len(rows)
    nodes = dict(left=np.array([r[1] for r in rows], np.int64), right=np.array([r[2] for r in rows], np.int64),
                 first=np.array([r[3] for r in rows], np.int64), count=np.array([r[4] for r in rows], np.int64),
                 lo=np.zeros((k, 3)), hi=np.zeros((k, 3)), axis=np.zeros((k, 3)), theta_o=np.zeros(k),
                 theta_e=np.zeros(k), energy=np.zeros(k))
    for i, r in enumerate(rows):
        m = r[0]
        if m.energy > 0:
            nodes["lo"][i], nodes["hi"][i] = m.lo, m.hi
            nodes["axis"][i], nodes["theta_o"][i], nodes["theta_e"][i] = m.cone
            nodes["energy"][i] = m.energy
    return nodes, order


def _split(units: Units, items, idx, whole: _Measure):
    """Cycles' should_split: (middle, dim) of the cheapest split (dim -1: the order stays), or (None, -1) for a leaf."""
    n = len(idx)
    if n < 2:
        return None, -1
    c = units.centroid[idx]
    lo_c, hi_c = c.min(axis=0), c.max(axis=0)
    extent = hi_c - lo_c
    max_extent = max(float(extent.max()), 0.0)
    total_cost = whole.cost()
    min_cost, best = math.inf, (n // 2, -1)
    if total_cost > 0 and (extent > 0).any():
        for dim in range(3):
            if extent[dim] == 0:
                continue
            inv = 1.0 / extent[dim]
            bucket = np.clip((BUCKETS * (c[:, dim] - lo_c[dim]) * inv).astype(np.int64), 0, BUCKETS - 1)
            measures = [_Measure() for _ in range(BUCKETS)]
            counts = np.bincount(bucket, minlength=BUCKETS)
            for b, i in zip(bucket.tolist(), idx.tolist()):
                measures[b].add(*items[i])
            left = [measures[0]]
            for b in range(1, BUCKETS - 1):
                left.append(left[-1].join(measures[b]))
            right = [None] * (BUCKETS - 1)
            right[-1] = measures[-1]
            for b in range(BUCKETS - 3, -1, -1):
                right[b] = right[b + 1].join(measures[b + 1])
            regularization = max_extent * inv
            left_count = np.cumsum(counts)
            for s in range(BUCKETS - 1):
                cost = regularization * (left[s].cost() + right[s].cost())
                if cost < total_cost and cost < min_cost:
                    min_cost, best = cost, (int(left_count[s]), dim)
    if min_cost < total_cost or n > MAX_IN_LEAF:
        middle, dim = best
        if dim < 0 or middle <= 0 or middle >= n:   # no cheaper split: more than 8 units are halved in order
            return n // 2, -1 if dim < 0 else dim
        return middle, dim
    return None, -1


# ---------------------------------------------------------------------------------------------- importance
def _importance(p2c, cos_u, axis, theta_o, theta_e, max_dist, min_dist, energy, facing, shape=None):
    """Cycles' light_tree_importance: (upper, lower), every argument (..., N) (p2c and axis (3, ...)): the unit
    direction from the point to the centre, cos theta_u, the cone, the distances, the energy; facing the points'
    (nx, ny, nz, two_sided) or None (a point in a medium: no incidence factor). shape: "omni" where every cone
    emits every way (theta_o pi: no orientation factor, no lower bound), "point" where every cone faces the point
    (a point lamp's: theta 0, theta_o 0, theta_e pi / 2), None in general; the same values, fewer passes."""
    sin_u = np.sqrt(np.maximum(1.0 - cos_u * cos_u, 0.0))
    cos_min_i, cos_max_i = np.ones_like(cos_u), np.ones_like(cos_u)
    behind = np.zeros(cos_u.shape, bool)
    if facing is not None:
        nx, ny, nz, two = facing
        cos_i = p2c[0] * nx + p2c[1] * ny + p2c[2] * nz
        cos_i = np.where(two, np.abs(cos_i), cos_i)
        sin_i = np.sqrt(np.maximum(1.0 - cos_i * cos_i, 0.0))
        free = (nx == 0) & (ny == 0) & (nz == 0)
        cos_min_i = np.where(cos_i >= cos_u, 1.0, cos_i * cos_u + sin_i * sin_u)
        behind = ~two & (cos_min_i < 0) & ~free
        cos_max_i = np.maximum(cos_i * cos_u - sin_i * sin_u, 0.0)
        cos_min_i = np.where(free, 1.0, cos_min_i)
        cos_max_i = np.where(free, 1.0, cos_max_i)
    if shape is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            upper = np.where(behind, 0.0, np.abs(cos_min_i * energy / (min_dist * min_dist)))
            if shape == "omni":
                lower = np.zeros_like(upper)
            else:   # cos(theta + theta_u + theta_o) = cos theta_u, none where negative
                lower = np.where(behind | (cos_u < 0), 0.0, np.abs(cos_max_i * energy * cos_u / (max_dist * max_dist)))
        return np.nan_to_num(upper, nan=0.0, posinf=0.0), np.nan_to_num(lower, nan=0.0, posinf=0.0)
    cos_t = np.clip(-(axis[0] * p2c[0] + axis[1] * p2c[1] + axis[2] * p2c[2]), -1.0, 1.0)
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    cos_t_minus_u = cos_t * cos_u + sin_t * sin_u
    cos_o, sin_o = np.cos(theta_o), np.sin(theta_o)
    first = (cos_t >= cos_u) | (cos_t_minus_u >= cos_o)
    second = (theta_o + theta_e > math.pi) | (cos_t_minus_u > np.cos(theta_o + theta_e))
    sin_t_minus_u = np.sqrt(np.maximum(1.0 - cos_t_minus_u * cos_t_minus_u, 0.0))
    cos_min_o = np.where(first, 1.0, np.where(second, cos_t_minus_u * cos_o + sin_t_minus_u * sin_o, 0.0))
    visible = (first | second) & ~behind
    with np.errstate(divide="ignore", invalid="ignore"):
        upper = np.where(visible, np.abs(cos_min_i * energy * cos_min_o / (min_dist * min_dist)), 0.0)
        cos_t_plus_u = cos_t * cos_u - sin_t * sin_u
        none = (theta_e - theta_o < 0) | (cos_t < 0) | (cos_u < 0) | (cos_t_plus_u < np.cos(theta_e - theta_o))
        sin_t_plus_u = np.sqrt(np.maximum(1.0 - cos_t_plus_u * cos_t_plus_u, 0.0))
        cos_max_o = cos_t_plus_u * cos_o - sin_t_plus_u * sin_o
        lower = np.where(visible & ~none, np.abs(cos_max_i * energy * cos_max_o / (max_dist * max_dist)), 0.0)
    return np.nan_to_num(upper, nan=0.0, posinf=0.0), np.nan_to_num(lower, nan=0.0, posinf=0.0)


def _unit_vector(vx, vy, vz):
    d = np.sqrt(vx * vx + vy * vy + vz * vz)
    inv = 1.0 / np.maximum(d, 1e-30)
    return np.stack([vx * inv, vy * inv, vz * inv]), d


def _box_importance(lo, hi, axis, theta_o, theta_e, energy, px, py, pz, facing):
    """A node's bounds (light_tree_node_importance), the node's arrays (..., N) and (3, ..., N)."""
    centre = 0.5 * (lo + hi)
    ext = hi - centre
    p2c, d = _unit_vector(centre[0] - px, centre[1] - py, centre[2] - pz)
    r2 = ext[0] ** 2 + ext[1] ** 2 + ext[2] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_u = np.where(d * d <= r2, -1.0, np.sqrt(np.maximum(1.0 - r2 / np.maximum(d * d, 1e-30), 0.0)))
    dist = np.maximum(0.5 * np.sqrt(r2), d)
    shape = "omni" if (theta_o >= np.float32(math.pi)).all() else None
    upper, lower = _importance(p2c, cos_u, axis, theta_o, theta_e, dist, dist, energy, facing, shape)
    if facing is not None:
        nx, ny, nz, two = facing
        seen = two | ((nx * (centre[0] - px) + ny * (centre[1] - py) + nz * (centre[2] - pz)
                       + np.abs(nx) * np.abs(ext[0]) + np.abs(ny) * np.abs(ext[1]) + np.abs(nz) * np.abs(ext[2])) > 0)
        seen |= (nx == 0) & (ny == 0) & (nz == 0)
        upper, lower = np.where(seen, upper, 0.0), np.where(seen, lower, 0.0)
    return upper, lower


class CyclesLightTree:
    """The choice among a scene's local emitters (slots 0..n-1) as Cycles' tree makes it (module docstring).

    units: Units over the lamps and the emissive objects; unit_of_slot (n,) the unit of each slot; tri_tree a
    LightTree over the triangles' slots tri_slots (its groups the objects), or None; unit_group (U,) the LightTree
    unit of each MESH unit (-1 for lamps)."""

    def __init__(self, units: Units, unit_of_slot, tri_tree: LightTree | None = None, tri_slots=None,
                 unit_group=None):
        self.nodes, order = build(units)
        self.u = units.as_float32()
        self.count = len(units.energy)
        self.unit_of_slot = np.asarray(unit_of_slot, np.int64)
        self.lamp_slot = np.full(self.count, -1, np.int64)
        lamps = np.flatnonzero(units.kind != MESH)
        slots = np.full(self.count, -1, np.int64)
        np.put(slots, self.unit_of_slot, np.arange(len(self.unit_of_slot)))
        self.lamp_slot[lamps] = slots[lamps]
        self.tri_tree = tri_tree
        self.tri_slots = None if tri_slots is None else np.asarray(tri_slots, np.int64)
        self.tri_index = np.full(len(self.unit_of_slot), -1, np.int64)
        if self.tri_slots is not None:
            self.tri_index[self.tri_slots] = np.arange(len(self.tri_slots))
        self.unit_group = np.full(self.count, -1, np.int64) if unit_group is None else np.asarray(unit_group, np.int64)
        nd = self.nodes
        k = len(nd["left"])
        # Leaves' units, padded with -1 to MAX_IN_LEAF (or the largest leaf).
        width = int(max(nd["count"][nd["left"] < 0].max(initial=1), 1))
        self.leaf_units = np.full((k, width), -1, np.int64)
        self.leaf_of_unit = np.zeros(self.count, np.int64)
        for i in np.flatnonzero(nd["left"] < 0):
            members = order[nd["first"][i]:nd["first"][i] + nd["count"][i]]
            self.leaf_units[i, :len(members)] = members
            self.leaf_of_unit[members] = i
        # The unit of each leaf holding one, -1 elsewhere.
        self._single = np.where((nd["left"] < 0) & (nd["count"] == 1), self.leaf_units[:, 0], -1)
        self._rows = np.concatenate([nd["lo"], nd["hi"], nd["axis"], nd["theta_o"][:, None], nd["theta_e"][:, None],
                                     nd["energy"][:, None]], axis=1).astype(np.float32)
        self.parent = np.full(k, -1, np.int64)
        inner = np.flatnonzero(nd["left"] >= 0)
        self.parent[nd["left"][inner]] = inner
        self.parent[nd["right"][inner]] = inner
        depth = np.zeros(k, np.int64)
        for i in range(k):              # parents come before their children
            if nd["left"][i] >= 0:
                depth[nd["left"][i]] = depth[nd["right"][i]] = depth[i] + 1
        self.depth = int(depth.max(initial=0))

    # -------------------------------------------------------------------------------------- bounds
    def _left_probability(self, node, px, py, pz, facing):
        """(N,) left probability (Cycles' get_left_probability), nan where neither child can light the point."""
        nd = self.nodes
        # Both children in one pass, (2, N) rows over which the points broadcast. A child holding one unit is
        # bounded as that unit (light_tree_child_importance), others as nodes.
        both = np.stack((nd["left"][node], nd["right"][node]))
        unit = self._single[both]
        alone = unit >= 0
        if alone.all():
            upper, lower = self._unit_bounds(unit, px, py, pz, facing)
        else:
            row = np.moveaxis(self._rows[both], -1, 0)            # lo, hi, axis, theta_o, theta_e, energy
            upper, lower = _box_importance(row[0:3], row[3:6], row[6:9], row[9], row[10], row[11], px, py, pz, facing)
            if alone.any():
                u_up, u_lo = self._unit_bounds(unit, px, py, pz, facing)
                upper, lower = np.where(alone, u_up, upper), np.where(alone, u_lo, lower)
        (a_max, b_max), (a_min, b_min) = upper, lower
        return left_probability(a_max, a_min, b_max, b_min)

    def root_bounds(self, px, py, pz, facing):
        """(upper, lower) (N,) of the whole tree at the points: its root bounded as a child of Cycles' root, whose
        other child holds the distant lights (light_tree_child_importance: a single unit as that unit)."""
        px, py, pz = (np.asarray(c, np.float32) for c in (px, py, pz))
        fac = None if facing is None else tuple(np.asarray(c) for c in facing)
        unit = int(self._single[0])
        if unit >= 0:
            upper, lower = self._unit_bounds(np.full((1, len(px)), unit, np.int64), px, py, pz, fac)
            return upper[0], lower[0]
        row = self._rows[0][:, None].astype(np.float64)
        return _box_importance(row[0:3], row[3:6], row[6:9], row[9], row[10], row[11], px, py, pz, fac)

    def _unit_bounds(self, unit, px, py, pz, facing):
        """(upper, lower) of units unit (K, N) (-1: none, 0) at the points (N,) (light_tree_emitter_importance)."""
        u = self.u
        ok = unit >= 0
        i = np.where(ok, unit, 0)
        kind = u.kind[i]
        c = u.centroid[i].transpose(2, 0, 1) if i.ndim == 2 else u.centroid[i].T
        p2c, d = _unit_vector(c[0] - px, c[1] - py, c[2] - pz)
        energy = u.energy[i].copy()
        axis = np.moveaxis(u.axis[i], -1, 0).copy()
        theta_o = u.theta_o[i].copy()
        theta_e = u.theta_e[i]
        cos_u = np.ones_like(d)
        min_d, max_d = d.copy(), d.copy()
        visible = np.ones(d.shape, bool)
        # Point and spot lamps (point_light_tree_parameters, spot_light_tree_parameters).
        punctual = (kind == POINT) | (kind == SPOT)
        r = u.radius[i]
        sphere = u.sphere[i] & (r > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            outside = d > r
            cos_sphere = np.sqrt(np.maximum(1.0 - (r / np.maximum(d, 1e-30)) ** 2, 0.0))
            hyp = np.sqrt(r * r + d * d)
            cos_soft = np.where(hyp > 0, d / np.where(hyp > 0, hyp, 1.0), 1.0)
        cos_p = np.where(sphere, np.where(outside, cos_sphere, -1.0), cos_soft)
        inside_ball = sphere & ~outside
        max_p = np.where(sphere, np.where(outside, d / np.maximum(cos_sphere, 1e-30), r / math.sqrt(2)), hyp)
        min_p = np.where(inside_ball, r / math.sqrt(2), d)
        cos_u = np.where(punctual, cos_p, cos_u)
        max_d = np.where(punctual, max_p, max_d)
        min_d = np.where(punctual, min_p, min_d)
        point = kind == POINT
        axis = np.where(point, -p2c, axis)                   # a point lamp's cone faces the point, theta_o 0
        theta_o = np.where(point, 0.0, theta_o)
        spot = kind == SPOT
        if spot.any():
            cos_t = np.clip(-(axis[0] * p2c[0] + axis[1] * p2c[1] + axis[2] * p2c[2]), -1.0, 1.0)
            cos_min_out = np.cos(np.maximum(0.0, np.arccos(cos_t) - np.arccos(np.clip(cos_u, -1.0, 1.0))))
            with np.errstate(invalid="ignore"):
                x = np.clip((cos_min_out - np.cos(theta_e)) * u.spot_smooth[i], 0.0, 1.0)
            x = np.nan_to_num(x, nan=1.0)
            energy = np.where(spot, energy * x * x * (3.0 - 2.0 * x), energy)
        # Area lamps (area_light_tree_parameters): their corners.
        area = kind == AREA
        if area.any():
            eu, ev = np.moveaxis(u.eu[i], -1, 0), np.moveaxis(u.ev[i], -1, 0)
            cu = np.full(d.shape, np.inf, d.dtype)
            far = d.copy()
            for su, sv in ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)):
                q = c + su * eu + sv * ev
                p2q, dq = _unit_vector(q[0] - px, q[1] - py, q[2] - pz)
                cu = np.minimum(cu, p2c[0] * p2q[0] + p2c[1] * p2q[1] + p2c[2] * p2q[2])
                far = np.maximum(far, dq)
            cos_u = np.where(area, cu, cos_u)
            max_d = np.where(area, far, max_d)
            front = (axis[0] * p2c[0] + axis[1] * p2c[1] + axis[2] * p2c[2]) < 0
            above = np.ones(d.shape, bool)
            if facing is not None:
                nx, ny, nz, two = facing
                above = ((nx * (c[0] - px) + ny * (c[1] - py) + nz * (c[2] - pz))
                         + np.abs(nx * eu[0] + ny * eu[1] + nz * eu[2]) + np.abs(nx * ev[0] + ny * ev[1] + nz * ev[2])
                         > 0) | ((nx == 0) & (ny == 0) & (nz == 0))
                above |= two
                front |= two
            visible = np.where(area, front & above, visible)
        shape = "point" if (point | ~ok).all() else None
        upper, lower = _importance(p2c, cos_u, axis, theta_o, theta_e, max_d, min_d, energy, facing, shape)
        # Emissive objects: their box as a node's.
        mesh = kind == MESH
        if mesh.any():
            m_up, m_lo = _box_importance(np.moveaxis(u.lo[i], -1, 0), np.moveaxis(u.hi[i], -1, 0),
                                         np.moveaxis(u.axis[i], -1, 0), u.theta_o[i], u.theta_e[i], u.energy[i],
                                         px, py, pz, facing)
            upper, lower = np.where(mesh, m_up, upper), np.where(mesh, m_lo, lower)
        keep = ok & visible
        return np.where(keep, upper, 0.0), np.where(keep, lower, 0.0)

    def _leaf_weights(self, leaf, px, py, pz, facing):
        """(K, N) upper and lower bounds of the leaves' units and the units (K, N)."""
        unit = self.leaf_units[leaf].T
        upper, lower = self._unit_bounds(unit, px, py, pz, facing)
        return unit, upper, lower

    @staticmethod
    def _leaf_pmf(upper, lower):
        """(K, N) probability of each leaf unit: the mean of its share of the upper and of the lower bounds (the
        lower ones even among units with an upper bound where none has a lower one), as light_tree_pdf."""
        total_max, total_min = upper.sum(axis=0), lower.sum(axis=0)
        has = upper > 0
        n_has = has.sum(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            by_min = np.where(total_min > 0, lower / np.where(total_min > 0, total_min, 1.0),
                              has / np.maximum(n_has, 1))
            p = 0.5 * (upper / np.where(total_max > 0, total_max, 1.0) + by_min)
        return np.where(has, p, 0.0)

    # -------------------------------------------------------------------------------------- sampling
    def sample(self, u, px, py, pz, facing=None):
        """(slot (N,) int64, pmf (N,) float64) for numbers u (N,) in [0, 1); pmf 0 (slot 0) where nothing can
        light the point."""
        n = len(u)
        u = np.asarray(u, np.float64).copy()
        px, py, pz = (np.asarray(c, np.float32) for c in (px, py, pz))
        fac = None if facing is None else tuple(np.asarray(c) for c in facing)
        node = np.zeros(n, np.int64)
        pmf = np.ones(n)
        nd = self.nodes
        idx = np.arange(n)
        for _ in range(self.depth):
            inner = nd["left"][node[idx]] >= 0
            idx = idx[inner]
            if not len(idx):
                break
            p = self._left_probability(node[idx], px[idx], py[idx], pz[idx], _rows(fac, idx))
            dead = np.isnan(p)
            pmf[idx[dead]] = 0.0
            p = np.where(dead, 0.5, p)
            left = u[idx] < p
            prob = np.where(left, p, 1.0 - p)
            u[idx] = np.clip(np.where(left, u[idx], u[idx] - p) / np.where(prob > 0, prob, 1.0), 0.0,
                             np.nextafter(1.0, 0.0))
            pmf[idx] *= prob
            node[idx] = np.where(left, nd["left"][node[idx]], nd["right"][node[idx]])
        unit, upper, lower = self._leaf_weights(node, px, py, pz, fac)
        probs = self._leaf_pmf(upper, lower).astype(np.float64)
        # Chosen by the upper bounds or by the lower ones, half the time each: the same mixture as probs.
        cdf = np.cumsum(probs, axis=0)
        total = cdf[-1]
        target = u * total
        k = np.minimum((target[None, :] >= cdf).sum(axis=0), probs.shape[0] - 1)
        cols = np.arange(n)
        k = _last_positive(probs, k)
        chosen = unit[k, cols]
        p_sel = probs[k, cols]
        before = np.where(k > 0, cdf[np.maximum(k - 1, 0), cols], 0.0)
        u = np.clip((target - before) / np.where(p_sel > 0, p_sel, 1.0), 0.0, np.nextafter(1.0, 0.0))
        pmf = np.where((total > 0) & (chosen >= 0), pmf * p_sel, 0.0)
        chosen = np.maximum(chosen, 0)
        slot = self.lamp_slot[chosen]
        mesh = self.unit_group[chosen] >= 0
        if mesh.any():
            m = np.flatnonzero(mesh)
            start = self.tri_tree.unit_root[self.unit_group[chosen[m]]]
            e, q = self.tri_tree.sample(u[m], px[m], py[m], pz[m], _rows(fac, m), start=start)
            slot[m] = self.tri_slots[e]
            pmf[m] *= q
        return np.maximum(slot, 0), pmf

    def pmf(self, slot, px, py, pz, facing=None):
        """(N,) float64 probability that sample() at the points chooses slot (-1: none, 0)."""
        slot = np.asarray(slot, np.int64)
        n = len(slot)
        known = slot >= 0
        unit = np.where(known, self.unit_of_slot[np.maximum(slot, 0)], 0)
        px, py, pz = (np.asarray(c, np.float32) for c in (px, py, pz))
        fac = None if facing is None else tuple(np.asarray(c) for c in facing)
        leaf = self.leaf_of_unit[unit]
        units_k, upper, lower = self._leaf_weights(leaf, px, py, pz, fac)
        probs = self._leaf_pmf(upper, lower).astype(np.float64)
        pmf = (probs * (units_k == unit[None, :])).sum(axis=0)
        node = leaf.copy()
        idx = np.flatnonzero(pmf > 0)
        for _ in range(self.depth):
            parent = self.parent[node[idx]]
            has = parent >= 0
            idx, parent = idx[has], parent[has]
            if not len(idx):
                break
            p = self._left_probability(parent, px[idx], py[idx], pz[idx], _rows(fac, idx))
            p = np.nan_to_num(p, nan=0.0)
            went_left = self.nodes["left"][parent] == node[idx]
            pmf[idx] *= np.where(went_left, p, 1.0 - p)
            node[idx] = parent
        mesh = known & (self.unit_group[unit] >= 0) & (pmf > 0)
        if mesh.any():
            m = np.flatnonzero(mesh)
            stop = self.tri_tree.unit_root[self.unit_group[unit[m]]]
            pmf[m] *= self.tri_tree.pmf(self.tri_index[slot[m]], px[m], py[m], pz[m], _rows(fac, m), stop=stop)
        return np.where(known, pmf, 0.0)


def distant_bounds(energy: float, cone, facing, n: int):
    """(upper, lower) (N,) of Cycles' distant node at n points (light_tree_node_importance for LIGHT_TREE_DISTANT, and
    for a single distant light background_ / distant_light_tree_parameters, which come to the same): the direction
    to it the reverse of its cone's axis, cos theta_u the cosine of theta_o + theta_e, distance 1. cone: (axis,
    theta_o, theta_e) as merge_cones gives them; facing the points' (nx, ny, nz, two_sided) or None."""
    axis, theta_o, theta_e = cone
    a = np.asarray(axis, np.float64)[:, None] * np.ones(n)
    cos_u = np.full(n, math.cos(min(theta_o + theta_e, math.pi)))
    ones = np.ones(n)
    return _importance(-a, cos_u, a, np.full(n, theta_o), np.full(n, theta_e), ones, ones, np.full(n, energy),
                       facing)


def left_probability(upper_a, lower_a, upper_b, lower_b):
    """Cycles' get_left_probability from the two children's bounds (N,) each: the mean of the left child's share of
    the upper bounds and of the lower ones (where neither has a lower bound, half between those with an upper
    one); nan where neither can light the point."""
    total_max, total_min = upper_a + upper_b, lower_a + lower_b
    with np.errstate(divide="ignore", invalid="ignore"):
        by_lower = np.where(total_min > 0, lower_a / np.where(total_min > 0, total_min, 1.0),
                            0.5 * ((upper_a > 0).astype(np.float64) + (upper_b == 0)))
        p = 0.5 * (upper_a / total_max + by_lower)
    return np.where(total_max > 0, p, np.nan).astype(np.float64)


def _rows(facing, idx):
    return None if facing is None else tuple(np.take(c, idx) for c in facing)


def _last_positive(probs, k):
    """k, moved down to the nearest row with probability above 0 (rounding of the cumulative sum may land past it)."""
    cols = np.arange(probs.shape[1])
    bad = probs[k, cols] <= 0
    if not bad.any():
        return k
    pos = probs > 0
    rows = np.arange(probs.shape[0])[:, None]
    first = np.where(pos, rows, probs.shape[0]).min(axis=0)
    below = np.where(pos & (rows <= k[None, :]), rows, -1).max(axis=0)
    fixed = np.where(below >= 0, below, np.where(first < probs.shape[0], first, 0))
    return np.where(bad, fixed, k)
