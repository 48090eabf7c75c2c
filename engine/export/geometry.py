"""Geometry: the depsgraph's object instances -> world-space triangle arrays.

Every instance whose object is a mesh is exported: mesh objects with their modifiers applied, and the
evaluated meshes Blender itself hands out as instances for curves, text, surfaces, metaballs,
geometry-nodes output, collection instances and particles (the set Cycles reads too; the curve or text
object itself carries no triangles). Each evaluated mesh is read once in object space, and all its
instances are transformed together, one matmul per group.

This module owns the Geometry record, export_geometry (the walk over the instances), the MeshCache that
keeps meshes between frames, and the assembly of the plain triangles into world space; reading a mesh is
engine/export/mesh.py, deciding and naming instances engine/export/instances.py.
"""
from __future__ import annotations

import dataclasses
from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np

from ...kernels.geometry import normal_matrices
from ...kernels.scene import NO_GROUP, OBJECT_COLUMNS, CornerRows, Instances, Prototype, object_rows, padded_triangles
from ...kernels.shading.input_ops import PARTICLE_OUTPUTS, particle_attribute_name
from ...kernels.textures import Texture
from .adaptive import Dicing
from .displacement import BlenderMesh, displace_mesh
from .instances import (RENDERED_TYPES, asset_name, instance_key, instance_random, instance_visibility, instanced_groups,
                        is_rendered, object_inputs, slot_materials)
from .light_groups import GroupTable
from .light_linking import ALL_MASK, LinkTable

