"""Light and shadow linking (Blender 4.0+), as Cycles renders it: which emitters light which objects, and which
objects block which emitters' light.

Every object row receives light in a light set and blocks it in a shadow set (kernels.scene.LightLinks; 0
for objects no linking collection names); every emitter reaches a mask of light sets and is blocked by the
objects of a mask of shadow sets (lamps: Lights.light_sets and shadow_sets; emissive triangles: their object
row's; the world, which is no object in Blender, every set: Cycles' background emission checks no link,
kernel/integrator/shade_background.h, and paths start as the background object, receiver set 0,
kernel/integrator/path_state.h). As Cycles:
- an emitter lights a point of an object when the object's receiver set is in its light mask
  (kernel/light/light.h light_link_object_match). Next-event estimation chooses among the emitters that
  reach the shading point's set only, as Cycles' light tree specialised per receiver set does
  (scene/light.cpp light_tree_specialize_nodes_flatten): here a Choice (selection.py) per set that
  receivers use, built over the emitters that reach it. BSDF rays count an emitter only where it reaches the
  set of the object the ray left (Cycles' mis_ray_object, kernel/integrator/shade_surface.h), and weigh it
  by MIS with that set's choice, so the two strategies stay one unbiased estimator.
- a shadow ray toward an emitter passes through objects whose blocker set is not in the emitter's shadow
  mask (kernel/bvh/util.h intersection_skip_shadow_link). BSDF rays do not count shadow-linked emitters
  (those whose shadow mask is not every set); the dedicated light rays of kernels/shadow_linking.py do.
Scenes without linking have no Linking: no stage looks further and images stay as they were.
"""
from __future__ import annotations

import numpy as np

from ..media.stack import last_objects
from ..scene import ALL_SETS
from .selection import Choice

BIT = np.uint64(1)   # the lowest set bit, shifted to a set's place in a mask


def reaches(masks: np.ndarray, sets: np.ndarray) -> np.ndarray:
    """(n,) bool: set sets[i] is in mask masks[i] (both broadcast)."""
    return ((np.asarray(masks, np.uint64) >> np.asarray(sets).astype(np.uint64)) & BIT) != 0


def set_groups(sets: np.ndarray):
    """(set, indices) for each distinct value of sets (n,), in increasing order."""
    values = np.unique(sets)
    if len(values) == 1:
        return [(int(values[0]), np.arange(len(sets)))]
    return [(int(v), np.flatnonzero(sets == v)) for v in values]


def object_links(scene) -> "ObjectLinks | None":
    """The scene's ObjectLinks, or None when nothing links (no object row, no lamp)."""
    lights = scene.lights
    if scene.light_links is None and lights.light_sets is None and lights.shadow_sets is None:
        return None
    return ObjectLinks(scene)


