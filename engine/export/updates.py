"""Partial exports: what the viewport reads again when the depsgraph says only part of the scene changed.

The viewport exports the whole scene once with every mesh a prototype placed by its instances
(export_scene(..., instance_everything=True)), and keeps the ExportIndex that export made: which instance
each object row is, which material each material row is. Later edits read only the part they touched,
with the same code the full export runs, so each part equals what a full export of the edited scene
would make:

    export_instances(depsgraph, index)   the instances' transforms and object rows (objects moved)
    export_shading(depsgraph, index)     the material table, its images and the world (shaders edited)
    export_lights(depsgraph, warnings)   the lights (engine/export/lights.py: read whole, it is cheap)

The first two return None when the scene no longer lines up with the index (an object added, removed
or hidden; a slot given another material; a material that now reads tangents or mesh attributes): the
caller then exports the whole scene again, as Cycles' Blender sync falls back to a full sync.
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ...kernels import Materials, World
from ...kernels.scene import OBJECT_COLUMNS
from .lights import export_lights
from .materials import MaterialTable
from .mesh import Geometry, instance_key, instance_row, is_rendered, slot_materials
from .world import export_world

__all__ = ["ExportIndex", "Shading", "export_index", "export_instances", "export_lights", "export_shading"]


@dataclass(frozen=True)
class ExportIndex:
    """What names the rows of an exported scene, so that a later partial export lines up with them.

    instance_keys : per object row (SceneArrays.objects), its instance (mesh.instance_key).
    slot_materials : per object row, mesh.slot_materials of its object when it was exported.
    empty_keys : rendered mesh instances without triangles (they have no row).
    instance_rows : (K,) int32 object row of each instance (Instances.object_ids), or None without instances.
    movable : every object row is an instance; otherwise some objects were copied into world space and
        moving them takes a full export.
    material_keys : per material row, MaterialTable.keys.
    mesh_needs : per material row, MaterialTable.mesh_needs().
    """
    instance_keys: tuple
    slot_materials: tuple
    empty_keys: frozenset
    instance_rows: np.ndarray | None
    movable: bool
    material_keys: tuple
    mesh_needs: tuple


def export_index(geometry: Geometry, materials: MaterialTable) -> ExportIndex:
    """The index of a full export, from its geometry and material table."""
    inst = geometry.instances
    rows = len(geometry.instance_keys or ())
    instance_rows = None if inst is None else inst.object_ids
    movable = len(geometry.material_ids) == 0 and (rows == 0 if inst is None else
                                                   np.array_equal(np.sort(instance_rows), np.arange(rows)))
    return ExportIndex(instance_keys=tuple(geometry.instance_keys or ()),
                       slot_materials=tuple(geometry.slot_materials or ()), empty_keys=geometry.empty_keys,
                       instance_rows=instance_rows, movable=bool(movable), material_keys=materials.keys,
                       mesh_needs=materials.mesh_needs())


def export_instances(depsgraph, index: ExportIndex) -> tuple[np.ndarray, np.ndarray] | None:
    """The instances read again: (world_from_object (K, 4, 4) float64 per instance, objects (R, OBJECT_COLUMNS)
    float32 per object row), in the order of the export the index describes; None when the rendered
    instances are no longer the same ones with the same material slots. Meshes are not read."""
    if not index.movable:
        return None
    row_of = {key: r for r, key in enumerate(index.instance_keys)}
    if len(row_of) != len(index.instance_keys):   # two instances under one key cannot be told apart
        return None
    matrices: list = [None] * len(row_of)
    rows: list = [None] * len(row_of)
    signatures: dict[tuple, tuple] = {}   # (object, mesh) pointers -> slot_materials()
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
        object_key = (ob.as_pointer(), ob.data.as_pointer())
        if object_key not in signatures:
            signatures[object_key] = slot_materials(ob)
        if rows[r] is not None or signatures[object_key] != index.slot_materials[r]:
            return None
        matrix = np.array(inst.matrix_world)
        matrices[r] = matrix
        rows[r] = instance_row(inst, ob, matrix)
    if any(row is None for row in rows):
        return None                       # an instance is gone
    if not rows:
        return np.zeros((0, 4, 4)), np.zeros((0, OBJECT_COLUMNS), np.float32)
    world_from_object = np.array(matrices, np.float64).reshape(-1, 4, 4)
    return world_from_object[index.instance_rows], np.stack(rows)


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
    materials = MaterialTable(warnings)
    for key in index.material_keys[1:]:
        material = evaluated.get(key)
        if material is None:
            return None
        materials.material_id(material)
    if materials.mesh_needs() != index.mesh_needs:
        return None
    world = export_world(depsgraph.scene_eval.world, warnings, materials.images)
    return Shading(materials.to_kernel(), materials.textures, materials.texture_srgb, world)
