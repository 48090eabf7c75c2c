"""Triangles, the primitive type Ember renders today: the triangle table (every triangle's corner, edges,
normals and UVs in one row, gathered per hit) and the barycentric interpolation of the shading data. Shared by
the integrator (hits) and the lights (points sampled on emissive triangles). Embree gets them as indexed meshes
(kernels/accel.py, kernels/embree.py)."""
from __future__ import annotations

import threading

import numpy as np

from ..scene import SceneArrays, corner_values, object_space_objects
from .instances import apply_matrices, normal_matrices
from ..vec import cross_xyz, dot_rows, normalize_floored_xyz

# Columns of the per-triangle table gathered for every hit (one contiguous row per component).
P0, E1, E2, NG, N0, N1, N2, UV0, UV1, UV2 = 0, 3, 6, 9, 12, 15, 18, 21, 23, 25
_COLUMNS = 27


class TriangleTable:
    """(R, 27) float32 rows: p0, e1, e2, unit geometric normal, three corner normals (unit, but those of an
    object that interpolates its normals in object space: world-space directions of one scale per triangle,
    _fill_rows), three corner UVs.
    Gathering whole rows of a (R, 27) table is ~9x faster than columns of a (27, R) one.

    Rows are the scene's plain triangles (world space) and then each instanced prototype's triangles once
    (object space). Every query takes scene triangle numbers (what ray hits report, kernels.scene.Instances)
    and answers in world space: rows of instanced triangles are placed by their instance's transform as
    they are gathered. A scene without instances gathers its rows as they are."""

    def __init__(self, scene: SceneArrays, deferred: bool = False):
        """deferred : a big scene without instances (at least DEFERRED_ROWS triangles) gets its rows
        later, from build_rows (on a thread, which the renderer starts with a render's second pass: a
        1-sample first image never waits for the table, nor pays for its memory); until they are there,
        gathers compute the rows they need from the scene's arrays, the same float32 operations per row,
        so the answers are the same bit for bit either way."""
        inst = scene.instances if scene.instances is not None and scene.instances.count else None
        parts = [scene] + list(inst.prototypes if inst is not None else ())
        self.plain_count = len(scene.positions)
        self._rows = None
        self._source = None      # (positions, normals, uvs, mirrored, object_space): the deferred rows' source
        self._building = None    # the thread building deferred rows
        self._build_lock = threading.Lock()
        mirrored, object_space = scene.mirrored_triangles(), scene.object_space_triangles()
        if deferred and inst is None and self.plain_count >= DEFERRED_ROWS:
            self._source = (scene.positions, scene.normals, scene.uvs, mirrored, object_space)
        else:
            self._rows = _concatenate([_triangle_table_of(scene.positions, scene.normals, scene.uvs, mirrored,
                                                          object_space)]
                                      + [_triangle_table_of(p.positions, p.normals, p.uvs) for p in parts[1:]])
        self.material_ids = _concatenate([part.material_ids for part in parts])
        # (R, 12) float32: per corner the tangent xyz and its sign; apart from the rows every hit gathers,
        # since only normal-mapped and anisotropic materials read it.
        if any(part.tangents is not None for part in parts):
            self.tangent_rows = _concatenate([
                np.ascontiguousarray(part.tangents.reshape(len(part.tangents), 12), np.float32)
                if part.tangents is not None else np.zeros((len(part.positions), 12), np.float32)
                for part in parts])
        else:
            self.tangent_rows = None
        widths: dict[str, int] = {}
        for part in parts:
            for name, values in part.attributes:
                widths[name] = max(widths.get(name, 0), values.shape[2])
        self.attributes = {}
        for name, c in widths.items():
            columns = []
            for part in parts:
                values = dict(part.attributes).get(name)
                if values is None or values.shape[2] != c:
                    padded = np.zeros((len(part.positions), 3, c), np.float32)
                    if values is not None:
                        padded[..., :values.shape[2]] = values
                    values = padded
                columns.append(values)
            self.attributes[name] = _concatenate(columns)
        self._plain_objects = scene.object_ids
        self._bases = None
        if inst is not None:
            self._bases = inst.bases(self.plain_count)
            starts = np.cumsum([self.plain_count] + [p.triangle_count for p in inst.prototypes])[:-1]
            self._first_row = np.asarray(starts, np.int64)[inst.prototype]
            self.place(inst, scene.objects)

    @property
    def rows(self) -> np.ndarray:
        """(R, 27) float32: the whole table (built now when it was deferred and is not there yet)."""
        rows = self._rows
        if rows is None:
            self.build_rows()
            self._building.join()
            rows = self._rows
        return rows

    @property
    def rows_built(self) -> bool:
        """Whether the table's rows are built (until then a deferred table computes the rows a gather needs)."""
        return self._rows is not None

    @property
    def building(self) -> bool:
        """Whether build_rows has started its thread (it may have finished: wait_rows)."""
        return self._building is not None

    def wait_rows(self) -> None:
        """Block until build_rows' thread, if it started one, is done."""
        if self._building is not None:
            self._building.join()

    def build_rows(self) -> None:
        """Start building deferred rows on a thread (nothing when they are built or being built)."""
        with self._build_lock:
            if self._rows is None and self._building is None:
                self._building = threading.Thread(target=self._build_deferred, name="ember-triangles",
                                                  daemon=True)
                self._building.start()

    def _build_deferred(self) -> None:
        table = _triangle_table_of(*self._source)
        self._rows = table        # one reference assignment: gathers see the whole table or none
        self._source = None

    @staticmethod
    def _computed_rows_from(source, prim: np.ndarray) -> np.ndarray:
        """(N, 27) rows of plain triangles prim computed from source, the scene's (positions, normals,
        uvs, mirrored, object_space), while the table is deferred."""
        positions, normals, uvs, mirrored, object_space = source
        out = np.empty((len(prim), _COLUMNS), np.float32)
        # (np.take would first copy a one-row view of a mesh without UVs whole; indexing reads its row.)
        corner_uvs = uvs[prim] if uvs.strides[0] == 0 else np.take(uvs, prim, axis=0)
        _fill_rows(out, corner_values(positions, prim), corner_values(normals, prim), corner_uvs,
                   None if mirrored is None else np.take(mirrored, prim),
                   None if object_space is None else np.take(object_space, prim))
        return out

    def place(self, instances, objects: np.ndarray | None = None) -> None:
        """Take the instances' transforms and object rows (kernels.scene.Instances) and the object table
        (SceneArrays.objects: which instances interpolate their normals in object space): at build, and again
        when they move (the same instances of the same prototypes; the rows themselves never change)."""
        if self._bases is None or len(instances.prototype) != len(self._bases):
            raise ValueError("place: the instances are not the ones the table was built for")
        m = instances.world_from_object
        self._linear = np.ascontiguousarray(m[:, :3, :3], np.float32)
        self._translation = np.ascontiguousarray(m[:, :3, 3], np.float32)
        self._normal = normal_matrices(m[:, :3, :3])
        self._det_sign = np.sign(np.linalg.det(m[:, :3, :3])).astype(np.float32)
        self._instance_objects = instances.object_ids
        flags = object_space_objects(objects)
        self._object_space = None if flags is None or instances.object_ids is None else \
            np.take(flags, instances.object_ids)

    @property
    def instanced(self) -> bool:
        return self._bases is not None

    def locate(self, prim: np.ndarray):
        """(rows, instance): each scene triangle's row of the tables and its instance, -1 for plain
        triangles (instance is None in a scene without instances, where rows are prim)."""
        if self._bases is None:
            return prim, None
        k = np.searchsorted(self._bases, prim, side="right") - 1
        rows = np.where(k >= 0, np.take(self._first_row, k) + (prim - np.take(self._bases, k)), prim)
        return rows, k

    def gather(self, prim: np.ndarray) -> np.ndarray:
        """(27, N) view: one row per component of the triangles prim (world space)."""
        return self.rows_of(prim).T

    def rows_of(self, prim: np.ndarray) -> np.ndarray:
        """(N, 27) world-space rows of the triangles prim."""
        if self._bases is None:
            rows = self._rows
            if rows is None:
                source = self._source
                rows = self._rows   # the build may have just finished (it sets _rows, then _source)
                if rows is None:
                    return self._computed_rows_from(source, prim)
            return np.take(rows, prim, axis=0)
        rows, k = self.locate(prim)
        g = np.take(self.rows, rows, axis=0)
        sel = np.flatnonzero(k >= 0)
        if len(sel):
            g[sel] = self._place(np.take(g, sel, axis=0), np.take(k, sel))
        return g

    def _place(self, g: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Object-space rows g (m, 27) of instances k in world space."""
        linear, normal = np.take(self._linear, k, axis=0), np.take(self._normal, k, axis=0)
        out = np.empty_like(g)
        out[:, P0:P0 + 3] = apply_matrices(linear, g[:, P0:P0 + 3]) + np.take(self._translation, k, axis=0)
        e1 = apply_matrices(linear, g[:, E1:E1 + 3])
        e2 = apply_matrices(linear, g[:, E2:E2 + 3])
        out[:, E1:E1 + 3], out[:, E2:E2 + 3] = e1, e2
        out[:, NG:NG + 3] = np.stack(normalize_floored_xyz(cross_xyz(e1.T, e2.T)), axis=1)
        # A mirroring transform turns the winding over, not the face: its front stays Blender's.
        out[:, NG:NG + 3] *= np.take(self._det_sign, k)[:, None]
        turned = [apply_matrices(normal, g[:, col:col + 3]) for col in (N0, N1, N2)]
        for col, n in zip((N0, N1, N2), turned):
            out[:, col:col + 3] = np.stack(normalize_floored_xyz(n.T), axis=1)
        common = None if self._object_space is None else np.flatnonzero(np.take(self._object_space, k))
        if common is not None and len(common):
            # Normals interpolated in object space: the corners turned by the normal matrix keep their lengths'
            # ratios (one scale per triangle), so the interpolated normal is the object-space one turned.
            n = np.stack([np.take(t, common, axis=0) for t in turned], axis=1)
            out[common, N0:N2 + 3] = _one_scale(n).reshape(len(common), 9)
        out[:, UV0:] = g[:, UV0:]
        return out

    def materials(self, prim: np.ndarray) -> np.ndarray:
        """(N,) int32 material rows of the triangles prim."""
        return np.take(self.material_ids, self.locate(prim)[0])

    def object_rows(self, prim: np.ndarray) -> np.ndarray | None:
        """(N,) int32 rows of SceneArrays.objects of the triangles prim; None without an object table."""
        if self._plain_objects is None:
            return None
        if self._bases is None:
            return np.take(self._plain_objects, prim)
        rows, k = self.locate(prim)
        plain = np.take(self._plain_objects, np.minimum(prim, max(self.plain_count - 1, 0))) \
            if self.plain_count else np.zeros(len(prim), np.int32)
        return np.where(k >= 0, np.take(self._instance_objects, k), plain).astype(np.int32)

    def attribute(self, name: str, prim: np.ndarray) -> np.ndarray | None:
        """(N, 3, C) per-corner values of attribute name on the triangles prim, None when no mesh has it."""
        table = self.attributes.get(name)
        if table is None:
            return None
        return np.take(table, self.locate(prim)[0], axis=0)

    def tangent_frame(self, prim: np.ndarray, b1: np.ndarray, b2: np.ndarray):
        """The unnormalized interpolated tangent (x, y, z), bitangent sign and corner normal (x, y, z) at
        barycentrics (b1, b2) of triangles prim, as Cycles interpolates them for a normal map; None
        without tangents. The normal is the one the corners give, not yet flipped for back faces."""
        if self.tangent_rows is None:
            return None
        w0 = np.float32(1.0) - b1 - b2
        rows, k = self.locate(prim)
        t = np.take(self.tangent_rows, rows, axis=0)
        if self._rows is None and k is None:
            n = self.rows_of(prim)[:, N0:N2 + 3]
        else:
            n = np.take(self.rows[:, N0:N2 + 3], rows, axis=0)
        if k is not None and (k >= 0).any():
            sel = np.flatnonzero(k >= 0)
            ks = np.take(k, sel)
            linear, normal = np.take(self._linear, ks, axis=0), np.take(self._normal, ks, axis=0)
            sign = np.take(self._det_sign, ks)
            object_n = n[sel]
            for c in range(3):
                v = apply_matrices(linear, t[sel, 4 * c:4 * c + 3])
                length = np.sqrt(np.einsum("ij,ij->i", v, v))
                t[sel, 4 * c:4 * c + 3] = np.where(length[:, None] > 0, v / np.where(length > 0, length, 1)[:, None], 0)
                t[sel, 4 * c + 3] *= sign
                m = apply_matrices(normal, n[sel, 3 * c:3 * c + 3])
                n[sel, 3 * c:3 * c + 3] = np.stack(normalize_floored_xyz(m.T), axis=1)
            common = None if self._object_space is None else np.flatnonzero(np.take(self._object_space, ks))
            if common is not None and len(common):   # as _place
                turned = np.stack([apply_matrices(normal[common], object_n[common, 3 * c:3 * c + 3])
                                   for c in range(3)], axis=1)
                n[sel[common]] = _one_scale(turned).reshape(len(common), 9)
        t, n = t.T, n.T
        tangent = tuple(w0 * t[k] + b1 * t[4 + k] + b2 * t[8 + k] for k in range(3))
        sign = w0 * t[3] + b1 * t[7] + b2 * t[11]
        normal = tuple(w0 * n[k] + b1 * n[3 + k] + b2 * n[6 + k] for k in range(3))
        return tangent, sign, normal


def _concatenate(arrays: list) -> np.ndarray:
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


def interpolate_uv(g: np.ndarray, w0, w1, w2):
    """Texture coordinates (u, v) at barycentrics (w0, w1, w2) of gathered rows g."""
    u = w0 * g[UV0] + w1 * g[UV1] + w2 * g[UV2]
    v = w0 * g[UV0 + 1] + w1 * g[UV1 + 1] + w2 * g[UV2 + 1]
    return u, v


# Tables of more triangles than this are built in slices on threads (NumPy releases the GIL).
_PARALLEL_ROWS = 1 << 18


# Scenes without instances of at least this many triangles defer their table (TriangleTable, deferred).
DEFERRED_ROWS = 2 * _PARALLEL_ROWS


def _triangle_table_of(positions: np.ndarray, normals: np.ndarray, uvs: np.ndarray,
                       mirrored: np.ndarray | None = None, object_space: np.ndarray | None = None) -> np.ndarray:
    """(T, 27) rows of triangles (SceneArrays fields; mirrored: SceneArrays.mirrored_triangles(), object_space
    SceneArrays.object_space_triangles()); big ones built in slices, in parallel."""
    t = len(positions)
    table = np.empty((t, _COLUMNS), np.float32)
    if t < 2 * _PARALLEL_ROWS:
        _fill_rows(table, corner_values(positions), corner_values(normals), uvs, mirrored, object_space)
        return table
    from concurrent.futures import ThreadPoolExecutor
    import os
    slices = [slice(i, min(i + _PARALLEL_ROWS, t)) for i in range(0, t, _PARALLEL_ROWS)]
    with ThreadPoolExecutor(max(1, os.cpu_count() or 1)) as pool:
        # positions[s], normals[s]: slices of the arrays, or the slice's corners gathered from CornerRows.
        list(pool.map(lambda s: _fill_rows(table[s], positions[s], normals[s], uvs[s],
                                           None if mirrored is None else mirrored[s],
                                           None if object_space is None else object_space[s]), slices))
    return table


def _fill_rows(table: np.ndarray, p: np.ndarray, n: np.ndarray, uvs: np.ndarray,
               mirrored: np.ndarray | None = None, object_space: np.ndarray | None = None) -> None:
    """Rows in float32, straight in the layout the renderer gathers from; whole (T, 3) and (T, 3, 3)
    blocks at a time (the same float32 operations, in the same order, as component by component).
    mirrored : (T,) bool or None, triangles whose geometric normal is turned to their object's front.
    object_space : (T,) bool or None, triangles whose normals n are object-space unit normals turned by their
    object's normal matrix (not made unit again): their corners are divided by one length, the longest."""
    t = len(p)
    p0 = table[:, P0:P0 + 3]
    p0[:] = p[:, 0]
    e1 = np.subtract(p[:, 1], p0, out=table[:, E1:E1 + 3])
    e2 = np.subtract(p[:, 2], p0, out=table[:, E2:E2 + 3])
    ng = table[:, NG:NG + 3]
    ng[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
    ng[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    ng[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ng *= _inverse_length(ng)[:, None]
    if mirrored is not None:
        np.negative(ng, out=ng, where=mirrored[:, None])
    normals = table[:, N0:N2 + 3].reshape(t, 3, 3)
    length2 = dot_rows(n, n)
    scale = np.float32(1.0) / np.sqrt(np.maximum(length2, np.float32(1e-37)))
    if object_space is not None and object_space.any():
        common = np.float32(1.0) / np.sqrt(np.maximum(length2.max(axis=1), np.float32(1e-37)))
        scale = np.where(object_space[:, None], common[:, None], scale)
    np.multiply(n, scale[:, :, None], out=normals)
    # A zero-length corner normal falls back to the face normal.
    zero_t, zero_c = np.nonzero(length2 < np.float32(1e-30))
    if len(zero_t):
        normals[zero_t, zero_c] = ng[zero_t]
    table[:, UV0:UV2 + 2] = uvs.reshape(t, 6)


def _one_scale(n: np.ndarray) -> np.ndarray:
    """(m, 3, 3) float32: each triangle's three corner normals n divided by the longest one's length."""
    length = np.sqrt(np.maximum(np.einsum("ijk,ijk->ij", n, n).max(axis=1), np.float32(1e-37)))
    return (n / length[:, None, None]).astype(np.float32)


def _inverse_length(v: np.ndarray) -> np.ndarray:
    return np.float32(1.0) / np.sqrt(np.maximum(dot_rows(v, v), np.float32(1e-37)))


