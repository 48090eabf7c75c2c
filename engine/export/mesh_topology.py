"""What the Geometry node reads of a mesh's topology: Pointiness per vertex and Random Per Island per triangle,
computed as Blender's Cycles sync computes them (intern/cycles/blender/mesh.cpp: attr_create_pointiness,
attr_create_random_per_island), and only for meshes whose materials read them.

Pointiness (Cycles' ATTR_STD_POINTINESS, a vertex attribute interpolated over the triangles):
1. Vertices closer than sqrt(FLT_EPSILON) are welded: sorted by x + y + z (exact doubles with the higher index
   first), each vertex points to the first later one within 3 FLT_EPSILON of its sum and FLT_EPSILON of squared
   distance, and chains are followed to their end.
2. Blender's vertex normals are summed per welded vertex and normalized.
3. Over the mesh's edges (welded, each unordered pair once, in edge order), the unit directions to the
   neighbours are summed; raw = acos(normal . mean direction) / pi: 0.5 where the neighbours lie in the tangent
   plane, above it on convex corners, below in crevices; 0 for a vertex without edges.
4. One blur: (raw + the neighbours' raw) / (neighbours + 1), copied back to the welded duplicates.

Random Per Island (ATTR_STD_RANDOM_PER_ISLAND, a face attribute): vertices joined along every edge in Cycles'
union-by-rank disjoint set (util/disjoint_set.h), whose root is hashed, hash_uint_to_float(root) (util/hash.h);
a triangle takes the root of the vertex of its first corner.
"""
from __future__ import annotations

import numpy as np

from ...kernels.shading.hash import hash_uint_to_float

F32 = np.float32
FLT_EPSILON = F32(np.finfo(np.float32).eps)


def welded_vertices(positions: np.ndarray) -> np.ndarray:
    """(V,) int64: the vertex each vertex is welded to (itself when it has no duplicate), positions (V, 3)."""
    p = np.asarray(positions, F32)
    v = len(p)
    total = (p[:, 0] + p[:, 1]) + p[:, 2]
    order = np.lexsort((-np.arange(v), total))     # by the sum; ties with the higher index first
    s, q = total[order], p[order]
    target = np.arange(v)
    searching = np.arange(v)
    step = 1
    while len(searching):
        searching = searching[searching + step < v]
        searching = searching[(s[searching + step] - s[searching]) <= F32(3) * FLT_EPSILON]
        d = q[searching + step] - q[searching]
        same = np.einsum("ij,ij->i", d, d) < FLT_EPSILON
        target[order[searching[same]]] = order[searching[same] + step]
        searching = searching[~same]
        step += 1
    while True:                                    # follow each chain to its end
        nxt = target[target]
        if np.array_equal(nxt, target):
            return target
        target = nxt


def _unique_edges(edges: np.ndarray, welded: np.ndarray) -> np.ndarray:
    """(E', 2) the edges between welded vertices, each unordered pair once, in the order first met."""
    e = welded[np.asarray(edges, np.int64).reshape(-1, 2)]
    lo, hi = e.min(axis=1), e.max(axis=1)
    _, first = np.unique(lo * (len(welded) + 1) + hi, return_index=True)
    return e[np.sort(first)]


def _interleaved_add(out: np.ndarray, pairs: np.ndarray, to_first, to_second) -> None:
    """out[a] += to_first, out[b] += to_second for each pair (a, b), in pair order (float32 sums in Cycles' order)."""
    index = pairs.reshape(-1)
    values = np.stack([to_first, to_second], axis=1).reshape((len(index),) + out.shape[1:])
    np.add.at(out, index, values)


def pointiness(positions: np.ndarray, vertex_normals: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(V,) float32 Pointiness per vertex of a mesh: positions and Blender's vertex normals (V, 3), edges (E, 2)."""
    p = np.asarray(positions, F32)
    v = len(p)
    if v == 0:
        return np.zeros(0, F32)
    welded = welded_vertices(p)
    summed = np.zeros((v, 3), F32)
    np.add.at(summed, welded, np.asarray(vertex_normals, F32))
    normal = summed[welded]
    normal = normal / np.sqrt(np.einsum("ij,ij->i", normal, normal))[:, None]
    pairs = _unique_edges(edges, welded)
    d = p[pairs[:, 1]] - p[pairs[:, 0]]
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    d = np.where(length[:, None] != 0, d / np.where(length != 0, length, F32(1))[:, None], d).astype(F32)
    directions = np.zeros((v, 3), F32)
    _interleaved_add(directions, pairs, d, -d)
    count = np.bincount(pairs.reshape(-1), minlength=v)
    raw = np.zeros(v, F32)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = directions / count.astype(F32)[:, None]
        cos = np.clip(np.einsum("ij,ij->i", normal, mean), F32(-1), F32(1))
        angle = np.arccos(cos).astype(F32) * F32(1.0 / np.pi)
    own = (welded == np.arange(v)) & (count > 0)
    raw[own] = angle[own]
    blurred = raw.copy()
    _interleaved_add(blurred, pairs, raw[pairs[:, 1]], raw[pairs[:, 0]])
    blurred /= (count + 1).astype(F32)
    return np.nan_to_num(blurred[welded])   # a vertex whose normals cancel: 0, not NaN


def island_roots(vertex_count: int, edges: np.ndarray) -> np.ndarray:
    """(V,) int64: each vertex's island, as the root Cycles' DisjointSet gives it after joining every edge in
    order (union by rank; on equal ranks the first vertex's root stays the root)."""
    parent = list(range(vertex_count))
    rank = [0] * vertex_count

    def find(x: int) -> int:
        root = x
        while parent[root] != root:
            root = parent[root]
        while parent[x] != root:
            parent[x], x = root, parent[x]
        return root

    for a, b in np.asarray(edges, np.int64).reshape(-1, 2).tolist():
        ra, rb = find(a), find(b)
        if ra == rb:
            continue
        if rank[ra] < rank[rb]:
            ra, rb = rb, ra
        parent[rb] = ra
        if rank[ra] == rank[rb]:
            rank[ra] += 1
    return np.array([find(x) for x in range(vertex_count)], np.int64)


def random_per_island(vertex_count: int, edges: np.ndarray, first_corner_vertices: np.ndarray) -> np.ndarray:
    """(T,) float32 Random Per Island of each triangle, given the vertex of its first corner."""
    roots = island_roots(vertex_count, edges)
    return hash_uint_to_float(roots[np.asarray(first_corner_vertices, np.int64)].astype(np.uint32)).astype(F32)
