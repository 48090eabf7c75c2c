"""Reading one evaluated mesh: its buffers (foreach_get) -> object-space arrays of triangle corners.

LocalMesh is what the export keeps of a mesh: vertices, the corners of its triangles, Blender's normals
where it keeps them, the render UV map and material slots. read_tangents and read_attributes read the
extras node programs ask for, per triangle corner. Which instances show a mesh is engine/export/instances.py;
placing the meshes in the world is engine/export/geometry.py.

Tangents (for tangent-space normal maps and Tangent nodes) are read only for meshes whose materials ask
for them: Blender's MikkTSpace tangents of the UV map the material names (the render UV map by default),
as Cycles computes them. Meshes without a UV map get tangents of Cycles' fallback, a spherical mapping
of the vertex positions; meshes with n-gons (which Blender's MikkTSpace refuses) tangents of each
triangle's UV gradient; both with a warning.
"""
from __future__ import annotations

import contextlib
import functools

from dataclasses import dataclass

import bpy
import numpy as np

from ...kernels.shading.image_ops import map_to_sphere
from . import mesh_topology

# Attribute name kinds the object table holds (engine/export/rgba_attributes.py), not the mesh.
OBJECT_ATTRIBUTE_KINDS = ("object", "instancer", "particle")


@dataclass(frozen=True)
class LocalMesh:
    """One evaluated mesh in object space, as the 3 corners of each of its T triangles.

    vertices : (V, 3) float32 vertex positions; corners : (T*3,) int32 the vertex of each triangle corner.
    normal_rows : (N, 3) float32, Blender's normals (flat, smooth, sharp edges, custom normals) in the domain
    it keeps them: its vertices for a mesh smooth all over (normals_domain POINT), else its face corners;
    normal_index : (T*3,) the row of each triangle corner.
    uvs : (T*3, 2) float32, the active render UV map, zeros without one.
    slots : (T,) int32, material slot of each triangle.
    """
    vertices: np.ndarray
    corners: np.ndarray
    normal_rows: np.ndarray
    normal_index: np.ndarray
    uvs: np.ndarray
    slots: np.ndarray

    @functools.cached_property
    def normals(self) -> np.ndarray:
        """(T*3, 3) float32 normals at the triangle corners."""
        return np.take(self.normal_rows, self.normal_index, axis=0)

    @functools.cached_property
    def positions(self) -> np.ndarray:
        """(T*3, 3) float32 corner positions."""
        return np.take(self.vertices, self.corners, axis=0)

    @property
    def triangle_count(self) -> int:
        return len(self.slots)


@contextlib.contextmanager
def readable_mesh(ob):
    """The evaluated mesh of `ob` to read from. An object in Edit Mode (a file saved in it opens in it, and
    F12 renders it so) has a mesh that lists only its BMesh's layers as attributes, without 'position',
    '.corner_vert' or 'material_index', and UV maps that read empty: its to_mesh() copy has them all."""
    if not ob.data.is_editmode:
        yield ob.data
        return
    try:
        yield ob.to_mesh()
    finally:
        ob.to_mesh_clear()


def read_mesh(mesh) -> LocalMesh:
    """An evaluated mesh's triangles in object space."""
    mesh.calc_loop_triangles()
    t = len(mesh.loop_triangles)
    if t == 0:  # loose vertices and edges only; such meshes may lack the corner attributes too
        empty = np.zeros((0, 3), np.float32)
        return LocalMesh(empty, np.zeros(0, np.int32), empty, np.zeros(0, np.uint32), np.zeros((0, 2), np.float32),
                         np.zeros(0, np.int32))
    n_corners = len(mesh.loops)
    # uint32 / int32 match Blender's storage: foreach_get then copies memory instead of converting.
    tri_loops = read_values(mesh.loop_triangles, "loops", t * 3, np.uint32)
    corner_verts = read_values(mesh.attributes[".corner_vert"].data, "value", n_corners, np.int32)
    positions = read_values(mesh.attributes["position"].data, "vector", 3 * len(mesh.vertices), np.float32)
    corners = np.take(corner_verts, tri_loops)
    vertices = positions.reshape(-1, 3)
    if mesh.normals_domain == "POINT":
        # Blender's corner normals are then its vertex normals, copied: a quarter of the rows to read and move.
        normal_rows = read_values(mesh.vertex_normals, "vector", 3 * len(mesh.vertices), np.float32).reshape(-1, 3)
        normal_index = corners
    elif mesh.normals_domain == "FACE":
        # A mesh of flat faces only: Cycles shades each triangle by its own normal, where Blender's corner
        # normals give a face's triangles the face's. They differ on quads and n-gons that are not planar
        # (sculpted or displaced terrain). Flat faces of a mesh with corner normals keep the face's, in
        # Cycles too.
        normal_rows = triangle_normals(vertices, corners)
        normal_index = np.repeat(np.arange(t, dtype=np.uint32), 3)
    else:
        normal_rows = read_values(mesh.corner_normals, "vector", 3 * n_corners, np.float32).reshape(-1, 3)
        normal_index = tri_loops
    return LocalMesh(vertices=vertices, corners=corners,
                     normal_rows=normal_rows, normal_index=normal_index,
                     uvs=_corner_uvs(mesh, tri_loops),
                     slots=_triangle_slots(mesh, t))


