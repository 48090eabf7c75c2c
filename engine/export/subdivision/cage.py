"""The cage: the base mesh Cycles subdivides (its Mesh::subd_* arrays) and the patches it splits.

Cycles makes one patch of each quad and one of each corner of any other face (its ptex faces,
scene/mesh_subdivision.cpp Mesh::tessellate): a quad's patch has (u, v) = (0, 0) at its first corner, u towards
the second and v towards the fourth; a corner patch of an n-gon has (0, 0) at its corner, u towards the middle
of the edge to the next corner, v towards the middle of the edge from the previous one, and (1, 1) at the face's
centre (subd/split.cpp DiagSplit::split_ngon, OpenSubdiv's ptex faces).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Cage:
    """A polygon mesh in object space, F faces over V vertices and C face corners.

    positions : (V, 3) float64. face_starts, face_sizes : (F,) int64, each face's first corner and corner count;
    corner_verts : (C,) int64, each corner's vertex, faces wound as Blender winds them.
    """
    positions: np.ndarray
    face_starts: np.ndarray
    face_sizes: np.ndarray
    corner_verts: np.ndarray

    @classmethod
    def from_faces(cls, positions, face_sizes, corner_verts) -> "Cage":
        sizes = np.asarray(face_sizes, np.int64)
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) if len(sizes) else sizes
        return cls(np.asarray(positions, np.float64).reshape(-1, 3), starts, sizes,
                   np.asarray(corner_verts, np.int64))

    @property
    def face_count(self) -> int:
        return len(self.face_sizes)

    def patches(self) -> "Patches":
        """The patch table: one patch per quad, then per corner of other faces, in face order (Cycles' ptex
        offsets)."""
        per_face = np.where(self.face_sizes == 4, 1, self.face_sizes)
        first = np.concatenate([[0], np.cumsum(per_face)[:-1]]).astype(np.int64) if len(per_face) else per_face
        face = np.repeat(np.arange(self.face_count), per_face)
        corner = np.arange(len(face)) - first[face]
        return Patches(face=face, corner=corner, ngon=self.face_sizes[face] != 4, first=first)

    def loop(self, face: np.ndarray, corner: np.ndarray) -> np.ndarray:
        """The corner index (into corner_verts) of `corner` of `face`, wrapping around the face."""
        return self.face_starts[face] + np.mod(corner, self.face_sizes[face])


@dataclass(frozen=True)
class Patches:
    """P patches: face (P,) the face each belongs to, corner (P,) its corner (0 for a quad's), ngon (P,) bool
    whether it is a corner patch of a face other than a quad; first (F,) each face's first patch."""
    face: np.ndarray
    corner: np.ndarray
    ngon: np.ndarray
    first: np.ndarray

    def __len__(self) -> int:
        return len(self.face)


def bilinear_corners(cage: Cage, patches: Patches, values: np.ndarray) -> np.ndarray:
    """(P, 4, C) the values at each patch's corners (0, 0), (1, 0), (1, 1), (0, 1), from values (C_loops, C) per
    face corner: a quad's four corners; for an n-gon's corner patch its corner, the middles of its two edges and
    the face's mean (Cycles' linear interpolation, subd/interpolation.cpp, and LinearQuadPatch's hull)."""
    values = np.asarray(values, np.float64)
    f, c = patches.face, patches.corner
    out = np.empty((len(patches), 4, values.shape[1]))
    quad = ~patches.ngon
    if quad.any():
        start = cage.face_starts[f[quad]]
        for k in range(4):
            out[quad, k] = values[start + (0, 1, 2, 3)[k]]
    if patches.ngon.any():
        fn, cn = f[patches.ngon], c[patches.ngon]
        here = values[cage.loop(fn, cn)]
        following = values[cage.loop(fn, cn + 1)]
        previous = values[cage.loop(fn, cn - 1)]
        sums = np.stack([np.bincount(np.repeat(np.arange(cage.face_count), cage.face_sizes), weights=values[:, k],
                                     minlength=cage.face_count) for k in range(values.shape[1])], axis=1)
        centre = sums[fn] / cage.face_sizes[fn, None]
        out[patches.ngon] = np.stack([here, 0.5 * (here + following), centre, 0.5 * (here + previous)], axis=1)
    return out


def bilinear(corners: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, C) the bilinear interpolation of (N, 4, C) corner values (corners (0,0), (1,0), (1,1), (0,1)) at
    (N, 2) uv, as Cycles' interp(interp(c0, c1, u), interp(c3, c2, u), v)."""
    u, v = uv[:, 0:1], uv[:, 1:2]
    bottom = corners[:, 0] + u * (corners[:, 1] - corners[:, 0])
    top = corners[:, 3] + u * (corners[:, 2] - corners[:, 3])
    return bottom + v * (top - bottom)
