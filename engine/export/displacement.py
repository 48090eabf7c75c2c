"""True displacement ("Displacement Only" and "Displacement and Bump"): the material's Displacement output
compiled into a node program of its own, evaluated at the mesh's vertices, and the vertices moved before
the BVH is built, as Cycles' GeometryManager::displace does (scene/mesh_displace.cpp).

- Each vertex is shaded once, as at the corner of the first triangle (of a displaced material) that uses
  it: its world position, Blender's vertex normal (Cycles forces smooth shading here), that corner's UVs
  and attributes, the object's data; the world-space offset goes back to object space. A mesh shown by
  several objects is displaced once, with the first object's transform (Cycles: the first object using it).
- Normals: with "Displacement Only" the vertex normals are recomputed as the normalized sum of the unit
  normals of the displaced triangles around each vertex; meshes with corner normals (sharp edges, custom
  normals) get the change of that vertex normal added to each smooth corner's normal, flat triangles their
  new face normal (Cycles 5.2+). "Displacement and Bump" keeps the undisplaced vertex normals (the bump then
  perturbs them). Flat-shaded meshes shade by their displaced faces either way.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...kernels.programs import Program, Ref
from ...kernels.shading.displace import VertexInputs, displacement_offsets
from ...kernels.shading.ops import OPS
from ...kernels.textures import Texture
from .mesh import LocalMesh, read_attributes, read_tangents, triangle_normals
from .subdivision.refine import scatter_sum

# Blender's Material.displacement_method -> (moves vertices, keeps the undisplaced normals, bumps).
METHODS = {"BUMP": (False, False, True), "DISPLACEMENT": (True, False, False), "BOTH": (True, True, True)}


@dataclass(frozen=True)
class TrueDisplacement:
    """A material's Displacement output as the vertices read it.

    program : its node program; value : a Ref into it (a VECTOR), or a constant (x, y, z).
    keeps_normals : "Displacement and Bump" (the vertex normals are not recomputed).
    attributes : the mesh attributes the program reads; tangent_uv_maps : the UV maps whose tangents it reads.
    """
    program: Program
    value: object
    keeps_normals: bool
    attributes: frozenset = frozenset()
    tangent_uv_maps: tuple = ()

    @property
    def signature(self) -> str:
        """What a viewport edit compares (MaterialTable.mesh_needs): a change needs the meshes read again."""
        return repr((self.program.ops, self.value, self.keeps_normals))


class BlenderMesh:
    """What displacement reads of an evaluated Blender mesh besides its LocalMesh (adaptive.AdaptiveMesh reads
    the same of a diced one): vertex normals, attributes, tangents, flat faces. vertex_rows : None (the
    LocalMesh's normal rows say where Blender keeps its normals)."""
    vertex_rows = None

    def __init__(self, mesh, scratch=None):
        """scratch : the evaluated object whose to_mesh() copy read_tangents may use (None: it may not)."""
        self.mesh, self.scratch = mesh, scratch

    def vertex_normals(self) -> np.ndarray:
        return _read_vertex_normals(self.mesh)

    def attributes(self, names: tuple, object_name: str, warnings: list[str]) -> dict:
        return read_attributes(self.mesh, names, object_name, warnings)

    def tangents(self, local: LocalMesh, uv_maps: tuple, object_name: str, warnings: list[str]) -> np.ndarray:
        return read_tangents(self.mesh, local, uv_maps, object_name, warnings, self.scratch)

    def flat_triangles(self, t: int) -> np.ndarray:
        return _flat_triangles(self.mesh, t)


def displace_mesh(source, local: LocalMesh, per_slot: tuple, object_row: np.ndarray, world_from_object: np.ndarray,
                  textures: list[Texture], object_name: str, warnings: list[str]) -> LocalMesh:
    """`local` (read from `source`, a BlenderMesh or an adaptive.AdaptiveMesh) with its vertices moved by the
    materials of its slots (per_slot: a TrueDisplacement or None per slot row) and its normals recomputed as
    Cycles does."""
    slots = np.clip(local.slots, 0, len(per_slot) - 1)
    moved = np.array([d is not None for d in per_slot])[slots]          # (T,) triangles displaced
    if not moved.any():
        return local
    corner_ids = np.flatnonzero(np.repeat(moved, 3))
    vertex_ids, first = np.unique(local.corners[corner_ids], return_index=True)
    corner = corner_ids[first]                                           # (V',) the corner shading each vertex
    m = np.asarray(world_from_object, np.float64)
    normals_obj = source.vertex_normals()[vertex_ids]
    inverse_t = np.linalg.pinv(m[:3, :3]).T
    n_world = normals_obj.astype(np.float64) @ inverse_t.T
    n_world /= np.maximum(np.linalg.norm(n_world, axis=1, keepdims=True), 1e-30)
    p_world = local.vertices[vertex_ids].astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    b1 = (corner % 3 == 1).astype(np.float32)
    b2 = (corner % 3 == 2).astype(np.float32)
    offsets = np.zeros((len(vertex_ids), 3), np.float32)
    for row, displacement in enumerate(per_slot):
        which = np.flatnonzero(slots[corner // 3] == row) if displacement is not None else ()
        if not len(which):
            continue
        if not isinstance(displacement.value, Ref):
            offsets[which] = np.nan_to_num(np.asarray(displacement.value, np.float32))
            continue
        c = corner[which]
        attributes = {}
        if displacement.attributes:
            rows = source.attributes(tuple(sorted(displacement.attributes)), object_name, warnings)
            attributes = {name: values[c] for name, values in rows.items()}
        tangents = None
        if displacement.tangent_uv_maps:
            tangents = source.tangents(local, displacement.tangent_uv_maps, object_name, warnings)[c]
        inputs = VertexInputs(p_world[which].astype(np.float32), n_world[which].astype(np.float32),
                              np.asarray(local.uvs[c], np.float32), attributes, b1[which], b2[which],
                              object_row, textures, tangents)
        try:
            offsets[which] = displacement_offsets(displacement.program, displacement.value, inputs, OPS)
        except (AttributeError, TypeError, KeyError, IndexError):
            # An op reading what a vertex does not have (a ray, the camera): Cycles' bake state reads defaults.
            warnings.append(f"Object '{object_name}': a node of its displacement cannot be evaluated at vertices, "
                            f"not displaced")
    linear_inverse = np.linalg.pinv(m[:3, :3])
    vertices = local.vertices.copy()
    vertices[vertex_ids] += (offsets.astype(np.float64) @ linear_inverse.T).astype(np.float32)
    keeps = all(d is None or d.keeps_normals for d in per_slot)
    return replace(local, vertices=vertices, **_normals(local, vertices, moved, keeps, source))


def _read_vertex_normals(mesh) -> np.ndarray:
    out = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertex_normals.foreach_get("vector", out)
    return out.reshape(-1, 3)


def vertex_normal_sums(vertices: np.ndarray, corners: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 3) float64: per vertex, the sum of the unit normals of `triangles` (indices) around it (Cycles'
    compute_vertex_normals; a triangle without area counts as (1, 0, 0))."""
    tri = corners.reshape(-1, 3)[triangles]
    face = triangle_normals(vertices, tri).astype(np.float64)
    face[~np.any(face != 0, axis=1)] = (1.0, 0.0, 0.0)
    # Corner 0 of every triangle, then corner 1, then corner 2: each vertex sums in the order three np.add.at
    # passes would (bincount adds in index order), several times faster.
    return scatter_sum(tri.T.reshape(-1), np.tile(face, (3, 1)), len(vertices))


def _unit(v: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(length > 0, v / np.where(length > 0, length, 1.0), 0.0)


def _normals(local: LocalMesh, vertices: np.ndarray, moved: np.ndarray, keeps: bool, source) -> dict:
    """The LocalMesh normal fields after displacement (mesh_displace.cpp's recompute)."""
    t = local.triangle_count
    if len(local.normal_rows) == t and np.array_equal(local.normal_index, np.repeat(np.arange(t), 3)):
        return {"normal_rows": triangle_normals(vertices, local.corners)}   # flat faces: their displaced normals
    if source.vertex_rows is not None:
        return {"normal_rows": _vertex_row_normals(local, vertices, moved, keeps, source.vertex_rows)}
    corner_domain = not np.array_equal(local.normal_index, local.corners)
    if keeps and not corner_domain:
        return {}
    touched = np.flatnonzero(moved)
    post = _unit(vertex_normal_sums(vertices, local.corners, touched))
    if not corner_domain:
        rows = local.normal_rows.copy()
        used = _used_vertices(local.corners, touched, len(rows))
        rows[used] = post[used]
        return {"normal_rows": rows.astype(np.float32)}
    # Corner normals: every smooth corner moves by its vertex normal's change, flat triangles take their face's.
    pre = _unit(vertex_normal_sums(local.vertices, local.corners, np.arange(t)))
    normals = local.normals.astype(np.float64).copy()
    corner_ids = (touched[:, None] * 3 + np.arange(3)).ravel()
    v = local.corners[corner_ids]
    normals[corner_ids] = _unit(normals[corner_ids] + post[v] - pre[v])
    flat = source.flat_triangles(t) & moved
    if flat.any():
        faces = triangle_normals(vertices, local.corners)[flat]
        normals.reshape(-1, 3, 3)[flat] = faces[:, None, :]
    return {"normal_rows": normals.astype(np.float32), "normal_index": np.arange(3 * t, dtype=np.uint32)}


def _used_vertices(corners: np.ndarray, triangles: np.ndarray, n: int) -> np.ndarray:
    """The vertices (< n) of `triangles`, ascending, each once (np.unique's result, without its sort)."""
    used = np.zeros(n, bool)
    used[corners.reshape(-1, 3)[triangles]] = True
    return np.flatnonzero(used)


def _vertex_row_normals(local: LocalMesh, vertices: np.ndarray, moved: np.ndarray, keeps: bool,
                        vertex_rows: int) -> np.ndarray:
    """Normal rows of a diced mesh after displacement: its first vertex_rows rows are its vertex normals
    (recomputed from the displaced triangles, unless kept), the rest each flat triangle's own normal."""
    rows = local.normal_rows.copy()
    touched = np.flatnonzero(moved)
    if not keeps:
        post = _unit(vertex_normal_sums(vertices, local.corners, touched))
        used = _used_vertices(local.corners, touched, len(rows))
        rows[used] = post[used]
    first = local.normal_index.reshape(-1, 3)[:, 0].astype(np.int64)
    flat = np.flatnonzero((first >= vertex_rows) & moved)
    rows[first[flat]] = triangle_normals(vertices, local.corners)[flat]
    return rows.astype(np.float32)


def _flat_triangles(mesh, t: int) -> np.ndarray:
    """(T,) bool: triangles of faces shaded flat (Blender's sharp_face attribute)."""
    sharp = mesh.attributes.get("sharp_face")
    if sharp is None:
        return np.zeros(t, bool)
    faces = np.empty(len(mesh.polygons), bool)
    sharp.data.foreach_get("value", faces)
    tri_faces = np.empty(t, np.int32)
    mesh.loop_triangle_polygons.foreach_get("value", tri_faces)
    return faces[tri_faces]
