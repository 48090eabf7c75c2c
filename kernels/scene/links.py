"""Light and shadow linking per row of the object table: LightLinks, ALL_SETS, and its validation.

Cycles keeps four numbers per object (kernel/types.h, KernelObject): the light set it receives light in
(receiver_light_set), the shadow set it blocks light in (blocker_shadow_set), and, as an emitter, the masks of
the light sets its light reaches (light_set_membership) and of the shadow sets whose objects block it
(shadow_set_membership). A set is a bit of a uint64: 64 sets at most, set 0 is that of objects linked
nowhere."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import check_array, require

# An emitter's mask when it has no linking collection: every set (Cycles' LIGHT_LINK_MASK_ALL).
ALL_SETS = np.uint64(0xFFFF_FFFF_FFFF_FFFF)
# Sets are numbered 0..63 (Cycles' LIGHT_LINK_SET_MAX).
MAX_LINK_SETS = 64


@dataclass(frozen=True)
class LightLinks:
    """Light and shadow linking of the K rows of SceneArrays.objects.

    receiver : (K,) uint8, the light set each object receives light in (0: no linking collection names it).
    blocker : (K,) uint8, the shadow set each object blocks light in.
    light_sets : (K,) uint64, as an emitter (an emissive object): the mask of the light sets its light reaches.
    shadow_sets : (K,) uint64, as an emitter: the mask of the shadow sets whose objects block its light.
    """
    receiver: np.ndarray
    blocker: np.ndarray
    light_sets: np.ndarray
    shadow_sets: np.ndarray

    def validate(self, k: int) -> None:
        check_array(self.receiver, "light_links.receiver", (k,), np.uint8, finite=False)
        check_array(self.blocker, "light_links.blocker", (k,), np.uint8, finite=False)
        check_array(self.light_sets, "light_links.light_sets", (k,), np.uint64, finite=False)
        check_array(self.shadow_sets, "light_links.shadow_sets", (k,), np.uint64, finite=False)
        for name in ("receiver", "blocker"):
            require(not k or int(getattr(self, name).max()) < MAX_LINK_SETS, f"light_links.{name}",
                    f"must be below {MAX_LINK_SETS}")
