"""Object ray visibility and holdout: which rays may hit an object (Object > Visibility > Ray Visibility,
indirect-only collections) and which objects cut a hole in the film where the camera sees them.

Cycles gives every object a mask of ray types (scene/object.cpp, kobject.visibility) and every ray the
type of the bounce that sent it (integrator/path_state.h, path_state_next): a camera ray, and a ray
that only passed transparent surfaces since, is CAMERA; after a bounce, TRANSMIT for a transmission,
else DIFFUSE or GLOSSY (singular counts as glossy), VOLUME_SCATTER after a scatter in a medium; shadow
rays are SHADOW. Its BVH skips objects whose mask lacks the ray's type. Here the closest hit is traced as
usual and, where the object it found does not see that type of ray, traced again from just past it, as
the transparent shadow loop steps past transparent surfaces (kernels/lights/nee.py). The rays of a shadow
catcher's own paths see shadow catchers only (kernels/shadow_catcher.py), which the same step past does.
the transparent shadow loop steps past transparent surfaces (kernels/lights/nee.py). Rays leaving a curve or
a point step past that curve or point the same way (kernels/geometry/primitives.py).
"""
from __future__ import annotations

import numpy as np

from .accel import Hits
from .interaction import spawn_offset
from .paths import DIFFUSE, TRANSMIT, VOLUME_SCATTER as SCATTER_LABEL
from .scene.objects import (ALL_RAYS, HOLDOUT, RAY_CAMERA as CAMERA, RAY_DIFFUSE as DIFFUSE_RAY,
                            RAY_GLOSSY as GLOSSY_RAY, RAY_SCATTER as SCATTER_RAY, RAY_SHADOW as SHADOW,
                            RAY_TRANSMIT as TRANSMIT_RAY, SHADOW_CATCHER)

# A ray steps past at most this many objects that do not see it (or hits on its own curve), as a safeguard
# (each is one more query).
MAX_SKIPS = 64


def object_visibility(scene) -> np.ndarray | None:
    """(K,) uint8 per row of the object table (SceneArrays.object_visibility), or None when every object is
    seen by every ray and none is a holdout or a shadow catcher: then nothing here runs and images stay as
    they were."""
    vis = scene.object_visibility
    if vis is None or scene.objects is None or not len(vis) or (vis == ALL_RAYS).all():
        return None
    return np.asarray(vis, np.uint8)


def ray_types(state, first: bool) -> np.ndarray:
    """(N,) uint8: the visibility bit of each path's current ray. A path still on its camera ray (bounce 0:
    only transparent surfaces passed) is CAMERA; else the label of its last bounce (PathState.lobes)."""
    n = len(state)
    if first or state.lobes is None:
        return np.full(n, CAMERA, np.uint8)
    label = state.lobes[0]
    kind = np.where((label & SCATTER_LABEL) != 0, SCATTER_RAY,
                    np.where((label & TRANSMIT) != 0, TRANSMIT_RAY,
                             np.where((label & DIFFUSE) != 0, DIFFUSE_RAY, GLOSSY_RAY)))
    return np.where(state.bounce == 0, CAMERA, kind).astype(np.uint8)


def hidden(tables, prim: np.ndarray, types, catchers_only: bool = False) -> np.ndarray:
    """(n,) bool: the hits prim (all >= 0) are on objects that rays of `types` ((n,) or one uint8) do not see,
    or, for catchers_only rays (a shadow catcher's own paths), that are no shadow catchers."""
    vis = np.take(tables.visibility, tables.triangles.object_rows(prim))
    unseen = (vis & types) == 0
    if catchers_only:
        unseen |= (vis & SHADOW_CATCHER) == 0
    return unseen


def holdouts(tables, prim: np.ndarray) -> np.ndarray:
    """(n,) bool: the hits prim are on holdout objects."""
    return (np.take(tables.visibility, tables.triangles.object_rows(prim)) & HOLDOUT) != 0


