"""Surfaces that lie on one another: a liquid's wall on the inside of its glass, a label on a bottle, two
duplicated faces. Which triangles coincide with which, and where a ray that goes through one meets the
other.

Cycles' self-intersection test skips only the primitive a ray leaves (kernel/bvh/util.h), so a ray refracted
through a glass's inner wall meets the liquid's wall lying on it at distance zero, and refracts again. Ember
moves each new ray's origin off its surface instead (Embree as embreex calls it has no per-ray exclusion),
which steps over every surface within that offset. So the partners of the triangles a ray can pass through
are found once per scene, and a ray that passes through one of them is handed its partner's hit at the same
point (Renderer's crossing of coincident surfaces).

A partner lies in the triangle's plane (normals within PLANE_ANGLE, planes within the ray offset's distance)
and overlaps it with some area, not only along an edge (a mesh's own flat neighbours are not partners).
"""
from __future__ import annotations

import numpy as np

from .scene import corner_values
from .vec import cross_rows_fused, dot_rows_fused

# Largest angle between two triangles' normals for them to lie on one another (radians).
PLANE_ANGLE = 1e-3
# About this many candidate pairs are tested at once (memory of the vectorised tests).
_CHUNK = 1 << 20


class Coincident:
    """Partners of triangles: for triangle a, partners[offsets[a]:offsets[a + 1]] are the triangles that lie on
    it (int64, ascending). Only the T plain triangles take part (world space; instanced meshes do not)."""

    def __init__(self, offsets: np.ndarray, partners: np.ndarray, positions, objects: np.ndarray | None = None,
                 copy: np.ndarray | None = None):
        self.offsets, self.partners = offsets, partners
        self._positions = positions
        self._objects = objects   # (T,) object rows, for crossing(other_object=True); None: all one object
        # Per partner, whether it is a copy of the triangle (copy_pairs): met whatever its material (among).
        self.copy = np.zeros(len(partners), bool) if copy is None else copy
        self.opaque = None        # (T,) bool, the triangles that stop what meets them (set by the renderer)
        self.offset = None        # offset(|p|max) -> how far a new ray's origin moves off a surface (find's), or None
        self.instances = None     # InstanceCopies: instances placed twice at one transform, or None
        self.groups = None        # CopyGroups: exact copies kept as groups (scenes too large for pairs), or None
        self._boxes = _pair_boxes(offsets, partners, positions)

    @classmethod
    def find(cls, positions, through: np.ndarray, offset, objects: np.ndarray | None = None,
             copies: np.ndarray | None = None, overlaps: np.ndarray | None = None) -> "Coincident | None":
        """Partners of the triangles `through` (T,) bool marks (those a ray may pass through) among all the
        triangles (SceneArrays.positions, world space); offset(|p|max) -> the distance a new ray's origin is
        moved off a surface at that size of coordinate: planes closer than twice that lie on one another.
        objects: (T,) each triangle's object row, or None; partners are then of another object (a finely
        subdivided glass's neighbouring triangles are not looked at: a mesh lying on itself is left alone).
        copies: pair keys of copies to add (copy_pairs: a duplicated face or object, a doubled quad split the
        other way, found by sorting edges, not by the search above, whose cost on a large flat mesh is too high
        for every triangle), or None. overlaps: pair keys of opaque faces overlapping in part to add
        (overlap_pairs), or None. None when no triangle has a partner."""
        found = [] if copies is None else [copies]
        if overlaps is not None and len(overlaps):
            found.append(overlaps)
        candidates = np.flatnonzero(through)
        if len(candidates) and len(positions) >= 2:
            found += _through_pairs(positions, through, candidates, offset, objects)
        coincident = cls._of_keys(found, len(positions), positions, objects, copies)
        if coincident is not None:
            coincident.offset = offset
        return coincident

    @classmethod
    def _of_keys(cls, found, count: int, positions, objects, copies=None) -> "Coincident | None":
        """From lists of pair keys a * count + b; copies: the keys among them that are copies, or None."""
        key = _unique(np.concatenate(found)) if found else np.zeros(0, np.int64)
        if not len(key):
            return None
        a, b = key // count, key % count
        offsets = np.zeros(count + 1, np.int64)
        offsets[1:] = np.bincount(a, minlength=count)
        copy = None if copies is None or not len(copies) else _in_sorted(key, _unique(copies))
        return cls(np.cumsum(offsets), b, positions, objects, copy)

    def crossing(self, prim: np.ndarray, px, py, pz, among: np.ndarray | None = None, other_object: bool = False,
                 side=None):
        """For rays passing through triangles prim (n,) at points p (x, y, z of (n,)): the partner each meets
        there (-1 for none: no partner, a point outside them all, an instanced triangle but on a copy of its instance
        met on its side: InstanceCopies; and in scenes too large for pairs, a copy met on its side: CopyGroups), and
        that hit's
        barycentrics (b1, b2) of the partner's corners 1 and 2, float32. among: (T,) bool, the triangles that
        may be met besides copies of the triangle left, which always may (None: all); other_object: only partners
        of another object than the triangle left.
        side: for rays that leave their surface on one side (a reflection, a shadow ray), that side's normal
        (x, y, z of (n,)): a partner is met where Embree's own test meets it from the point (embree_meets)."""
        partner, b1, b2 = self._pairs_crossing(prim, px, py, pz, among, other_object, side)
        if self.groups is not None and side is not None:
            rows = np.flatnonzero(partner < 0)
            if len(rows):
                q = np.stack([np.take(c, rows) for c in (px, py, pz)], axis=1).astype(np.float32)
                g = np.stack([np.take(c, rows) for c in side], axis=1).astype(np.float32)
                partner[rows], b1[rows], b2[rows] = self.groups.crossing(np.take(prim, rows), q, g)
        return partner, b1, b2

    def _pairs_crossing(self, prim, px, py, pz, among, other_object, side):
        """crossing by the pairs (and InstanceCopies)."""
        m = len(prim)
        partner = np.full(m, -1, np.int64)
        b1, b2 = np.zeros(m, np.float32), np.zeros(m, np.float32)
        if self.instances is not None and side is not None:
            rows = np.flatnonzero(prim >= len(self.offsets) - 1)
            if len(rows):
                q = np.stack([np.take(c, rows) for c in (px, py, pz)], axis=1).astype(np.float32)
                g = np.stack([np.take(c, rows) for c in side], axis=1).astype(np.float32)
                partner[rows], b1[rows], b2[rows] = self.instances.crossing(np.take(prim, rows), q, g)
        inside = prim < len(self.offsets) - 1
        start = np.where(inside, np.take(self.offsets, np.where(inside, prim, 0)), 0)
        count = np.where(inside, np.take(self.offsets, np.where(inside, prim + 1, 0)) - start, 0)
        rows = np.flatnonzero(count > 0)
        if not len(rows):
            return partner, b1, b2
        # Every (ray, partner) pair; the first partner (in index order) that holds the point wins.
        per = count[rows]
        ray = np.repeat(rows, per)
        entry = np.repeat(start[rows], per) + _ranks(per)
        which = self.partners[entry]
        keep = np.ones(len(which), bool) if among is None else np.take(among, which) | self.copy[entry]
        if other_object and self._objects is not None:
            keep &= np.take(self._objects, which) != np.take(self._objects, np.take(prim, ray))
        # A point outside its pair's box (_pair_boxes) is outside the partner: most rays leaving a large floor
        # that a small face lies on are dropped here, before the exact test.
        box = self._boxes[entry]
        coords = [np.take(c, ray) for c in (px, py, pz)]
        for k, x in enumerate(coords):
            keep &= (x >= box[:, k]) & (x <= box[:, 3 + k])
        ray, which = ray[keep], which[keep]
        q = np.stack([x[keep] for x in coords], axis=1).astype(np.float64)
        tri = corner_values(self._positions, which).astype(np.float64)
        w1, w2, holds = _barycentrics(tri, q)
        if side is not None:
            g = np.stack([np.take(c, ray) for c in side], axis=1).astype(np.float32)
            holds = embree_meets(tri.astype(np.float32), q.astype(np.float32), g)   # the float32 corners, exactly
        if self.offset is not None:
            # A partner further from the point than a new ray's origin moves (twice, for rounding) is met by that ray
            # itself: pairs are found by the offset at their corners' size, and a Solidify spike hundreds of km long
            # pairs with a parallel wall metres away.
            n = _normals(tri)
            height = np.abs(np.einsum("ij,ij->i", n, tri[:, 0] - q)) / np.maximum(np.linalg.norm(n, axis=1), 1e-300)
            holds &= height <= 2.0 * self.offset(np.abs(q).max(axis=1))
        _first_held(holds, ray, which, w1, w2, partner, b1, b2)
        return partner, b1, b2


    def opaque_of(self, prims: np.ndarray) -> np.ndarray:
        """Whether triangles prims (plain or instanced: a hit handed over by crossing) stop what meets them."""
        plain = prims < len(self.opaque)
        out = np.take(self.opaque, np.where(plain, prims, 0))
        if self.instances is not None and not plain.all():
            out[~plain] = self.instances.opaque_of(prims[~plain])
        return out

    @classmethod
    def empty(cls, positions, objects=None) -> "Coincident":
        """No plain triangle with a partner (InstanceCopies alone)."""
        return cls(np.zeros(len(positions) + 1, np.int64), np.zeros(0, np.int64), positions, objects)


