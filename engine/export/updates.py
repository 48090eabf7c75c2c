"""What a depsgraph update changed, and reading that part of the scene again: the viewport's incremental
updates, as Cycles' Blender sync tracks what changed per data type (BlenderSync::sync_recalc,
intern/cycles/blender/sync.cpp) and re-syncs only that.

Classifying (scene_changes): each content update is sorted by the type of its data-block (RECALC) into the
part of the scene it changes, cheapest first: INSTANCES (objects moved or their object-level settings),
SHADING (materials, images, the world), LIGHTS, or FULL (anything else: when unsure, export everything).

Reading again: the viewport exports the whole scene once with every mesh a prototype placed by its instances
(export_scene(..., instance_everything=True)), and keeps the ExportIndex that export made: which instance
each object row is, which material each material row is. Later edits read only the part they touched,
with the same code the full export runs, so each part equals what a full export of the edited scene
would make:

    export_instances(depsgraph, index)   the instances' transforms and object rows (objects moved)
    export_shading(depsgraph, index)     the material table, its images and the world (shaders edited)
    export_lights(depsgraph, warnings)   the lights (engine/export/lights.py: read whole, it is cheap)
    export_changes(depsgraph, index, parts, scene)   the parts scene_changes named, together

The first two return None when the scene no longer lines up with the index (an object added, removed
or hidden; a slot given another material; a material that now reads tangents or mesh attributes): the
caller then exports the whole scene again, as Cycles' Blender sync falls back to a full sync.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import bpy
import numpy as np

from ...kernels import Lights, Materials, SceneArrays, World
from ...kernels.scene import OBJ_OBJECT_SPACE_NORMALS, OBJECT_COLUMNS
from .geometry import Geometry
from .instances import instance_key, instance_row, instance_visibility, is_rendered, slot_materials
from .light_linking import link_table
from .lights import export_lights
from .images import texture_limit
from .materials import DEFAULT_VOLUME_KEY, MaterialTable
from .mesh import OBJECT_ATTRIBUTE_KINDS
from .rgba_attributes import view_layer_attribute
from .world import export_layer_world

__all__ = ["FULL", "INSTANCES", "LIGHTS", "SHADING", "Changes", "ExportIndex", "Shading", "export_changes",
           "export_index", "export_instances", "export_lights", "export_shading", "is_content_update",
           "scene_changes", "scene_needs_export", "update_part", "visibility_key"]

# The parts of a scene an update can change, cheapest first: the instances' transforms and object rows, the
# materials and world, the lights; FULL is a new export.
INSTANCES, SHADING, LIGHTS, FULL = "instances", "shading", "lights", "full"


# ====================================================================== what the depsgraph says changed
def is_content_update(update) -> bool:
    """True when a depsgraph update can change the rendered image.

    Cameras are invisible: moving or editing one matters only when the view looks through it, and
    view_draw sees that in the view itself. Updates without any flag (the scene after a selection,
    node trees next to their material) change nothing by themselves.
    """
    if not (update.is_updated_transform or update.is_updated_geometry or update.is_updated_shading):
        return False
    data = update.id
    if data.id_type == "CAMERA" or (data.id_type == "OBJECT" and data.type == "CAMERA"):
        return False
    return True


def _object_part(update) -> str:
    """A light object is its light; any other object's transform or object-level settings are its instances
    (an object whose geometry was evaluated again is a new export)."""
    if update.id.type == "LIGHT":
        return LIGHTS
    return _geometry_part(update)


def _geometry_part(update) -> str:
    """Object data Ember turns into triangles: edited geometry is a new export; their other updates come along
    with their objects' (a material edit tags its meshes for shading)."""
    return FULL if update.is_updated_geometry else INSTANCES


def _node_tree_part(update) -> str:
    """A light's own node tree is the light's; any other shader tree reaches the image through the materials
    and world that use it; other trees (geometry nodes) are a new export."""
    tree = update.id
    if _is_light_node_tree(tree):
        return LIGHTS
    return SHADING if tree.bl_idname == "ShaderNodeTree" else FULL


def _is_light_node_tree(tree) -> bool:
    """Whether a node tree is a light's own (Blender 5.3 gives every light one, and an edit of the light
    updates it too): such an update is the light's, not a material's."""
    original = tree.original
    return bool(original.is_embedded_data) and any(light.node_tree == original for light in bpy.data.lights
                                                   if getattr(light, "node_tree", None) is not None)


def _shading_part(update) -> str:
    return SHADING


def _lights_part(update) -> str:
    return LIGHTS


# Per data-block type (ID.id_type), the part of the scene an update of it changes. Curves, surfaces and text
# are CURVE. Images and textures reach the image only through the materials and the world that read them.
RECALC = {
    "OBJECT": _object_part,
    "MESH": _geometry_part, "CURVE": _geometry_part, "METABALL": _geometry_part,
    "LIGHT": _lights_part,
    "NODETREE": _node_tree_part,
    "MATERIAL": _shading_part, "WORLD": _shading_part, "IMAGE": _shading_part, "TEXTURE": _shading_part,
}


