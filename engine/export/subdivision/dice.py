"""EdgeDice as Cycles runs it (subd/dice.cpp): each subpatch of a DiagSplit becomes a grid of Mu x Mv cells (the
larger factor of each pair of opposite sides), or a triangular grid, stitched to the vertices its sides have
(their factors), each stitch step taking the shorter diagonal. Vertices are set by the subpatch that owns
them (split.py's ownership), at the surface's point of their (patch, u, v); every triangle keeps the patch (u,
v) of its corners for the attributes interpolated per face corner.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .split import DiagSplit, SubPatch


@dataclass(frozen=True)
class Tessellation:
    """V vertices and T triangles in object space.

    positions, normals : (V, 3) float64 (normals unit); vertex_patch : (V,) int64 the patch each vertex was
    evaluated on (-1: a cage vertex no face uses), vertex_uv : (V, 2) its (u, v) there.
    triangles : (T, 3) int64; triangle_patch : (T,) int64; corner_uv : (T, 3, 2) the patch (u, v) of each corner.
    """
    positions: np.ndarray
    normals: np.ndarray
    vertex_patch: np.ndarray
    vertex_uv: np.ndarray
    triangles: np.ndarray
    triangle_patch: np.ndarray
    corner_uv: np.ndarray


def dice(split: DiagSplit, surface) -> Tessellation:
    """The vertices and triangles of a run DiagSplit; surface : evaluate(patch, uv) -> (positions, normals)."""
    n = split.vertex_count
    patch = np.full(n, -1, np.int64)
    uv = np.zeros((n, 2))
    for sub in split.subpatches:
        _set_sides(sub, patch, uv)
        _set_inner(sub, patch, uv)
    used = patch >= 0
    positions = np.zeros((n, 3))
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    base = len(split.cage.positions)
    positions[:base] = split.cage.positions
    if used.any():
        positions[used], normals[used] = surface.evaluate(patch[used], uv[used])
    t = split.triangle_total
    triangles = np.zeros((t, 3), np.int64)
    corner_uv = np.zeros((t, 3, 2))
    triangle_patch = np.zeros(t, np.int64)
    out = _Triangles(triangles, corner_uv, positions)
    for sub in split.subpatches:
        out.at = sub.first_triangle
        (_tri_dice if sub.triangle else _quad_dice)(sub, out)
        triangle_patch[sub.first_triangle:out.at] = sub.patch
    return Tessellation(positions, normals, patch, uv, triangles, triangle_patch, corner_uv)


class _Triangles:
    def __init__(self, triangles, corner_uv, positions):
        self.triangles, self.corner_uv, self.positions, self.at = triangles, corner_uv, positions, 0

    def add(self, v0, v1, v2, uv0, uv1, uv2) -> None:
        self.triangles[self.at] = (v0, v1, v2)
        self.corner_uv[self.at] = (uv0, uv1, uv2)
        self.at += 1

    def shorter_first(self, v0, v1, a, b) -> bool:
        """Cycles' stitch step: v0 - a shorter than v1 - b."""
        p = self.positions
        da, db = p[v0] - p[a], p[v1] - p[b]
        return float(da @ da) < float(db @ db)


def _set(patch, uv, vertex: int, sub: SubPatch, at) -> None:
    patch[vertex] = sub.patch
    uv[vertex] = sub.map_uv(*at)


def _set_sides(sub: SubPatch, patch, uv) -> None:
    count = 3 if sub.triangle else 4
    for k in range(count):
        side = sub.sides[k]
        t = side.edge.T
        for i in range(0 if side.own_vertex else 1, t if side.own_edge else 1):
            f = i / t
            if sub.triangle:
                at = ((f, 0.0), (1.0 - f, f), (0.0, 1.0 - f))[k]
            else:
                at = ((f, 0.0), (1.0, f), (1.0 - f, 1.0), (0.0, 1.0 - f))[k]
            _set(patch, uv, side.vertex(i), sub, at)


def _set_inner(sub: SubPatch, patch, uv) -> None:
    t = sub.factors()
    if sub.triangle:
        m = max(t)
        if m <= 2:
            return
        d = 1.0 / (m + 1)
        for j in range(m - 1):
            for i in range(j + 1):
                _set(patch, uv, _tri_vertex(sub, i, j), sub, (d + i * d, d + (j - i) * d))
        return
    mu, mv = max(t[0], t[2]), max(t[3], t[1])
    for j in range(1, mv):
        for i in range(1, mu):
            _set(patch, uv, sub.inner + (i - 1) + (j - 1) * (mu - 1), sub, (i / mu, j / mv))


