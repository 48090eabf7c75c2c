"""Per-triangle arrays, shared by SceneArrays and Prototype: CornerRows (corner values kept once per row),
comparing triangle arrays, checking their shapes and dtypes, and cleaning them (degenerate or non-finite
triangles dropped, bad normals, UVs and tangents repaired), big meshes on threads."""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..vec import matmul
from .checks import check_array, require


@dataclass(frozen=True, eq=False)
class CornerRows:
    """Per-corner values kept once per row and gathered by index: the (T, 3, C) values are rows[index].

    rows : (N, C) float32; index : (T, 3) uint32, each below N. SceneArrays.positions and normals may hold
    one instead of their (T, 3, 3) arrays: the export's world vertices with the triangles' vertex numbers
    (the very arrays Embree builds its BVH from), and each mesh's world normals once per vertex (a mesh
    smooth all over) or face corner: a third or less of the memory, gathered only where they are read (the
    triangle table's rows, validation in blocks, emissive triangles). It reads like the array it stands
    for: len, shape, dtype, triangles by slice, numbers or mask, and np.asarray (which builds the whole
    array)."""
    rows: np.ndarray
    index: np.ndarray

    @property
    def shape(self) -> tuple:
        return (len(self.index), 3, self.rows.shape[1] if self.rows.ndim == 2 else 0)

    @property
    def dtype(self):
        return self.rows.dtype

    ndim = 3

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, key) -> np.ndarray:
        if isinstance(key, slice) or (isinstance(key, np.ndarray) and key.ndim == 1):
            return np.take(self.rows, self.index[key], axis=0)    # triangles: a slice, numbers or a mask
        return self.dense()[key]

    def bounds(self):
        """(lo, hi) float32 (3,) of the values the corners read (rows no corner reads left out)."""
        used = np.zeros(len(self.rows), bool)
        used[self.index.ravel()] = True
        values = self.rows if used.all() else self.rows[used]
        # Column by column: a strided min per column is ~10x faster than min(axis=0) over (N, 3) rows.
        columns = range(values.shape[1])
        return (np.array([values[:, k].min() for k in columns], values.dtype),
                np.array([values[:, k].max() for k in columns], values.dtype))

    def dense(self) -> np.ndarray:
        return np.take(self.rows, self.index, axis=0)

    def __array__(self, dtype=None, copy=None):
        values = self.dense()
        return values if dtype is None else values.astype(dtype)

    def astype(self, dtype) -> np.ndarray:
        return self.dense().astype(dtype)

    def finite_triangles(self) -> np.ndarray:
        """(T,) bool: every value of the triangle's three corners is finite."""
        ok = _finite_rows(self.rows)
        if ok.all():
            return np.ones(len(self.index), bool)
        bad = np.take(~ok, self.index, axis=0)
        return ~(bad[:, 0] | bad[:, 1] | bad[:, 2])


def corner_values(values, triangles: np.ndarray | None = None) -> np.ndarray:
    """A (T, 3, C) array or CornerRows as an array: all of it, or the triangles numbered `triangles`."""
    if isinstance(values, CornerRows):
        return values.dense() if triangles is None else values[np.asarray(triangles)]
    return values if triangles is None else np.take(values, triangles, axis=0)


def padded_triangles(count: int) -> np.ndarray:
    """An uninitialised (count, 3, 3) float32 positions array followed by one spare vertex in its
    buffer, which lets Embree read the corners in place (kernels.embree.padded_vertices)."""
    return np.empty(count * 9 + 3, np.float32)[:count * 9].reshape(count, 3, 3)


def same_arrays(a, b) -> bool:
    """Equal arrays (None only equals None), at once when they are the same memory seen the same way;
    CornerRows equal CornerRows of the same rows and index."""
    if a is None or b is None:
        return a is b
    if isinstance(a, CornerRows) or isinstance(b, CornerRows):
        return (isinstance(a, CornerRows) and isinstance(b, CornerRows) and same_arrays(a.rows, b.rows)
                and same_arrays(a.index, b.index))
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.__array_interface__["data"][0] == b.__array_interface__["data"][0] and a.strides == b.strides:
        return True
    return np.array_equal(a, b)