# The light_linking row of an object linked nowhere: no receiver or blocker set, in every light and shadow set.
UNLINKED_ROW = (0, 0, ALL_MASK, ALL_MASK)
from .materials import MaterialTable
from .mesh import OBJECT_ATTRIBUTE_KINDS, LocalMesh, read_mesh, readable_mesh
from .shapes import ShapeExport
from .rgba_attributes import InstanceAttributes, instancer_attribute, object_attribute, particle_values
from .volumes import is_volume, read_volume


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
    instance_visibility: list | None = None  # per object row: instance_visibility() (SceneArrays.object_visibility)
    instance_links: list | None = None     # per object row: (receiver set, blocker set, light and shadow masks)
    instance_groups: list | None = None    # per object row: its light group (light_groups.GroupTable.of)
    slot_materials: list | None = None     # per object row: slot_materials() of its object
    empty_keys: frozenset = frozenset()    # instance keys of rendered mesh instances without triangles
    instances: Instances | None = None     # meshes stored once and placed by transforms (not in the arrays above)
    bvh: tuple | None = None               # (vertices, indices): the plain triangles indexed (SceneArrays.bvh_vertices)
    volumes: tuple = ()                    # ((object row, {name: VoxelGrid}, density scale, step), ...) (SceneArrays.volumes)
    object_attributes: tuple = ()          # ((name, (K, 4) float32), ...) per object row (SceneArrays.object_attributes)
    curves: tuple = ()                     # world-space kernels.scene.Curves (SceneArrays.curves), rows after the meshes'
    points: object = None                  # world-space kernels.scene.Points or None (SceneArrays.points)
    shape_instances: object = None         # kernels.scene.ShapeInstances or None (SceneArrays.shape_instances)


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
                    cache: MeshCache | None = None, links: LinkTable | None = None,
                    light_groups: GroupTable | None = None, dicing: Dicing | None = None, motion=None,
                    surfaces: bool = True, culling=None) -> Geometry:
    """Read every rendered mesh instance; register the materials its slots use in `materials`.
    poll() is called for every instance (it raises to cancel the export). moving : instance keys
    (instance_key) of objects that move during the shutter: their meshes are never instanced. motion : the
    motion.MotionSamples they come from, or None (curves and points read their keys over the shutter there).
    instance_everything : every mesh is a prototype placed by its instances, even when used once (the
    viewport: an object that moves then only changes its transform, engine/export/updates.py).
    cache : a MeshCache that keeps meshes between frames (Persistent Data), or None.
    links : the scene's light_linking.LinkTable (None: nothing links); light_groups : the view layer's
    light_groups.GroupTable (None: no light groups).
    dicing : adaptive.Dicing for objects with adaptive subdivision (None: they are read as Blender evaluates
    them). surfaces : False where View Layer > Filter > Surfaces is off: no mesh gives geometry, mesh volumes
    included (Cycles' use_surfaces); Volume objects, hair, curves and points stay. culling : the render's
    culling.Culling (Simplify > Culling), or None: the instances it culls are left out."""
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
    volume_sources: dict = {}                # Volume or smoke domain data pointer -> its volumes.VolumeSource
    grids: dict[tuple, list] = {}            # (mesh pointer, slot rows) -> (grids, density scale) or None
    properties: dict[tuple, list] = {}       # (mesh pointer, slot rows) -> {object attribute name: RGBA} per instance
    object_values = ObjectValues(depsgraph.scene_eval)
    displaced: set = set()                   # evaluated mesh pointers whose true displacement is done
    diced: dict[int, object] = {}            # evaluated mesh pointer -> its adaptive.AdaptiveMesh
    visibility: dict[tuple, list] = {}       # (mesh pointer, slot rows) -> instance_visibility() per instance
    linked: dict[tuple, list] = {}           # (mesh pointer, slot rows) -> LinkTable.row() per instance
    linking = links is not None and links.used
    grouped: dict[tuple, list] = {}          # (mesh pointer, slot rows) -> GroupTable.of() per instance
    shown: dict[int, str] = {}               # mesh pointer -> the name of the first object showing it
    grouping = light_groups is not None and light_groups.used
    view_layer = depsgraph.view_layer_eval
    shapes = ShapeExport(depsgraph, warnings, moving, motion)   # curves and points (shapes.py)
    for inst in depsgraph.object_instances:
        if poll is not None:
            poll()
        # An instance is only valid during its iteration step: copy what is needed now.
        ob = inst.object
        if culling is not None and ob.type in RENDERED_TYPES and culling.culled(ob, np.array(inst.matrix_world)):
            empty.add(instance_key(inst))
            continue
        if ob.type == "MESH" and inst.show_particles and shapes.has_hair(ob):
            _add_shape(shapes, inst, ob, materials, view_layer, described, signatures, object_values, warnings,
                       hair=True)
        if not is_rendered(inst, ob, warnings):
            continue
        if ob.type in ("POINTCLOUD", "CURVES"):
            _add_shape(shapes, inst, ob, materials, view_layer, described, signatures, object_values, warnings)
            continue
        if not surfaces and ob.type != "VOLUME":
            empty.add(instance_key(inst))
            continue
        seen_by = instance_visibility(inst, ob, view_layer)
        if not seen_by:   # no ray sees it: not rendered (as Cycles' sync)
            continue
        # An object Ember dices itself (adaptive subdivision) is keyed by the object: reading its ob.data would have
        # Blender subdivide it at the modifier's render levels first (rna_Object_data_get ensures the subdivision;
        # at 11 levels, 4M faces a quad), as Cycles' sync never asks it to.
        dices = dicing is not None and ob.type == "MESH" and dicing.dices(ob)
        mesh_key = ob.as_pointer() if dices else ob.data.as_pointer()
        object_key = (ob.as_pointer(), mesh_key)
        if ob.type == "VOLUME" or (ob.type == "MESH" and is_volume(ob)):
            if not depsgraph.view_layer.use_volumes:   # View Layer > Filter > Volumes off: none, as in Cycles
                continue
            # A Volume object or a smoke domain: its grids' boundary box, wearing the object's materials (the
            # default volume without one), its grids looked up where its medium is shaded.
            if object_key not in slot_rows:
                slot_rows[object_key] = materials.slot_ids(ob) \
                    if len(ob.material_slots) or materials.override is not None else (materials.default_volume_id(),)
                signatures[object_key] = slot_materials(ob)
            if mesh_key not in meshes:
                source = read_volume(ob, depsgraph.scene.frame_current, materials.interpolation(slot_rows[object_key]))
                warnings.extend(source.warnings)
                meshes[mesh_key] = boundary_mesh(source.vertices, source.triangles)
                volume_sources[mesh_key] = source
            if meshes[mesh_key].triangle_count == 0:
                empty.add(instance_key(inst))
                continue
        else:
            if dicing is not None and mesh_key not in meshes:
                adaptive = dicing.tessellate(ob, warnings, poll)
                if adaptive is not None:   # diced per camera: never kept between frames
                    diced[mesh_key], meshes[mesh_key] = adaptive, adaptive.local
            with nullcontext() if mesh_key in diced else readable_mesh(ob) as mesh:
                if mesh_key not in meshes:   # (not diced: Blender's evaluated mesh, at the render levels)
                    meshes[mesh_key] = read_mesh(mesh) if cache is None else cache.mesh(inst, ob, mesh)
                # Tangents may use a to_mesh() copy of the object, unless the mesh read is that copy (Edit Mode).
                source = diced.get(mesh_key) or BlenderMesh(mesh, ob if mesh == ob.data else None)
                if meshes[mesh_key].triangle_count == 0:
                    empty.add(instance_key(inst))
                    continue
                # Instances share meshes, but slots linked to the object can give one mesh different materials.
                if object_key not in slot_rows:
                    slot_rows[object_key] = materials.slot_ids(ob)
                    signatures[object_key] = slot_materials(ob)
                if mesh_key not in displaced:
                    displaced.add(mesh_key)
                    meshes[mesh_key] = _displaced(inst, ob, source, meshes[mesh_key], materials,
                                                  slot_rows[object_key], warnings, _base_mesh(diced, mesh_key))
                uv_maps = materials.tangent_uv_maps(slot_rows[object_key])
                if uv_maps and mesh_key not in tangents:
                    tangents[mesh_key] = source.tangents(meshes[mesh_key], uv_maps, ob.name, warnings)
                names = materials.attribute_names(slot_rows[object_key])
                if names and mesh_key not in attributes:
                    attributes[mesh_key] = source.attributes(names, ob.name, warnings)
        matrix = np.array(inst.matrix_world)
        shown.setdefault(mesh_key, ob.name)
        source = volume_sources.get(mesh_key)
        grids.setdefault((mesh_key, slot_rows[object_key]), []).append(
            None if source is None or not source.grids else (source.grids, volume_density(source, matrix),
                                                             volume_step(source, matrix)))
        groups.setdefault((mesh_key, slot_rows[object_key]), []).append(matrix)
        if object_key[0] not in described:
            described[object_key[0]] = object_inputs(ob, _base_mesh(diced, mesh_key))
        location, size, color, pass_index, own, terminator, shading = described[object_key[0]]
        rows.setdefault((mesh_key, slot_rows[object_key]), []).append(
            (location, size, color, pass_index, instance_random(inst, own), terminator, shading))
        keys.setdefault((mesh_key, slot_rows[object_key]), []).append(instance_key(inst))
        properties.setdefault((mesh_key, slot_rows[object_key]), []).append(
            _object_attributes(inst, ob, materials.attribute_names(slot_rows[object_key]), object_values))
        assets.setdefault((mesh_key, slot_rows[object_key]), []).append(asset_name(ob))
        visibility.setdefault((mesh_key, slot_rows[object_key]), []).append(seen_by)
        if linking:
            linked.setdefault((mesh_key, slot_rows[object_key]), []).append(
                links.row(ob, inst.parent if inst.is_instance else None))
        if grouping:
            grouped.setdefault((mesh_key, slot_rows[object_key]), []).append(
                light_groups.of(ob, inst.parent if inst.is_instance else None))
        slots.setdefault((mesh_key, slot_rows[object_key]), []).append(signatures[object_key])
    if cache is not None:
        cache.end()
    if object_values.instances.unmatched:
        warnings.append(f"Instancer attributes: {object_values.instances.unmatched} geometry-nodes instances placed "
                        "inside other instances read no instance attribute (Ember reads those of an instancer's own "
                        "instances): they read the instancer's and the object's properties")
    if object_values.instances.unreachable:
        warnings.append("Instancer attributes: this Blender's Python does not reach geometry-nodes instance attributes "
                        "(Object.evaluated_geometry): instances of geometry nodes read the instancer's and the "
                        "object's properties instead")
    _drop_singular_instances(groups, (rows, keys, properties, assets, visibility, linked, grouped, grids, slots),
                             keys, empty, shown, warnings)
    instanced = instanced_groups(groups, meshes, keys, moving, instance_everything)
    object_space = object_space_groups(groups, keys, moving, materials, diced)
    # Object table rows per group, all of a group's instances at once.
    rows = {group: object_rows(np.stack(groups[group]), *(np.array(column) for column in zip(*inputs)),
                               object_space_normals=object_space[group])
            for group, inputs in rows.items()}
    row_grids = [g for group in grids.values() for g in group]
    geometry = _assemble(meshes, groups, tangents, attributes, rows, instanced)
    per_row = dict(object_attributes=_attribute_table(properties),
                   volumes=tuple((row, *g) for row, g in enumerate(row_grids) if g is not None),
                   instance_keys=[k for group in keys.values() for k in group],
                   instance_matrices=[m for group in groups.values() for m in group],
                   instance_assets=[a for group in assets.values() for a in group],
                   instance_visibility=[v for group in visibility.values() for v in group],
                   instance_links=[v for group in linked.values() for v in group] if linking else None,
                   instance_groups=[v for group in grouped.values() for v in group] if grouping else None,
                   slot_materials=[m for group in slots.values() for m in group],
                   empty_keys=frozenset(empty))
    if not shapes.empty:   # the curves' and points' object rows come after the meshes'
        placed = shapes.assemble(len(per_row["instance_keys"]))
        per_row.update(object_attributes=_attribute_table({**properties, "shapes": placed.properties}),
                       instance_keys=per_row["instance_keys"] + placed.keys,
                       instance_matrices=per_row["instance_matrices"] + placed.matrices,
                       instance_assets=per_row["instance_assets"] + placed.assets,
                       instance_visibility=per_row["instance_visibility"] + placed.visibility,
                       slot_materials=per_row["slot_materials"] + placed.slots,
                       objects=np.concatenate([geometry.objects, placed.objects]),
                       instance_count=geometry.instance_count + len(placed.keys),
                       curves=placed.curves, points=placed.points, shape_instances=placed.instances)
        if linking:   # curves and points are lit and shadowed as objects linked nowhere
            per_row["instance_links"] = per_row["instance_links"] + [UNLINKED_ROW] * len(placed.keys)
            warnings.append("Light Linking: curves and points are lit and shadowed as if they were linked nowhere")
        if grouping:   # an emitting curve or point is in no light group
            per_row["instance_groups"] = per_row["instance_groups"] + [NO_GROUP] * len(placed.keys)
    return dataclasses.replace(geometry, **per_row)