def _tri_vertex(sub: SubPatch, i: int, j: int) -> int:
    return sub.inner + j * (j + 1) // 2 + i


def _grid_edge_vertex(sub: SubPatch, k: int, n: int, mu: int, mv: int) -> int:
    """The n-th vertex of the inner grid along side k (Cycles' get_vert_along_grid_edge)."""
    if sub.triangle:
        inner = max(sub.factors()) - 2
        i, j = ((n, n), (inner - n, inner), (0, inner - n))[k]
        return _tri_vertex(sub, i, j)
    o = sub.inner
    return (o + n, o + (mu - 2) + n * (mu - 1), o + (mu - 1) * (mv - 2) + (mu - 2 - n),
            o + (mv - 2 - n) * (mu - 1))[k]


def _stitch(sub: SubPatch, out: _Triangles, k: int, inner_t: int, inner_uv, inner_step, outer_uv, outer_step,
            mu: int = 0, mv: int = 0) -> None:
    """Triangles between the inner grid's row along side k and the side's own vertices."""
    side = sub.sides[k]
    outer_t = side.edge.T
    i = j = 0
    iu, ou = list(inner_uv), list(outer_uv)
    while i < inner_t or j < outer_t:
        v0 = _grid_edge_vertex(sub, k, i, mu, mv)
        v1 = side.vertex(j)
        uv0, uv1 = sub.map_uv(*iu), sub.map_uv(*ou)
        if j == outer_t:
            i += 1
            v2, iu = _grid_edge_vertex(sub, k, i, mu, mv), [iu[0] + inner_step[0], iu[1] + inner_step[1]]
            uv2 = sub.map_uv(*iu)
        elif i == inner_t:
            j += 1
            v2, ou = side.vertex(j), [ou[0] + outer_step[0], ou[1] + outer_step[1]]
            uv2 = sub.map_uv(*ou)
        else:
            a, b = side.vertex(j + 1), _grid_edge_vertex(sub, k, i + 1, mu, mv)
            if out.shorter_first(v0, v1, a, b):
                v2, j = a, j + 1
                ou = [ou[0] + outer_step[0], ou[1] + outer_step[1]]
                uv2 = sub.map_uv(*ou)
            else:
                v2, i = b, i + 1
                iu = [iu[0] + inner_step[0], iu[1] + inner_step[1]]
                uv2 = sub.map_uv(*iu)
        out.add(v0, v1, v2, uv0, uv1, uv2)


def _strip(sub: SubPatch, out: _Triangles, left: int, right: int) -> None:
    """Triangles between two opposite sides when the other two have one segment (Cycles' add_triangle_strip)."""
    lt, rt = sub.sides[left].edge.T, sub.sides[right].edge.T
    if right == 0:
        lu, ru, ls, rs = [0.0, 1.0], [0.0, 0.0], (1.0 / lt, 0.0), (1.0 / rt, 0.0)
    else:
        lu, ru, ls, rs = [0.0, 0.0], [1.0, 0.0], (0.0, 1.0 / lt), (0.0, 1.0 / rt)
    ls_, rs_ = sub.sides[left], sub.sides[right]
    i = j = 0
    while i < lt or j < rt:
        v0, v1 = ls_.vertex(lt - i), rs_.vertex(j)
        uv0, uv1 = sub.map_uv(*lu), sub.map_uv(*ru)
        if j == rt:
            i += 1
            v2, lu = ls_.vertex(lt - i), [lu[0] + ls[0], lu[1] + ls[1]]
            uv2 = sub.map_uv(*lu)
        elif i == lt:
            j += 1
            v2, ru = rs_.vertex(j), [ru[0] + rs[0], ru[1] + rs[1]]
            uv2 = sub.map_uv(*ru)
        else:
            a, b = rs_.vertex(j + 1), ls_.vertex(lt - i - 1)
            if out.shorter_first(v0, v1, a, b):
                v2, j = a, j + 1
                ru = [ru[0] + rs[0], ru[1] + rs[1]]
                uv2 = sub.map_uv(*ru)
            else:
                v2, i = b, i + 1
                lu = [lu[0] + ls[0], lu[1] + ls[1]]
                uv2 = sub.map_uv(*lu)
        out.add(v0, v1, v2, uv0, uv1, uv2)


