"""Geometry: the depsgraph's object instances -> world-space triangle arrays.

Every instance whose object is a mesh is exported: mesh objects with their modifiers applied, and the
evaluated meshes Blender itself hands out as instances for curves, text, surfaces, metaballs,
geometry-nodes output, collection instances and particles (the set Cycles reads too; the curve or text
object itself carries no triangles). Each evaluated mesh is read once in object space, and all its
instances are transformed together, one matmul per group.

Tangents (for tangent-space normal maps and Tangent nodes) are read only for meshes whose materials ask
for them: Blender's MikkTSpace tangents of the UV map the material names (the render UV map by default),
as Cycles computes them. Meshes without a UV map get tangents of Cycles' fallback, a spherical mapping
of the vertex positions; meshes with n-gons (which Blender's MikkTSpace refuses) tangents of each
triangle's UV gradient; both with a warning.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools

from dataclasses import dataclass

import numpy as np

from ...kernels.geometry import normal_matrices
from ...kernels.scene import (OBJECT_COLUMNS, TERMINATOR_OFFSET, CornerRows, Instances, Prototype, object_rows,
                              padded_triangles)
from ...kernels.shading.image_ops import map_to_sphere
from .materials import MaterialTable

# A mesh placed by two or more instances is stored once in object space and instanced (two-level BVH,
# kernels.scene.Instances) when its copies together would hold at least this many triangles; smaller sets
# are copied into world space, which traces a little faster (no transform per ray and per hit).
INSTANCE_MIN_TRIANGLES = 20_000

# Object types that carry geometry Ember cannot render yet.
UNSUPPORTED_TYPES = {"CURVES": "hair curves", "POINTCLOUD": "point clouds", "VOLUME": "volumes"}
RAY_VISIBILITY = ("visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission",
                  "visible_volume_scatter", "visible_shadow")


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


@dataclass(frozen=True)
class Geometry:
    """All triangles of the scene in world space, T in total.

    positions, normals : kernels.scene.CornerRows standing for (T, 3, 3) float32 arrays (positions: the
    arrays of bvh; a (T, 3, 3) array where its vertex numbers would not fit uint32); uvs : (T, 3, 2) float32;
    material_ids : (T,) int32.
    instance_count : object instances that contributed triangles.
    tangents : (T, 3, 4) float32 world-space tangents and bitangent signs (SceneArrays.tangents), zero
        for meshes whose materials read none; None when no material reads them.
    attributes : ((name, (T, 3, C) float32), ...) the attributes node programs read (SceneArrays.attributes),
        zero on meshes without them.
    objects, object_ids : the object table (SceneArrays.objects), one row per instance, and each
        triangle's row.
    """
    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    material_ids: np.ndarray
    instance_count: int
    tangents: np.ndarray | None = None
    attributes: tuple = ()
    objects: np.ndarray | None = None
    object_ids: np.ndarray | None = None
    instance_keys: list | None = None      # per object row: instance_key() (motion blur)
    instance_matrices: list | None = None  # per object row: the (4, 4) world matrix its triangles used
    instance_assets: list | None = None    # per object row: the top-most parent's name (Cryptomatte asset)
    slot_materials: list | None = None     # per object row: slot_materials() of its object
    empty_keys: frozenset = frozenset()    # instance keys of rendered mesh instances without triangles
    instances: Instances | None = None     # meshes stored once and placed by transforms (not in the arrays above)
    bvh: tuple | None = None               # (vertices, indices): the plain triangles indexed (SceneArrays.bvh_vertices)


def instance_key(inst) -> tuple:
    """What names one object instance across frames (motion blur): the object, and for instances the
    instancer and the persistent id."""
    if inst.is_instance:
        return (inst.object.name, inst.parent.name if inst.parent else "", tuple(inst.persistent_id))
    return (inst.object.name, "", ())


def _asset_name(ob) -> str:
    """Cryptomatte's asset: the object's top-most parent (Cycles' Blender sync)."""
    while ob.parent is not None:
        ob = ob.parent
    return ob.name


class MeshCache:
    """The meshes read for the last frame, reused by the next one where the depsgraph says their geometry
    did not change (Persistent Data: Blender then keeps the render depsgraph between frames, and its
    updates list only what changed since). An entry is keyed by the evaluated mesh's address and name, and
    is used only when neither the object that shows the mesh nor its instancer nor the mesh itself has a
    geometry update; an update of the geometry of anything but objects, meshes, collections and data that
    holds no mesh (a node tree, a curve) empties the cache."""

    def __init__(self):
        self._meshes: dict[tuple, LocalMesh] = {}
        self._changed: set = set()
        self._used: set = set()
        self.reads = 0      # meshes read from Blender in the last export (tests read it)

    def begin(self, depsgraph) -> None:
        self._changed, self._used, self.reads = set(), set(), 0
        for update in depsgraph.updates:
            if not update.is_updated_geometry:
                continue
            kind = update.id.id_type
            if kind in ("OBJECT", "MESH"):
                self._changed.add(update.id.name_full)
            elif kind not in ("COLLECTION", "KEY", "LIGHT", "CAMERA", "SCENE", "WORLD", "MATERIAL"):
                # A collection or a shape key is tagged with its objects or mesh (which carry their own
                # updates); lights, cameras, worlds and materials hold no mesh. Anything else (a node tree,
                # a curve...) may change meshes that show no update of their own: read them all again.
                self._meshes.clear()

    def mesh(self, inst, ob, mesh) -> LocalMesh:
        """The triangles of `mesh` (readable_mesh(ob)), read again only if they may have changed."""
        key = (ob.data.as_pointer(), ob.data.name_full)
        owners = {ob.original.name_full, ob.data.name_full}
        if inst.is_instance and inst.parent is not None:
            owners.add(inst.parent.original.name_full)
        local = self._meshes.get(key)
        if local is None or owners & self._changed:
            local = self._meshes[key] = read_mesh(mesh)
            self.reads += 1
        self._used.add(key)
        return local

    def end(self) -> None:
        """Forget the meshes this frame did not show."""
        self._meshes = {key: mesh for key, mesh in self._meshes.items() if key in self._used}


def export_geometry(depsgraph, materials: MaterialTable, warnings: list[str], poll=None,
                    moving: set | frozenset = frozenset(), instance_everything: bool = False,
                    cache: MeshCache | None = None) -> Geometry:
    """Read every rendered mesh instance; register the materials its slots use in `materials`.
    poll() is called for every instance (it raises to cancel the export). moving : instance keys
    (instance_key) of objects that move during the shutter: their meshes are never instanced.
    instance_everything : every mesh is a prototype placed by its instances, even when used once (the
    viewport: an object that moves then only changes its transform, engine/export/updates.py).
    cache : a MeshCache that keeps meshes between frames (Persistent Data), or None."""
    if cache is not None:
        cache.begin(depsgraph)
    meshes: dict[int, LocalMesh] = {}        # evaluated mesh pointer -> its triangles
    tangents: dict[int, np.ndarray] = {}     # evaluated mesh pointer -> (T*3, 4) object-space tangents
    slot_rows: dict[tuple, tuple] = {}       # (object, mesh) pointers -> material row of each slot
    groups: dict[tuple, list] = {}           # (mesh pointer, slot rows) -> world_from_object matrices
    rows: dict[tuple, list] = {}             # (mesh pointer, slot rows) -> object table rows
    attributes: dict[int, dict] = {}         # evaluated mesh pointer -> {name: (T*3, C) float32}
    keys: dict[tuple, list] = {}             # (mesh pointer, slot rows) -> instance keys
    assets: dict[tuple, list] = {}           # (mesh pointer, slot rows) -> asset names
    slots: dict[tuple, list] = {}            # (mesh pointer, slot rows) -> slot_materials() of each instance
    signatures: dict[tuple, tuple] = {}      # (object, mesh) pointers -> slot_materials()
    empty: set = set()                       # instance keys of meshes without triangles
    described: dict[int, tuple] = {}         # object pointer -> what its object rows take from it
    for inst in depsgraph.object_instances:
        if poll is not None:
            poll()
        # An instance is only valid during its iteration step: copy what is needed now.
        ob = inst.object
        if not is_rendered(inst, ob, warnings):
            continue
        mesh_key = ob.data.as_pointer()
        with readable_mesh(ob) as mesh:
            if mesh_key not in meshes:
                meshes[mesh_key] = read_mesh(mesh) if cache is None else cache.mesh(inst, ob, mesh)
            if meshes[mesh_key].triangle_count == 0:
                empty.add(instance_key(inst))
                continue
            # Instances share meshes, but slots linked to the object can give one mesh different materials.
            object_key = (ob.as_pointer(), mesh_key)
            if object_key not in slot_rows:
                slot_rows[object_key] = materials.slot_ids(ob)
                signatures[object_key] = slot_materials(ob)
                _check_visibility(ob, warnings)
            uv_maps = materials.tangent_uv_maps(slot_rows[object_key])
            if uv_maps and mesh_key not in tangents:
                tangents[mesh_key] = read_tangents(mesh, meshes[mesh_key], uv_maps, ob.name, warnings)
            names = materials.attribute_names(slot_rows[object_key])
            if names and mesh_key not in attributes:
                attributes[mesh_key] = read_attributes(mesh, names, ob.name, warnings)
        matrix = np.array(inst.matrix_world)
        groups.setdefault((mesh_key, slot_rows[object_key]), []).append(matrix)
        if object_key[0] not in described:
            described[object_key[0]] = object_inputs(ob)
        location, size, color, pass_index, own, terminator = described[object_key[0]]
        rows.setdefault((mesh_key, slot_rows[object_key]), []).append(
            (location, size, color, pass_index, instance_random(inst, own), terminator))
        keys.setdefault((mesh_key, slot_rows[object_key]), []).append(instance_key(inst))
        assets.setdefault((mesh_key, slot_rows[object_key]), []).append(_asset_name(ob))
        slots.setdefault((mesh_key, slot_rows[object_key]), []).append(signatures[object_key])
    if cache is not None:
        cache.end()
    # Groups with a moving member stay plain: motion blur moves plain triangles (kernels.accel._Moving).
    instanced = set(groups) if instance_everything else \
        {group for group, matrices in groups.items()
         if len(matrices) >= 2 and len(matrices) * meshes[group[0]].triangle_count >= INSTANCE_MIN_TRIANGLES
         and not any(key in moving for key in keys[group])}
    # Object table rows per group, all of a group's instances at once.
    rows = {group: object_rows(np.stack(groups[group]), *(np.array(column) for column in zip(*inputs)))
            for group, inputs in rows.items()}
    return dataclasses.replace(_assemble(meshes, groups, tangents, attributes, rows, instanced),
                               instance_keys=[k for group in keys.values() for k in group],
                               instance_matrices=[m for group in groups.values() for m in group],
                               instance_assets=[a for group in assets.values() for a in group],
                               slot_materials=[m for group in slots.values() for m in group],
                               empty_keys=frozenset(empty))


def slot_materials(ob) -> tuple:
    """The materials in an object's slots by name ('' for an empty slot): what picks its material rows."""
    return tuple(slot.material.name_full if slot.material is not None else "" for slot in ob.material_slots)


def object_inputs(ob) -> tuple:
    """What an object's rows of the object table take from the object and its mesh: (texture space
    location, size, colour, pass index, its own random number: Blender's sync hashes its name, its Shadow
    Terminator Geometry Offset)."""
    from ...kernels.shading.hash import hash_uint2
    h = 0
    for c in ob.name.encode("utf-8"):
        h = (h * 37 + c) & 0xFFFFFFFF
    own_random = np.float32(int(hash_uint2(np.array([h], np.uint32), np.array([0], np.uint32))[0])) \
        * np.float32(1.0 / 0xFFFFFFFF)
    mesh = ob.data
    terminator = float(getattr(ob, "shadow_terminator_geometry_offset", TERMINATOR_OFFSET))
    return (tuple(mesh.texspace_location), tuple(mesh.texspace_size), tuple(ob.color), ob.pass_index,
            float(own_random), terminator)


def instance_random(inst, own_random: float) -> float:
    """Cycles' random number of an instance: its random id, or for an object itself its own (object_inputs)."""
    if inst.is_instance:
        return float(np.float32(inst.random_id & 0xFFFFFFFF) * np.float32(1.0 / 0xFFFFFFFF))
    return own_random


def instance_row(inst, ob, matrix) -> np.ndarray:
    """The object table row of an instance (kernels.scene.object_row)."""
    location, size, color, pass_index, own, terminator = object_inputs(ob)
    return object_rows(np.asarray(matrix, np.float64)[None], [location], [size], [color], [pass_index],
                       [instance_random(inst, own)], [terminator])[0]


def read_attributes(mesh, names: tuple, object_name: str, warnings: list[str]) -> dict:
    """{name: (T*3, C) float32} per triangle corner of an evaluated mesh, for the names node programs
    read: "uv:<map>", "color:<name>" ('' for the render colour attribute), "attr:<name>". Missing ones
    are left out (they read zero, as in Cycles)."""
    out = {}
    t = len(mesh.loop_triangles)
    tri_loops = _read(mesh.loop_triangles, "loops", t * 3, np.uint32)
    for name in names:
        kind, _, key = name.partition(":")
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
        values = _attribute_values(mesh, attr)
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


# Attribute data types: (property, components).
_ATTRIBUTE_TYPES = {"FLOAT": ("value", 1), "INT": ("value", 1), "INT8": ("value", 1), "BOOLEAN": ("value", 1),
                    "FLOAT2": ("vector", 2), "FLOAT_VECTOR": ("vector", 3), "FLOAT_COLOR": ("color", 4),
                    "BYTE_COLOR": ("color", 4)}


def _attribute_values(mesh, attr) -> np.ndarray | None:
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
        corner_verts = _read(mesh.attributes[".corner_vert"].data, "value", len(mesh.loops), np.int32)
        return np.take(corner_verts, tri_loops)
    if domain == "FACE":
        return np.repeat(_read(mesh.loop_triangle_polygons, "value", t, np.int32), 3)
    return None


def is_rendered(inst, ob, warnings: list[str]) -> bool:
    """Whether Ember renders this depsgraph instance: a mesh, shown, and not hidden for render (unsupported
    kinds of geometry warn in `warnings`)."""
    if ob.type != "MESH":
        if ob.type in UNSUPPORTED_TYPES:
            warnings.append(f"Object '{ob.name}': {UNSUPPORTED_TYPES[ob.type]} are not supported, "
                            f"not rendered")
        return False
    # A render depsgraph has already dropped objects hidden for render; a viewport one has not. Particles
    # of a hidden object still render, so an instance follows its instancer.
    owner = (inst.parent if inst.is_instance else None) or ob
    return inst.show_self and not owner.hide_render


def _check_visibility(ob, warnings: list[str]) -> None:
    if not all(getattr(ob, name) for name in RAY_VISIBILITY) or ob.is_holdout or ob.is_shadow_catcher:
        warnings.append(f"Object '{ob.name}': ray visibility, holdout and shadow catcher settings are not "
                        f"supported, rendered as a plain object")
    if float(getattr(ob, "shadow_terminator_shading_offset", 0.0)) > 0:
        warnings.append(f"Object '{ob.name}': Shadow Terminator > Shading Offset is not supported yet, ignored "
                        f"(Geometry Offset is)")


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
    tri_loops = _read(mesh.loop_triangles, "loops", t * 3, np.uint32)
    corner_verts = _read(mesh.attributes[".corner_vert"].data, "value", n_corners, np.int32)
    positions = _read(mesh.attributes["position"].data, "vector", 3 * len(mesh.vertices), np.float32)
    corners = np.take(corner_verts, tri_loops)
    vertices = positions.reshape(-1, 3)
    if mesh.normals_domain == "POINT":
        # Blender's corner normals are then its vertex normals, copied: a quarter of the rows to read and move.
        normal_rows = _read(mesh.vertex_normals, "vector", 3 * len(mesh.vertices), np.float32).reshape(-1, 3)
        normal_index = corners
    elif mesh.normals_domain == "FACE":
        # A mesh of flat faces only: Cycles shades each triangle by its own normal, where Blender's corner
        # normals give a face's triangles the face's. They differ on quads and n-gons that are not planar
        # (sculpted or displaced terrain). Flat faces of a mesh with corner normals keep the face's, in
        # Cycles too.
        normal_rows = triangle_normals(vertices, corners)
        normal_index = np.repeat(np.arange(t, dtype=np.uint32), 3)
    else:
        normal_rows = _read(mesh.corner_normals, "vector", 3 * n_corners, np.float32).reshape(-1, 3)
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


def _read(collection, name: str, size: int, dtype) -> np.ndarray:
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
    uvs = _read(layer.uv, "vector", 2 * len(mesh.loops), np.float32)
    return np.take(uvs.reshape(-1, 2), tri_loops, axis=0)


def read_tangents(mesh, local: LocalMesh, uv_maps: tuple, object_name: str, warnings: list[str]) -> np.ndarray:
    """(T*3, 4) float32 object-space tangent and bitangent sign of each triangle corner of an evaluated mesh
    (read by read_mesh into `local`), from the UV map uv_maps names ('' for the render UV map)."""
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
        warnings.append(f"Object '{object_name}': tangents of n-gons are approximated per triangle "
                        f"(not MikkTSpace)")
        # The failed call leaves the layer reference stale (it reads zeros): look it up again.
        return triangle_tangents(local.positions, local.normals, local_uvs(mesh, mesh.uv_layers[name]))
    n_corners = len(mesh.loops)
    tri_loops = _read(mesh.loop_triangles, "loops", 3 * local.triangle_count, np.uint32)
    out = np.empty((len(tri_loops), 4), np.float32)
    out[:, :3] = np.take(_read(mesh.loops, "tangent", 3 * n_corners, np.float32).reshape(-1, 3), tri_loops, axis=0)
    out[:, 3] = np.take(_read(mesh.loops, "bitangent_sign", n_corners, np.float32), tri_loops)
    mesh.free_tangents()
    return out


def _uv_label(name: str) -> str:
    return f"UV map '{name}'" if name else "the render UV map"


def local_uvs(mesh, layer) -> np.ndarray:
    """(T*3, 2) float32 coordinates of one UV map at the triangle corners."""
    tri_loops = _read(mesh.loop_triangles, "loops", 3 * len(mesh.loop_triangles), np.uint32)
    return np.take(_read(layer.uv, "vector", 2 * len(mesh.loops), np.float32).reshape(-1, 2), tri_loops, axis=0)


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
    face_slots = _read(material_index.data, "value", len(mesh.polygons), np.int32)
    return np.take(face_slots, _read(mesh.loop_triangle_polygons, "value", t, np.int32))


def _assemble(meshes: dict, groups: dict, tangents: dict, attributes: dict, object_rows: dict,
              instanced: set = frozenset()) -> Geometry:
    """Transform every plain group of instances into preallocated world-space arrays; the instanced groups
    become prototypes (object space) and transforms. Object table rows follow the groups' order."""
    plain = {group: matrices for group, matrices in groups.items() if group not in instanced}
    total = sum(meshes[key].triangle_count * len(matrices) for (key, _), matrices in plain.items())
    # The plain triangles' corners are the BVH's world vertices gathered by its indices (kernels.scene.
    # CornerRows) wherever the vertex numbers fit uint32; else a (T, 3, 3) array.
    plain_vertices = sum(len(meshes[key].vertices) * len(matrices) for (key, _), matrices in plain.items())
    indexed = 0 < plain_vertices < 2**32
    positions = None if indexed else padded_triangles(total)
    # The plain triangles' normals stay where Blender keeps them, moved into world space once per
    # instance: rows, and each triangle corner's row (kernels.scene.CornerRows).
    normal_rows, normal_index, row_count = [], [], 0
    # One mesh placed once (a big scanned or sculpted mesh alone, say): its UVs are the world's as they are.
    alone = next(iter(plain)) if len(plain) == 1 and len(next(iter(plain.values()))) == 1 else None
    uvs = meshes[alone[0]].uvs.reshape(total, 3, 2) if alone is not None else np.empty((total, 3, 2), np.float32)
    material_ids = np.empty(total, np.int32)
    world_tangents = np.zeros((total, 3, 4), np.float32) if tangents else None
    widths: dict[str, int] = {}
    for per_mesh in attributes.values():
        for name, values in per_mesh.items():
            widths[name] = max(widths.get(name, 0), values.shape[1])
    attribute_arrays = {name: np.zeros((total, 3, c), np.float32) for name, c in sorted(widths.items())}
    objects = np.concatenate(list(object_rows.values())) if object_rows else np.zeros((0, OBJECT_COLUMNS), np.float32)
    object_ids = np.empty(total, np.int32)
    prototypes, prototype_ids, placements, instance_rows = [], [], [], []
    # The plain triangles once more as an indexed mesh (world vertices shared by their triangles): Embree
    # builds its BVH from it about 1.5x faster than from the corners (SceneArrays.bvh_vertices).
    bvh_vertices, bvh_indices, vertex_count = [], [], 0
    first_row = 0
    start = 0
    for group, matrices in groups.items():
        key, rows = group
        mesh = meshes[key]
        k, t = len(matrices), mesh.triangle_count
        # Blender clamps slot indices beyond the last slot to it.
        table = np.array(rows, np.int32)
        mesh_materials = table[np.clip(mesh.slots, 0, len(table) - 1)]
        if group in instanced:
            per_mesh = attributes.get(key, {})
            prototypes.append(Prototype(
                positions=mesh.positions.reshape(t, 3, 3), normals=mesh.normals.reshape(t, 3, 3),
                uvs=mesh.uvs.reshape(t, 3, 2), material_ids=mesh_materials,
                tangents=tangents[key].reshape(t, 3, 4) if key in tangents else None,
                attributes=tuple((name, np.ascontiguousarray(v.reshape(t, 3, -1))) for name, v in per_mesh.items())))
            prototype_ids.extend([len(prototypes) - 1] * k)
            placements.extend(matrices)
            instance_rows.extend(range(first_row, first_row + k))
            first_row += k
            continue
        end = start + k * t
        moved, moved_normals = _transform(mesh, np.stack(matrices), None if indexed else positions[start:end])
        normal_rows.append(moved_normals)
        normal_index.append(mesh.normal_index.reshape(t, 3))
        row_count += moved_normals.shape[0] * moved_normals.shape[1]
        v = len(mesh.vertices)
        bvh_vertices.append(moved.reshape(-1, 3))
        # Vertex numbers within uint32 are made in uint32 (the corners are non-negative int32).
        wide = np.int64 if vertex_count + k * v >= 2**32 else np.uint32
        if k == 1 and vertex_count == 0:
            bvh_indices.append(mesh.corners.reshape(t, 3).astype(wide, copy=False) if wide is np.int64
                               else mesh.corners.reshape(t, 3).view(np.uint32))
        else:
            bvh_indices.append((mesh.corners.reshape(1, t, 3).astype(wide)
                                + (vertex_count + v * np.arange(k, dtype=np.int64)).astype(wide)[:, None, None])
                               .reshape(-1, 3))
        vertex_count += k * v
        if key in tangents:
            transform_tangents(tangents[key], np.stack(matrices), world_tangents[start:end].reshape(k, t * 3, 4))
        if group != alone:
            uvs[start:end].reshape(k, t, 3, 2)[:] = mesh.uvs.reshape(t, 3, 2)
        material_ids[start:end].reshape(k, t)[:] = mesh_materials
        object_ids[start:end].reshape(k, t)[:] = np.arange(first_row, first_row + k, dtype=np.int32)[:, None]
        for name, values in attributes.get(key, {}).items():
            attribute_arrays[name][start:end].reshape(k, t, 3, -1)[..., :values.shape[1]] = values.reshape(t, 3, -1)
        first_row += k
        start = end
    instance_count = sum(len(matrices) for matrices in groups.values())
    instances = Instances(tuple(prototypes), np.array(prototype_ids, np.int32),
                          np.array(placements, np.float64).reshape(-1, 4, 4),
                          np.array(instance_rows, np.int32)) if prototypes else None
    if bvh_vertices and vertex_count < 2**32:
        # One spare vertex after the array lets Embree read the vertices in place (kernels.embree).
        vertices = np.empty(3 * vertex_count + 3, np.float32)[:3 * vertex_count].reshape(-1, 3)
        np.concatenate(bvh_vertices, out=vertices)
        bvh = (vertices, (bvh_indices[0] if len(bvh_indices) == 1 else np.concatenate(bvh_indices))
               .astype(np.uint32, copy=False))
    else:
        bvh = None
    if indexed:
        positions = CornerRows(*bvh)
    normals = _plain_normals(normal_rows, normal_index, row_count)
    return Geometry(positions, normals, uvs, material_ids, instance_count, world_tangents,
                    tuple(attribute_arrays.items()), objects, object_ids, instances=instances, bvh=bvh)


def _plain_normals(rows: list, indices: list, row_count: int):
    """The plain triangles' normals from each group's moved rows (K, N, 3) and its mesh's (T, 3) row numbers:
    a CornerRows (one rows array, each copy's numbers offset to its own rows), or the (T, 3, 3) array
    itself where the rows outnumber uint32."""
    if row_count >= 2**32:
        return np.concatenate([np.take(r, i, axis=1).reshape(-1, 3, 3) for r, i in zip(rows, indices)])
    if len(rows) == 1 and len(rows[0]) == 1:      # one mesh placed once: its arrays as they are
        i = indices[0]   # int32 corners (non-negative: seen as uint32, shared with the BVH's indices) or uint32
        return CornerRows(rows[0][0], i.view(np.uint32) if i.dtype == np.int32 else i.astype(np.uint32, copy=False))
    index, first = [], 0
    for r, i in zip(rows, indices):
        k, n = r.shape[0], r.shape[1]
        offsets = (first + n * np.arange(k, dtype=np.int64)).astype(np.uint32)
        index.append((i.astype(np.uint32)[None] + offsets[:, None, None]).reshape(-1, 3))
        first += k * n
    return CornerRows(np.concatenate([r.reshape(-1, 3) for r in rows]) if rows else np.zeros((0, 3), np.float32),
                      np.concatenate(index) if index else np.zeros((0, 3), np.uint32))


def _transform(mesh: LocalMesh, world_from_object: np.ndarray, positions_out: np.ndarray | None):
    """K instances of a mesh in world space, world_from_object (K, 4, 4) float64: the moved vertices, (K, V, 3)
    float32, and the moved normal rows, (K, N, 3) float32 (where Blender keeps the normals: a shading normal
    per row, gathered by mesh.normal_index). positions_out (K*T, 3, 3) float32, when given, gets the
    corners: the moved vertices (fewer than the corners) gathered.

    Positions keep their winding, so a mirrored instance's geometric normal flips while its shading
    normals (inverse-transpose) point the way Blender shows them; the kernel reconciles the two per side.
    """
    k = len(world_from_object)
    linear = world_from_object[:, :3, :3]
    # Transforms beyond float32 give inf coordinates: validate() drops those triangles and says so.
    with np.errstate(over="ignore", invalid="ignore"):
        moved = np.matmul(mesh.vertices[None], linear.transpose(0, 2, 1).astype(np.float32))
        moved += world_from_object[:, None, :3, 3].astype(np.float32)
        if positions_out is not None:
            _gather(moved, mesh.corners, positions_out.reshape(k, -1, 3))
    # The normals are moved where Blender keeps them (no more of them than triangle corners); each row is
    # the product the corners' gathered array held, rounded to float32 the same way.
    moved_normals = np.matmul(mesh.normal_rows[None], normal_matrices(linear).transpose(0, 2, 1)).astype(np.float32)
    return moved, moved_normals


def _gather(rows: np.ndarray, index: np.ndarray, out: np.ndarray) -> None:
    """out[i] = rows[i][index] for (K, N, C) rows and (K, M, C) out; a 2D gather per instance for a few
    instances (several times faster than one gather along axis 1), one along axis 1 for many."""
    if len(rows) > 4:
        np.take(rows, index, axis=1, out=out, mode="clip")
        return
    for i in range(len(rows)):
        np.take(rows[i], index, axis=0, out=out[i], mode="clip")


def transform_tangents(tangents: np.ndarray, world_from_object: np.ndarray, out: np.ndarray) -> None:
    """K instances of (C, 4) object-space tangents and signs into out (K, C, 4), world_from_object (K, 4, 4).

    Tangents are directions on the surface: they transform with the matrix itself, then are brought back to
    unit length. Cycles evaluates a normal map in object space with MikkTSpace's unit tangents; keeping
    them unit here keeps their weight against the (unit) normal under a scaled instance. A mirroring
    matrix flips the sign, as the cross product N x T flips with it.
    """
    linear = world_from_object[:, :3, :3]
    with np.errstate(over="ignore", invalid="ignore"):
        t = np.matmul(tangents[None, :, :3].astype(np.float64), linear.transpose(0, 2, 1))
        length = np.linalg.norm(t, axis=2, keepdims=True)
        t = np.where(length > 0, t / np.where(length > 0, length, 1.0), 0.0)
    out[:, :, :3] = t
    out[:, :, 3] = tangents[None, :, 3] * np.sign(np.linalg.det(linear))[:, None]
