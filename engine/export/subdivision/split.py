"""DiagSplit (Fisher et al. 2009) as Cycles runs it (subd/split.cpp, subd/subpatch.h): each patch is split into
subpatches until every edge has an edge factor T, the number of segments it is diced into, so that a segment
projects to about the dicing rate in pixels (or object units). Edges are shared between the subpatches on
either side (keyed by their end vertices), so both sides dice them alike and the mesh is watertight.

- T of an edge (u0 -> u1 in a patch): the surface is sampled at 3 points; L is each step's length divided by the
  dicing camera's pixel size at its middle (object space: not divided); tmin = ceil(sum L / rate), tmax =
  ceil(2 max L / rate). T = max(tmax, 1), but -1 ("split it") when tmax - tmin > 1 or T > 8; an edge met first
  by a subpatch (an n-gon's) sums the T of its two halves instead. T is capped at 2^max_level times the edge's
  length in the patch (half for an n-gon's patches): Max Subdivisions.
- A quad's edges are split once in both directions from the start. A subpatch splits across the longer pair
  of opposite edges when an edge must be split (or when edge factors above 8 differ by half or more); a
  split edge gets its middle vertex, the new edge across its own T. A quad with an edge to split whose
  opposite edge has one segment becomes two triangles.
"""
from __future__ import annotations

import math
import sys

import numpy as np

from .cage import Cage

NON_UNIFORM = -1
MAX_DEPTH = 16
MAX_SEGMENTS = 8
TEST_STEPS = 3
SPLIT_THRESHOLD = 1
# Cycles' tie-break towards splitting u when opposite edges have equal lengths.
BIAS = 1.00012345


class Edge:
    """An edge between two vertices: T its edge factor (0 unset, -1 to split), its vertices along it from
    `second` on, its middle vertex once split, its length in world (or object) units."""
    __slots__ = ("start", "end", "mid", "T", "length", "second", "depth")

    def __init__(self, start: int, end: int, depth: int):
        self.start, self.end, self.depth = start, end, depth
        self.mid, self.T, self.length, self.second = -1, 0, 0.0, -1

    def must_split(self) -> bool:
        return self.T == NON_UNIFORM

    def vertex(self, n: int) -> int:
        if n == 0:
            return self.start
        if n == self.T:
            return self.end
        return self.second + n - 1


class Side:
    """A subpatch's side: its edge, whether it runs against the edge, and which vertices it sets (its start
    vertex, the vertices inside it)."""
    __slots__ = ("edge", "reversed", "own_vertex", "own_edge")

    def __init__(self):
        self.edge, self.reversed, self.own_vertex, self.own_edge = None, False, False, False

    def copy(self) -> "Side":
        s = Side()
        s.edge, s.reversed, s.own_vertex, s.own_edge = self.edge, self.reversed, self.own_vertex, self.own_edge
        return s

    def start(self) -> int:
        return self.edge.end if self.reversed else self.edge.start

    def end(self) -> int:
        return self.edge.start if self.reversed else self.edge.end

    def vertex(self, n: int) -> int:
        return self.edge.vertex(self.edge.T - n if self.reversed else n)