def skip_hidden(tables, origins, dirs, t_max, hits: Hits, types, split: bool = True, times=None, keys=None,
                catchers_only: bool = False, rule=None) -> Hits:
    """The closest hits of the rays among objects that see them: where `hits` (from tables.accel.intersect of
    the same rays) found an object that rays of `types` ((N,) uint8, or one value; None: every object sees them)
    do not see (or, with catchers_only, no shadow catcher), or that rule(prim, rows) turns down (a skip_hits
    test, or None), the ray is traced again from just past that hit. keys: (N,) int64 the curve or point each
    ray leaves (PrimitiveTable.self_keys, -1 none), or None: hits on it are stepped past too, as Cycles' rays
    skip the primitive they leave. t stays the distance from the ray's own origin. Changes hits."""
    tests = []
    if types is not None:
        types = np.broadcast_to(np.asarray(types, np.uint8), (len(origins),))
        tests.append(lambda prim, rows: hidden(tables, prim, types[rows], catchers_only))
    if rule is not None:
        tests.append(rule)
    swap = None
    if keys is not None:
        tests.append(_own_primitive(tables, keys))
        swap = _twin(tables, keys)
    if not tests:
        return hits
    if len(tests) == 1:
        return skip_hits(tables, origins, dirs, t_max, hits, tests[0], split, times, swap)

    def reject(prim, rows):
        out = tests[0](prim, rows)
        for test in tests[1:]:
            out = out | test(prim, rows)
        return out
    return skip_hits(tables, origins, dirs, t_max, hits, reject, split, times, swap)


def _own_primitive(tables, keys: np.ndarray):
    """A skip_hits test: hits on the curve or point each ray left (keys per ray, -1 none)."""
    def reject(prim, rows):
        mine = np.take(keys, rows)
        out = mine >= 0
        if out.any():
            sel = np.flatnonzero(out)
            out[sel] = tables.triangles.self_keys(np.take(prim, sel)) == np.take(mine, sel)
        return out
    return reject


def _twin(tables, keys: np.ndarray):
    """A skip_hits swap: a hit on the curve or point a ray left, where an exact copy of it lies (PrimitiveTable.
    twins), becomes a hit on the copy at the same place. Cycles' Embree filter turns the ray's own primitive down
    and goes on to the copy at the very same distance; stepping past the hit would miss the copy."""
    if not tables.triangles.has_twins:
        return None

    def swap(prim, rows):
        mine = np.take(keys, rows)
        sel = np.flatnonzero(mine >= 0)
        if not len(sel):
            return prim
        own = tables.triangles.self_keys(np.take(prim, sel)) == np.take(mine, sel)
        sel = sel[own]
        if len(sel):
            twin = tables.triangles.twin_prims(np.take(prim, sel))
            found = twin >= 0
            prim = prim.copy()
            prim[sel[found]] = twin[found]
        return prim
    return swap


def skip_hits(tables, origins, dirs, t_max, hits: Hits, reject, split: bool = True, times=None, swap=None) -> Hits:
    """The closest hits of the rays but those reject(prim, rows) turns down ((m,) bool for the hits prim of the
    rays rows): each such ray is traced again from just past its hit, at most MAX_SKIPS times (then nothing is
    found). swap(prim, rows), if given, first replaces hits by others at the same place (the hits' new prim).
    t stays the distance from the ray's own origin. Changes hits."""
    live = np.flatnonzero(hits.prim >= 0)
    if swap is not None:
        hits.prim[live] = swap(hits.prim[live], live)
    live = live[reject(hits.prim[live], live)]
    for _ in range(MAX_SKIPS):
        if not len(live):
            return hits
        o = origins[live]
        t = hits.t[live]
        step = t + spawn_offset(tables.ray_epsilon, o[:, 0], o[:, 1], o[:, 2])
        left = t_max[live] - step
        hits.prim[live] = -1
        hits.t[live] = np.inf
        go = np.flatnonzero(left > 0)
        live, step, left = live[go], step[go], left[go]
        if not len(live):
            return hits
        start = np.ascontiguousarray(origins[live] + dirs[live] * step[:, None], np.float32)
        again = tables.accel.intersect(start, np.ascontiguousarray(dirs[live]), left.astype(np.float32), split,
                                       None if times is None else times.take(live))
        found = np.flatnonzero(again.prim >= 0)
        at = live[found]
        hits.prim[at] = again.prim[found] if swap is None else swap(again.prim[found], at)
        hits.t[at] = again.t[found] + step[found]
        hits.u[at], hits.v[at] = again.u[found], again.v[found]
        live = at[reject(hits.prim[at], at)]
    hits.prim[live] = -1   # past the safeguard: nothing found
    hits.t[live] = np.inf
    return hits
