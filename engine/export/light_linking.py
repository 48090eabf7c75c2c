"""Light and shadow linking (Object > Shading > Light Linking and Shadow Linking, Blender 4.0+): the light set
each object receives in and the shadow set it blocks in, and the sets each emitter (a light, an emissive
object) reaches and is blocked by: the numbers Cycles' sync reads (intern/cycles/blender/light_linking.cpp).

Blender's depsgraph computes them (source/blender/depsgraph/intern/depsgraph_light_linking.cc) and RNA does
not show them, so they are computed here by its rules, for receivers (an emitter's receiver collection) and
blockers (its blocker collection) alike:
- each distinct linking collection on an emitter gets a bit of its own (at most 64; emitters sharing one
  share it);
- every object of such a collection, and of its child collections (where the state of the child directly
  under the linking collection counts), is included in or excluded from it (the last mention wins);
- each distinct (included bits, excluded bits) pair of an object is a set, numbered 1 to 63 (an object
  mentioned nowhere is in set 0, as is one past the 63rd set);
- an emitter's membership is the sets that include its collection (every set where none does), less the
  sets that exclude it; an emitter without a linking collection is in every set;
- an instance receives (blocks) in its instancer's set where that is not 0, else in its object's own.
An emitter lights an object when the object's receiver set is in the emitter's light membership
(kernel/light/light.h light_link_object_match), and an object blocks an emitter's light when its blocker
set is in the emitter's shadow membership (kernel/bvh/util.h intersection_skip_shadow_link). The world is
not an object: it lights everything, and everything blocks it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ...kernels.scene import ALL_SETS, LightLinks

# Bits of a light set or emitter mask (Blender's LightSet::MAX_ID + 1, EmitterData::MAX_COLLECTION_ID + 1).
MAX_SETS = 64
KINDS = (("receiver_collection", "Light Linking"), ("blocker_collection", "Shadow Linking"))


@dataclass
class _Linking:
    """One kind of linking (receivers of light, or blockers of it): per object, its set; per linking
    collection, the sets it reaches."""
    sets: dict = field(default_factory=dict)          # object name -> set number (1..63)
    membership: dict = field(default_factory=dict)    # collection name -> mask of sets (int)


@dataclass
class LinkTable:
    """The scene's light and shadow linking: for objects by name (original objects), their sets; for emitters,
    the masks of the collections they link. Empty (used False) when nothing links."""
    light: _Linking = field(default_factory=_Linking)
    shadow: _Linking = field(default_factory=_Linking)
    emitters: dict = field(default_factory=dict)      # object name -> (receiver collection, blocker collection)
    warnings: list = field(default_factory=list)

    @property
    def used(self) -> bool:
        return bool(self.emitters)

    def signature(self) -> tuple:
        """What a change of linking would change: the viewport's partial updates compare it."""
        return (tuple(sorted(self.light.sets.items())), tuple(sorted(self.shadow.sets.items())),
                tuple(sorted(self.light.membership.items())), tuple(sorted(self.shadow.membership.items())),
                tuple(sorted(self.emitters.items())))

    def object_sets(self, ob, parent=None) -> tuple[int, int]:
        """(receiver set, blocker set) of an object, or of an instance of it made by `parent` (the instancer's
        sets win where they are not 0: BlenderLightLink::get_receiver_light_set)."""
        out = []
        for linking in (self.light, self.shadow):
            own = linking.sets.get(ob.original.name_full, 0)
            if parent is not None:
                own = linking.sets.get(parent.original.name_full, 0) or own
            out.append(own)
        return out[0], out[1]

    def row(self, ob, parent=None) -> tuple[int, int, int, int]:
        """An object row's (receiver set, blocker set, light membership, shadow membership) (light_links)."""
        return (*self.object_sets(ob, parent), *self.memberships(ob))

    def memberships(self, ob) -> tuple[int, int]:
        """(light membership, shadow membership) of an emitter object: the masks of sets its light reaches and
        whose objects block it."""
        receiver, blocker = self.emitters.get(ob.original.name_full, (None, None))
        return (self.light.membership.get(receiver, ALL_MASK) if receiver is not None else ALL_MASK,
                self.shadow.membership.get(blocker, ALL_MASK) if blocker is not None else ALL_MASK)


ALL_MASK = int(ALL_SETS)


def link_table(depsgraph) -> LinkTable:
    """The linking of every object of the depsgraph that has a Light or Shadow Linking collection."""
    table = LinkTable()
    collections = {}                                   # collection name -> the collection (original)
    for ob in _emitters(depsgraph):
        names = []
        for attribute, _ in KINDS:
            c = getattr(ob.light_linking, attribute)
            names.append(None if c is None else c.name_full)
            if c is not None:
                collections[c.name_full] = c
        table.emitters[ob.name_full] = tuple(names)
    if not table.used:
        return table
    for kind, (attribute, label) in enumerate(KINDS):
        linked = sorted({names[kind] for names in table.emitters.values() if names[kind] is not None})
        if len(linked) > MAX_SETS:
            table.warnings.append(f"{label}: more than {MAX_SETS} linking collections; those past the "
                                  f"{MAX_SETS}th by name are ignored (Blender too ignores some): "
                                  + ", ".join(f"'{n}'" for n in linked[MAX_SETS:]))
            linked = linked[:MAX_SETS]
        bits = {name: 1 << i for i, name in enumerate(linked)}
        _build(table.light if kind == 0 else table.shadow, bits, collections, label, table.warnings)
    return table