def _quad_dice(sub: SubPatch, out: _Triangles) -> None:
    t = sub.factors()
    mu, mv = max(t[0], t[2]), max(t[3], t[1])
    if mv == 1:
        _strip(sub, out, 2, 0)
        return
    if mu == 1:
        _strip(sub, out, 3, 1)
        return
    du, dv = 1.0 / mu, 1.0 / mv
    o = sub.inner
    for j in range(1, mv - 1):
        for i in range(1, mu - 1):
            u, v = i * du, j * dv
            i1, i2 = o + (i - 1) + (j - 1) * (mu - 1), o + i + (j - 1) * (mu - 1)
            i3, i4 = o + i + j * (mu - 1), o + (i - 1) + j * (mu - 1)
            uv1, uv2 = sub.map_uv(u, v), sub.map_uv(u + du, v)
            uv3, uv4 = sub.map_uv(u + du, v + dv), sub.map_uv(u, v + dv)
            out.add(i1, i2, i3, uv1, uv2, uv3)
            out.add(i1, i3, i4, uv1, uv3, uv4)
    starts = (((du, dv), (du, 0.0), (0.0, 0.0)), ((1.0 - du, dv), (0.0, dv), (1.0, 0.0)),
              ((1.0 - du, 1.0 - dv), (-du, 0.0), (1.0, 1.0)), ((du, 1.0 - dv), (0.0, -dv), (0.0, 1.0)))
    for k in range(4):
        outer_t = sub.sides[k].edge.T
        outer_step = ((1.0 / outer_t, 0.0), (0.0, 1.0 / outer_t), (-1.0 / outer_t, 0.0), (0.0, -1.0 / outer_t))[k]
        inner_uv, inner_step, outer_uv = starts[k]
        _stitch(sub, out, k, (mu if k % 2 == 0 else mv) - 2, inner_uv, inner_step, outer_uv, outer_step, mu, mv)


def _tri_dice(sub: SubPatch, out: _Triangles) -> None:
    t = sub.factors()
    m = max(t)
    s = sub.sides
    corners = (sub.map_uv(0.0, 0.0), sub.map_uv(1.0, 0.0), sub.map_uv(0.0, 1.0))
    v = [s[0].start(), s[1].start(), s[2].start()]
    if m == 1:
        out.add(*v, *corners)
        return
    if m == 2:
        split = [k for k in range(3) if t[k] == 2]
        first = split[0]
        if first == 0 and t[2] == 2:
            first = 2                      # of two split sides, the first of the two consecutive ones
        second, third = (first + 1) % 3, (first + 2) % 3
        mid = [s[k].vertex(1) for k in range(3)]
        mid_uv = (sub.map_uv(0.5, 0.0), sub.map_uv(0.5, 0.5), sub.map_uv(0.0, 0.5))
        if len(split) == 3:
            out.add(v[0], mid[0], mid[2], corners[0], mid_uv[0], mid_uv[2])
            out.add(v[1], mid[1], mid[0], corners[1], mid_uv[1], mid_uv[0])
            out.add(v[2], mid[2], mid[1], corners[2], mid_uv[2], mid_uv[1])
            out.add(mid[0], mid[1], mid[2], mid_uv[0], mid_uv[1], mid_uv[2])
            return
        out.add(v[first], mid[first], v[third], corners[first], mid_uv[first], corners[third])
        if len(split) == 1:
            out.add(mid[first], v[second], v[third], mid_uv[first], corners[second], corners[third])
        else:
            out.add(mid[first], v[second], mid[second], mid_uv[first], corners[second], mid_uv[second])
            out.add(mid[first], mid[second], v[third], mid_uv[first], mid_uv[second], corners[third])
        return
    inner = m - 2
    d = 1.0 / (m + 1)
    for j in range(inner):
        for i in range(j + 1):
            a, b, c = _tri_vertex(sub, i, j), _tri_vertex(sub, i + 1, j + 1), _tri_vertex(sub, i, j + 1)
            uv_a = sub.map_uv(d + i * d, d + (j - i) * d)
            uv_b = sub.map_uv(d + (i + 1) * d, d + (j - i) * d)
            uv_c = sub.map_uv(d + i * d, d + (j + 1 - i) * d)
            out.add(a, b, c, uv_a, uv_b, uv_c)
            if i < j:
                e = _tri_vertex(sub, i + 1, j)
                out.add(a, e, b, uv_a, sub.map_uv(d + (i + 1) * d, d + (j - i - 1) * d), uv_b)
    for k in range(3):
        outer_t = s[k].edge.T
        inner_uv, inner_step, outer_uv, outer_step = (
            ((d, d), (d, 0.0), (0.0, 0.0), (1.0 / outer_t, 0.0)),
            ((1.0 - 2.0 * d, d), (-d, d), (1.0, 0.0), (-1.0 / outer_t, 1.0 / outer_t)),
            ((d, 1.0 - 2.0 * d), (0.0, -d), (0.0, 1.0), (0.0, -1.0 / outer_t)))[k]
        _stitch(sub, out, k, inner, inner_uv, inner_step, outer_uv, outer_step)
