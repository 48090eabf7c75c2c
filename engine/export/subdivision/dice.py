"""EdgeDice as Cycles runs it (subd/dice.cpp): each subpatch of a DiagSplit becomes a grid of Mu x Mv cells (the
larger factor of each pair of opposite sides), or a triangular grid, stitched to the vertices its sides have
(their factors), each stitch step taking the shorter diagonal. Vertices are set by the subpatch that owns
them (split.py's ownership), at the surface's point of their (patch, u, v); every triangle keeps the patch (u,
v) of its corners for the attributes interpolated per face corner.

The work is laid out as arrays: every subpatch lists its vertices and its stitch strips (two rows of vertices
to join: the grid's row along a side and the side's own vertices, or two opposite sides), then the surface is
evaluated once for all vertices and all strips are stitched together, one step of each per round.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .split import DiagSplit, Side, SubPatch


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
    subs = split.subpatches
    corners = np.array([s.uvs for s in subs], np.float64).reshape(-1, 4, 2)
    triangle = np.array([s.triangle for s in subs], bool)
    patch_of = np.array([s.patch for s in subs], np.int64)
    plan = _Plan()
    for index, sub in enumerate(subs):
        plan.subpatch(index, sub)
    n = split.vertex_count
    vertex_patch = np.full(n, -1, np.int64)
    vertex_uv = np.zeros((n, 2))
    if plan.vertices:
        ids, owner, local = (np.concatenate(x) for x in zip(*plan.vertices))
        vertex_patch[ids] = patch_of[owner]
        vertex_uv[ids] = _map_uv(corners[owner], triangle[owner], local)
    positions = np.zeros((n, 3))
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    positions[:len(split.cage.positions)] = split.cage.positions
    used = vertex_patch >= 0
    if used.any():
        positions[used], normals[used] = surface.evaluate(vertex_patch[used], vertex_uv[used])
    parts = plan.triangles + ([_stitch(plan.strips, positions)] if plan.strips else [])
    if parts:
        verts, owner, local = (np.concatenate(x) for x in zip(*parts))
    else:
        verts, owner, local = np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros((0, 3, 2))
    uv = _map_uv(np.repeat(corners[owner], 3, axis=0), np.repeat(triangle[owner], 3), local.reshape(-1, 2))
    return Tessellation(positions, normals, vertex_patch, vertex_uv, verts, patch_of[owner], uv.reshape(-1, 3, 2))


def _map_uv(corners: np.ndarray, triangle: np.ndarray, local: np.ndarray) -> np.ndarray:
    """(N, 2) subpatch coordinates `local` in their patch: bilinear over a quad subpatch's corners (N, 4, 2),
    barycentric over a triangle's first three, clamped to the patch (SubPatch::map_uv)."""
    u, v = local[:, 0:1], local[:, 1:2]
    d0 = corners[:, 0] + v * (corners[:, 3] - corners[:, 0])
    d1 = corners[:, 1] + v * (corners[:, 2] - corners[:, 1])
    out = d0 + u * (d1 - d0)
    if triangle.any():
        t = np.flatnonzero(triangle)
        c = corners[t]
        out[t] = (1.0 - u[t] - v[t]) * c[:, 0] + u[t] * c[:, 1] + v[t] * c[:, 2]
    return np.clip(out, 0.0, 1.0)


def _side_vertices(side: Side, i: np.ndarray) -> np.ndarray:
    """The vertices at steps i (along the side's own direction) of a side."""
    e = side.edge
    n = e.T - i if side.reversed else i
    return np.where(n == 0, e.start, np.where(n == e.T, e.end, e.second + n - 1))


# A side's step f in [0, 1] in its subpatch's (u, v): quads' sides 0-3, triangles' 0-2.
_QUAD_SIDES = (lambda f: (f, 0 * f), lambda f: (0 * f + 1, f), lambda f: (1 - f, 0 * f + 1), lambda f: (0 * f, 1 - f))
_TRI_SIDES = (lambda f: (f, 0 * f), lambda f: (1 - f, f), lambda f: (0 * f, 1 - f))