def _drop_singular_instances(groups: dict, columns: tuple, keys: dict, empty: set, shown: dict,
                             warnings: list[str]) -> None:
    """Leave out the instances of a mesh shown more than once whose transform is singular (a zero scale: geometry
    nodes flattening buildings to nothing, say), as Cycles renders them: it places a mesh with several users by its
    transform in the BVH (ObjectManager::apply_static_transforms applies only single users'), and rays taken into
    object space by the inverse of a singular transform meet nothing. A mesh shown once has its transform applied,
    flat, in both engines. groups: (mesh pointer, slot rows) -> matrices; columns: the other per-instance lists of
    the same keys, filtered alike; the instances left out join `empty`."""
    users: dict[int, int] = {}
    for (mesh_key, _), matrices in groups.items():
        users[mesh_key] = users.get(mesh_key, 0) + len(matrices)
    dropped: dict[str, int] = {}
    for group in list(groups):
        if users[group[0]] < 2:
            continue
        keep = np.linalg.det(np.asarray(groups[group], np.float64)[:, :3, :3]) != 0.0   # (one call per group)
        if keep.all():
            continue
        empty.update(k for k, kept in zip(keys[group], keep) if not kept)
        name = shown.get(group[0], "?")
        dropped[name] = dropped.get(name, 0) + int((~keep).sum())
        for column in (groups,) + tuple(columns):
            if group in column:
                if keep.any():
                    column[group] = [v for v, kept in zip(column[group], keep) if kept]
                else:
                    del column[group]
    for name, count in dropped.items():
        warnings.append(f"Object '{name}': {count} of its mesh's instances have a zero scale: not rendered, as in "
                        f"Cycles (a mesh shown more than once is placed by its transform, which cannot be inverted)")