class SubPatch:
    """A quad (4 sides, uvs counter-clockwise from the patch's (0, 0)) or triangle (3) of a patch."""
    __slots__ = ("patch", "face", "corner", "triangle", "uvs", "sides", "inner", "first_triangle")

    def __init__(self, patch: int, face: int, corner: int = 0):
        self.patch, self.face, self.corner, self.triangle = patch, face, corner, False
        self.uvs = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
        self.sides = [Side() for _ in range(4)]
        self.inner = self.first_triangle = 0

    def copy(self) -> "SubPatch":
        s = SubPatch(self.patch, self.face, self.corner)
        s.triangle, s.uvs = self.triangle, list(self.uvs)
        s.sides = [side.copy() for side in self.sides]
        for side in s.sides:
            side.own_vertex = side.own_edge = False
        return s

    def factors(self) -> tuple:
        return tuple(side.edge.T for side in self.sides[:3 if self.triangle else 4])

    def inner_vertex_count(self) -> int:
        t = self.factors()
        if self.triangle:
            m = max(t)
            return 0 if m <= 2 else m * (m - 1) // 2
        return (max(t[0], t[2]) - 1) * (max(t[3], t[1]) - 1)

    def triangle_count(self) -> int:
        t = self.factors()
        if self.triangle:
            m = max(t)
            if m == 1:
                return 1
            if m == 2:
                return sum(t) - 2
            return (m - 2) ** 2 + sum(t) + 3 * (m - 2)
        mu, mv = max(t[0], t[2]), max(t[3], t[1])
        if mu == 1:
            return t[3] + t[1]
        if mv == 1:
            return t[0] + t[2]
        return (mu - 2) * (mv - 2) * 2 + sum(t) + 2 * (mu - 2) + 2 * (mv - 2)

    def map_uv(self, u: float, v: float) -> tuple[float, float]:
        """A point of the subpatch (its own (u, v)) in the patch's (u, v)."""
        a, b, c = self.uvs[0], self.uvs[1], self.uvs[2]
        if self.triangle:
            w = 1.0 - u - v
            x, y = w * a[0] + u * b[0] + v * c[0], w * a[1] + u * b[1] + v * c[1]
        else:
            d = self.uvs[3]
            x0, y0 = a[0] + v * (d[0] - a[0]), a[1] + v * (d[1] - a[1])
            x1, y1 = b[0] + v * (c[0] - b[0]), b[1] + v * (c[1] - b[1])
            x, y = x0 + u * (x1 - x0), y0 + u * (y1 - y0)
        return min(max(x, 0.0), 1.0), min(max(y, 0.0), 1.0)