def update_part(update) -> str:
    """The part of the scene one content update (is_content_update) changes: RECALC's for its data-block's
    type; anything else (collections, the scene, unknown data) is FULL."""
    recalc = RECALC.get(update.id.id_type)
    return FULL if recalc is None else recalc(update)


def scene_changes(updates) -> frozenset:
    """The parts of the scene that depsgraph.updates change (update_part of each content update); empty
    when nothing Ember renders changed."""
    return frozenset(update_part(update) for update in updates if is_content_update(update))


def scene_needs_export(updates) -> bool:
    """Whether any of depsgraph.updates changes what Ember renders (see is_content_update)."""
    return bool(scene_changes(updates))


def visibility_key(depsgraph) -> tuple:
    """What the export sees besides the updates: hiding an object in the view layer (the eye icon)
    reaches view_update as a bare scene update, so the set of visible objects is compared as well."""
    scene = depsgraph.scene_eval
    world = scene.world.name_full if scene.world is not None else ""
    return frozenset(ob.name_full for ob in depsgraph.objects), world


# ====================================================================== reading parts again


@dataclass(frozen=True)
class ExportIndex:
    """What names the rows of an exported scene, so that a later partial export lines up with them.

    instance_keys : per object row (SceneArrays.objects), its instance (instances.instance_key).
    slot_materials : per object row, instances.slot_materials of its object when it was exported.
    empty_keys : rendered mesh instances without triangles (they have no row).
    instance_rows : (K,) int32 object row of each instance (Instances.object_ids), or None without instances.
    movable : every object row is an instance; otherwise some objects were copied into world space and
        moving them takes a full export.
    material_keys : per material row, MaterialTable.keys.
    mesh_needs : per material row, MaterialTable.mesh_needs().
    visibility : per object row, instances.instance_visibility (Ray Visibility, holdout): a change of it takes
        a full export.
    object_space : per object row, whether it interpolates its normals in object space
        (geometry.object_space_groups), which moving an instance does not change.
    linking : light_linking.LinkTable.signature() of the scene: a change of Light or Shadow Linking takes a full
        export (it reaches object rows and lights alike).
    """
    instance_keys: tuple
    slot_materials: tuple
    empty_keys: frozenset
    instance_rows: np.ndarray | None
    movable: bool
    material_keys: tuple
    mesh_needs: tuple
    visibility: tuple = ()
    linking: tuple = ()
    object_space: tuple = ()


def export_index(geometry: Geometry, materials: MaterialTable, linking: tuple = ()) -> ExportIndex:
    """The index of a full export, from its geometry and material table."""
    inst = geometry.instances
    rows = len(geometry.instance_keys or ())
    instance_rows = None if inst is None else inst.object_ids
    # Curves and points are copied into world space or instanced apart from the meshes: moving them is a new export.
    shapes = bool(geometry.curves) or geometry.points is not None or geometry.shape_instances is not None
    movable = len(geometry.material_ids) == 0 and not shapes and (
        rows == 0 if inst is None else np.array_equal(np.sort(instance_rows), np.arange(rows)))
    return ExportIndex(instance_keys=tuple(geometry.instance_keys or ()),
                       slot_materials=tuple(geometry.slot_materials or ()), empty_keys=geometry.empty_keys,
                       instance_rows=instance_rows, movable=bool(movable), material_keys=materials.keys,
                       mesh_needs=materials.mesh_needs(),
                       visibility=tuple(geometry.instance_visibility or ()), linking=linking,
                       object_space=tuple(bool(v) for v in geometry.objects[:rows, OBJ_OBJECT_SPACE_NORMALS] > 0)
                       if geometry.objects is not None else ())