class CopyGroups:
    """Exact copies (exact_copies' groups) of scenes too large for pairs (renderer.COPY_SCENE_LIMIT): a ray leaving
    a member on its side meets another where Embree's test meets it (embree_meets), as pairs would have it. Kept as
    groups: a realized Geometry Nodes scatter of 19M triangles, 10M of them in 4M groups of 2-9, makes 19M pairs,
    whose boxes alone would take 450 MB."""

    def __init__(self, members: np.ndarray, starts: np.ndarray, positions):
        order = np.argsort(members, kind="stable")
        self._sorted = members[order]
        self._group = np.repeat(np.arange(len(starts) - 1), np.diff(starts))[order]
        self.members, self.starts = members, starts
        self._positions = positions

    def crossing(self, prims, q, side):
        """For rays leaving plain triangles prims (m,) at points q (m, 3) float32 on the side side (m, 3): the copy
        each meets at once (-1: none) and the hit's barycentrics (b1, b2)."""
        m = len(prims)
        partner = np.full(m, -1, np.int64)
        b1, b2 = np.zeros(m, np.float32), np.zeros(m, np.float32)
        at = np.minimum(np.searchsorted(self._sorted, prims), len(self._sorted) - 1)
        rows = np.flatnonzero(self._sorted[at] == prims)
        if not len(rows):
            return partner, b1, b2
        group = self._group[at[rows]]
        per = self.starts[group + 1] - self.starts[group]
        ray = np.repeat(rows, per)
        other = self.members[np.repeat(self.starts[group], per) + _ranks(per)]
        keep = other != prims[ray]
        ray, other = ray[keep], other[keep]
        tri = corner_values(self._positions, other)
        holds = embree_meets(tri, q[ray], side[ray])
        w1, w2, _ = _barycentrics(tri.astype(np.float64), q[ray].astype(np.float64))
        _first_held(holds, ray, other, w1, w2, partner, b1, b2)
        return partner, b1, b2


class InstanceCopies:
    """Instances of one prototype placed at one transform, to the bit (an object duplicated in place by Alt+D, a
    Geometry Nodes instance put twice on one point): Cycles traces each instance in its object space, so a ray
    leaving one meets the other at once where Embree's test (embree_meets), run on the prototype's corners from
    the point taken into that space by the inverse transform (float32), meets it: always on a face of constant x,
    y or z under an identity transform, about half the time on a turned one. Ember's instances had no partners:
    a floor placed twice rendered lit where Cycles renders it black. Triangle j of instance k is scene number
    bases[k] + j (Instances.bases)."""

    def __init__(self, instances, bases: np.ndarray, opaque_materials: np.ndarray):
        k = instances.count
        matrices = np.ascontiguousarray(instances.world_from_object[:, :3, :], np.float32)
        rows = np.concatenate([instances.prototype.astype(np.float32)[:, None], matrices.reshape(k, 12)], axis=1)
        _, group, size = np.unique(rows.view(np.uint32), axis=0, return_inverse=True, return_counts=True)
        group = group.ravel()
        self.bases = np.asarray(bases, np.int64)
        self.prototype = instances.prototype
        self.prototypes = instances.prototypes
        self.opaque_materials = opaque_materials
        order = np.argsort(group, kind="stable")
        counts = size[group]
        # Per instance, the other instances of its group (CSR: others[start[i]:start[i] + count[i] - 1]).
        self._order, self._first = order, np.r_[0, np.cumsum(size)][group]
        self._count = counts
        inverse = np.linalg.inv(instances.world_from_object.astype(np.float64))
        self.inverse = np.ascontiguousarray(inverse[:, :3, :], np.float32)

    @classmethod
    def find(cls, instances, plain_count: int, opaque_materials: np.ndarray) -> "InstanceCopies | None":
        """None when no two instances share a prototype and a transform."""
        if instances is None or instances.count < 2:
            return None
        found = cls(instances, instances.bases(plain_count), opaque_materials)
        return found if (found._count > 1).any() else None

    def _locate(self, prims):
        inst = np.searchsorted(self.bases, prims, side="right") - 1
        return inst, prims - self.bases[inst]

    def opaque_of(self, prims) -> np.ndarray:
        inst, local = self._locate(prims)
        out = np.zeros(len(prims), bool)
        for p in np.unique(self.prototype[inst]):
            rows = np.flatnonzero(self.prototype[inst] == p)
            out[rows] = self.opaque_materials[self.prototypes[p].material_ids[local[rows]]]
        return out

    def crossing(self, prims, q, side):
        """For rays leaving instanced triangles prims (m,) at points q (m, 3) float32 on the side side (m, 3):
        the copy of the triangle each meets at once (-1: none) and the hit's barycentrics there (b1, b2)."""
        m = len(prims)
        partner = np.full(m, -1, np.int64)
        b1, b2 = np.zeros(m, np.float32), np.zeros(m, np.float32)
        inst, local = self._locate(prims)
        count = self._count[inst] - 1
        rows = np.flatnonzero(count > 0)
        if not len(rows):
            return partner, b1, b2
        # Every (ray, other instance) pair, the others in their group's order.
        per = count[rows] + 1
        ray = np.repeat(rows, per)
        other = self._order[np.repeat(self._first[inst[rows]], per) + _ranks(per)]
        keep = other != inst[ray]
        ray, other = ray[keep], other[keep]
        proto = self.prototype[other]
        tri = np.empty((len(ray), 3, 3), np.float32)
        for p in np.unique(proto):
            at = np.flatnonzero(proto == p)
            tri[at] = self.prototypes[p].positions[local[ray[at]]]
        a = self.inverse[other]
        point = _transform_f32(a, q[ray], 1.0)
        direction = _transform_f32(a, side[ray], 0.0)
        holds = embree_meets(tri, point, direction)
        w1, w2, _ = _barycentrics(tri.astype(np.float64), point.astype(np.float64))
        _first_held(holds, ray, self.bases[other] + local[ray], w1, w2, partner, b1, b2)
        return partner, b1, b2