def _add_shape(shapes: ShapeExport, inst, ob, materials: MaterialTable, view_layer, described: dict,
               signatures: dict, object_values: dict, warnings: list[str], hair: bool = False) -> None:
    """Hand one instance's curves or points (a Point Cloud or Curves object; hair: a mesh object's hair
    particle systems) to the shape export, with what its object row takes."""
    owner = (inst.parent if inst.is_instance else None) or ob
    if owner.hide_render:
        return
    seen_by = instance_visibility(inst, ob, view_layer)
    if not seen_by:
        return
    object_key = (ob.as_pointer(), ob.data.as_pointer())
    rows = materials.slot_ids(ob)
    if object_key not in signatures:
        signatures[object_key] = slot_materials(ob)
    names = materials.attribute_names(rows)
    if ob.as_pointer() not in described:
        described[ob.as_pointer()] = object_inputs(ob)
    location, size, color, pass_index, own, terminator, shading = described[ob.as_pointer()]
    place = {"matrix": np.array(inst.matrix_world), "key": instance_key(inst), "asset": asset_name(ob),
             "visibility": seen_by, "slots": signatures[object_key],
             "inputs": (location, size, color, pass_index, instance_random(inst, own), terminator, shading),
             "properties": _object_attributes(inst, ob, names, object_values)}
    if hair:
        shapes.add_hair(ob, rows, names, place)
    else:
        shapes.add_data(ob, rows, names, place)


