"""Light groups (View Layer > Light Groups; an emitter's Object > Shading > Light Group, the World's Settings >
Light Group), read as Cycles' sync reads them:
- a group's number is its place in the view layer's list (Blender's sync adds the Combined_<name> passes in
  that order, intern/cycles/blender/sync.cpp sync_render_passes, and Cycles numbers the groups in the order of
  their passes, scene/film.cpp Film::update_lightgroups);
- an object's group is its Light Group, or its instancer's where its own is empty (blender/object.cpp
  sync_object; lamps alike, blender/light.cpp); the world's is the World's (blender/sync.cpp sync_background);
- a name the view layer does not list is no group (scene/object.cpp, background.cpp: LIGHTGROUP_NONE).
A view layer without light groups exports none, and the kernel takes no step for them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...kernels.scene import NO_GROUP, LightGroups


@dataclass
class GroupTable:
    """The view layer's light groups: names in order; index, name -> group number."""
    names: tuple = ()
    index: dict = field(default_factory=dict)

    @property
    def used(self) -> bool:
        return bool(self.names)

    def of(self, ob, parent=None) -> int:
        """The group of an object, or of an instance of it made by `parent`: NO_GROUP for none."""
        name = _group_name(ob) or (_group_name(parent) if parent is not None else "")
        return self.index.get(name, NO_GROUP)

    def world(self, world) -> int:
        """The world's group (NO_GROUP without a world or a group)."""
        return NO_GROUP if world is None else self.index.get(_group_name(world), NO_GROUP)


def _group_name(data) -> str:
    """The Light Group of an object or world, read from the original: Blender 5.0 does not tag the depsgraph
    when it changes, so an evaluated copy made before keeps the old name (5.3 does)."""
    return getattr(getattr(data, "original", data), "lightgroup", "")


def group_table(view_layer) -> GroupTable:
    """The light groups of a view layer (an empty table when it has none, or a Blender without them)."""
    names = tuple(g.name for g in getattr(view_layer, "lightgroups", ()))
    return GroupTable(names, {name: k for k, name in enumerate(names)})


def object_groups(rows: list | None, world: int) -> LightGroups | None:
    """kernels.scene.LightGroups of the object rows' groups (rows: per row, GroupTable.of) and the world's group;
    None when none is in a group."""
    rows = rows or []
    if world == NO_GROUP and all(g == NO_GROUP for g in rows):
        return None
    return LightGroups(objects=np.array(rows, np.int32).reshape(len(rows)), world=int(world))


def lamp_groups(groups: list) -> np.ndarray | None:
    """kernels.scene.Lights.light_groups from each light's group, None when none is in a group."""
    if all(g == NO_GROUP for g in groups):
        return None
    return np.array(groups, np.int32)