def _first_held(holds, ray, met, w1, w2, partner, b1, b2) -> None:
    """Of (ray, candidate) pairs whose candidate holds the ray's point (holds), each ray's first: its triangle met
    (met, per pair) into partner and the hit's barycentrics into b1, b2 (per ray, in place)."""
    hit = np.flatnonzero(holds)
    if len(hit):
        chosen = hit[np.unique(ray[hit], return_index=True)[1]]
        partner[ray[chosen]] = met[chosen]
        b1[ray[chosen]], b2[ray[chosen]] = w1[chosen], w2[chosen]


def _transform_f32(m, x, w: float) -> np.ndarray:
    """(n, 3) float32: (n, 3, 4) float32 matrices times points (w 1) or directions (w 0), in float32."""
    out = m[:, :, 0] * x[:, :1] + m[:, :, 1] * x[:, 1:2] + m[:, :, 2] * x[:, 2:3]
    return out + m[:, :, 3] if w else out


# Slack of a pair's box (_pair_boxes), of the coordinates' size: a hit point is its triangle's corners
# interpolated in float32 (a few float32 steps off the triangle), and _barycentrics' margin is a millionth of
# the partner's size. Generous: the box only spares the exact test.
BOX_SLACK = 2.0 ** -16


def _pair_boxes(offsets: np.ndarray, partners: np.ndarray, positions, chunk: int = 1 << 18) -> np.ndarray:
    """(P, 6) float32 bounds (low x, y, z, high x, y, z) per pair (a, partners[k]): where a point of triangle
    a must lie for its projection onto the partner's plane to fall inside the partner (crossing). That
    projection moves the point by its height over the plane, which on triangle a is at most its corners'
    largest height; the partner's box grown by that and BOX_SLACK holds every such point (rounded outward to
    float32). A degenerate partner (no plane) gets an unbounded box (the exact test decides)."""
    own = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    boxes = np.empty((len(partners), 6), np.float32)
    for s in range(0, len(partners), chunk):
        a = corner_values(positions, own[s:s + chunk]).astype(np.float64)
        b = corner_values(positions, partners[s:s + chunk]).astype(np.float64)
        n = _normals(b)
        length = np.linalg.norm(n, axis=1)
        n /= np.where(length > 0, length, 1.0)[:, None]
        height = np.abs(np.einsum("pcj,pj->pc", a - b[:, :1], n)).max(axis=1)
        size = np.maximum(np.abs(a).max(axis=(1, 2)), np.abs(b).max(axis=(1, 2)))
        grow = (height + BOX_SLACK * size)[:, None]
        low, high = b.min(axis=1) - grow, b.max(axis=1) + grow
        low[length == 0], high[length == 0] = -np.inf, np.inf
        with np.errstate(over="ignore"):
            boxes[s:s + chunk, :3] = np.nextafter(low.astype(np.float32), np.float32(-np.inf))
            boxes[s:s + chunk, 3:] = np.nextafter(high.astype(np.float32), np.float32(np.inf))
    return boxes


def _planes(p):
    """(n, ok, dominant, d) of triangles p (T, 3, 3): unit normals oriented one way per plane (the largest
    component positive), whether they have one (non-zero area), the axis of that component and the plane's offset
    from the origin along n."""
    n = _normals(p)
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    ok = length > 0
    n /= np.where(ok, length, np.float32(1.0))[:, None]
    dominant = np.argmax(np.abs(n), axis=1)
    n *= np.where(np.take_along_axis(n, dominant[:, None], 1) < 0, np.float32(-1.0), np.float32(1.0))
    return n, ok, dominant, np.einsum("ij,ij->i", n, p[:, 0])