def _base_mesh(diced: dict, mesh_key: int):
    """The base mesh of a diced object (what its texture space is read from), None for others (their ob.data)."""
    return diced[mesh_key].base if mesh_key in diced else None


def object_space_groups(groups: dict, keys: dict, moving, materials: MaterialTable, diced: dict) -> dict:
    """group -> (K,) bool: which instances of each group interpolate their normals in object space, as Cycles
    shades the objects whose transform it does not apply to their mesh (scene/object.cpp
    apply_static_transforms, for final renders): a mesh shown more than once (linked duplicates, collection and
    geometry-nodes instances), with subsurface scattering, true displacement or adaptive subdivision, or an
    object moving under motion blur. The others' normals are made unit in world space at each corner, as
    Cycles' Mesh::apply_transform does; the two differ under a non-uniform scale."""
    users: dict = {}
    for (mesh_key, _), matrices in groups.items():
        users[mesh_key] = users.get(mesh_key, 0) + len(matrices)
    out = {}
    for group, matrices in groups.items():
        mesh_key, slot_rows = group
        kept = users[mesh_key] > 1 or mesh_key in diced or materials.has_subsurface(slot_rows) or \
            any(materials.true_displacements(slot_rows))
        out[group] = np.array([kept or key in moving for key in keys[group]], bool)
    return out


def _displaced(inst, ob, source, local: LocalMesh, materials: MaterialTable, rows: tuple, warnings,
               base=None) -> LocalMesh:
    """The mesh with the true displacement of its materials applied (displacement.py), once per mesh, with
    the object data (base: a diced object's base mesh) and transform of the first instance showing it (as Cycles
    takes the first object)."""
    per_slot = materials.true_displacements(rows)
    if not any(per_slot):
        return local
    matrix = np.array(inst.matrix_world)
    location, size, color, pass_index, own, terminator, shading = object_inputs(ob, base)
    row = object_rows(matrix[None], np.array([location]), np.array([size]), np.array([color]), np.array([pass_index]),
                      np.array([instance_random(inst, own)]), np.array([terminator]), np.array([shading]))[0]
    textures = [Texture(t, bool(flag)) for t, flag in zip(materials.textures, materials.texture_srgb)]
    return displace_mesh(source, local, per_slot, row, matrix, textures, ob.name, warnings)


class ObjectValues(dict):
    """(object pointer, name) -> an Object attribute's RGBA, read once; the scene's time (Blender's ctime:
    the frame and subframe, remapped by Time Stretching), which Particle Info's Age counts from; and the
    instancers' geometry-nodes instance attributes (rgba_attributes.InstanceAttributes)."""

    def __init__(self, scene):
        super().__init__()
        render = scene.render
        self.time = (scene.frame_current + scene.frame_subframe) * render.frame_map_new / max(render.frame_map_old, 1)
        self.instances = InstanceAttributes()   # geometry-nodes instance attributes (Instancer type)