def triangle_normals(vertices: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(T, 3) float32 unit normals of triangles (corners (T*3,) or (T, 3) vertex indices) by their winding,
    in the space of `vertices` (V, 3); zero for a triangle without area."""
    p = np.take(vertices, corners.reshape(-1, 3), axis=0)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.sqrt(np.einsum("ti,ti->t", n, n))
    return (n / np.where(length > 0, length, 1.0)[:, None]).astype(np.float32)


def read_values(collection, name: str, size: int, dtype) -> np.ndarray:
    out = np.empty(size, dtype)
    collection.foreach_get(name, out)
    return out


def _corner_uvs(mesh, tri_loops: np.ndarray) -> np.ndarray:
    """(T*3, 2) float32 coordinates of the UV map marked for rendering."""
    layer = next((uv for uv in mesh.uv_layers if uv.active_render), None)
    if layer is None:
        # No UV map: every corner's coordinates are (0, 0). One row seen T*3 times (a read-only view with a
        # zero stride), so a big mesh without UVs neither writes nor reads 24 bytes per triangle of zeros.
        return np.broadcast_to(np.zeros((1, 2), np.float32), (len(tri_loops), 2))
    uvs = read_values(layer.uv, "vector", 2 * len(mesh.loops), np.float32)
    return np.take(uvs.reshape(-1, 2), tri_loops, axis=0)


def read_tangents(mesh, local: LocalMesh, uv_maps: tuple, object_name: str, warnings: list[str],
                  scratch=None) -> np.ndarray:
    """(T*3, 4) float32 object-space tangent and bitangent sign of each triangle corner of an evaluated mesh
    (read by read_mesh into `local`), from the UV map uv_maps names ('' for the render UV map). scratch: the
    evaluated object whose to_mesh() copy may take a mesh with n-gons (ngon_tangents), or None."""
    wanted = uv_maps[0]
    if len(uv_maps) > 1:
        warnings.append(f"Object '{object_name}': its materials read tangents of several UV maps, Ember uses "
                        f"those of {_uv_label(wanted)}")
    layer = mesh.uv_layers.get(wanted) if wanted else next((uv for uv in mesh.uv_layers if uv.active_render), None)
    if layer is None and wanted:
        # Cycles leaves the normal unperturbed without the tangent attribute: zero tangents do the same.
        warnings.append(f"Object '{object_name}': no UV map '{wanted}' for its normal map or tangent, "
                        f"left unperturbed")
        return np.zeros((3 * local.triangle_count, 4), np.float32)
    if layer is None:
        warnings.append(f"Object '{object_name}': no UV map for its normal map or tangent: tangents of a "
                        f"spherical mapping, as Cycles (per triangle, not MikkTSpace)")
        return triangle_tangents(local.positions, local.normals, sphere_uvs(local.positions))
    name = layer.name
    try:
        mesh.calc_tangents(uvmap=name)
    except RuntimeError:  # Blender's MikkTSpace takes triangles and quads only
        out = ngon_tangents(scratch, mesh, local, name) if scratch is not None else None
        if out is not None:
            return out
        warnings.append(f"Object '{object_name}': tangents of n-gons are approximated per triangle "
                        f"(not MikkTSpace)")
        # The failed call leaves the layer reference stale (it reads zeros): look it up again.
        return triangle_tangents(local.positions, local.normals, local_uvs(mesh, mesh.uv_layers[name]))
    n_corners = len(mesh.loops)
    tri_loops = read_values(mesh.loop_triangles, "loops", 3 * local.triangle_count, np.uint32)
    out = np.empty((len(tri_loops), 4), np.float32)
    tangents = read_values(mesh.loops, "tangent", 3 * n_corners, np.float32).reshape(-1, 3)
    out[:, :3] = np.take(tangents, tri_loops, axis=0)
    out[:, 3] = np.take(read_values(mesh.loops, "bitangent_sign", n_corners, np.float32), tri_loops)
    mesh.free_tangents()
    return out


def ngon_tangents(scratch, mesh, local: LocalMesh, name: str) -> np.ndarray | None:
    """MikkTSpace tangents of a mesh with n-gons, which Blender's calc_tangents refuses and Cycles computes on its
    triangles (scene/mesh.cpp): the to_mesh() copy of the evaluated object `scratch` (not part of the file) has its
    n-gons split into triangles (bmesh), MikkTSpace runs on it, and each triangle corner of `mesh` takes the tangent
    of its vertex in the triangles its polygon became (a planar n-gon's triangles share one tangent space). None
    where that fails (the caller approximates)."""
    import bmesh
    temp = scratch.to_mesh()
    try:
        faces = len(temp.polygons)
        if faces != len(mesh.polygons) or len(temp.vertices) != len(mesh.vertices):
            return None
        origin = temp.attributes.new("ember_polygon", "INT", "FACE")
        origin.data.foreach_set("value", np.arange(faces, dtype=np.int32))
        bm = bmesh.new()
        try:
            bm.from_mesh(temp)
            bmesh.ops.triangulate(bm, faces=[f for f in bm.faces if len(f.verts) > 4], ngon_method="EAR_CLIP")
            bm.to_mesh(temp)
        finally:
            bm.free()
        temp.calc_tangents(uvmap=name)
        corners = len(temp.loops)
        polygon = read_values(temp.attributes["ember_polygon"].data, "value", len(temp.polygons), np.int32)
        totals = read_values(temp.polygons, "loop_total", len(temp.polygons), np.int32)
        key = read_values(temp.loops, "vertex_index", corners, np.int64) * faces + np.repeat(polygon, totals)
        tangents = read_values(temp.loops, "tangent", 3 * corners, np.float32).reshape(-1, 3)
        signs = read_values(temp.loops, "bitangent_sign", corners, np.float32)
        tri_loops = read_values(mesh.loop_triangles, "loops", 3 * local.triangle_count, np.int64)
        tri_faces = read_values(mesh.loop_triangles, "polygon_index", local.triangle_count, np.int64)
        wanted = read_values(mesh.loops, "vertex_index", len(mesh.loops), np.int64)[tri_loops] * faces + \
            np.repeat(tri_faces, 3)
        keys, first = np.unique(key, return_index=True)
        at = np.minimum(np.searchsorted(keys, wanted), len(keys) - 1)
        if not np.array_equal(keys[at], wanted):
            return None
        out = np.empty((len(wanted), 4), np.float32)
        out[:, :3] = tangents[first[at]]
        out[:, 3] = signs[first[at]]
        return out
    except (RuntimeError, KeyError, ValueError):
        return None
    finally:
        scratch.to_mesh_clear()


def _uv_label(name: str) -> str:
    return f"UV map '{name}'" if name else "the render UV map"


def local_uvs(mesh, layer) -> np.ndarray:
    """(T*3, 2) float32 coordinates of one UV map at the triangle corners."""
    tri_loops = read_values(mesh.loop_triangles, "loops", 3 * len(mesh.loop_triangles), np.uint32)
    return np.take(read_values(layer.uv, "vector", 2 * len(mesh.loops), np.float32).reshape(-1, 2), tri_loops, axis=0)


def sphere_uvs(points: np.ndarray) -> np.ndarray:
    """(N, 2) float32: Cycles' map_to_sphere of (N, 3) object-space points, its UVs for meshes without."""
    return map_to_sphere(points)[:, :2]


def triangle_tangents(positions: np.ndarray, normals: np.ndarray, uvs: np.ndarray) -> np.ndarray:
    """(T*3, 4) float32 tangents from each triangle's UV gradient (corners (T*3, 3) positions and normals,
    (T*3, 2) UVs): dP/du made orthogonal to each corner normal, sign from dP/dv's side, as MikkTSpace
    before it averages over shared vertices. Zero where the UVs are degenerate."""
    p = positions.reshape(-1, 3, 3).astype(np.float64)
    uv = uvs.reshape(-1, 3, 2).astype(np.float64)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > 1e-20
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    dpdu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv
    dpdv = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv
    n = normals.reshape(-1, 3, 3).astype(np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-30)
    t = dpdu[:, None, :] - n * np.einsum("tcj,tj->tc", n, dpdu)[:, :, None]
    length = np.linalg.norm(t, axis=2, keepdims=True)
    t = np.where(length > 1e-30, t / np.maximum(length, 1e-30), 0.0)
    sign = np.where(np.einsum("tcj,tj->tc", np.cross(n, t), dpdv) < 0, -1.0, 1.0)
    return np.concatenate([t, sign[:, :, None]], axis=2).reshape(-1, 4).astype(np.float32)


def _triangle_slots(mesh, t: int) -> np.ndarray:
    """(T,) int32 material slot per triangle; Blender omits the attribute when every face uses slot 0."""
    material_index = mesh.attributes.get("material_index")
    if material_index is None:
        return np.zeros(t, np.int32)
    face_slots = read_values(material_index.data, "value", len(mesh.polygons), np.int32)
    return np.take(face_slots, read_values(mesh.loop_triangle_polygons, "value", t, np.int32))


def read_attributes(mesh, names: tuple, object_name: str, warnings: list[str]) -> dict:
    """{name: (T*3, C) float32} per triangle corner of an evaluated mesh, for the names node programs
    read: "uv:<map>", "color:<name>" ('' for the render colour attribute), "attr:<name>", the Geometry
    node's "geom:pointiness" and "geom:random_per_island" (mesh_topology.py), "geom:undisplaced_position"
    and "geom:undisplaced_normal" (this mesh, before true displacement moves it: _undisplaced_attribute) and
    "geom:undeformed_position" (before its deforming modifiers, where that differs: _undeformed_attribute).
    Missing ones are left out (they read zero, as in Cycles); object attributes ("object:", "instancer:") are
    the object table's."""
    out = {}
    t = len(mesh.loop_triangles)
    tri_loops = read_values(mesh.loop_triangles, "loops", t * 3, np.uint32)
    for name in names:
        kind, _, key = name.partition(":")
        if kind in OBJECT_ATTRIBUTE_KINDS:
            continue
        if kind == "geom":
            if key == "undeformed_position":
                undeformed = _undeformed_attribute(mesh, tri_loops)
                if undeformed is not None:
                    out[name] = undeformed
                continue
            out[name] = (_undisplaced_attribute if key.startswith("undisplaced_") else _topology_attribute)(
                mesh, key, tri_loops)
            continue
        if kind == "uv":
            layer = mesh.uv_layers.get(key)
            if layer is not None:
                out[name] = local_uvs(mesh, layer)
            continue
        if kind == "color":
            colors = mesh.color_attributes
            attr = colors.get(key) if key else (colors[colors.render_color_index]
                                                if 0 <= colors.render_color_index < len(colors) else None)
        else:
            attr = mesh.attributes.get(key)
        if attr is None:
            continue
        values = attribute_values(mesh, attr)
        if values is None:
            warnings.append(f"Object '{object_name}': attribute '{key}' ({attr.data_type}, {attr.domain}) is "
                            f"not supported, reads zero")
            continue
        corners = _domain_corners(mesh, attr.domain, tri_loops, t)
        if corners is None:
            warnings.append(f"Object '{object_name}': attribute '{key}' on the {attr.domain.lower()} domain "
                            f"is not supported, reads zero")
            continue
        out[name] = np.take(values, corners, axis=0)
    return out


def _undisplaced_attribute(mesh, key: str, tri_loops: np.ndarray) -> np.ndarray:
    """(T*3, C) float32 per corner, object space: the evaluated mesh's positions and a 1 ("undisplaced_position"), or
    the normals Cycles keeps for the bump of Displacement and Bump ("undisplaced_normal",
    ATTR_STD_NORMAL_UNDISPLACED, scene/mesh.cpp Mesh::add_undisplaced): from Blender 5.2 the shading normals
    the mesh has before displacement (corner normals, else vertex normals; flat faces their own normal,
    kernel/geom/primitive.h primitive_normal_set_undisplaced); before, the vertex normals on every face."""
    if key == "undisplaced_normal" and bpy.app.version >= (5, 2, 0):
        local = read_mesh(mesh)
        return np.take(local.normal_rows, local.normal_index, axis=0).astype(np.float32)
    corner_verts = read_values(mesh.attributes[".corner_vert"].data, "value", len(mesh.loops), np.int32)
    corners = np.take(corner_verts, tri_loops)
    v = len(mesh.vertices)
    if key == "undisplaced_normal":
        return np.take(read_values(mesh.vertex_normals, "vector", 3 * v, np.float32).reshape(-1, 3), corners, axis=0)
    positions = read_values(mesh.attributes["position"].data, "vector", 3 * v, np.float32).reshape(-1, 3)
    return np.concatenate([np.take(positions, corners, axis=0), np.ones((len(corners), 1), np.float32)], axis=1)


def _undeformed_attribute(mesh, tri_loops: np.ndarray) -> np.ndarray | None:
    """(T*3, 4) float32 per corner, object space: the positions before the object's deforming modifiers and a 1, as
    Cycles' Generated reads them (blender/mesh.cpp: the ORCO layer, which a render's depsgraph always computes,
    through the texture space; MeshVertex.undeformed_co gives the same); None where they are the positions (no
    deformation, or a viewport's mesh without the layer)."""
    v = len(mesh.vertices)
    undeformed = np.empty(3 * v, np.float32)
    mesh.vertices.foreach_get("undeformed_co", undeformed)
    positions = read_values(mesh.attributes["position"].data, "vector", 3 * v, np.float32)
    if np.array_equal(undeformed, positions):
        return None
    corner_verts = read_values(mesh.attributes[".corner_vert"].data, "value", len(mesh.loops), np.int32)
    corners = np.take(corner_verts, tri_loops)
    return np.concatenate([np.take(undeformed.reshape(-1, 3), corners, axis=0), np.ones((len(corners), 1), np.float32)],
                          axis=1)


def _topology_attribute(mesh, key: str, tri_loops: np.ndarray) -> np.ndarray:
    """(T*3, 1) float32 Pointiness (per vertex, at each corner) or Random Per Island (per triangle)."""
    corner_verts = read_values(mesh.attributes[".corner_vert"].data, "value", len(mesh.loops), np.int32)
    edges = read_values(mesh.edges, "vertices", 2 * len(mesh.edges), np.int32)
    v = len(mesh.vertices)
    if key == "pointiness":
        positions = read_values(mesh.attributes["position"].data, "vector", 3 * v, np.float32).reshape(-1, 3)
        normals = read_values(mesh.vertex_normals, "vector", 3 * v, np.float32).reshape(-1, 3)
        per_vertex = mesh_topology.pointiness(positions, normals, edges)
        return np.take(per_vertex, np.take(corner_verts, tri_loops))[:, None]
    per_triangle = mesh_topology.random_per_island(v, edges, np.take(corner_verts, tri_loops[0::3]))
    return np.repeat(per_triangle, 3)[:, None]


# Attribute data types: (property, components).
_ATTRIBUTE_TYPES = {"FLOAT": ("value", 1), "INT": ("value", 1), "INT8": ("value", 1), "BOOLEAN": ("value", 1),
                    "FLOAT2": ("vector", 2), "FLOAT_VECTOR": ("vector", 3), "FLOAT_COLOR": ("color", 4),
                    "BYTE_COLOR": ("color", 4)}


def attribute_values(mesh, attr) -> np.ndarray | None:
    """(n, C) float32 values of a generic attribute of any geometry (mesh, curves, points), None for a data type
    Ember does not read; colours come linear (Blender's `color`)."""
    kind = _ATTRIBUTE_TYPES.get(attr.data_type)
    if kind is None:
        return None
    prop, c = kind
    n = len(attr.data)
    raw = np.empty(n * c, np.int32 if attr.data_type in ("INT", "INT8") else
                   bool if attr.data_type == "BOOLEAN" else np.float32)
    attr.data.foreach_get(prop, raw)
    return np.nan_to_num(raw.astype(np.float32).reshape(n, c))


def _domain_corners(mesh, domain: str, tri_loops: np.ndarray, t: int) -> np.ndarray | None:
    """For each triangle corner, its element of the attribute's domain."""
    if domain == "CORNER":
        return tri_loops
    if domain == "POINT":
        corner_verts = read_values(mesh.attributes[".corner_vert"].data, "value", len(mesh.loops), np.int32)
        return np.take(corner_verts, tri_loops)
    if domain == "FACE":
        return np.repeat(read_values(mesh.loop_triangle_polygons, "value", t, np.int32), 3)
    return None
