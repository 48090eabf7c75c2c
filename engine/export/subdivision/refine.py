"""Catmull-Clark refinement of a cage, with OpenSubdiv's rules as Cycles sets them up (subd/osd.cpp: scheme
CATMARK, boundary interpolation from the modifier's Boundary Smooth, no creases here), kept as one regular grid
of control points per patch.

One step makes a face point per face (the mean of its corners), an edge point per edge ((ends + the two face
points) / 4 inside, the midpoint on a boundary) and moves each vertex: inside, with n edges, to
((n - 2) P + (sum of edge neighbours + sum of face points) / n) / n; on a boundary, to (a + 6 P + b) / 8 over its
two boundary neighbours, except the corners kept where they are (with EDGE_AND_CORNER, Boundary Smooth
"Keep Corners": the boundary vertices of one face; a UV map's own rules keep others, adaptive.py). A kept
corner's vertex points stay kept at every level. After the first step every face is a quad and a patch's
control points are a grid: (2^L + 1)^2 after L steps for a quad's patch, (2^(L-1) + 1)^2 for an n-gon's corner.

Limit positions of the last level: inside (n^2 P + 4 sum of edge neighbours + sum of diagonal neighbours) /
(n (n + 5)), on a boundary (a + 4 P + b) / 6, corners P. A vertex is regular (its neighbourhood a bicubic
B-spline's) inside with 4 edges, on a boundary with 3, as a kept corner with 2.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cage import Cage


class Unsupported(ValueError):
    """The cage has topology these rules do not cover (an edge of three faces or more, a vertex where two
    boundaries meet); the message says what."""


@dataclass(frozen=True)
class Level:
    """A refinement level: positions (V, 3) float64; grids per group of patches (quads' and n-gon corners'),
    each (P_g, n_g + 1, n_g + 1) int64 vertex indices, row j along v, column i along u (its cells are the
    level's quads, cells()); kept (V,) bool the kept corners."""
    positions: np.ndarray
    grids: tuple
    kept: np.ndarray


def cage_valence(cage: Cage) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex of the cage: (its faces, its boundary edges), (V,) int64 each."""
    f_of_loop = np.repeat(np.arange(cage.face_count), cage.face_sizes)
    following = cage.corner_verts[cage.loop(f_of_loop, np.arange(len(f_of_loop)) - cage.face_starts[f_of_loop] + 1)]
    v = len(cage.positions)
    ends, count, _ = _edges(cage.corner_verts, following, v)
    return np.bincount(cage.corner_verts, minlength=v), np.bincount(ends[count == 1].ravel(), minlength=v)


def boundary_corners(cage: Cage) -> np.ndarray:
    """(V,) bool: the cage's vertices on a boundary with one face (Boundary Smooth "Keep Corners" keeps them)."""
    faces, boundary = cage_valence(cage)
    return (boundary == 2) & (faces == 1)


def first_level(cage: Cage, kept: np.ndarray) -> tuple[Level, np.ndarray]:
    """One step from the cage's polygons, kept (V,) bool its kept corners. Returns the level and, per patch,
    (group, index in the group)."""
    v = len(cage.positions)
    f_of_loop = np.repeat(np.arange(cage.face_count), cage.face_sizes)
    loop_next = cage.loop(f_of_loop, np.arange(len(f_of_loop)) - cage.face_starts[f_of_loop] + 1)
    positions, edge_of_loop, edges = _step(cage.positions, cage.corner_verts, cage.corner_verts[loop_next],
                                           f_of_loop, cage.face_count, kept)
    e = len(edges)
    ep = v + edge_of_loop                                 # each loop's edge point (edge to the next corner)
    fp = v + e + np.arange(cage.face_count)
    patches = cage.patches()
    quads = ~patches.ngon
    qs = cage.face_starts[patches.face[quads]]
    vert = cage.corner_verts
    # A quad's patch: a 3 x 3 grid; row 0 runs from corner 0 to corner 1, column 0 from corner 0 to corner 3.
    quad_grid = np.stack([np.stack([vert[qs], ep[qs], vert[qs + 1]], 1),
                          np.stack([ep[qs + 3], fp[patches.face[quads]], ep[qs + 1]], 1),
                          np.stack([vert[qs + 3], ep[qs + 2], vert[qs + 2]], 1)], 1)
    nf, nc = patches.face[patches.ngon], patches.corner[patches.ngon]
    here, previous = cage.loop(nf, nc), cage.loop(nf, nc - 1)
    ngon_grid = np.stack([np.stack([vert[here], ep[here]], 1), np.stack([ep[previous], fp[nf]], 1)], 1)
    index = np.empty((len(patches), 2), np.int64)
    index[quads] = np.stack([np.zeros(quads.sum(), np.int64), np.arange(quads.sum())], 1)
    index[patches.ngon] = np.stack([np.ones(len(nf), np.int64), np.arange(len(nf))], 1)
    return Level(positions, (quad_grid.astype(np.int64), ngon_grid.astype(np.int64)),
                 _children_kept(kept, len(positions))), index


def _children_kept(kept: np.ndarray, count: int) -> np.ndarray:
    """The next level's kept corners: the vertex points of the kept ones (listed first)."""
    out = np.zeros(count, bool)
    out[:len(kept)] = kept
    return out


def next_level(level: Level) -> Level:
    """One more step: every cell of every grid split in four, grids twice as fine."""
    quads = cells(level.grids)
    v = len(level.positions)
    loop_vert = quads.reshape(-1)
    loop_next = np.roll(quads, -1, axis=1).reshape(-1)
    positions, edge_of_loop, edges = _step(level.positions, loop_vert, loop_next,
                                           np.repeat(np.arange(len(quads)), 4), len(quads), level.kept)
    e = len(edges)
    grids, first = [], 0
    for grid in level.grids:
        p, n = len(grid), grid.shape[1] - 1
        eid = edge_of_loop[4 * first:4 * (first + p * n * n)].reshape(p, n, n, 4)
        face = first + np.arange(p * n * n).reshape(p, n, n)
        fine = np.empty((p, 2 * n + 1, 2 * n + 1), np.int64)
        fine[:, ::2, ::2] = grid
        across = np.concatenate([eid[:, :, :, 0], eid[:, -1:, :, 2]], axis=1)     # (p, n + 1, n): along u
        up = np.concatenate([eid[:, :, :, 3], eid[:, :, -1:, 1]], axis=2)         # (p, n, n + 1): along v
        fine[:, ::2, 1::2] = v + across
        fine[:, 1::2, ::2] = v + up
        fine[:, 1::2, 1::2] = v + e + face
        grids.append(fine)
        first += p * n * n
    return Level(positions, tuple(grids), _children_kept(level.kept, len(positions)))


def cells(grids: tuple) -> np.ndarray:
    """(Q, 4) int64 the cells of the grids, corners counter-clockwise in (u, v): (j, i), (j, i+1), (j+1, i+1),
    (j+1, i)."""
    out = [np.stack([g[:, :-1, :-1], g[:, :-1, 1:], g[:, 1:, 1:], g[:, 1:, :-1]], axis=-1).reshape(-1, 4)
           for g in grids if g.size]
    return np.concatenate(out) if out else np.zeros((0, 4), np.int64)


@dataclass(frozen=True)
class Valence:
    """Per vertex of a quad mesh: edges (V,) its edge count, faces (V,) its face count, boundary (V,) its
    boundary edges; and the sums of its edge neighbours, of its boundary neighbours and of its diagonal
    neighbours (the corner opposite it in each of its quads), (V, 3) each."""
    edges: np.ndarray
    faces: np.ndarray
    boundary: np.ndarray
    neighbours: np.ndarray
    boundary_neighbours: np.ndarray
    diagonals: np.ndarray


def valence(positions: np.ndarray, quads: np.ndarray) -> Valence:
    v = len(positions)
    ends, count, _ = _edges(quads.reshape(-1), np.roll(quads, -1, axis=1).reshape(-1), v)
    edges = np.bincount(ends.ravel(), minlength=v)
    faces = np.bincount(quads.ravel(), minlength=v)
    border = ends[count == 1]
    boundary = np.bincount(border.ravel(), minlength=v)
    neighbours = _gather_sums(v, ends, positions)
    boundary_neighbours = _gather_sums(v, border, positions)
    diagonals = scatter_sum(quads.reshape(-1), positions[np.roll(quads, 2, axis=1).reshape(-1)], v)
    return Valence(edges, faces, boundary, neighbours, boundary_neighbours, diagonals)


def limit_positions(level: Level, quads: np.ndarray, stats: Valence | None = None) -> np.ndarray:
    """(V, 3) the limit position of each vertex of a level whose faces are all quads."""
    positions = level.positions
    s = stats or valence(positions, quads)
    n = np.maximum(s.edges, 1)[:, None].astype(np.float64)
    out = (n * n * positions + 4.0 * s.neighbours + s.diagonals) / (n * (n + 5.0))
    edge = s.boundary > 0
    out[edge] = (s.boundary_neighbours[edge] + 4.0 * positions[edge]) / 6.0
    fixed = level.kept | (s.faces == 0)
    out[fixed] = positions[fixed]
    return out


def regular_vertices(stats: Valence, kept: np.ndarray) -> np.ndarray:
    """(V,) bool: vertices around which the surface is a bicubic B-spline's (a kept corner only with one face,
    where the B-spline's mirrored points make it interpolate the corner)."""
    inside = (stats.boundary == 0) & (stats.edges == 4) & (stats.faces == 4)
    edge = (stats.boundary == 2) & (stats.edges == 3) & (stats.faces == 2) & ~kept
    return inside | edge | (kept & (stats.edges == 2) & (stats.faces == 1))


def _edges(loop_vert: np.ndarray, loop_next: np.ndarray, v: int):
    """The undirected edges of the loops (vertex -> next vertex): (E, 2) ends, (E,) faces per edge, and each
    loop's edge."""
    a, b = np.minimum(loop_vert, loop_next), np.maximum(loop_vert, loop_next)
    keys, edge_of_loop, count = np.unique(a * v + b, return_inverse=True, return_counts=True)
    return np.stack([keys // v, keys % v], axis=1), count, edge_of_loop.reshape(-1)


def scatter_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(n, C) the sums of values (K, C) by index (K,): np.add.at's result, several times faster."""
    return np.stack([np.bincount(index, weights=values[:, c], minlength=n) for c in range(values.shape[1])], axis=1)


def _gather_sums(v: int, ends: np.ndarray, positions: np.ndarray) -> np.ndarray:
    return scatter_sum(ends.reshape(-1), positions[ends[:, ::-1].reshape(-1)], v)


def _step(positions, loop_vert, loop_next, face_of_loop, face_count: int, kept: np.ndarray):
    """One Catmull-Clark step over polygons given as loops. Returns the new positions (vertex points, then
    edge points, then face points), each loop's edge and the edges' ends."""
    v = len(positions)
    ends, count, edge_of_loop = _edges(loop_vert, loop_next, v)
    if (count > 2).any():
        raise Unsupported("an edge has three faces or more")
    sizes = np.bincount(face_of_loop, minlength=face_count).astype(np.float64)
    face_points = scatter_sum(face_of_loop, positions[loop_vert], face_count) / np.maximum(sizes, 1.0)[:, None]
    # Each loop is one face's side of its edge: the edge's two faces add their points once each.
    edge_faces = scatter_sum(edge_of_loop, face_points[face_of_loop], len(ends))
    edge_points = np.where((count == 2)[:, None], (positions[ends[:, 0]] + positions[ends[:, 1]] + edge_faces) / 4.0,
                           0.5 * (positions[ends[:, 0]] + positions[ends[:, 1]]))
    edges = np.bincount(ends.ravel(), minlength=v)
    faces = np.bincount(loop_vert, minlength=v)
    border = ends[count == 1]
    boundary = np.bincount(border.ravel(), minlength=v)
    if (boundary > 2).any():
        raise Unsupported("boundaries meet at a vertex")
    neighbours = _gather_sums(v, ends, positions)
    around = scatter_sum(loop_vert, face_points[face_of_loop], v)
    n = np.maximum(edges, 1)[:, None].astype(np.float64)
    vertex_points = ((n - 2.0) * positions + (neighbours + around) / n) / n
    edge = boundary == 2
    vertex_points[edge] = (_gather_sums(v, border, positions)[edge] + 6.0 * positions[edge]) / 8.0
    fixed = kept | (faces == 0)
    vertex_points[fixed] = positions[fixed]
    return np.concatenate([vertex_points, edge_points, face_points]), edge_of_loop, ends
