"""The surface a cage's patches describe, evaluated at (patch, u, v): position and shading normal, object space.

LinearSurface is Cycles' Simple subdivision (LinearQuadPatch, subd/patch.cpp): each patch the bilinear map of its
corners. Its normals are Blender's vertex normals interpolated the same way: Cycles computes the patch's
normal, then its linear interpolation of the vertex normal attribute overwrites it (subd/dice.cpp set_vertex,
subd/interpolation.cpp).

CatmullClarkSurface is the Catmull-Clark limit surface, which Cycles evaluates through OpenSubdiv (subd/osd.cpp:
adaptive refinement isolating irregular vertices to level 3, B-spline patches, Gregory patches at the
isolation level; the normal is normalize(dP/du x dP/dv)). Here the cage is refined uniformly (refine.py) to a
level L chosen from its size (MAX_LEVEL for small cages); a cell of a patch's grid whose corners are all
regular is evaluated as the bicubic B-spline of its 4 x 4 control points, which is the limit surface exactly
(the same patch OpenSubdiv makes there); a cell touching an irregular vertex (an extraordinary vertex, a
smooth corner) interpolates the limit positions and normals of its corners bilinearly. Such cells span
1/2^L of a quad's side around each irregular vertex (1/32 for a cube of 6 faces), where Cycles' Gregory
patches span 1/8.
"""
from __future__ import annotations

import numpy as np

from . import refine
from .cage import Cage, bilinear, bilinear_corners

MAX_LEVEL = 6
# Control points kept for the refined grids (float64, with a ring around each patch): about 10 MB, built in
# about a quarter of a second.
CONTROL_POINT_BUDGET = 400_000


