"""Light groups (View Layer > Light Groups): which emitter each contribution to the image came from, so that its
light also goes to its group's pass (kernels.passes, "lightgroup:<k>"; Blender's Combined_<name>), as Cycles
writes its light group passes (kernel/film/light_passes.h: film_write_direct_light and
film_write_emission_or_background_pass take the emitter's group). The emitter of each accumulation, as Cycles
knows it:
- next-event estimation, at surfaces and in media: the light sample's emitter (ls->group,
  kernel/light/light.h and triangle.h, carried by the shadow ray: integrator/shade_surface.h);
- emission met by a ray: the object hit (shade_surface.h integrate_surface_emission);
- lamps met by BSDF rays: the lamp (shade_light.h);
- rays that leave the scene: the world, and each sun disc they look into (shade_background.h);
- volume emission: the object of the medium (shade_volume.h), none for the world's fog;
- shadow linking's dedicated rays: the emitter they picked (shade_dedicated_light.h).
The contribution goes to the pass with the path's throughput, MIS weight and clamping, as it goes to Combined;
emitters in no group add to Combined only, so the groups' passes and the light of ungrouped emitters add up
to Combined. Emitters are in the groups of their objects (lamps and instances: the instancer's when their own
is empty, Blender's intern/cycles/blender/object.cpp and light.cpp), the world in the World's group
(blender/sync.cpp sync_background): engine/export/light_groups.py reads them.

Nothing here runs unless the render records a group's pass (the integrator's wave.groups), so renders without
light groups do not change.
"""
from __future__ import annotations

import numpy as np

from . import passes
from .media.stack import last_objects
from .scene import NO_GROUP


def emitter_groups(scene, light_count: int, tri_rows) -> np.ndarray | None:
    """(L + E + 1,) int32 the group of each emitter of a LightSampler (lamps, emissive triangles whose object rows
    tri_rows() gives, the world), or None when none is in a group."""
    lamps, groups = scene.lights.light_groups, scene.light_groups
    if lamps is None and groups is None:
        return None
    lamp = np.full(light_count, NO_GROUP, np.int32) if lamps is None else lamps.astype(np.int32)
    if groups is None:
        tri, world = np.full(len(tri_rows()), NO_GROUP, np.int32), NO_GROUP
    else:
        rows = tri_rows()
        tri = np.take(groups.objects, rows) if len(groups.objects) else np.full(len(rows), NO_GROUP, np.int32)
        world = int(groups.world)
    out = np.concatenate([lamp, tri.astype(np.int32), np.array([world], np.int32)])
    return None if (out == NO_GROUP).all() else out


def world_group(tables) -> int:
    """The world's group (NO_GROUP without one)."""
    groups = tables.scene.light_groups
    return NO_GROUP if groups is None else int(groups.world)


def lamp_groups(tables, lamps: np.ndarray):
    """(n,) int32 groups of the lamps `lamps` (one NO_GROUP when none has one)."""
    groups = tables.lights.groups
    return NO_GROUP if groups is None else np.take(groups, lamps)


def of_samples(tables, ls, rows: np.ndarray):
    """(n,) int32 groups of the emitters the light samples rows of ls (LightSample) chose, one NO_GROUP when no
    emitter is in a group."""
    groups = tables.lights.groups
    return NO_GROUP if groups is None else np.take(groups, np.take(ls.emitter, rows))


def of_objects(tables, rows: np.ndarray):
    """(n,) int32 groups of the object rows `rows` (one NO_GROUP when no object is in one)."""
    groups = tables.scene.light_groups
    if groups is None or not len(groups.objects):
        return NO_GROUP
    return np.take(groups.objects, rows)


def of_triangles(tables, prim: np.ndarray):
    """(n,) int32 groups of the objects of the triangles prim (emission met by rays)."""
    rows = tables.triangles.object_rows(prim)
    return NO_GROUP if rows is None else of_objects(tables, rows)


def of_media(tables, stacks: np.ndarray):
    """(n,) int32 groups of the emission of points inside media, stacks (K, n) of medium ids: the object of the
    last medium on each stack (media.stack.last_objects: the one whose shading Cycles' volume emission is
    written with), NO_GROUP for the world's fog and points in no medium."""
    groups = tables.scene.light_groups
    if groups is None or not len(groups.objects):
        return NO_GROUP
    rows = last_objects(tables.media, stacks)
    return np.where(rows >= 0, np.take(groups.objects, np.maximum(rows, 0)), NO_GROUP).astype(np.int32)


def sky_parts(tables, world: np.ndarray | None, suns: list, columns: np.ndarray | None = None) -> list:
    """passes.write_parts' parts of light from the sky: the world's (3, n) (None: none) and the sun discs'
    (suns: sun.seen's parts, (lamp, columns, (3, m))); columns: the sun parts' columns among the n (None: theirs)."""
    parts = [] if world is None else [(None, world_group(tables), world)]
    for lamp, cols, value in suns:
        parts.append((cols if columns is None else columns[cols], lamp_groups(tables, lamp), value))
    return parts


def write(wave, paths: np.ndarray, value: np.ndarray, groups) -> None:
    """passes.write_groups, when the wave records groups."""
    if wave.groups is not None:
        passes.write_groups(wave, paths, value, groups)
