"""Rays that look only for their own object's surfaces, as Cycles' scene_intersect_local (kernel/bvh/bvh.h,
kernel/device/cpu/bvh.h: a local ray keeps the hits on one object, at most LOCAL_MAX_HITS of them, a random
subset when it meets more). The Ambient Occlusion and Bevel nodes (kernels/shading/raytrace.py) and the
Christensen-Burley disk probes (kernels/subsurface_disk.py) trace with them.
"""
from __future__ import annotations

import numpy as np

from .geometry import NG
from .interaction import spawn_offset
from .rng import keyed_uniforms
from .vec import F32, ONE, columns, dot_rows

# Cycles' LOCAL_MAX_HITS and BSSRDF_MAX_HITS (kernel/types.h): a local ray keeps a random subset of this many hits.
LOCAL_MAX_HITS = 4
# Surfaces a ray looking for its own object passes at most (other objects' surfaces, or its own when it wants
# them all): beyond them it is taken as meeting no more.
MAX_LAYERS = 16


class LocalRays:
    """What local rays trace with: the scene's accel.Accel and geometry.TriangleTable, and the scale of the
    offset rays start with past a surface (the renderer's ray_epsilon)."""

    def __init__(self, accel, triangles, epsilon):
        self.accel, self.triangles = accel, triangles
        self.epsilon = F32(epsilon)

    def object_rows(self, prim: np.ndarray) -> np.ndarray:
        rows = self.triangles.object_rows(prim)
        return np.zeros(len(prim), np.int32) if rows is None else rows

    def offset_origins(self, p: np.ndarray, ng: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(n, 3) origins moved off the surfaces (points p, unit normals ng) to the side directions d leave on,
        as the integrator spawns rays (Cycles starts at P and skips the hit's own triangle instead)."""
        eps = spawn_offset(self.epsilon, p[:, 0], p[:, 1], p[:, 2])
        side = np.where(dot_rows(d, ng) >= 0, eps, -eps).astype(F32)
        return (p + ng * columns(side)).astype(F32)


def own_hits(rays: LocalRays, objects: np.ndarray, origins: np.ndarray, d: np.ndarray, t_max, split: bool = True,
             time=None, first_only: bool = False):
    """The hits of rays (origins, unit directions d (n, 3), lengths t_max (n,)) on each ray's own object
    (objects (n,) rows), passing the surfaces of others: per surface layer met, (rays, prim, t, u, v) of those
    on the ray's object, t from the first origin. first_only: rays stop at their first own hit. time:
    accel.RayTimes of the rays or None."""
    live = np.arange(len(origins))
    o = origins
    travelled = np.zeros(len(origins), F32)
    t_max = np.broadcast_to(np.asarray(t_max, F32), (len(origins),))
    for _ in range(MAX_LAYERS):
        if not len(live):
            return
        left = (t_max[live] - travelled[live]).astype(F32)
        met = rays.accel.intersect(o, d[live], left, split, None if time is None else time.take(live))
        found = np.flatnonzero(met.prim >= 0)
        if not len(found):
            return
        ray = live[found]
        prim = met.prim[found]
        step = met.t[found]
        t = travelled[ray] + step
        own = rays.object_rows(prim) == objects[ray]
        if own.any():
            yield ray[own], prim[own], t[own], met.u[found][own], met.v[found][own]
        go_on = ~own if first_only else np.ones(len(found), bool)
        found, ray, prim, step, t = found[go_on], ray[go_on], prim[go_on], step[go_on], t[go_on]
        # On from just past the surface met, off it on the side the ray leaves.
        point = (o[found] + d[ray] * columns(step)).astype(F32)
        o = rays.offset_origins(point, rays.triangles.rows_of(prim)[:, NG:NG + 3], d[ray])
        travelled[ray] = t
        live = ray


def pick_hits(rows: np.ndarray, count: np.ndarray, keys, sample, salt: int):
    """Which of the hits (rays `rows`, in the order met; count per ray) a local query keeps: all of a ray with
    at most LOCAL_MAX_HITS, else a uniformly random LOCAL_MAX_HITS of them (what Cycles' reservoir of local
    hits keeps), and each ray's weight: count / LOCAL_MAX_HITS where it dropped some, else 1. The choice is
    drawn from the rays' keys (x, y), `sample` (an int, or (n,) one per ray) and the rng.keyed_uniforms `salt`."""
    scale = np.where(count > LOCAL_MAX_HITS, count.astype(F32) / F32(LOCAL_MAX_HITS), ONE).astype(F32)
    keep = np.ones(len(rows), bool)
    many = np.flatnonzero(count[rows] > LOCAL_MAX_HITS)
    if not len(many):
        return keep, scale
    ray = rows[many]
    # Each hit a random number (its ray's keys and its place among the ray's hits); a ray keeps its smallest.
    by_ray = np.argsort(ray, kind="stable")
    place = np.empty(len(many), np.uint32)
    place[by_ray] = np.arange(len(many)) - np.searchsorted(ray[by_ray], ray[by_ray])
    x, y = (np.take(k, ray) for k in keys)
    if np.ndim(sample):
        sample = np.take(sample, ray).astype(np.int64)
    chance = keyed_uniforms((x ^ (place * np.uint32(0x2C1B3C6D)), y), sample, salt)[0]
    ranked = np.lexsort((chance, ray))
    rank = np.arange(len(many)) - np.searchsorted(ray[ranked], ray[ranked])
    keep[many[ranked]] = rank < LOCAL_MAX_HITS
    return keep, scale
