"""Depsgraph instances: which ones Ember renders, what names one across frames, the object table row of
each, and which meshes are instanced rather than copied into world space.

The export (engine/export/geometry.py), the viewport's instance updates (engine/export/updates.py) and
motion blur (engine/export/motion.py) all decide and name instances here, so they agree on them.
"""
from __future__ import annotations

import numpy as np

from ...kernels.scene import TERMINATOR_OFFSET, object_rows
from ...kernels.scene.objects import (HOLDOUT, RAY_CAMERA, RAY_DIFFUSE, RAY_GLOSSY, RAY_SCATTER, RAY_SHADOW,
                                      RAY_TRANSMIT, SHADOW_CATCHER)

# A mesh placed by two or more instances is stored once in object space and instanced (two-level BVH,
# kernels.scene.Instances) when its copies together would hold at least this many triangles; smaller sets
# are copied into world space, which traces a little faster (no transform per ray and per hit).
INSTANCE_MIN_TRIANGLES = 20_000

# Object types whose geometry Ember renders: meshes (and what Blender hands out as meshes), volumes, point clouds
# and Curves objects (engine/export/shapes.py).
RENDERED_TYPES = ("MESH", "VOLUME", "POINTCLOUD", "CURVES")
# Object > Visibility > Ray Visibility, each with its bit of SceneArrays.object_visibility (Cycles' sync:
# intern/cycles/blender/object.cpp, object_ray_visibility).
RAY_VISIBILITY = (("visible_camera", RAY_CAMERA), ("visible_diffuse", RAY_DIFFUSE), ("visible_glossy", RAY_GLOSSY),
                  ("visible_transmission", RAY_TRANSMIT), ("visible_volume_scatter", RAY_SCATTER),
                  ("visible_shadow", RAY_SHADOW))


def is_rendered(inst, ob, warnings: list[str]) -> bool:
    """Whether Ember renders this depsgraph instance: a mesh, a Volume, Point Cloud or Curves object, shown, and not
    hidden for render. (Cameras, lights and empties carry nothing to render; nor, in Cycles, does Grease Pencil.)"""
    if ob.type not in RENDERED_TYPES:
        return False
    # A render depsgraph has already dropped objects hidden for render; a viewport one has not. Particles
    # of a hidden object still render, so an instance follows its instancer.
    owner = (inst.parent if inst.is_instance else None) or ob
    return inst.show_self and not owner.hide_render


def ray_visibility(ob) -> int:
    """The object's own Ray Visibility bits."""
    return sum(bit for name, bit in RAY_VISIBILITY if getattr(ob, name, True))


def instance_visibility(inst, ob, view_layer) -> int:
    """An instance's SceneArrays.object_visibility bits, as Cycles' sync (intern/cycles/blender/object.cpp,
    sync_object): the object's Ray Visibility, and its instancer's too; a holdout (the object's Holdout or a
    holdout collection of the view layer: Object.holdout_get) is HOLDOUT; in an indirect-only collection (and
    not a holdout) camera rays do not see it; the object's or its instancer's Shadow Catcher is SHADOW_CATCHER.
    0: no ray sees it, and it is not rendered at all.
    view_layer : the evaluated view layer (depsgraph.view_layer_eval: the original one answers False)."""
    parent = (inst.parent if inst.is_instance else None) or ob
    bits = ray_visibility(ob)
    if parent != ob:
        bits &= ray_visibility(parent)
    holdout = bool(parent.holdout_get(view_layer=view_layer))
    if not holdout and parent.indirect_only_get(view_layer=view_layer):
        bits &= ~RAY_CAMERA
    if not bits:
        return 0
    if ob.is_shadow_catcher or parent.is_shadow_catcher:
        bits |= SHADOW_CATCHER
    return bits | HOLDOUT if holdout else bits


def instance_key(inst) -> tuple:
    """What names one object instance across frames (motion blur): the object, and for instances the
    instancer and the persistent id."""
    if inst.is_instance:
        return (inst.object.name, inst.parent.name if inst.parent else "", tuple(inst.persistent_id))
    return (inst.object.name, "", ())


def asset_name(ob) -> str:
    """Cryptomatte's asset: the object's top-most parent (Cycles' Blender sync)."""
    while ob.parent is not None:
        ob = ob.parent
    return ob.name


def slot_materials(ob) -> tuple:
    """The materials in an object's slots by name ('' for an empty slot): what picks its material rows."""
    return tuple(slot.material.name_full if slot.material is not None else "" for slot in ob.material_slots)


def object_inputs(ob, mesh=None) -> tuple:
    """What an object's rows of the object table take from the object and its mesh (mesh: ob.data when None):
    (texture space location, size, colour, pass index, its own random number: Blender's sync hashes its name,
    its Shadow Terminator Geometry and Shading Offsets)."""
    from ...kernels.shading.hash import hash_uint2
    h = 0
    for c in ob.name.encode("utf-8"):
        h = (h * 37 + c) & 0xFFFFFFFF
    own_random = np.float32(int(hash_uint2(np.array([h], np.uint32), np.array([0], np.uint32))[0])) \
        * np.float32(1.0 / 0xFFFFFFFF)
    mesh = ob.data if mesh is None else mesh
    terminator = float(getattr(ob, "shadow_terminator_geometry_offset", TERMINATOR_OFFSET))
    if hasattr(mesh, "texspace_location"):
        location, size = tuple(mesh.texspace_location), tuple(mesh.texspace_size)
    else:   # a Volume: its bounding box
        corners = np.array([tuple(c) for c in ob.bound_box], np.float64)
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        location, size = tuple((lo + hi) / 2), tuple((hi - lo) / 2)
    shading = float(getattr(ob, "shadow_terminator_shading_offset", 0.0))
    return (location, size, tuple(ob.color), ob.pass_index, float(own_random), terminator, shading)


def instance_random(inst, own_random: float) -> float:
    """Cycles' random number of an instance: its random id, or for an object itself its own (object_inputs)."""
    if inst.is_instance:
        return float(np.float32(inst.random_id & 0xFFFFFFFF) * np.float32(1.0 / 0xFFFFFFFF))
    return own_random


def instance_row(inst, ob, matrix) -> np.ndarray:
    """The object table row of an instance (kernels.scene.object_row)."""
    location, size, color, pass_index, own, terminator, shading = object_inputs(ob)
    return object_rows(np.asarray(matrix, np.float64)[None], [location], [size], [color], [pass_index],
                       [instance_random(inst, own)], [terminator], [shading])[0]


def instanced_groups(groups: dict, meshes: dict, keys: dict, moving, instance_everything: bool) -> set:
    """The groups (mesh pointer, slot rows) stored once and placed by transforms: every group when
    instance_everything, else those of two or more instances that together hold INSTANCE_MIN_TRIANGLES.
    groups : group -> world_from_object matrices; meshes : mesh pointer -> LocalMesh; keys : group ->
    instance keys; moving : instance keys of objects that move during the shutter."""
    # Groups with a moving member stay plain: motion blur moves plain triangles (kernels.moving.Moving).
    return set(groups) if instance_everything else \
        {group for group, matrices in groups.items()
         if len(matrices) >= 2 and len(matrices) * meshes[group[0]].triangle_count >= INSTANCE_MIN_TRIANGLES
         and not any(key in moving for key in keys[group])}
