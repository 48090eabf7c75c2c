"""Voxel grids: a dense block of voxel values placed in an object's space, looked up at points as Cycles
samples volume grids (the media's majorants come from the shader's values, kernels/media/medium.py).

Conventions, as Cycles (Blender 5.0 on) samples a grid (kernel/util/image_3d.h, kernel_image_interp_3d):

- Index space. Voxel (i, j, k) holds its value at the integer index point (i, j, k): OpenVDB's convention,
  which Cycles adopted in Blender 5.0 ("Use grid voxel corners as value locations like OpenVDB"; before, the
  kernel subtracted half a voxel). A point is taken to index space by the inverse of the grid's
  index-to-object transform (scene/image_vdb.cpp: transform_3d = transform_inverse(index_to_object)).
- Closest reads the voxel at floor(P), so voxel i answers for P in [i, i + 1).
- Linear blends the 8 voxels floor(P) + {0, 1}^3 with weights t = P - floor(P).
- Cubic is the uniform cubic B-spline over floor(P) - 1 ... floor(P) + 2 (fill_cubic_weights): its weights
  are non-negative and sum to 1, so, as Linear, it never leaves the range of the voxels it reads.
- A voxel outside the stored block reads the grid's background (NanoVDB's accessor returns the root's
  background outside the active tree; 0 for density).
- Four-channel grids (the smoke domain's premultiplied RGBA colour) are un-premultiplied after the
  interpolation when alpha is neither ~0 nor 1 (kernel/geom/volume.h, volume_attribute_float4).

Cycles' stochastic one-tap filtering (interp_stochastic) picks one voxel at random with the filter's weights,
so its expectation is the deterministic filter computed here.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..vec import F32, F64, matmul

INTERPOLATIONS = ("CLOSEST", "LINEAR", "CUBIC")
# Voxels a lookup reads beyond its cell, per side: how far Cycles dilates the active voxels before it builds
# a volume's bounding mesh (scene/volume.cpp, create_volume_mesh: pad 1 for Linear, 2 for Cubic).
PADDING = {"CLOSEST": 0, "LINEAR": 1, "CUBIC": 2}
_BORDER = 4   # background voxels around the stored block: a cubic lookup's 4 taps fit in it outside the block


@dataclass(frozen=True, eq=False)
class VoxelGrid:
    """A dense grid of voxel values in an object's space.

    values : (nx, ny, nz, C) float32, C = 1 (density, temperature, flame, heat), 3 (colour, velocity) or 4
        (premultiplied RGBA); values[i, j, k] sits at index point (i, j, k).
    index_to_object : (4, 4) float64, index coordinates of `values` -> the object's local space (the VDB
        transform, offset by the stored block's first voxel).
    background : the value outside the stored block, a scalar or (C,).
    active_box : ((i0, j0, k0), (i1, j1, k1)) inclusive index bounds of the active voxels (above Cycles'
        clipping), the region bounds() and the boundary mesh enclose; None: the whole block.
    """
    values: np.ndarray
    index_to_object: np.ndarray
    background: np.ndarray | float = 0.0
    active_box: tuple | None = None
    object_to_index: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        values = np.ascontiguousarray(self.values, dtype=F32)
        if values.ndim == 3:
            values = values[..., None]
        if values.ndim != 4 or values.shape[3] not in (1, 3, 4):
            raise ValueError(f"VoxelGrid values must be (nx, ny, nz, C) with C in 1, 3, 4, not {values.shape}")
        index_to_object = np.asarray(self.index_to_object, dtype=F64)
        background = np.broadcast_to(np.asarray(self.background, dtype=F32), (values.shape[3],)).copy()
        box = self.active_box
        if box is None:
            box = ((0, 0, 0), tuple(n - 1 for n in values.shape[:3]))
        box = tuple(tuple(int(c) for c in corner) for corner in box)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "index_to_object", index_to_object)
        object.__setattr__(self, "background", background)
        object.__setattr__(self, "active_box", box)
        object.__setattr__(self, "object_to_index", np.linalg.inv(index_to_object))

    @property
    def channels(self) -> int:
        return self.values.shape[3]

    @property
    def shape(self) -> tuple:
        return self.values.shape[:3]

    # ---------------------------------------------------------------- lookups
    def index_coordinates(self, points, to_object=None) -> np.ndarray:
        """(n, 3) object-space points -> (n, 3) float64 index coordinates P; to_object: a (3, 4) affine map that
        takes the points to object space first (one product of both), or None."""
        points = np.asarray(points, dtype=F64).reshape(-1, 3)
        m = self.object_to_index
        if to_object is not None:
            m = m @ np.vstack([np.asarray(to_object, F64), [0.0, 0.0, 0.0, 1.0]])
        return matmul(points, m[:3, :3].T) + m[:3, 3]

    def lookup(self, points, interpolation: str = "LINEAR", to_object=None) -> np.ndarray:
        """(n, 3) float32 object-space points -> (n, C) float32 values, interpolated as Cycles does
        (module docstring); interpolation is 'CLOSEST', 'LINEAR' or 'CUBIC'; to_object: a (3, 4) affine map of
        the points to object space (world points of one object), or None."""
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, not {interpolation!r}")
        p = self.index_coordinates(points, to_object)
        cell = np.floor(p)
        t = (p - cell).astype(F32)
        cell = cell.astype(np.int64)
        if interpolation == "CLOSEST":
            out = self._gather(cell[:, 0], cell[:, 1], cell[:, 2])
        elif interpolation == "LINEAR":
            out = self._blend(cell, [np.stack([1 - t[:, a], t[:, a]]) for a in range(3)], first=0)
        else:
            out = self._blend(cell, [cubic_bspline_weights(t[:, a]) for a in range(3)], first=-1)
        return _unpremultiply(out) if self.channels == 4 else out

    def _blend(self, cell: np.ndarray, weights: list, first: int) -> np.ndarray:
        """Sum over the taps cell + first + (a, b, c) of weights[0][a] * weights[1][b] * weights[2][c] * value."""
        flat, strides = self._padded()
        taps = len(weights[0])
        base = self._base(cell + first, taps, strides)
        out = np.zeros((len(cell), self.channels), dtype=F32)
        for a, wx in enumerate(weights[0]):
            for b, wy in enumerate(weights[1]):
                wxy = wx * wy
                for c, wz in enumerate(weights[2]):
                    out += (wxy * wz)[:, None] * np.take(flat, base + (a * strides[0] + b * strides[1] + c), axis=0)
        return out

    def _gather(self, i, j, k) -> np.ndarray:
        """(n, C) values of the voxels (i, j, k), the background outside the stored block."""
        flat, strides = self._padded()
        return np.take(flat, self._base(np.stack([i, j, k], axis=1), 1, strides), axis=0)

    def _base(self, cell: np.ndarray, taps: int, strides) -> np.ndarray:
        """Flat indices into the padded values of the first taps at cell (n, 3): each axis moved by the border
        and clamped so that all taps stay in the padded block; a cell far outside reads the border alone."""
        lo = cell + _BORDER
        dims = np.array(self.shape) + 2 * _BORDER - taps
        lo = np.clip(lo, 0, dims)
        return lo[:, 0] * strides[0] + lo[:, 1] * strides[1] + lo[:, 2]

    def __getstate__(self):
        """Pickled (to worker processes) without the lookups' padded copy, made again where it is used."""
        state = dict(self.__dict__)
        state.pop("_padded_cache", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)

    def _padded(self):
        """The values with a border of _BORDER background voxels on each side, flat (N, C), and the strides of
        its i and j axes: lookups read it without bounds tests (made on first use)."""
        cached = self.__dict__.get("_padded_cache")
        if cached is None:
            nx, ny, nz = self.shape
            b = _BORDER
            block = np.full((nx + 2 * b, ny + 2 * b, nz + 2 * b, self.channels), self.background, F32)
            block[b:b + nx, b:b + ny, b:b + nz] = self.values
            cached = (block.reshape(-1, self.channels), ((ny + 2 * b) * (nz + 2 * b), nz + 2 * b))
            object.__setattr__(self, "_padded_cache", cached)
        return cached

    # ---------------------------------------------------------------- extent
    def box_corners(self, padding: int = 0) -> np.ndarray:
        """(8, 3) float64 object-space corners of the active box grown by `padding` voxels per side; corner n
        takes the maximum on axis a where bit a of n is set."""
        lo = np.asarray(self.active_box[0], dtype=F64) - padding
        hi = np.asarray(self.active_box[1], dtype=F64) + padding
        corners = np.array([[(hi if (n >> a) & 1 else lo)[a] for a in range(3)] for n in range(8)])
        return matmul(corners, self.index_to_object[:3, :3].T) + self.index_to_object[:3, 3]

    def bounds(self, padding: int = 0) -> np.ndarray:
        """(2, 3) float32 object-space AABB (min, max) of the active box grown by `padding` voxels (PADDING
        gives Cycles' padding per interpolation)."""
        corners = self.box_corners(padding)
        return np.stack([corners.min(axis=0), corners.max(axis=0)]).astype(F32)

def cubic_bspline_weights(t: np.ndarray) -> np.ndarray:
    """(4, n) float32 uniform cubic B-spline weights of the taps floor(P) - 1 ... floor(P) + 2 for
    t = P - floor(P) (Cycles' fill_cubic_weights, kernel/util/image_3d.h)."""
    t = np.asarray(t, dtype=F32)
    sixth = F32(1.0 / 6.0)
    return np.stack([((-sixth * t + F32(0.5)) * t - F32(0.5)) * t + sixth,
                     ((F32(0.5) * t - 1) * t) * t + F32(2.0 / 3.0),
                     ((F32(-0.5) * t + F32(0.5)) * t + F32(0.5)) * t + sixth,
                     sixth * t * t * t])


def _unpremultiply(rgba: np.ndarray) -> np.ndarray:
    """Cycles' volume_attribute_float4: RGB / alpha where alpha > 1e-6 and alpha != 1."""
    alpha = rgba[:, 3:4]
    divide = (alpha > F32(1e-6)) & (alpha != 1)
    rgba[:, :3] = np.where(divide, rgba[:, :3] / np.where(divide, alpha, F32(1)), rgba[:, :3])
    return rgba