def _through_pairs(positions, through, candidates, offset, objects) -> list:
    """Coincident.find's search for the partners of the triangles rays pass through (candidates, rows of
    `through`): exact copies (exact_copies) are searched by their group's first alone, which stands for the group on
    either side, and paired with each other (a glass duplicated in place, its 311k triangles each met in the search by
    its copy: 11 s of a public file's start-up)."""
    t = len(positions)
    members, starts = exact_copies(positions)
    if not len(members):
        return _pair_keys(corner_values(positions), [(candidates, objects, None)], offset)
    later = np.zeros(t, bool)
    later[members] = True
    later[members[starts[:-1]]] = False
    keys = _pair_keys(corner_values(positions), [(candidates[~later[candidates]], objects, None)], offset, skip=later)
    key = np.concatenate(keys) if keys else np.zeros(0, np.int64)
    a, b = _with_groups(key // t, key % t, members, starts)
    group_a, group_b = _group_pairs(members, starts)
    a, b = np.concatenate([a, group_a]), np.concatenate([b, group_b])
    keep = np.take(through, a) & (a != b)
    if objects is not None:
        keep &= np.take(objects, a) != np.take(objects, b)
    return [a[keep] * t + b[keep]]


def _pair_keys(p, passes, offset, skip=None) -> list:
    """The search behind Coincident.find and overlap_pairs: per pass (ask: the candidates, (m,) rows; objects: their
    rows' objects, partners then of another object, or None; pool: (T,) bool, the triangles partners may be, None:
    all) the pair keys a * T + b of triangles p (T, 3, 3) lying on one another with some area. A pass with a pool
    is mutual (its keys both ways) and tests at most OVERLAP_PAIR_BUDGET candidate pairs, those of its sparsest cells
    (_join); a pass without one is not bounded. skip: (T,) bool, triangles that are no one's partner, or None."""
    found = []
    n, ok, dominant, d = _planes(p)
    lo = np.minimum(np.minimum(p[:, 0], p[:, 1]), p[:, 2])
    hi = np.maximum(np.maximum(p[:, 0], p[:, 1]), p[:, 2])
    size = np.maximum(np.abs(lo), np.abs(hi))
    distance = 2.0 * offset(np.maximum(np.maximum(size[:, 0], size[:, 1]), size[:, 2]))
    corner_keys = None
    for ask, among_objects, pool in passes:
        if not len(ask):
            continue
        budget = None if pool is None else [OVERLAP_PAIR_BUDGET]
        for shift in (0.0, 0.5):
            for a, b in _cell_pairs(n, d, p, lo, hi, dominant, ask, ok, distance, shift, among_objects,
                                    pool if skip is None else (~skip if pool is None else pool & ~skip), budget):
                if among_objects is not None:
                    apart = among_objects[a] != among_objects[b]
                    a, b = a[apart], b[apart]
                margin = distance[a, None]
                near = np.all((lo[a] <= hi[b] + margin) & (lo[b] <= hi[a] + margin), axis=1)
                a, b = a[near], b[near]
                if among_objects is None and pool is not None:
                    # Both triangles ask here: each pair once (the test is symmetric), kept both ways below.
                    # Within one mesh, triangles sharing an edge are neighbours (or, on its same side, copies
                    # and folds, which copy_pairs finds): a flat face's fan and grid, most of the pairs here.
                    if corner_keys is None:
                        corner_keys = _corner_keys(p)
                    keep = (a < b) & (_shared_corners(corner_keys, a, b) < 2)
                    a, b = a[keep], b[keep]
                pa, pb = p[a].astype(np.float64), p[b].astype(np.float64)
                # b's corners within the distance of a's plane (not the planes' offsets from the origin:
                # two planes a hair apart and turned by a fraction of PLANE_ANGLE differ there by more
                # far from it)
                height = np.einsum("ij,ikj->ik", n[a].astype(np.float64), pb - pa[:, :1])
                near = np.abs(height).max(axis=1) <= distance[a]
                a, b, pa, pb = a[near], b[near], pa[near], pb[near]
                keep = _overlap(pa, pb, dominant[a])
                found.append(a[keep] * len(p) + b[keep])
                if pool is not None:   # the overlap is mutual
                    found.append(b[keep] * len(p) + a[keep])
    return found


def overlap_pairs(positions, offset, objects: np.ndarray | None, across: np.ndarray, asking: np.ndarray,
                  within: np.ndarray, mirrored: np.ndarray | None = None) -> np.ndarray:
    """Pair keys a * T + b (both ways) of opaque faces overlapping in part in one plane, from overlapping_planes'
    candidates: across's partners among other objects' triangles of across, looked for by asking's; within's among
    all of within, their own object's included. The search runs over those triangles only. Every ray leaving a
    triangle tests its partners, so their number is capped, facing and opposite partners apart: a triangle with
    more than MAX_OVERLAPS partners facing the other way keeps none of those (a floor under many objects standing
    on it: rays leave it at their footprints, which they cover, and they keep the floor), and one with more than
    MAX_SAME_FACING facing its way keeps none of those. Faces of one side lying on each other are seen, one or
    the other by the pixel, and Cycles' rays leaving either meet the other at once: a wall's long base face under
    the merlons of a battlement, coplanar with their fronts, is dark where they overlap. A triangle's front is its
    winding's side, the other where mirrored (T,) bool says its object mirrors it (None: none does)."""
    rows = np.flatnonzero(across | within)
    if len(rows) < 2:
        return np.zeros(0, np.int64)
    count = len(across)
    passes = [(np.flatnonzero(within[rows]), None, within[rows])]
    if objects is not None:
        passes.insert(0, (np.flatnonzero(asking[rows]), np.take(objects, rows), across[rows]))
    tri = corner_values(positions, rows)
    keys = _pair_keys(tri, passes, offset)
    if not keys:
        return np.zeros(0, np.int64)
    key = _unique(np.concatenate(keys))
    a, b = key // len(rows), key % len(rows)
    normal = _normals(tri.astype(np.float64))
    if mirrored is not None:
        normal *= np.where(np.take(mirrored, rows), -1.0, 1.0)[:, None]
    same = np.einsum("ij,ij->i", normal[a], normal[b]) > 0
    facing = np.bincount(a[same], minlength=len(rows))
    opposite = np.bincount(a[~same], minlength=len(rows))
    keep = np.where(same, facing[a] <= MAX_SAME_FACING, opposite[a] <= MAX_OVERLAPS)
    return rows[a[keep]] * count + rows[b[keep]]


def _normals(tri) -> np.ndarray:
    """(m, 3) the (unnormalised) normals of triangles tri (m, 3, 3), by their corners' order."""
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


# A plane holding more triangles than this (a finely subdivided floor, a terrain) is searched for overlaps only
# between objects: among one mesh's own triangles the search meets every neighbour, and its cost grows with them.
PLANE_GROUP_LIMIT = 4096
# ... and past this many such triangles in all, not at all (the search pairs each with its neighbours).
WITHIN_LIMIT = 1 << 16
# A triangle with more partners facing the other way, found by overlapping_planes, than this keeps none of them;
# with more facing its own way than MAX_SAME_FACING, none of those (overlap_pairs). A ray leaving it tests each in
# turn; faces of one side lying on each other are seen, so they are allowed more.
MAX_OVERLAPS = 16
MAX_SAME_FACING = 128
# The most (triangle, triangle) pairs one of those searches tests, its sparsest cells first (about 1 s).
OVERLAP_PAIR_BUDGET = 1 << 20


def overlapping_planes(positions, mask: np.ndarray, offset, objects: np.ndarray | None):
    """(across, asking, within), (T,) bool each, of the triangles `mask` marks: the candidates whose partners
    Coincident.find looks for. Triangles fall in one plane group when their normals share a bin of PLANE_ANGLE
    and their planes a slab far wider than the distance partners lie apart (two passes, bins and slabs moved by
    half of one). across: in a group holding another object's triangle (a wall's end face on the floor's rim, a
    rug on the floor), searched among other objects' triangles of that kind by those of `asking` (all but each
    group's largest object's, which they find); within: in a group of 3 to PLANE_GROUP_LIMIT triangles (a
    solidified wall's end face lying on its own mesh's next face), searched among all, their own object's
    included, none when they number more than WITHIN_LIMIT. Cycles' rays leaving one such face meet the other at
    once where they overlap. A sort per pass over the marked triangles: a curved mesh, every triangle in its own
    group, has none."""
    across, asking, within = (np.zeros(len(mask), bool) for _ in range(3))
    rows = np.flatnonzero(mask)
    if len(rows) < 2:
        return across, asking, within
    p = corner_values(positions, rows)
    n, ok, _, d = _planes(p)
    rows, n, p, d = rows[ok], n[ok], p[ok], d[ok]
    # Slabs eight times the distance partners may lie apart, which grows with the coordinates as the offsets from
    # the origin of two planes turned by a hair do (up to about a tenth of a milliradian: a solidified copy's).
    size = float(np.abs(p).max(initial=0.0))
    slab = 16.0 * float(offset(np.float32(size)))
    keys = []
    shared = np.zeros(len(rows), bool)   # in a group of two or more in either pass: most triangles are not
    for shift in (0.0, 0.5):
        bins = np.floor(n / PLANE_ANGLE + shift).astype(np.int64)
        key = _hash(_hash(bins[:, 0], bins[:, 1], bins[:, 2]), np.floor(d / slab + shift).astype(np.int64), 0)
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        shared |= counts[inverse.ravel()] > 1
        keys.append(key)
    rows = rows[shared]
    if len(rows) < 2:
        return across, asking, within
    owner = np.zeros(len(rows), np.int64) if objects is None else np.take(objects, rows).astype(np.int64)
    for key in keys:
        key = key[shared]
        order = np.lexsort((owner, key))
        k, o = key[order], owner[order]
        start = np.r_[True, k[1:] != k[:-1]]
        group = np.cumsum(start) - 1
        members = np.bincount(group)
        run_start = start | np.r_[True, o[1:] != o[:-1]]
        owners = np.bincount(group[run_start], minlength=len(members))
        mixed = (owners > 1)[group]
        across[rows[order[mixed]]] = True
        # Each group's largest owner (a floor under the objects standing on it) does not ask: the others find it
        # and the pair counts both ways, so that its own triangles are not paired with one another.
        run = np.cumsum(run_start) - 1
        run_size = np.bincount(run)
        run_group = group[run_start]
        top = np.zeros(len(members), np.int64)
        np.maximum.at(top, run_group, run_size)
        first_top = np.full(len(members), np.iinfo(np.int64).min)
        is_top = run_size == top[run_group]
        np.maximum.at(first_top, run_group[is_top], -np.flatnonzero(is_top))   # the first run of that size
        largest = -first_top[group] == run
        asking[rows[order[mixed & ~largest]]] = True
        # A quad's two halves share a plane and only touch: three or more triangles in one plane may overlap.
        within[rows[order[((members > 2) & (members <= PLANE_GROUP_LIMIT))[group]]]] = True
    if within.sum() > WITHIN_LIMIT:
        within[:] = False
    return across, asking, within


def exact_copies(positions) -> tuple[np.ndarray, np.ndarray]:
    """Groups of triangles whose three corners are the same points, in any order (a duplicated object or face, a
    Geometry Nodes instance placed twice on one point): (members, starts), int64, each group's members ascending in
    members[starts[g]:starts[g + 1]], groups of two or more only. A hash per triangle (its corners' hashes summed and
    xored, whatever their order) shares a 64-bit word with the triangle's index, and one sort of those words lines
    copies up (an index sort took ten times as long: 2 s for 19M triangles). Triangles whose hashes agree by chance
    (about 2^-30 of all pairs at 19M triangles, the hash keeping 39 bits there) are paired too: a ray leaving one never
    meets the other, whose points it is tested against (Coincident.crossing). Positions: (T, 3, 3) float32 or
    CornerRows, read a slice at a time."""
    t = len(positions)
    none = np.zeros(0, np.int64), np.zeros(1, np.int64)
    if t < 2:
        return none
    bits = np.uint64(max(1, (t - 1).bit_length()))
    words = np.empty(t, np.uint64)
    with np.errstate(over="ignore"):
        for s in range(0, t, KEY_CHUNK):
            corner = _corner_keys(positions[s:s + KEY_CHUNK])
            total = corner[:, 0] + corner[:, 1] + corner[:, 2]
            total *= np.uint64(0xD6E8FEB86659FD93)
            total ^= corner[:, 0] ^ corner[:, 1] ^ corner[:, 2]
            total >>= bits
            total <<= bits
            total |= np.arange(s, s + len(corner), dtype=np.uint64)
            words[s:s + len(corner)] = total
    words.sort()
    key = words >> bits
    same = key[1:] == key[:-1]
    if not same.any():
        return none
    in_group = np.r_[same, False] | np.r_[False, same]
    rows = (words[in_group] & ((np.uint64(1) << bits) - np.uint64(1))).astype(np.int64)
    key = key[in_group]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1], True])
    return rows, starts