# Particle Info's object attribute names -> its outputs.
_PARTICLE_NAMES = {particle_attribute_name(output): output for output in PARTICLE_OUTPUTS}


def _object_attributes(inst, ob, names: tuple, cache: ObjectValues) -> dict:
    """{name: RGBA} of the Object ("object:"), Instancer ("instancer:") and particle ("particle:", Particle Info)
    attributes among names, for one depsgraph instance (read while it is valid); Object ones are the object's,
    read once per object."""
    out = {}
    wanted = [_PARTICLE_NAMES[name] for name in names if name in _PARTICLE_NAMES]
    if wanted:
        out.update((particle_attribute_name(output), value)
                   for output, value in particle_values(inst, wanted, cache.time).items())
    for name in names:
        kind, _, key = name.partition(":")
        if kind not in OBJECT_ATTRIBUTE_KINDS or kind == "particle":
            continue
        if kind == "instancer" and inst.is_instance:
            out[name] = instancer_attribute(inst, ob, key, cache.instances)
            continue
        cached = (ob.as_pointer(), key)
        if cached not in cache:
            cache[cached] = object_attribute(ob, key)
        out[name] = cache[cached]
    return out


def _attribute_table(properties: dict) -> tuple:
    """SceneArrays.object_attributes from each group's per-instance {name: RGBA} (the object rows' order);
    zero, alpha too, for an instance whose materials do not read the name (as Cycles leaves it unset)."""
    per_row = [values for group in properties.values() for values in group]
    names = sorted(set().union(*per_row)) if per_row else []
    zero = (0.0, 0.0, 0.0, 0.0)
    return tuple((name, np.array([values.get(name, zero) for values in per_row], np.float32).reshape(-1, 4))
                 for name in names)


def boundary_mesh(vertices: np.ndarray, triangles: np.ndarray) -> LocalMesh:
    """A volume's boundary (object space, outward triangles) as a LocalMesh: flat normals, no UVs, slot 0."""
    t = len(triangles)
    corners = np.ascontiguousarray(triangles, np.int32).reshape(-1)
    p = vertices[triangles] if t else np.zeros((0, 3, 3), np.float32)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) if t else np.zeros((0, 3), np.float32)
    n = (n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)).astype(np.float32)
    return LocalMesh(np.ascontiguousarray(vertices, np.float32), corners, n,
                     np.repeat(np.arange(t, dtype=np.int32), 3), np.zeros((3 * t, 2), np.float32),
                     np.zeros(t, np.int32))


def volume_density(source, world_from_object: np.ndarray) -> float:
    """Cycles' object_volume_density (scene/object.cpp): a Volume object whose Render > Space is Object has
    its density follow the object's scale, 1 / |M normalize(1, 1, 1)|; 1 otherwise."""
    if not source.object_space:
        return 1.0
    unit = np.full(3, 1.0 / np.sqrt(3.0))
    length = float(np.linalg.norm(world_from_object[:3, :3] @ unit))
    return 1.0 / length if length > 0 else 1.0


def volume_step(source, world_from_object: np.ndarray) -> float:
    """The world-space step the Biased option marches a Volume object with before its material's and the
    scene's Step Rates, as Cycles' Object::compute_volume_step_size: Render > Step Size when set (in object space
    when Space is Object: the smallest component of M (s, s, s)), else the voxel size, the smallest component
    of the index-to-world transform applied to (1, 1, 1), the least over the grids. 0: none."""
    matrix = np.asarray(world_from_object, np.float64)[:3, :3]
    if source.step_size > 0:
        size = float(source.step_size)
        return float(np.abs(matrix @ np.full(3, size)).min()) if source.object_space else size
    steps = [float(np.abs(matrix @ grid.index_to_object[:3, :3] @ np.ones(3)).min()) for grid in source.grids.values()]
    steps = [s for s in steps if s > 0]
    return min(steps) if steps else 0.0


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