class _Plan:
    """Per subpatch: its vertices (ids, subpatch, local uv), its grid's own triangles (vertex triples, subpatch,
    local uv per corner) and its stitch strips."""

    def __init__(self):
        self.vertices, self.triangles, self.strips = [], [], []

    def subpatch(self, index: int, sub: SubPatch) -> None:
        self._sides(index, sub)
        (self._triangle if sub.triangle else self._quad)(index, sub)

    def _sides(self, index: int, sub: SubPatch) -> None:
        shapes = _TRI_SIDES if sub.triangle else _QUAD_SIDES
        for k, side in enumerate(sub.sides[:len(shapes)]):
            t = side.edge.T
            i = np.arange(0 if side.own_vertex else 1, t if side.own_edge else 1)
            if len(i):
                local = np.stack(shapes[k](i / t), axis=1).astype(np.float64)
                self.vertices.append((_side_vertices(side, i), np.full(len(i), index), local))

    def _strip(self, index, inner_ids, inner_uv, outer_side: Side, outer_uv) -> None:
        """A strip from the inner row (ids and local uvs) to a side's vertices (outer_uv: (start, step))."""
        t = outer_side.edge.T
        j = np.arange(t + 1)
        outer = _side_vertices(outer_side, j)
        ou = np.asarray(outer_uv[0], np.float64) + j[:, None] * np.asarray(outer_uv[1], np.float64)
        self.strips.append((index, np.asarray(inner_ids, np.int64), np.asarray(inner_uv, np.float64), outer, ou))

    def _add(self, index, verts, local) -> None:
        verts = np.asarray(verts, np.int64).reshape(-1, 3)
        self.triangles.append((verts, np.full(len(verts), index), np.asarray(local, np.float64).reshape(-1, 3, 2)))

    def _quad(self, index: int, sub: SubPatch) -> None:
        t = sub.factors()
        mu, mv = max(t[0], t[2]), max(t[3], t[1])
        s = sub.sides
        if mv == 1 or mu == 1:
            # No inner grid: one strip between two opposite sides (Cycles' add_triangle_strip).
            left, right = (2, 0) if mv == 1 else (3, 1)
            lt, rt = s[left].edge.T, s[right].edge.T
            start_l, step_l, start_r, step_r = (((0.0, 1.0), (1.0 / lt, 0.0), (0.0, 0.0), (1.0 / rt, 0.0)) if mv == 1
                                                else ((0.0, 0.0), (0.0, 1.0 / lt), (1.0, 0.0), (0.0, 1.0 / rt)))
            i = np.arange(lt + 1)
            inner_uv = np.asarray(start_l) + i[:, None] * np.asarray(step_l)
            self._strip(index, _side_vertices(s[left], lt - i), inner_uv, s[right], (start_r, step_r))
            return
        jj, ii = np.meshgrid(np.arange(1, mv), np.arange(1, mu), indexing="ij")
        grid = sub.inner + (ii - 1) + (jj - 1) * (mu - 1)                  # (mv - 1, mu - 1)
        self.vertices.append((grid.ravel(), np.full(grid.size, index),
                              np.stack([ii.ravel() / mu, jj.ravel() / mv], axis=1)))
        if mu > 2 and mv > 2:
            a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, 1:], grid[1:, :-1]
            ua = np.stack([ii[:-1, :-1] / mu, jj[:-1, :-1] / mv], axis=-1)
            du, dv = np.array([1.0 / mu, 0.0]), np.array([0.0, 1.0 / mv])
            verts = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=2)
            local = np.stack([np.stack([ua, ua + du, ua + du + dv], -2), np.stack([ua, ua + du + dv, ua + dv], -2)],
                             axis=2)
            self._add(index, verts, local)
        du, dv = 1.0 / mu, 1.0 / mv
        rows = (grid[0, :], grid[:, -1], grid[-1, ::-1], grid[::-1, 0])   # the grid along sides 0-3
        starts = (((du, dv), (du, 0.0), (0.0, 0.0)), ((1.0 - du, dv), (0.0, dv), (1.0, 0.0)),
                  ((1.0 - du, 1.0 - dv), (-du, 0.0), (1.0, 1.0)), ((du, 1.0 - dv), (0.0, -dv), (0.0, 1.0)))
        for k in range(4):
            outer_t = s[k].edge.T
            step = ((1.0 / outer_t, 0.0), (0.0, 1.0 / outer_t), (-1.0 / outer_t, 0.0), (0.0, -1.0 / outer_t))[k]
            start, inner_step, outer_start = starts[k]
            i = np.arange(len(rows[k]))
            self._strip(index, rows[k], np.asarray(start) + i[:, None] * np.asarray(inner_step), s[k],
                        (outer_start, step))

    def _triangle(self, index: int, sub: SubPatch) -> None:
        t = sub.factors()
        m = max(t)
        s = sub.sides
        v = [s[0].start(), s[1].start(), s[2].start()]
        c = ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))
        if m == 1:
            self._add(index, v, c)
            return
        if m == 2:
            split = [k for k in range(3) if t[k] == 2]
            first = 2 if split[0] == 0 and t[2] == 2 else split[0]   # of two, the first of the consecutive pair
            second, third = (first + 1) % 3, (first + 2) % 3
            mid = [s[k].vertex(1) for k in range(3)]
            mc = ((0.5, 0.0), (0.5, 0.5), (0.0, 0.5))
            if len(split) == 3:
                self._add(index, [v[0], mid[0], mid[2], v[1], mid[1], mid[0], v[2], mid[2], mid[1], *mid],
                          [c[0], mc[0], mc[2], c[1], mc[1], mc[0], c[2], mc[2], mc[1], *mc])
            elif len(split) == 1:
                self._add(index, [v[first], mid[first], v[third], mid[first], v[second], v[third]],
                          [c[first], mc[first], c[third], mc[first], c[second], c[third]])
            else:
                self._add(index, [v[first], mid[first], v[third], mid[first], v[second], mid[second],
                                  mid[first], mid[second], v[third]],
                          [c[first], mc[first], c[third], mc[first], c[second], mc[second],
                           mc[first], mc[second], c[third]])
            return
        inner = m - 2
        d = 1.0 / (m + 1)
        jj, ii = np.nonzero(np.tril(np.ones((inner + 1, inner + 1), bool)))       # i <= j <= inner
        ids = sub.inner + jj * (jj + 1) // 2 + ii
        self.vertices.append((ids, np.full(len(ids), index), np.stack([d + ii * d, d + (jj - ii) * d], axis=1)))

        def vertex(i, j):
            return sub.inner + j * (j + 1) // 2 + i

        def at(i, j):
            return np.stack([d + i * d, d + (j - i) * d], axis=-1)
        jj, ii = np.nonzero(np.tril(np.ones((inner, inner), bool)))                 # i <= j < inner
        self._add(index, np.stack([vertex(ii, jj), vertex(ii + 1, jj + 1), vertex(ii, jj + 1)], -1),
                  np.stack([at(ii, jj), at(ii + 1, jj + 1), at(ii, jj + 1)], -2))
        below = ii < jj
        ib, jb = ii[below], jj[below]
        self._add(index, np.stack([vertex(ib, jb), vertex(ib + 1, jb), vertex(ib + 1, jb + 1)], -1),
                  np.stack([at(ib, jb), at(ib + 1, jb), at(ib + 1, jb + 1)], -2))
        n = np.arange(inner + 1)
        rows = ((n, n), (inner - n, np.full_like(n, inner)), (np.zeros_like(n), inner - n))
        starts = (((d, d), (d, 0.0), (0.0, 0.0)), ((1.0 - 2.0 * d, d), (-d, d), (1.0, 0.0)),
                  ((d, 1.0 - 2.0 * d), (0.0, -d), (0.0, 1.0)))
        for k in range(3):
            outer_t = s[k].edge.T
            step = ((1.0 / outer_t, 0.0), (-1.0 / outer_t, 1.0 / outer_t), (0.0, -1.0 / outer_t))[k]
            start, inner_step, outer_start = starts[k]
            self._strip(index, vertex(*rows[k]), np.asarray(start) + n[:, None] * np.asarray(inner_step), s[k],
                        (outer_start, step))