class DiagSplit:
    """Splits every patch of a cage. surface : positions(patch (N,), uv (N, 2)) -> (N, 3) object space;
    to_world : (4, 4) object-to-world matrix; camera : a dicing.DicingCamera (None: object space, rate in
    object units); rate : the dicing rate; max_level : Max Subdivisions."""

    def __init__(self, cage: Cage, surface, rate: float, max_level: int, camera=None, to_world=None):
        self.cage, self.surface, self.camera = cage, surface, camera
        self.patches = cage.patches()
        self.rate = float(rate)
        self.max_t = 1 << int(max_level)
        self.to_world = None if camera is None else np.asarray(to_world, np.float64)
        if self.to_world is not None:
            self.linear, self.offset = self.to_world[:3, :3], self.to_world[:3, 3]
        self.edges: dict[tuple, Edge] = {}
        self.subpatches: list[SubPatch] = []
        self.vertex_count = len(cage.positions)
        self.triangle_total = 0
        self.owned = np.zeros(len(cage.positions), bool)

    # ------------------------------------------------------------ allocation
    def alloc_vertices(self, n: int) -> int:
        first = self.vertex_count
        self.vertex_count += n
        return first

    def edge(self, v0: int, v1: int, depth: int) -> tuple[Edge, bool]:
        key = (v0, v1) if v0 < v1 else (v1, v0)
        found = self.edges.get(key)
        if found is not None:
            return found, False
        made = self.edges[key] = Edge(v0, v1, depth)
        return made, True

    def side(self, side: Side, v0: int, v1: int, depth: int, own_edge: bool, own_vertex: bool) -> None:
        side.edge, missing = self.edge(min(v0, v1), max(v0, v1), depth)
        side.own_vertex = False
        side.own_edge = missing and own_edge
        side.reversed = side.edge.start != v0
        if own_vertex:
            if v0 < len(self.owned):
                if not self.owned[v0]:
                    self.owned[v0] = True
                    side.own_vertex = True
            else:
                side.own_vertex = True

    def finish(self, sub: SubPatch) -> None:
        sub.inner = self.alloc_vertices(sub.inner_vertex_count())
        sub.first_triangle = self.triangle_total
        self.triangle_total += sub.triangle_count()
        self.subpatches.append(sub)

    # ------------------------------------------------------------ edge factors
    def _world(self, patch: int, u: float, v: float):
        p = self.surface.point(patch, u, v)
        return p if self.to_world is None else self.linear @ p + self.offset

    def factor(self, patch: int, uv0, uv1, depth: int, resolve: bool = False) -> tuple[int, float]:
        """(T, world length) of the edge uv0 -> uv1 of a patch (Cycles' DiagSplit::T, 3 test steps)."""
        a, b = uv0, uv1
        if b[0] < a[0] or b[1] < a[1]:
            a, b = b, a
        mid = (0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]))
        p0, p1, p2 = self._world(patch, *a), self._world(patch, *mid), self._world(patch, *b)
        d0, d1 = p1 - p0, p2 - p1
        l0, l1 = math.sqrt(d0 @ d0), math.sqrt(d1 @ d1)
        world = l0 + l1
        if self.camera is not None:
            l0 /= self.camera.pixel_size_at(0.5 * (p0 + p1))
            l1 /= self.camera.pixel_size_at(0.5 * (p1 + p2))
        tmin = math.ceil((l0 + l1) / self.rate)
        tmax = math.ceil((TEST_STEPS - 1) * max(l0, l1) / self.rate)
        t = max(tmax, 1)
        if tmax - tmin > SPLIT_THRESHOLD:
            if not resolve:
                t = NON_UNIFORM
            else:
                ta, la = self.factor(patch, a, mid, depth, True)
                tb, lb = self.factor(patch, mid, b, depth, True)
                t, world = ta + tb, la + lb
        if not resolve and t > MAX_SEGMENTS:
            t = NON_UNIFORM
        t = self.limit(patch, a, b, t)
        if depth >= MAX_DEPTH - 3 and t == NON_UNIFORM:
            t = MAX_SEGMENTS
        return t, world

    def limit(self, patch: int, a, b, t: int) -> int:
        most = int(self.max_t * math.hypot(b[0] - a[0], b[1] - a[1]))
        if self.patches.ngon[patch]:
            most >>= 1     # an n-gon's patches span half its edges
        return 1 if most <= 1 else min(t, most)

    def assign(self, edge: Edge, patch: int, uv0, uv1, resolve: bool = False) -> None:
        edge.T, edge.length = self.factor(patch, uv0, uv1, edge.depth, resolve)
        if edge.depth == -1 and edge.T == 1:
            edge.T = 2     # the first split of a quad must be able to split this edge again
        if edge.T > 0:
            edge.second = self.alloc_vertices(edge.T - 1)

    def resolve(self, sub: SubPatch) -> None:
        count = 3 if sub.triangle else 4
        for k in range(count):
            if sub.sides[k].edge.T == 0:
                self.assign(sub.sides[k].edge, sub.patch, sub.uvs[k], sub.uvs[(k + 1) % count], True)

    # ------------------------------------------------------------ splitting
    def split_edge(self, patch: int, side: Side, side_a: Side, side_b: Side, uv0, uv1):
        """Split a side in two (side_a from its start, side_b to its end); returns the patch uv of the split."""
        if side.reversed:
            uv0, uv1 = uv1, uv0
        edge = side.edge
        if edge.must_split():
            p = (0.5 * (uv0[0] + uv1[0]), 0.5 * (uv0[1] + uv1[1]))
            if edge.mid == -1:
                edge.mid = self.alloc_vertices(1)
                self.assign(self.edge(edge.start, edge.mid, edge.depth + 1)[0], patch, uv0, p)
                self.assign(self.edge(edge.mid, edge.end, edge.depth + 1)[0], patch, p, uv1)
        else:
            mid = edge.T // 2
            if edge.mid == -1:
                edge.mid = edge.second - 1 + mid
                first = self.edge(edge.start, edge.mid, edge.depth + 1)[0]
                rest = self.edge(edge.mid, edge.end, edge.depth + 1)[0]
                first.T, rest.T = mid, edge.T - mid
                first.second, rest.second = edge.second, edge.second + mid
            f = mid / edge.T
            p = (uv0[0] + f * (uv1[0] - uv0[0]), uv0[1] + f * (uv1[1] - uv0[1]))
        self.side(side_a, side.start(), edge.mid, edge.depth + 1, False, False)
        self.side(side_b, edge.mid, side.end(), edge.depth + 1, False, False)
        side_a.own_edge = side_b.own_edge = side.own_edge
        side_a.own_vertex, side_b.own_vertex = side.own_vertex, side.own_edge
        return p

    def split_quad(self, sub: SubPatch) -> None:
        self.resolve(sub)
        s = sub.sides
        t0, t1, t2, t3 = (side.edge.T for side in s)
        min_u, max_u, min_v, max_v = min(t0, t2), max(t0, t2), min(t3, t1), max(t3, t1)
        # Cycles divides the integer factors (as integers) before comparing with 1.5.
        split_u = s[0].edge.must_split() or s[2].edge.must_split() or \
            (min_u >= 2 and min_v > MAX_SEGMENTS and max_v // min_v > 1.5)
        split_v = s[3].edge.must_split() or s[1].edge.must_split() or \
            (min_v >= 2 and min_u > MAX_SEGMENTS and max_u // min_u > 1.5)
        if split_u and split_v:
            split_v = not ((s[0].edge.length + s[2].edge.length) * BIAS >= s[1].edge.length + s[3].edge.length)
            split_u = not split_v
        if not (split_u or split_v):
            self.finish(sub)
            return
        if (split_u and (t0 == 1 or t2 == 1)) or (not split_u and (t1 == 1 or t3 == 1)):
            self.split_quad_into_triangles(sub)
            return
        a, b = sub.copy(), sub.copy()
        if split_u:
            across0, across1 = 0, 2
            a.sides[3].own_edge, a.sides[3].own_vertex = s[3].own_edge, s[3].own_vertex
            b.sides[1].own_edge, b.sides[1].own_vertex = s[1].own_edge, s[1].own_vertex
            a_split, b_split = a.sides[1], b.sides[3]
            spots = ((a, 2), (a, 1), (b, 3), (b, 0))          # uv_a, uv_b, uv_c, uv_d
            depth = max(s[1].edge.depth, s[3].edge.depth)
        else:
            across0, across1 = 3, 1
            a.sides[2].own_edge, a.sides[2].own_vertex = s[2].own_edge, s[2].own_vertex
            b.sides[0].own_edge, b.sides[0].own_vertex = s[0].own_edge, s[0].own_vertex
            a_split, b_split = a.sides[0], b.sides[2]
            spots = ((a, 1), (a, 0), (b, 2), (b, 3))
            depth = max(s[0].edge.depth, s[2].edge.depth)
        uv_a, uv_b, uv_c, uv_d = (owner.uvs[k] for owner, k in spots)
        uv0 = self.split_edge(sub.patch, s[across0], a.sides[across0], b.sides[across0], uv_d, uv_b)
        uv1 = self.split_edge(sub.patch, s[across1], b.sides[across1], a.sides[across1], uv_a, uv_c)
        for (owner, k), value in zip(spots, (uv1, uv0, uv1, uv0)):
            owner.uvs[k] = value
        self.side(a_split, s[across0].edge.mid, s[across1].edge.mid, depth, True, False)
        self.side(b_split, s[across1].edge.mid, s[across0].edge.mid, depth, True, False)
        self.assign(a_split.edge, sub.patch, uv0, uv1)
        self.split_quad(a)
        self.split_quad(b)

    def split_quad_into_triangles(self, sub: SubPatch) -> None:
        a, b = sub.copy(), sub.copy()
        a.triangle = b.triangle = True
        s = sub.sides
        depth = max(side.edge.depth for side in s)
        a.sides[0], a.sides[1] = s[0].copy(), s[1].copy()
        a.uvs = list(sub.uvs[:3]) + [sub.uvs[3]]
        self.side(a.sides[2], s[2].start(), s[0].start(), depth, True, False)
        b.sides[1], b.sides[2] = s[2].copy(), s[3].copy()
        b.uvs = [sub.uvs[0], sub.uvs[2], sub.uvs[3], sub.uvs[3]]
        self.side(b.sides[0], s[0].start(), s[2].start(), depth, True, False)
        self.assign(b.sides[0].edge, sub.patch, sub.uvs[0], sub.uvs[2])
        self.split_triangle(a)
        self.split_triangle(b)

    def split_triangle(self, sub: SubPatch) -> None:
        self.resolve(sub)
        s = sub.sides
        if not any(s[k].edge.must_split() for k in range(3)):
            self.finish(sub)
            return
        first, longest = -1, 0.0
        for k in range(3):
            if s[k].edge.must_split() and (first == -1 or s[k].edge.length > longest):
                first, longest = k, s[k].edge.length * BIAS
        second, third = (first + 1) % 3, (first + 2) % 3
        a, b = sub.copy(), sub.copy()
        a.sides[2], b.sides[1] = s[third].copy(), s[second].copy()
        uv = self.split_edge(sub.patch, s[first], a.sides[0], b.sides[0], sub.uvs[first], sub.uvs[second])
        a.uvs[:3] = [sub.uvs[first], uv, sub.uvs[third]]
        b.uvs[:3] = [uv, sub.uvs[second], sub.uvs[third]]
        middle, opposite = s[first].edge.mid, s[third].start()
        depth = s[first].edge.depth + 1
        self.side(a.sides[1], middle, opposite, depth, True, False)
        self.side(b.sides[2], opposite, middle, depth, True, False)
        self.assign(a.sides[1].edge, sub.patch, uv, sub.uvs[third])
        self.split_triangle(a)
        self.split_triangle(b)

    # ------------------------------------------------------------ faces
    def split_face_quad(self, face: int, patch: int) -> None:
        start = self.cage.face_starts[face]
        v = [int(x) for x in self.cage.corner_verts[start:start + 4]]
        sub = SubPatch(patch, face)
        for k in range(4):
            self.side(sub.sides[k], v[k], v[(k + 1) % 4], -1, True, True)
        for k in range(4):
            sub.sides[k].edge.T = NON_UNIFORM      # split both ways first, as n-gons are split into quads
        self.split_quad(sub)

    def split_face_ngon(self, face: int, first_patch: int) -> None:
        start, n = int(self.cage.face_starts[face]), int(self.cage.face_sizes[face])
        verts = [int(x) for x in self.cage.corner_verts[start:start + n]]
        centre = self.alloc_vertices(1)
        ring = [Side() for _ in range(n)]
        for c in range(n):
            self.side(ring[c], verts[c], verts[(c + 1) % n], 0, True, True)
            if ring[c].edge.mid == -1:
                ring[c].edge.mid = self.alloc_vertices(1)
        for c in range(n):
            this, before = ring[c], ring[(c - 1) % n]
            v0, v1, v3 = this.start(), this.edge.mid, before.edge.mid
            sub = SubPatch(first_patch + c, face, c)
            self.side(sub.sides[0], v0, v1, 0, False, False)
            self.side(sub.sides[1], v1, centre, 0, True, False)
            self.side(sub.sides[2], centre, v3, 0, True, c == 0)
            self.side(sub.sides[3], v3, v0, 0, False, False)
            sub.sides[0].own_edge, sub.sides[0].own_vertex = this.own_edge, this.own_vertex
            sub.sides[3].own_edge, sub.sides[3].own_vertex = before.own_edge, before.own_edge
            self.split_quad(sub)

    def run(self, poll=None) -> "DiagSplit":
        """Split every face; poll() (when given) is called every few faces (it raises to cancel)."""
        limit = sys.getrecursionlimit()
        sys.setrecursionlimit(max(limit, 10_000))
        try:
            for face in range(self.cage.face_count):
                if poll is not None and face % 64 == 0:
                    poll()
                if self.cage.face_sizes[face] == 4:
                    self.split_face_quad(face, int(self.patches.first[face]))
                else:
                    self.split_face_ngon(face, int(self.patches.first[face]))
        finally:
            sys.setrecursionlimit(limit)
        return self