def _normalized(v: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(length > 0, v / np.where(length > 0, length, 1.0), np.array([0.0, 0.0, 1.0]))


class LinearSurface:
    """Simple subdivision: patch corners (P, 4, 3) and vertex normals at the corners (P, 4, 3)."""

    def __init__(self, cage: Cage, vertex_normals: np.ndarray):
        self.patches = cage.patches()
        self.corners = bilinear_corners(cage, self.patches, cage.positions[cage.corner_verts])
        self.normal_corners = bilinear_corners(cage, self.patches,
                                               np.asarray(vertex_normals, np.float64)[cage.corner_verts])

    def positions(self, patch: np.ndarray, uv: np.ndarray) -> np.ndarray:
        return bilinear(self.corners[patch], uv)

    def point(self, patch: int, u: float, v: float) -> np.ndarray:
        """(3,) the position at one (u, v) of one patch (DiagSplit's many single evaluations)."""
        c = self.corners[patch]
        bottom = c[0] + u * (c[1] - c[0])
        return bottom + v * (c[3] + u * (c[2] - c[3]) - bottom)

    def evaluate(self, patch: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.positions(patch, uv), _normalized(bilinear(self.normal_corners[patch], uv))


def _bspline(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The uniform cubic B-spline basis at t (N,) and its derivative, (N, 4) each."""
    s = 1.0 - t
    t2, t3 = t * t, t * t * t
    basis = np.stack([s * s * s, 3 * t3 - 6 * t2 + 4, -3 * t3 + 3 * t2 + 3 * t + 1, t3], axis=1) / 6.0
    slope = np.stack([-s * s, 3 * t2 - 4 * t, -3 * t2 + 2 * t + 1, t2], axis=1) / 2.0
    return basis, slope


def _cubic(t: float) -> np.ndarray:
    """(4,) the uniform cubic B-spline basis at one t."""
    s = 1.0 - t
    t2 = t * t
    return np.array([s * s * s, 3.0 * t2 * t - 6.0 * t2 + 4.0, -3.0 * t2 * t + 3.0 * t2 + 3.0 * t + 1.0, t2 * t]) / 6.0


def level_for(cage: Cage) -> int:
    """The refinement level: the finest up to MAX_LEVEL whose grids fit CONTROL_POINT_BUDGET, at least 1."""
    patches = cage.patches()
    quads, ngons = int((~patches.ngon).sum()), int(patches.ngon.sum())
    for level in range(MAX_LEVEL, 0, -1):
        n = 2 ** level
        if quads * (n + 3) ** 2 + ngons * (n // 2 + 3) ** 2 <= CONTROL_POINT_BUDGET:
            return level
    return 1


class CatmullClarkSurface:
    """The Catmull-Clark limit surface of a cage (refine.py's rules). keep_corners : Boundary Smooth "Keep
    Corners" (OpenSubdiv's EDGE_AND_CORNER), else boundary corners are smoothed (EDGE_ONLY); kept : (V,) bool
    the cage's kept corners instead (a UV map's rules). Raises refine.Unsupported for topology the rules do
    not cover."""

    def __init__(self, cage: Cage, keep_corners: bool = False, level: int | None = None,
                 kept: np.ndarray | None = None):
        self.patches = cage.patches()
        self.level = level or level_for(cage)
        if kept is None:
            kept = refine.boundary_corners(cage) if keep_corners else np.zeros(len(cage.positions), bool)
        fine, self.index = refine.first_level(cage, kept)
        for _ in range(self.level - 1):
            fine = refine.next_level(fine)
        self.grids = fine.grids
        quads = refine.cells(fine.grids)
        stats = refine.valence(fine.positions, quads)
        self.limit = refine.limit_positions(fine, quads, stats)
        self.limit_normals = _vertex_normals(self.limit, quads)
        regular = refine.regular_vertices(stats, fine.kept)
        self.regular = [regular[g[:, :-1, :-1]] & regular[g[:, :-1, 1:]] & regular[g[:, 1:, 1:]]
                        & regular[g[:, 1:, :-1]] for g in fine.grids]
        self.control = _extended_grids(fine.positions, quads, fine.grids)

    def positions(self, patch: np.ndarray, uv: np.ndarray) -> np.ndarray:
        return self.evaluate(patch, uv, normals=False)[0]

    def point(self, patch: int, u: float, v: float) -> np.ndarray:
        """(3,) the position at one (u, v) of one patch (DiagSplit's many single evaluations)."""
        g, p = self.index[patch]
        grid = self.grids[g]
        n = grid.shape[1] - 1
        s, t = min(max(u * n, 0.0), float(n)), min(max(v * n, 0.0), float(n))
        i, j = min(int(s), n - 1), min(int(t), n - 1)
        a, b = s - i, t - j
        if self.regular[g][p, j, i]:
            return _cubic(b) @ (_cubic(a) @ self.control[g][p, j:j + 4, i:i + 4])
        c = self.limit[[grid[p, j, i], grid[p, j, i + 1], grid[p, j + 1, i + 1], grid[p, j + 1, i]]]
        bottom = c[0] + a * (c[1] - c[0])
        return bottom + b * (c[3] + a * (c[2] - c[3]) - bottom)

    def evaluate(self, patch: np.ndarray, uv: np.ndarray, normals: bool = True):
        patch = np.asarray(patch, np.int64)
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        p_out = np.empty((len(patch), 3))
        n_out = np.empty((len(patch), 3)) if normals else None
        group, local = self.index[patch, 0], self.index[patch, 1]
        for g, grid in enumerate(self.grids):
            sel = np.flatnonzero(group == g)
            if not len(sel):
                continue
            n = grid.shape[1] - 1
            p = local[sel]
            s = np.clip(uv[sel] * n, 0.0, float(n))
            cell = np.minimum(np.floor(s), n - 1).astype(np.int64)
            t = s - cell
            i, j = cell[:, 0], cell[:, 1]
            smooth = self.regular[g][p, j, i]
            if smooth.any():
                k = sel[smooth]
                rows = j[smooth, None] + np.arange(4)
                cols = i[smooth, None] + np.arange(4)
                control = self.control[g][p[smooth, None, None], rows[:, :, None], cols[:, None, :]]
                bu, du = _bspline(t[smooth, 0])
                bv, dv = _bspline(t[smooth, 1])
                p_out[k] = np.einsum("nr,nc,nrcx->nx", bv, bu, control)
                if normals:
                    along_u = np.einsum("nr,nc,nrcx->nx", bv, du, control)
                    along_v = np.einsum("nr,nc,nrcx->nx", dv, bu, control)
                    n_out[k] = _normalized(np.cross(along_u, along_v))
            rough = ~smooth
            if rough.any():
                k = sel[rough]
                pr, jr, ir = p[rough], j[rough], i[rough]
                corners = np.stack([grid[pr, jr, ir], grid[pr, jr, ir + 1], grid[pr, jr + 1, ir + 1],
                                    grid[pr, jr + 1, ir]], axis=1)
                p_out[k] = bilinear(self.limit[corners], t[rough])
                if normals:
                    n_out[k] = _normalized(bilinear(self.limit_normals[corners], t[rough]))
        return p_out, n_out


def _vertex_normals(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(V, 3) unit normals: the sum of the normals (cross of diagonals) of the quads around each vertex."""
    a, b, c, d = (points[quads[:, k]] for k in range(4))
    face = np.cross(c - a, d - b)
    return _normalized(refine.scatter_sum(quads.reshape(-1), np.repeat(face, 4, axis=0), len(points)))


def _extended_grids(positions: np.ndarray, quads: np.ndarray, grids: tuple) -> list:
    """Per group of patches, (P, n + 3, n + 3, 3) control points: each patch's grid with a ring around it, the
    neighbours across its sides and corners (through the quads' half-edges), mirrored across boundaries (a
    boundary B-spline's phantom points, 2 b - i)."""
    v = len(positions)
    loops = quads.reshape(-1)
    following = np.roll(quads, -1, axis=1).reshape(-1)
    key = loops * v + following
    order = np.argsort(key)
    wanted = following * v + loops
    found = np.clip(np.searchsorted(key[order], wanted), 0, len(key) - 1)
    twin = np.where(key[order][found] == wanted, order[found], -1)

    def nxt(h, steps=1):
        return 4 * (h // 4) + (h % 4 + steps) % 4

    out, first = [], 0
    for grid in grids:
        p, n = len(grid), grid.shape[1] - 1
        ext = np.full((p, n + 3, n + 3, 3), np.nan)
        ext[:, 1:n + 2, 1:n + 2] = positions[grid]
        cell = first + np.arange(p * n * n).reshape(p, n, n)
        m = np.arange(n)
        # Each side's half-edges in counter-clockwise order, and where its across points and corner go.
        sides = ((cell[:, 0, m], 0, (lambda k: (0, k + 1)), (0, 0)),
                 (cell[:, m, n - 1], 1, (lambda k: (k + 1, n + 2)), (0, n + 2)),
                 (cell[:, n - 1, n - 1 - m], 2, (lambda k: (n + 2, n + 1 - k)), (n + 2, n + 2)),
                 (cell[:, n - 1 - m, 0], 3, (lambda k: (n + 1 - k, 0)), (n + 2, 0)))
        for cells_, k, place, corner in sides:
            h = 4 * cells_ + k                                       # (p, n)
            t = twin[h]
            ok = t >= 0
            ts = np.where(ok, t, 0)
            across = np.empty((p, n + 1), np.int64)
            across[:, :n] = loops[nxt(ts, 2)]
            across[:, n] = loops[nxt(ts[:, -1], 3)]
            known = np.concatenate([ok, ok[:, -1:]], axis=1)
            known[:, 1:n] |= ok[:, :n - 1]
            idx = np.arange(n + 1)
            r, c = place(idx)
            ext[:, r, c] = np.where(known[:, :, None], positions[across], np.nan)
            q = np.where(ok[:, 0], twin[nxt(ts[:, 0], 1)], -1)
            diag_ok = q >= 0
            ext[diag_ok, corner[0], corner[1]] = positions[loops[nxt(q[diag_ok], 3)]]
        _phantoms(ext)
        out.append(ext)
        first += p * n * n
    return out


def _phantoms(ext: np.ndarray) -> None:
    """Fill the ring's points that have no neighbour (boundaries) by mirroring: columns, rows, columns again."""
    last = ext.shape[1] - 1
    for _ in range(2):
        for col, a, b in ((0, 1, 2), (last, last - 1, last - 2)):
            gap = np.isnan(ext[:, :, col, 0])
            ext[:, :, col] = np.where(gap[..., None], 2.0 * ext[:, :, a] - ext[:, :, b], ext[:, :, col])
        for row, a, b in ((0, 1, 2), (last, last - 1, last - 2)):
            gap = np.isnan(ext[:, row, :, 0])
            ext[:, row] = np.where(gap[..., None], 2.0 * ext[:, a] - ext[:, b], ext[:, row])