def _emitters(depsgraph) -> list:
    """The original objects of the depsgraph with a linking collection, by name. Only objects refer to a
    collection through Light Linking (or instance it), and Blender's user map finds them in C: 10,000 objects
    take 6 ms, where reading every object's linking from Python took 50. Without collections, nothing links."""
    collections = bpy.data.collections
    if not len(collections):
        return []
    users = bpy.data.user_map(subset=collections, value_types={"OBJECT"})
    found = []
    for ob in sorted({ob for objects in users.values() for ob in objects}, key=lambda ob: ob.name_full):
        linking = getattr(ob, "light_linking", None)
        if linking is None or (linking.receiver_collection is None and linking.blocker_collection is None):
            continue
        if ob.evaluated_get(depsgraph).is_evaluated:   # an object of this depsgraph (not hidden, not unused)
            found.append(ob)
    return found


def _build(linking: _Linking, bits: dict, collections: dict, label: str, warnings: list) -> None:
    """Sets of the objects the linking collections name, and each collection's membership mask."""
    include: dict[str, int] = {}
    exclude: dict[str, int] = {}
    for name, bit in bits.items():
        for ob, state in _linked_objects(collections[name]):
            key = ob.name_full
            include.setdefault(key, 0)
            exclude.setdefault(key, 0)
            if state == "INCLUDE":
                include[key] |= bit
                exclude[key] &= ~bit
            else:
                exclude[key] |= bit
                include[key] &= ~bit
    numbers: dict[tuple, int] = {}
    dropped = []
    for key in include:
        pair = (include[key], exclude[key])
        number = numbers.setdefault(pair, len(numbers) + 1)
        if number >= MAX_SETS:
            dropped.append(key)
            continue
        linking.sets[key] = number
    if dropped:
        warnings.append(f"{label}: more than {MAX_SETS - 1} distinct sets of linked objects; these are linked as "
                        f"if they were in no collection (Blender too leaves those past its limit so): "
                        + ", ".join(f"'{n}'" for n in dropped))
    included = dict.fromkeys(bits, 0)
    excluded = dict.fromkeys(bits, 0)
    for (inc, exc), number in numbers.items():
        if number >= MAX_SETS:
            continue
        for name, bit in bits.items():
            if inc & bit:
                included[name] |= 1 << number
            if exc & bit:
                excluded[name] |= 1 << number
    for name in bits:
        linking.membership[name] = (included[name] or ALL_MASK) & ~excluded[name] & ALL_MASK


def _linked_objects(collection):
    """(object, link state) of every object the linking collection names, in Blender's order: each child
    collection's objects (recursively, with the state of the child directly under `collection`), then its own
    objects with theirs. collection_children and collection_objects list the children and objects in the
    order of `children` and `objects`: the same lists (source/blender/makesrna/intern/rna_collection.cc)."""
    for child, entry in zip(collection.children, collection.collection_children):
        state = entry.light_linking.link_state
        for ob in child.all_objects:
            yield ob, state
    for ob, entry in zip(collection.objects, collection.collection_objects):
        yield ob, entry.light_linking.link_state


def light_links(rows: list | None) -> LightLinks | None:
    """kernels.scene.LightLinks of the object rows (per row: (receiver set, blocker set, light membership,
    shadow membership)); None when every row is linked nowhere and lights and shadows everything (then no
    stage of the kernel looks further)."""
    if not rows or all(r[0] == 0 and r[1] == 0 and r[2] == ALL_MASK and r[3] == ALL_MASK for r in rows):
        return None
    k = len(rows)
    sets = np.array([r[:2] for r in rows], np.uint8).reshape(k, 2)
    masks = np.array([r[2:] for r in rows], np.uint64).reshape(k, 2)
    return LightLinks(receiver=sets[:, 0].copy(), blocker=sets[:, 1].copy(), light_sets=masks[:, 0].copy(),
                      shadow_sets=masks[:, 1].copy())


def lamp_masks(masks: list) -> tuple:
    """(light_sets, shadow_sets) of kernels.scene.Lights from each light's (light membership, shadow
    membership): (L,) uint64 each, or None where every light's is every set."""
    out = []
    for k in range(2):
        column = [m[k] for m in masks]
        out.append(None if all(v == ALL_MASK for v in column) else np.array(column, np.uint64))
    return tuple(out)