def _group_pairs(members, starts) -> tuple[np.ndarray, np.ndarray]:
    """Every ordered pair (a, b), a != b, within each group of exact_copies: groups of each size up to 8 (most: a
    duplicated object's are two) as a (groups, size) table, column by column; larger ones by their ranks."""
    size = np.diff(starts)
    a, b = [], []
    for k in np.unique(size):
        first = starts[:-1][size == k]
        if k <= 8:
            table = members[first[:, None] + np.arange(k)]
            for i in range(k):
                for j in range(k):
                    if i != j:
                        a.append(table[:, i])
                        b.append(table[:, j])
        else:
            n = len(first) * k * k
            rank, base = np.arange(n) % (k * k), np.repeat(first, k * k)
            x, y = members[base + rank // k], members[base + rank % k]
            a.append(x[x != y])
            b.append(y[x != y])
    if not a:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(a), np.concatenate(b)


def copy_pairs(positions, offset, edges: bool = True) -> np.ndarray:
    """Pair keys a * T + b (a != b) of triangles lying on one another that share an edge (by its corners'
    coordinates, in either direction) and lie on its same side: a copy of a triangle (a duplicated face or
    object, its normal turned or not) and the halves of a doubled quad split along its other diagonal. Their
    planes are within PLANE_ANGLE and twice the ray offset (offset(|p|max)) of each other. A mesh's neighbours
    share an edge from its two sides and are not looked at: each edge is keyed by its two corners and the side
    its triangle lies on, so that only copies (and folds) share a key.

    Edge e of triangle i is numbered e * T + i (corners e and e + 1, the third e + 2). The keys are sorted
    alone first: most scenes have no equal keys and stop there; otherwise only the edges of equal keys are
    ordered and compared. A 1M-triangle mesh takes about a third of a second and under 50 MB beside its
    positions. Exact copies (exact_copies) are paired as groups first, and only each group's first triangle takes
    part in the edges' search, its pairs then given to the whole group: paired by their three shared edges, a
    mesh duplicated whole cost 14 us a triangle. edges=False: exact copies alone (for scenes too large for the
    edges' search)."""
    t = len(positions)
    members, starts = exact_copies(positions)
    group_a, group_b = _group_pairs(members, starts)
    exact = group_a * t + group_b
    if not edges:
        return exact
    # 32-bit keys: half the sort; edges of equal keys are compared whole below, so a collision costs a compare.
    keys = np.empty(3 * t, np.uint32)
    for s in range(0, t, KEY_CHUNK):   # small temporaries, used again: fresh pages cost more than the arithmetic
        q = positions[s:s + KEY_CHUNK]   # a slice of an array or of CornerRows: the whole is never gathered
        corner = _corner_keys(q)
        with np.errstate(over="ignore"):
            for k in range(3):
                edge = corner[:, k] + corner[:, (k + 1) % 3]
                edge ^= edge >> np.uint64(32)
                edge ^= _edge_sides(*_edge_corners(q, k))[0].astype(np.uint64)
                keys[k * t + s:k * t + s + len(q)] = edge
    live = None
    if len(members):
        # Only each exact group's first triangle takes part: the others' edges would pair with it three times over.
        later = np.ones(len(members), bool)
        later[starts[:-1]] = False
        live = np.ones(t, bool)
        live[members[later]] = False
        live = np.tile(live, 3)
    ordered = np.sort(keys if live is None else keys[live])
    repeated = ordered[1:][ordered[1:] == ordered[:-1]]
    del ordered
    if not len(repeated):
        return exact
    values = _unique(repeated, ordered=True)
    # The edges of repeated keys: a table of 2^24 flags by the keys' low bits, then the few flagged looked up.
    flags = np.zeros(1 << 24, bool)
    flags[values & np.uint32(0xFFFFFF)] = True
    flagged = flags[keys & np.uint32(0xFFFFFF)]
    edges = np.flatnonzero(flagged if live is None else flagged & live)
    at = np.minimum(np.searchsorted(values, keys[edges]), len(values) - 1)
    edges = edges[values[at] == keys[edges]]
    by = edges[np.argsort(keys[edges], kind="stable")]
    hs = keys[by]
    start = np.flatnonzero(np.r_[True, hs[1:] != hs[:-1]])
    size = np.diff(np.r_[start, len(hs)])
    start, size = start[size > 1], size[size > 1]
    rank, per = _ranks(size * size), np.repeat(size, size * size)
    base = np.repeat(start, size * size)
    i, j = by[base + rank // per], by[base + rank % per]
    a, b = i % t, j % t
    (first_i, second_i, third_i), (first_j, second_j, third_j) = _edge_corners(positions, i), _edge_corners(positions, j)
    same_edge = ((first_i == first_j).all(axis=1) & (second_i == second_j).all(axis=1)) | \
        ((first_i == second_j).all(axis=1) & (second_i == first_j).all(axis=1))
    side_i, across_i, e_i, f_i = _edge_sides(first_i, second_i, third_i)
    side_j, across_j = _edge_sides(first_j, second_j, third_j)[:2]
    keep = (a != b) & same_edge & (side_i == side_j)
    if not keep.any():
        return exact
    a, b, first_i, third_j = a[keep], b[keep], first_i[keep], third_j[keep]
    # In one plane: the third corners' offsets across the edge parallel, and b's third corner near a's plane.
    e0 = first_i.astype(np.float64)
    ua, ub = across_i[keep].astype(np.float64), across_j[keep].astype(np.float64)
    la, lb = np.linalg.norm(ua, axis=1), np.linalg.norm(ub, axis=1)
    ok = (la > 0) & (lb > 0)
    la, lb = np.where(ok, la, 1.0), np.where(ok, lb, 1.0)
    cos = np.einsum("ij,ij->i", ua, ub) / (la * lb)
    na = np.cross(e_i[keep].astype(np.float64), f_i[keep].astype(np.float64))
    na /= np.maximum(np.linalg.norm(na, axis=1), 1e-300)[:, None]
    size = np.maximum(np.abs(corner_values(positions, a)).max(axis=(1, 2)),
                      np.abs(corner_values(positions, b)).max(axis=(1, 2)))
    near = np.abs(np.einsum("ij,ij->i", na, third_j.astype(np.float64) - e0)) <= 2.0 * offset(size)
    keep = ok & (cos >= np.cos(PLANE_ANGLE)) & near
    a, b = a[keep].astype(np.int64), b[keep].astype(np.int64)
    if len(members):
        a, b = _with_groups(a, b, members, starts)
    return np.concatenate([exact, a * t + b])


def _unique(x, ordered: bool = False) -> np.ndarray:
    """The distinct values of x, ascending (np.unique by a sort: NumPy 2's hashing np.unique took 1.3 s for the 2M
    keys of a duplicated mesh, a sort 0.1 s). ordered: x is sorted already."""
    x = x if ordered else np.sort(x)
    return x[np.r_[True, x[1:] != x[:-1]]] if len(x) else x


def _in_sorted(x, values) -> np.ndarray:
    """np.isin(x, values) for values sorted ascending and distinct."""
    if not len(values):
        return np.zeros(len(x), bool)
    at = np.minimum(np.searchsorted(values, x), len(values) - 1)
    return values[at] == x


def _with_groups(a, b, members, starts):
    """Pairs (a, b) of group firsts (exact_copies) given to every member of their groups, on either side."""
    group = np.repeat(np.arange(len(starts) - 1), np.diff(starts))
    order = np.argsort(members, kind="stable")
    sorted_members, sorted_group = members[order], group[order]

    def spread(x, y):
        at = np.minimum(np.searchsorted(sorted_members, x), len(sorted_members) - 1)
        grouped = sorted_members[at] == x
        g = sorted_group[at[grouped]]
        size = starts[g + 1] - starts[g]
        extra_x = members[np.repeat(starts[g], size) + _ranks(size)]
        extra_y = np.repeat(y[grouped], size)
        return np.concatenate([x[~grouped], extra_x]), np.concatenate([y[~grouped], extra_y])
    a, b = spread(a, b)
    b, a = spread(b, a)
    return a, b


# Triangles whose edge keys copy_pairs makes at once.
KEY_CHUNK = 1 << 16


def _edge_corners(p, edge):
    """The corners (first, second, third), each (m, 3) float32, of edges numbered as copy_pairs numbers them:
    an int k for edge k of every triangle of p (T, 3, 3), or an array of numbers e * T + i of the triangles p
    (an array or CornerRows) holds."""
    if isinstance(edge, int):
        return p[:, edge], p[:, (edge + 1) % 3], p[:, (edge + 2) % 3]
    tri, k = edge % len(p), edge // len(p)
    corners, rows = corner_values(p, tri), np.arange(len(tri))
    return corners[rows, k], corners[rows, (k + 1) % 3], corners[rows, (k + 2) % 3]


# A direction of no symmetry: an edge's side is where its third corner's offset across it points along it.
_SIDE_DIRECTION = (np.float32(0.5773), np.float32(0.5781), np.float32(0.5766))


def _edge_sides(first, second, third):
    """(side, across, e, f) of edges: e = second - first, f = third - first, across f's part across e, and side
    (bool) whether across points along _SIDE_DIRECTION. Float32, so that copies of an edge, whose corners are
    equal, get equal sides in either direction but where across is within rounding of square to the direction."""
    e, f = second - first, third - first
    ee = e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2]
    fe = f[:, 0] * e[:, 0] + f[:, 1] * e[:, 1] + f[:, 2] * e[:, 2]
    along = fe / np.maximum(ee, np.float32(1e-30))
    across = f - along[:, None] * e
    w = _SIDE_DIRECTION
    side = across[:, 0] * w[0] + across[:, 1] * w[1] + across[:, 2] * w[2] > 0
    return side, across, e, f


def embree_meets(tri, q, d) -> np.ndarray:
    """(m,) bool: whether a ray from q (m, 3) float32, a point on a triangle lying on tri (m, 3, 3), leaving in
    direction d (m, 3) float32 (its side's normal will do: the ray starts in the plane, so where it meets it does
    not depend on the direction), meets tri by Embree's robust triangle test, the one Cycles' scenes use
    (RTC_SCENE_FLAG_ROBUST: embree kernels/geometry/triangle_intersector_pluecker.h), in float32 as Embree runs it.
    Cycles' rays skip only the triangle they leave and start where its hit lies (tmin 0, a hit at t >= 0 counts),
    so whether they meet a face lying on theirs is this test's rounding: the corners taken from the ray's origin,
    the edge tests U, V, W within a float32 epsilon of their sum, and the sign of T = (corner 0 - origin) . Ng
    against the side. A face of constant x, y or z that the point lies in exactly gives T = 0: met (a duplicated
    cube renders black); a turned one is met by about half the rays; a face a hair ahead or behind, beyond the
    rounding, is met or not; and the rounding grows with the distance to the corners (a Solidify spike hundreds of
    km long lying on a wall meets a ray or not by chance)."""
    v0, v1, v2 = (tri[:, k] - q for k in range(3))
    e0, e1, e2 = v2 - v0, v0 - v1, v1 - v2
    u = dot_rows_fused(cross_rows_fused(e0, v2 + v0), d)
    v = dot_rows_fused(cross_rows_fused(e1, v0 + v1), d)
    w = dot_rows_fused(cross_rows_fused(e2, v1 + v2), d)
    eps = np.float32(np.finfo(np.float32).eps) * np.abs(u + v + w)
    inside = (np.minimum(np.minimum(u, v), w) >= -eps) | (np.maximum(np.maximum(u, v), w) <= eps)
    # Embree's stable_triangle_normal (common/math/vec3.h): per component, the cross product of the two edges whose
    # products are the smaller.
    ab = e0[:, [2, 0, 1]] * e1[:, [1, 2, 0]]
    bc = e1[:, [2, 0, 1]] * e2[:, [1, 2, 0]]
    ng = np.where(np.abs(ab) < np.abs(bc), cross_rows_fused(e0, e1), cross_rows_fused(e1, e2))
    den = dot_rows_fused(ng, d)
    t = dot_rows_fused(v0, ng)
    return inside & (den != 0) & ((t == 0) | ((t > 0) == (den > 0)))


def _corner_keys(p) -> np.ndarray:
    """(T, 3) uint64: a hash of each corner's coordinates, to the bit (two corners may share one, rarely). Column
    by column in place: the whole (T, 3, 3) widened at once took twenty times as long."""
    bits = np.ascontiguousarray(p).reshape(-1, 3).view(np.uint32)
    out = bits[:, 0].astype(np.uint64)
    with np.errstate(over="ignore"):
        out *= np.uint64(0x9E3779B97F4A7C15)
        for k, factor in ((1, 0xC2B2AE3D27D4EB4F), (2, 0x165667B19E3779F9)):
            column = bits[:, k].astype(np.uint64)
            column *= np.uint64(factor)
            out ^= column
    return out.reshape(p.shape[:-1])


def _shared_corners(keys, a, b) -> np.ndarray:
    """(m,) how many of triangle a's corners are also b's (by _corner_keys)."""
    ka, kb = keys[a], keys[b]
    return sum((ka[:, i:i + 1] == kb).any(axis=1).astype(np.int8) for i in range(3))


def _ranks(counts: np.ndarray) -> np.ndarray:
    """0, 1, ..., c - 1 for each count c, concatenated."""
    if not len(counts):
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    return np.arange(ends[-1]) - np.repeat(ends - counts, counts)


def _cell_pairs(n, d, p, lo, hi, dominant, candidates, ok, distance, shift: float, objects=None, pool=None,
                budget=None):
    """(a, b) index pairs in chunks, a a candidate and b != a a triangle whose normal falls in a's bin of
    PLANE_ANGLE, whose plane lies in a's slab of planes and whose box, seen along that normal, shares a cell of
    the bin's grid (bins, slabs and cells moved by `shift` of one: two passes catch the pairs an edge splits).
    A bin's cells are about as wide as its candidates (their geometric mean), so that a triangle on a plane of
    many meets its neighbours only; a box of more than _MAX_CELLS cells meets its whole slab instead.
    pool: (T,) bool, the triangles b may be (None: all). budget: as _join's."""
    key = np.floor(n / PLANE_ANGLE + shift).astype(np.int64)
    # One int64 per bin (a hash: two bins may share one, which only adds pairs the exact tests drop).
    key = _hash(key[:, 0], key[:, 1], key[:, 2])
    _, nbin = np.unique(key, return_inverse=True)
    nbin = nbin.ravel()
    nbin[~ok] = -1                                     # degenerate triangles have no plane
    # A candidate alone in its bin (a smooth glass's triangles, each turned its own way) has no partner.
    members = np.bincount(nbin[ok], minlength=nbin.max() + 1)
    cand = candidates[ok[candidates]]
    cand = cand[members[nbin[cand]] > 1]
    if not len(cand):
        return
    others = np.isin(nbin, nbin[cand])
    others = np.flatnonzero(others if pool is None else others & pool)
    # Each bin seen along its candidates' dominant axis, in cells of its candidates' geometric mean size.
    axes = np.array([[1, 2], [2, 0], [0, 1]])
    drop = np.zeros(nbin.max() + 1, np.int64)
    drop[nbin[cand]] = dominant[cand]
    c_seen, t_seen = axes[dominant[cand]], axes[drop[nbin[others]]]
    c_lo = np.take_along_axis(lo[cand], c_seen, 1) - distance[cand, None]
    c_hi = np.take_along_axis(hi[cand], c_seen, 1) + distance[cand, None]
    t_lo, t_hi = np.take_along_axis(lo[others], t_seen, 1), np.take_along_axis(hi[others], t_seen, 1)
    size = np.log2(np.maximum((c_hi - c_lo).max(axis=1), 1e-30)).astype(np.float64)
    mean = np.bincount(nbin[cand], size, minlength=len(drop)) / np.maximum(np.bincount(nbin[cand], minlength=len(drop)), 1)
    cell = np.exp2(np.round(mean))                     # per bin
    # Slabs of planes one cell thick (far thicker than the distance partners may be apart).
    c_cell, t_cell = cell[nbin[cand]], cell[nbin[others]]
    c_group = _hash(nbin[cand], np.floor(d[cand] / c_cell + shift).astype(np.int64), 0)
    t_group = _hash(nbin[others], np.floor(d[others] / t_cell + shift).astype(np.int64), 0)
    if objects is not None:
        # Only slabs that hold more than one object's triangles can hold a partner.
        groups = np.concatenate([c_group, t_group])
        owners = np.concatenate([objects[cand], objects[others]])
        order = np.lexsort((owners, groups))
        g, o = groups[order], owners[order]
        new_owner = np.r_[True, (g[1:] != g[:-1]) | (o[1:] != o[:-1])]
        keys, count = np.unique(g[new_owner], return_counts=True)
        shared = keys[count > 1]
        c_in, t_in = np.isin(c_group, shared), np.isin(t_group, shared)
        cand, c_group, c_lo, c_hi, c_cell = cand[c_in], c_group[c_in], c_lo[c_in], c_hi[c_in], c_cell[c_in]
        others, t_group, t_lo, t_hi, t_cell = others[t_in], t_group[t_in], t_lo[t_in], t_hi[t_in], t_cell[t_in]
        if not len(cand):
            return
    c_keys, c_owner = _cells(c_lo / c_cell[:, None] + shift, c_hi / c_cell[:, None] + shift, c_group, _MAX_CELLS)
    t_keys, t_owner = _cells(t_lo / t_cell[:, None] + shift, t_hi / t_cell[:, None] + shift, t_group, _MAX_CELLS)
    yield from _join(c_keys, cand[c_owner], t_keys, others[t_owner], budget)
    # Boxes over _MAX_CELLS cells (a large floor under small glass, a large pane over small tiles) meet every
    # triangle of their slab on the other side.
    for side_keys, side, side_owner, other_keys, other in ((c_group, cand, c_owner, t_group, others),
                                                         (t_group, others, t_owner, c_group, cand)):
        big = np.ones(len(side), bool)
        big[side_owner] = False
        big = np.flatnonzero(big)
        if len(big):
            if side is cand:
                yield from _join(side_keys[big], side[big], other_keys, other, budget)
            else:
                yield from _join(other_keys, other, side_keys[big], side[big], budget)


def _hash(i, j, k):
    """One int64 for integer triples (two triples may share one)."""
    with np.errstate(over="ignore"):
        return (np.asarray(i, np.int64) * np.int64(73856093)) ^ (np.asarray(j, np.int64) * np.int64(19349663)) \
            ^ (np.asarray(k, np.int64) * np.int64(83492791))


# A box covering more grid cells than this is paired with its whole slab of planes on the other side.
_MAX_CELLS = 1024


def _cells(lo, hi, group, limit=None):
    """Keys (int64, a hash of (group, i, j): two cells may share one, never one cell two) of the grid cells
    that boxes [lo, hi] (m, 2) in cell units cover, and the box of each key; boxes over `limit` cells are left
    out."""
    first = np.floor(lo).astype(np.int64)
    span = np.floor(hi).astype(np.int64) - first + 1
    count = span[:, 0] * span[:, 1]
    owner = np.arange(len(lo))
    if limit is not None:
        owner = owner[count <= limit]
    c = count[owner]
    rank = _ranks(c) if len(c) else np.zeros(0, np.int64)
    who = np.repeat(owner, c)
    i = first[who, 0] + rank % span[who, 0]
    j = first[who, 1] + rank // span[who, 0]
    return _hash(group[who], i, j), who


def _join(c_keys, c_tri, t_keys, t_tri, budget=None):
    """(candidate, triangle) pairs with equal keys, in chunks of about _CHUNK. budget: None, or a one-item list
    of the pairs still allowed, lowered by these. Past it, the candidates' cells that meet the fewest triangles are
    joined, as many as it allows, and the densest are left out (a fan of thousands of triangles in one cell meets
    itself whole; two faces lying on each other elsewhere in the mesh are still found)."""
    if not len(c_keys) or not len(t_keys):
        return
    order = np.argsort(t_keys, kind="stable")
    t_sorted = t_keys[order]
    first = np.searchsorted(t_sorted, c_keys, side="left")
    counts = np.searchsorted(t_sorted, c_keys, side="right") - first
    ends = np.cumsum(counts)
    if budget is not None:
        if ends[-1] > budget[0]:
            sparse = np.argsort(counts, kind="stable")
            kept = np.sort(sparse[np.cumsum(counts[sparse]) <= budget[0]])
            c_keys, c_tri, first, counts = c_keys[kept], c_tri[kept], first[kept], counts[kept]
            ends = np.cumsum(counts)
            if not len(kept):
                return
        budget[0] -= int(ends[-1])
    start = 0
    while start < len(c_keys):
        stop = max(int(np.searchsorted(ends, (ends[start - 1] if start else 0) + _CHUNK, side="right")), start + 1)
        c = counts[start:stop]
        if c.sum():
            a = np.repeat(c_tri[start:stop], c)
            b = t_tri[order[np.repeat(first[start:stop], c) + _ranks(c)]]
            other = a != b
            yield a[other].astype(np.int64), b[other].astype(np.int64)
        start = stop


def _overlap(a, b, dominant) -> np.ndarray:
    """(m,) bool: triangles a and b (m, 3, 3) overlap with some area, seen along their common normal (projected
    by dropping each pair's dominant axis); touching along an edge or a corner is not overlap."""
    axes = np.array([[1, 2], [2, 0], [0, 1]])[dominant]                  # (m, 2) the two kept axes
    pa = np.take_along_axis(a, axes[:, None, :], 2)                       # (m, 3, 2)
    pb = np.take_along_axis(b, axes[:, None, :], 2)
    # Per component (x, y of each corner) arrays: NumPy's reductions over axes of length 3 are slow.
    ax, ay = [pa[:, c, 0] for c in range(3)], [pa[:, c, 1] for c in range(3)]
    bx, by = [pb[:, c, 0] for c in range(3)], [pb[:, c, 1] for c in range(3)]
    size = np.maximum.reduce([np.maximum.reduce(v) - np.minimum.reduce(v) for v in (ax, ay, bx, by)])
    margin = 1e-6 * size
    separated = np.zeros(len(a), bool)
    for xs, ys in ((ax, ay), (bx, by)):
        for k in range(3):
            ex, ey = xs[(k + 1) % 3] - xs[k], ys[(k + 1) % 3] - ys[k]
            length = np.sqrt(ex * ex + ey * ey)
            nx, ny = -ey / np.where(length > 0, length, 1.0), ex / np.where(length > 0, length, 1.0)
            sa = [x * nx + y * ny for x, y in zip(ax, ay)]
            sb = [x * nx + y * ny for x, y in zip(bx, by)]
            separated |= (np.maximum.reduce(sa) <= np.minimum.reduce(sb) + margin) | \
                (np.maximum.reduce(sb) <= np.minimum.reduce(sa) + margin)
    return ~separated


def _barycentrics(tri, q):
    """Barycentrics (w1, w2) of points q (m, 3) projected onto triangles tri (m, 3, 3), float32, and whether
    they lie inside (with a margin of a millionth of the triangle's size, for points on a shared edge)."""
    e1, e2, v = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], q - tri[:, 0]
    d11, d12, d22 = (np.einsum("ij,ij->i", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    v1, v2 = np.einsum("ij,ij->i", v, e1), np.einsum("ij,ij->i", v, e2)
    det = d11 * d22 - d12 * d12
    ok = det > 0
    det = np.where(ok, det, 1.0)
    w1 = (d22 * v1 - d12 * v2) / det
    w2 = (d11 * v2 - d12 * v1) / det
    tol = 1e-6
    inside = ok & (w1 >= -tol) & (w2 >= -tol) & (w1 + w2 <= 1 + tol)
    return w1.astype(np.float32), w2.astype(np.float32), inside