def _stitch(strips: list, positions: np.ndarray):
    """All strips stitched in lockstep, one triangle of each per round: from inner vertex i and outer vertex j,
    step along the row that is done, else along the one whose diagonal is shorter (the outer one when
    |inner i - outer j+1| < |outer j - inner i+1|), as Cycles' stitching loops."""
    count = len(strips)
    owner = np.array([s[0] for s in strips], np.int64)
    n_in = np.array([len(s[1]) - 1 for s in strips], np.int64)
    n_out = np.array([len(s[3]) - 1 for s in strips], np.int64)
    width_in, width_out = int(n_in.max()) + 2, int(n_out.max()) + 2
    inner = np.zeros((count, width_in), np.int64)
    outer = np.zeros((count, width_out), np.int64)
    inner_uv = np.zeros((count, width_in, 2))
    outer_uv = np.zeros((count, width_out, 2))
    for k, (_, ids, iu, out_ids, ou) in enumerate(strips):
        inner[k, :len(ids)], inner_uv[k, :len(ids)] = ids, iu
        outer[k, :len(out_ids)], outer_uv[k, :len(out_ids)] = out_ids, ou
    i = np.zeros(count, np.int64)
    j = np.zeros(count, np.int64)
    tris, owners, uvs = [], [], []
    live = np.flatnonzero((n_in > 0) | (n_out > 0))
    while len(live):
        il, jl = i[live], j[live]
        v0, v1 = inner[live, il], outer[live, jl]
        a, b = outer[live, jl + 1], inner[live, il + 1]
        da, db = positions[v0] - positions[a], positions[v1] - positions[b]
        shorter = np.einsum("ij,ij->i", da, da) < np.einsum("ij,ij->i", db, db)
        step_out = (il == n_in[live]) | ((jl < n_out[live]) & shorter)
        step_out &= jl < n_out[live]
        v2 = np.where(step_out, a, b)
        uv2 = np.where(step_out[:, None], outer_uv[live, jl + 1], inner_uv[live, il + 1])
        tris.append(np.stack([v0, v1, v2], axis=1))
        uvs.append(np.stack([inner_uv[live, il], outer_uv[live, jl], uv2], axis=1))
        owners.append(owner[live])
        j[live] += step_out
        i[live] += ~step_out
        live = live[(i[live] < n_in[live]) | (j[live] < n_out[live])]
    return np.concatenate(tris), np.concatenate(owners), np.concatenate(uvs)