def same_triangles(a, b) -> bool:
    """Whether two SceneArrays (or Prototypes) hold the same triangles, array for array."""
    for name in ("positions", "normals", "uvs", "material_ids", "tangents", "object_ids", "motion_ids"):
        if hasattr(a, name) and not same_arrays(getattr(a, name), getattr(b, name)):
            return False
    return len(a.attributes) == len(b.attributes) and all(
        na == nb and same_arrays(va, vb) for (na, va), (nb, vb) in zip(a.attributes, b.attributes))


def check_triangles(tris, prefix: str, materials: int | None) -> None:
    """Shapes and dtypes of a SceneArrays' or Prototype's per-triangle fields (and, given the material
    count, their material ids)."""
    t = len(tris.positions) if hasattr(tris.positions, "__len__") else -1
    for name in ("positions", "normals"):
        values = getattr(tris, name)
        if isinstance(values, CornerRows):
            rows, index = values.rows, values.index
            check_array(rows, f"{prefix}{name}.rows", (-1, 3), np.float32, finite=False)
            check_array(index, f"{prefix}{name}.index", (t, 3), np.uint32)
            require(not index.size or int(index.max()) < len(rows), f"{prefix}{name}.index",
                    f"must be below {len(rows)}")
        else:
            check_array(values, prefix + name, (t, 3, 3), np.float32, finite=False)
    check_array(tris.uvs, prefix + "uvs", (t, 3, 2), np.float32, finite=False)
    check_array(tris.material_ids, prefix + "material_ids", (t,), np.int32)
    if tris.tangents is not None:
        check_array(tris.tangents, prefix + "tangents", (t, 3, 4), np.float32, finite=False)
    for name, values in tris.attributes:
        require(isinstance(name, str), prefix + "attributes", "names must be strings")
        c = values.shape[2] if getattr(values, "ndim", 0) == 3 else 0
        require(1 <= c <= 4, f"{prefix}attributes[{name!r}]", "must be (T, 3, C) with C in 1..4")
        check_array(values, f"{prefix}attributes[{name!r}]", (t, 3, c), np.float32)
    if materials is not None:
        check_material_ids(tris, prefix, materials)


def check_material_ids(tris, prefix: str, m: int) -> None:
    if len(tris.material_ids):
        require(tris.material_ids.min() >= 0 and tris.material_ids.max() < m, prefix + "material_ids",
                f"must be in [0, {m}), got {tris.material_ids.min()}..{tris.material_ids.max()}")


def clean_triangles(tris, extra: tuple = ()) -> tuple[dict, int, int, int]:
    """Degenerate or non-finite triangles of a SceneArrays or Prototype dropped (with the per-triangle
    fields named in extra), non-finite normals, UVs and tangents of the others repaired (a geometric
    normal, turned where tris.mirrored_triangles() says): (the changed fields, for dataclasses.replace;
    dropped count; repaired normals count; how many of the dropped have corners that are not finite)."""
    t = len(tris.positions)
    keep = usable_triangles(tris.positions)
    # A non-finite normal or UV on a usable triangle falls back to the geometric normal / zero UV.
    normals = tris.normals
    uvs = tris.uvs
    bad_n = ~(normals.finite_triangles() if isinstance(normals, CornerRows) else _finite_rows(normals))
    bad_uv = ~_finite_rows(uvs)
    # A non-finite tangent on a usable triangle becomes "no tangent".
    tangents = tris.tangents
    bad_t = ~_finite_rows(tangents) if tangents is not None else np.zeros(t, bool)
    dropped = int(t - np.count_nonzero(keep))
    repaired = int(np.count_nonzero(bad_n & keep))
    if not (dropped or bad_n.any() or bad_uv.any() or bad_t.any()):
        return {}, 0, 0, 0
    nonfinite = int(np.count_nonzero(~np.isfinite(np.asarray(tris.positions[~keep])).all(axis=(1, 2)))) \
        if dropped else 0
    normals = np.array(normals)   # a copy (CornerRows: the whole array, which the repairs write into)
    uvs = uvs.copy()
    if bad_n.any():
        p = np.nan_to_num(tris.positions[bad_n])
        ng = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        mirrored = tris.mirrored_triangles()
        if mirrored is not None:
            ng[mirrored[bad_n]] *= -1
        normals[bad_n] = ng[:, None, :]
    uvs[bad_uv] = 0.0
    if tangents is not None:
        tangents = tangents.copy()
        tangents[bad_t] = 0.0
        tangents = np.ascontiguousarray(tangents[keep])
    positions = padded_triangles(int(np.count_nonzero(keep)))
    np.compress(keep, tris.positions, axis=0, out=positions)
    changes = dict(positions=positions, normals=np.ascontiguousarray(normals[keep]),
                   uvs=np.ascontiguousarray(uvs[keep]), material_ids=np.ascontiguousarray(tris.material_ids[keep]),
                   tangents=tangents,
                   attributes=tuple((name, np.ascontiguousarray(np.nan_to_num(v[keep]))) for name, v in tris.attributes))
    for name in extra:
        values = getattr(tris, name)
        changes[name] = None if values is None else np.ascontiguousarray(values[keep])
    return changes, dropped, repaired, nonfinite