class ObjectLinks:
    """The linking of the object rows (kernels.scene.LightLinks, or all rows linked nowhere) and of the lamps:
    receiver, blocker (K,) uint8; light_sets, shadow_sets (K,) uint64 per object row as an emitter; lamp_light,
    lamp_shadow (L,) uint64 per lamp."""

    def __init__(self, scene):
        links, lights = scene.light_links, scene.lights
        # Without an object table every triangle is row 0 (rows()): one row linked nowhere.
        k = 1 if scene.objects is None or not len(scene.objects) else len(scene.objects)
        if links is None:
            self.receiver, self.blocker = np.zeros(k, np.uint8), np.zeros(k, np.uint8)
            self.light_sets, self.shadow_sets = np.full(k, ALL_SETS), np.full(k, ALL_SETS)
        else:
            self.receiver, self.blocker = links.receiver, links.blocker
            self.light_sets, self.shadow_sets = links.light_sets, links.shadow_sets
        all_lamps = np.full(lights.count, ALL_SETS)
        self.lamp_light = all_lamps if lights.light_sets is None else lights.light_sets
        self.lamp_shadow = all_lamps if lights.shadow_sets is None else lights.shadow_sets
        # Some object's emission is blocked by some objects only: its BSDF rays' light takes dedicated rays.
        self.shadow_linked_rows = self.shadow_sets != ALL_SETS
        self.shadow_linking = bool(self.shadow_linked_rows.any() or (self.lamp_shadow != ALL_SETS).any())

    def rows(self, triangles, prim: np.ndarray) -> np.ndarray:
        """(n,) object rows of the triangles prim (row 0 without an object table)."""
        rows = triangles.object_rows(prim)
        return np.zeros(len(prim), np.int32) if rows is None else rows

    def receivers(self, triangles, prim: np.ndarray) -> np.ndarray:
        """(n,) uint8 light set of the objects of the triangles prim."""
        return np.take(self.receiver, self.rows(triangles, prim))

    def lit(self, rows: np.ndarray, receiver: np.ndarray) -> np.ndarray:
        """(n,) bool: the emission of objects rows reaches receivers in sets receiver and is not left to
        dedicated light rays (shadow-linked): what a BSDF ray counts of an emissive object it meets."""
        return reaches(np.take(self.light_sets, rows), receiver) & ~np.take(self.shadow_linked_rows, rows)

    def passes(self, prim_rows: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """(n,) bool: objects rows do not block shadow rays toward emitters of shadow masks `masks`."""
        return ~reaches(masks, np.take(self.blocker, prim_rows))


def medium_receivers(tables, stacks: np.ndarray) -> np.ndarray:
    """(n,) uint8 light sets of points inside media, stacks (K, n) of medium ids: the set of their object
    (media.stack.last_objects; Cycles' volume light samples take the shading point's object as receiver,
    kernel/integrator/shade_volume.h), 0 for the world's fog and for points in no medium."""
    rows = last_objects(tables.media, stacks)
    receiver = tables.links.receiver
    return np.where(rows >= 0, np.take(receiver, np.maximum(rows, 0)), 0).astype(np.uint8)


def media_emission_reaches(tables, stacks: np.ndarray, receiver: np.ndarray) -> np.ndarray:
    """(n,) bool: what the media of stacks (K, n) emit along a ray is counted by a path whose ray left an object
    in light set receiver (n,). Volume emission is no light in Cycles (only a Surface output's emission is
    sampled: scene/shader.cpp estimate_emission), so only the rays that cross it find it, and it is written
    only where the emitting object, the last on the stack (media.stack.last_objects), reaches the receiver
    of the ray (kernel/integrator/shade_volume.h: light_link_object_match(light_link_receiver_forward,
    sd->object)); camera rays are the world's object, set 0. The world's fog is no object: it reaches every
    set."""
    rows = last_objects(tables.media, stacks)
    masks = np.take(tables.links.light_sets, np.maximum(rows, 0))
    return (rows < 0) | reaches(masks, receiver)


class EmitterLinks:
    """The light sampler's view of linking: per emitter (lamps, emissive triangles, the world) its light and
    shadow masks, and per light set that receivers use a Choice among the emitters that reach it (set 0
    always: objects linked nowhere, the world's volume)."""

    def __init__(self, sampler, objects: ObjectLinks, scene, power: np.ndarray, tri_rows: np.ndarray):
        rows = np.asarray(tri_rows, np.int64)
        world = np.full(1, ALL_SETS)
        self.light = np.concatenate([objects.lamp_light, np.take(objects.light_sets, rows), world])
        self.shadow = np.concatenate([objects.lamp_shadow, np.take(objects.shadow_sets, rows), world])
        self.shadow_linked = self.shadow != ALL_SETS
        used = np.union1d(np.unique(objects.receiver), [0]).astype(np.int64)
        self.choices = {int(s): Choice(sampler, np.where(reaches(self.light, s), power, 0.0), scene, sampler.light_tree)
                        for s in used}

    def choice(self, s: int) -> Choice:
        """The Choice of light set s (a set no receiver uses falls back to set 0's)."""
        return self.choices.get(int(s), self.choices[0])

    def pmf(self, emitter: int, receiver: np.ndarray) -> np.ndarray:
        """(n,) float32 global pmf of one distant emitter (a sun, the world) for receivers in sets receiver."""
        out = np.empty(len(receiver), np.float32)
        for s, idx in set_groups(receiver):
            out[idx] = self.choice(s).pmf32[emitter]
        return out
