"""Light groups (View Layer > Light Groups) per row of the object table and for the world: LightGroups,
NO_GROUP, and its validation.

A group is a number, the place of its name in the view layer's list (Cycles numbers its light groups in the
order of their passes, scene/film.cpp Film::update_lightgroups, which Blender's sync adds in the view layer's
order); an emitter whose Light Group names no group of the view layer is in none (Cycles' LIGHTGROUP_NONE,
kernel/types.h). Lamps keep theirs in Lights.light_groups."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import check_array, require

# An emitter in no light group (Cycles' LIGHTGROUP_NONE).
NO_GROUP = -1


@dataclass(frozen=True)
class LightGroups:
    """The light groups of the emitters that are no lamps.

    objects : (K,) int32 per row of SceneArrays.objects: the group of the object's emission (its emissive
        surfaces, its volume), NO_GROUP for none.
    world : the world's group (what rays that leave the scene see of it, and its light samples), NO_GROUP for
        none. The world's fog emits in no group, as in Cycles (its volume emission takes the group of the
        volume's object, kernel/integrator/shade_volume.h, and the world is none: kernel/geom/object.h
        object_lightgroup).
    A group without a pass to record it (a number past the render's) gathers nothing.
    """
    objects: np.ndarray
    world: int = NO_GROUP

    def validate(self, k: int) -> None:
        check_array(self.objects, "light_groups.objects", (k,), np.int32, finite=False)
        require(not k or int(self.objects.min()) >= NO_GROUP, "light_groups.objects", f"must be {NO_GROUP} or more")
        require(int(self.world) >= NO_GROUP, "light_groups.world", f"must be {NO_GROUP} or more")