# Meshes of at least this many triangles are checked in slices on threads (NumPy releases the GIL), each
# slice in blocks of _BLOCK_TRIANGLES.
_PARALLEL_TRIANGLES = 1 << 19
_BLOCK_TRIANGLES = 1 << 15


def usable_triangles(positions: np.ndarray) -> np.ndarray:
    """(T,) bool: finite corners and non-zero area, relative to the triangle's own size (area x 2 above
    1e-12 x its longer edge squared, in float64).

    Sorted in float32 first: a triangle whose float32 area clears the bound by a factor 1e8 clears it in
    float64 too (float32 rounding moves the cross product by a few 1e-7 of |e1| |e2|); only the others
    (slivers, non-finite and overflowing corners) are measured again in float64. Same answer, 5x faster
    on a million triangles. Big meshes are checked in slices on threads, row by row the same answer."""
    t = len(positions)
    usable = np.empty(t, bool)

    def blocks(lo: int, hi: int) -> None:
        # Blocks of _BLOCK_TRIANGLES keep the temporaries small: the allocator reuses them, hot in cache,
        # instead of faulting in fresh pages for every one of a million rows.
        for start in range(lo, hi, _BLOCK_TRIANGLES):
            end = min(start + _BLOCK_TRIANGLES, hi)
            usable[start:end] = _usable_slice(positions[start:end])

    threads = min(os.cpu_count() or 1, t // (_PARALLEL_TRIANGLES // 2))
    if t >= _PARALLEL_TRIANGLES and threads > 1:
        from concurrent.futures import ThreadPoolExecutor
        bounds = np.linspace(0, t, threads + 1).astype(int)
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda i: blocks(bounds[i], bounds[i + 1]), range(threads)))
    else:
        blocks(0, t)
    return usable


def _usable_slice(positions: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore"):
        e1 = positions[:, 1] - positions[:, 0]
        e2 = positions[:, 2] - positions[:, 0]
        cx = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
        cy = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
        cz = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        area_sq = cx * cx + cy * cy + cz * cz
        scale = np.maximum(np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e2, e2))
        clear = area_sq > np.float32(1e-8) * scale * scale   # area > 1e-4 x scale, squared
    usable = clear & np.isfinite(area_sq)
    doubt = np.flatnonzero(~usable)
    if len(doubt):
        usable[doubt] = _usable_exact(positions[doubt])
    return usable


def _finite_rows(a: np.ndarray) -> np.ndarray:
    """(T,) bool: every value of each row a[i] is finite. A row's sum (one BLAS product) is finite when all
    its values are, unless finite values overflow it: only rows whose sum is not are looked at value by
    value. Six times faster than isfinite().all() on a million triangles."""
    if not a.size:
        return np.ones(len(a), bool)
    if a.strides[0] == 0:   # one row seen len(a) times (a mesh without UVs)
        return np.full(len(a), bool(np.isfinite(a[0]).all()))
    flat = a.reshape(len(a), -1)
    with np.errstate(over="ignore", invalid="ignore"):
        ok = np.isfinite(matmul(flat, np.ones(flat.shape[1], flat.dtype)))
    doubt = np.flatnonzero(~ok)
    if len(doubt):
        ok[doubt] = np.isfinite(flat[doubt]).all(axis=1)
    return ok


def _usable_exact(positions: np.ndarray) -> np.ndarray:
    finite = np.isfinite(positions).all(axis=(1, 2))
    p = np.where(finite[:, None, None], positions, 0).astype(np.float64)
    e1 = p[:, 1] - p[:, 0]
    e2 = p[:, 2] - p[:, 0]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    scale = np.maximum(np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e2, e2))
    return finite & (area2 > 1e-12 * scale) & (area2 > 0)