def export_instances(depsgraph, index: ExportIndex) -> tuple[np.ndarray, np.ndarray] | None:
    """The instances read again: (world_from_object (K, 4, 4) float64 per instance, objects (R, OBJECT_COLUMNS)
    float32 per object row), in the order of the export the index describes; None when the rendered
    instances are no longer the same ones with the same material slots. Meshes are not read."""
    if not index.movable or _reads_object_attributes(index):
        return None
    row_of = {key: r for r, key in enumerate(index.instance_keys)}
    if len(row_of) != len(index.instance_keys):   # two instances under one key cannot be told apart
        return None
    matrices: list = [None] * len(row_of)
    rows: list = [None] * len(row_of)
    # object pointer -> slot_materials() (not ob.data's: reading it has Blender subdivide an adaptive object)
    signatures: dict[int, tuple] = {}
    ignored: list[str] = []               # the full export has given these warnings already
    for inst in depsgraph.object_instances:
        ob = inst.object
        if not is_rendered(inst, ob, ignored):
            continue
        key = instance_key(inst)
        r = row_of.get(key)
        if r is None:
            if key in index.empty_keys:
                continue
            return None                   # a new instance
        object_key = ob.as_pointer()
        if object_key not in signatures:
            signatures[object_key] = slot_materials(ob)
        if rows[r] is not None or signatures[object_key] != index.slot_materials[r]:
            return None
        if index.visibility and instance_visibility(inst, ob, depsgraph.view_layer_eval) != index.visibility[r]:
            return None                   # Ray Visibility or holdout changed: the kernel's table is rebuilt whole
        matrix = np.array(inst.matrix_world)
        matrices[r] = matrix
        rows[r] = instance_row(inst, ob, matrix)
    if any(row is None for row in rows):
        return None                       # an instance is gone
    if not rows:
        return np.zeros((0, 4, 4)), np.zeros((0, OBJECT_COLUMNS), np.float32)
    world_from_object = np.array(matrices, np.float64).reshape(-1, 4, 4)
    objects = np.stack(rows)
    if index.object_space:
        objects[:, OBJ_OBJECT_SPACE_NORMALS] = index.object_space
    return world_from_object[index.instance_rows], objects


def _reads_object_attributes(index: ExportIndex) -> bool:
    """Whether a material reads Object or Instancer attributes: their values are kept beside the object
    table (SceneArrays.object_attributes), which an instance update does not read again, so such scenes are
    exported again instead."""
    return any(name.partition(":")[0] in OBJECT_ATTRIBUTE_KINDS for needs in index.mesh_needs for name in needs[1])


@dataclass(frozen=True)
class Shading:
    """The shading part of a SceneArrays (its fields of the same names)."""
    materials: Materials
    textures: tuple
    texture_srgb: tuple
    world: World


def export_shading(depsgraph, index: ExportIndex) -> Shading | None:
    """The materials of the index's rows read again, in their order (so textures keep their order too),
    and the world; None when a material is gone or now asks the meshes for other data (tangents,
    attributes)."""
    warnings: list[str] = []
    evaluated = {data.name_full: data for data in depsgraph.ids if isinstance(data, bpy.types.Material)}
    layer_attribute = functools.partial(view_layer_attribute, depsgraph.scene_eval, depsgraph.view_layer_eval)
    materials = MaterialTable(warnings, layer_attribute, depsgraph.scene_eval.frame_current,
                              override=depsgraph.view_layer_eval.material_override)
    materials.images.limit = texture_limit(depsgraph.scene_eval, viewport=True)
    for key in index.material_keys[1:]:
        if key == DEFAULT_VOLUME_KEY:
            materials.default_volume_id()
            continue
        material = evaluated.get(key)
        if material is None:
            return None
        materials.material_id(material)
    if materials.mesh_needs() != index.mesh_needs:
        return None
    world = export_layer_world(depsgraph, warnings, materials.images, layer_attribute)
    return Shading(materials.to_kernel(), materials.textures, materials.texture_srgb, world)


@dataclass(frozen=True)
class Changes:
    """The parts of a scene read again (export_changes); None where a part is unchanged.

    instances : (world_from_object, objects) as export_instances returns them.
    """
    instances: tuple | None
    shading: Shading | None
    lights: Lights | None


def export_changes(depsgraph, index: ExportIndex, parts: frozenset, scene: SceneArrays) -> Changes | None:
    """The parts (scene_changes) of the scene read again, to replace those of `scene`, the scene made by the
    export the index describes with every change so far. None when a part no longer lines up with that
    export: then only a full export will do."""
    placed = shading = lights = None
    links = link_table(depsgraph)
    if links.signature() != index.linking:
        return None
    if INSTANCES in parts:
        placed = export_instances(depsgraph, index)
        if placed is None:
            return None
        if _same_placement(scene, *placed):
            placed = None   # object-level updates that change nothing Ember reads (a material edit's)
    if SHADING in parts:
        if scene.lights.shader is not None:   # lamp programs index the export's textures, which this reads anew
            return None
        shading = export_shading(depsgraph, index)
        if shading is None:
            return None
    if LIGHTS in parts:
        lights = export_lights(depsgraph, [], links=links)
        if lights.shader is not None:   # light programs read the export's images and scene data: export again
            return None
    return Changes(placed, shading, lights)


def _same_placement(scene: SceneArrays, world_from_object: np.ndarray, objects: np.ndarray) -> bool:
    """Whether a scene's instances and object table already are these."""
    current = scene.instances.world_from_object if scene.instances is not None else np.zeros((0, 4, 4))
    table = scene.objects if scene.objects is not None else np.zeros((0, objects.shape[1]), np.float32)
    return np.array_equal(current, world_from_object) and np.array_equal(table, objects)
