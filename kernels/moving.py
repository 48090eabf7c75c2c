"""Moving and deforming triangles for motion blur (kernels.accel.Accel's second queries): the objects that move
rigidly as instances of their object-space triangles in one Embree scene, each instance's transform moving over the
shutter (MovingObjects); an object that also deforms in its own Embree scene, rays moved into it at their time;
deforming triangles (their corners at each motion step) as Embree's time steps, traced by packets that carry each
ray's time."""
from __future__ import annotations

import numpy as np

from . import embree, motion


class MovingObjects:
    """The objects that move rigidly (transform motion blur), traced as Cycles traces them: each object's triangles
    once in object space (a BVH of its own), placed in one Embree scene by an instance whose transform moves over
    the shutter, Embree interpolating its quaternion decomposition at each ray's time (embree.quaternion_steps, as
    Cycles' add_instance). A query is one traversal of that scene, whatever the number of objects: a particle
    system's hundreds of moving instances cost what one object does.

    objects: (ids, keys, reference) per object: the scene triangles ids (their world positions made with the
    (4, 4) matrix reference), keys (K, 4, 4) its world_from_object over the shutter."""

    def __init__(self, device, positions: np.ndarray, objects):
        placed, ids = [], []
        decomposed = motion.decompose_many([np.asarray(keys, np.float64) for _, keys, _ in objects])
        for (obj_ids, _, reference), steps in zip(objects, decomposed):
            object_from_world = np.linalg.inv(np.asarray(reference, np.float64))
            local = np.asarray(positions[obj_ids], np.float64) @ object_from_world[:3, :3].T + object_from_world[:3, 3]
            mesh = embree.Mesh(device, np.ascontiguousarray(local.reshape(-1, 3), np.float32))
            placed.append((mesh, np.eye(4), steps))
            ids.append(np.asarray(obj_ids, np.int64))
        self.scene = embree.Scene(device, None, placed)
        self.ids = np.concatenate(ids).astype(np.int32)
        self.first = np.cumsum([0] + [len(i) for i in ids[:-1]]).astype(np.int64)

    def intersect(self, origins, directions, t_max, times):
        """(prim, t, u, v) of the closest hits within t_max at the rays' times (N,) in [0, 1]: prim the scene
        triangle, -1 (t = t_max) for a miss."""
        p, inst, t, u, v = self.scene.intersect(origins, directions, t_max, times=times)
        hit = p >= 0
        prim = np.full(len(p), -1, np.int32)
        prim[hit] = self.ids[self.first[inst[hit]] + p[hit]]
        return prim, t, u, v

    def occluded(self, origins, directions, t_max, times) -> np.ndarray:
        return self.scene.occluded(origins, directions, t_max, times=times)


class Moving:
    """One deforming object for motion blur (deformation motion blur, with or without transform motion): steps,
    (S, n, 3, 3) its triangles' corners at S times over the shutter in the space of the stored positions, are
    Embree's triangles with time steps (kernels.embree, as Cycles' motion triangles) in a scene of their own,
    traced by packets that carry each ray's time. With keys (transform motion too) the steps are held in object
    space and a ray at time t is moved into the object's space at t (interpolated as Cycles does) without
    normalising its direction, so the hit distance is the world's; keys None: the triangles deform in place,
    the rays stay as they are."""

    def __init__(self, ids: np.ndarray, keys: np.ndarray | None, reference: np.ndarray | None, steps: np.ndarray,
                 device):
        self.ids = ids.astype(np.int32)
        self.motion = None if keys is None else motion.decompose(np.asarray(keys, np.float64))
        if keys is None:
            local = np.asarray(steps, np.float64)
        else:
            object_from_world = np.linalg.inv(np.asarray(reference, np.float64))
            local = np.asarray(steps, np.float64) @ object_from_world[:3, :3].T + object_from_world[:3, 3]
        local32 = np.ascontiguousarray(local, np.float32).reshape(len(steps), -1, 3)
        self.embree = embree.Scene(device, embree.Triangles(local32[0], steps=local32))
        self.scene = PacketQueries(self.embree)
        # A world box the object never leaves during the shutter: its pivot moves within the keys' pivots
        # (translation is lerped) and no point of it strays further from the pivot than at a key (rotation
        # keeps lengths; the lerped scale is a convex mix); deforming corners stay within their steps' box.
        # Rays that miss the box skip the object.
        corners = np.asarray(local, np.float64).reshape(-1, 3)
        if keys is None:
            self.lo = (corners.min(axis=0) - (np.abs(corners).max() * 1e-5 + 1e-6)).astype(np.float32)
            self.hi = (corners.max(axis=0) + (np.abs(corners).max() * 1e-5 + 1e-6)).astype(np.float32)
            return
        keys = np.asarray(keys, np.float64)
        reach = max(float(np.linalg.norm(corners @ k[:3, :3].T, axis=1).max()) for k in keys)
        reach = reach * (1 + 1e-5) + 1e-6
        self.lo = (keys[:, :3, 3].min(axis=0) - reach).astype(np.float32)
        self.hi = (keys[:, :3, 3].max(axis=0) + reach).astype(np.float32)

    def query(self, o, d, dists, times, occluded: bool = False):
        """embreex's run() interface on the object's scene at the rays' times (n,)."""
        if occluded:
            return self.scene.run(o, d, dists=dists, query="OCCLUDED", times=times)
        return self.scene.run(o, d, dists=dists, output=1, times=times)

    def crossing(self, origins, directions, t_max) -> np.ndarray:
        """Indices of the rays whose segment [0, t_max] meets the object's box (slab test)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.float32(1.0) / directions
            t0 = (self.lo - origins) * inv
            t1 = (self.hi - origins) * inv
        near = np.nan_to_num(np.minimum(t0, t1), nan=-np.inf).max(axis=1)
        far = np.nan_to_num(np.maximum(t0, t1), nan=np.inf).min(axis=1)
        return np.flatnonzero((near <= far) & (far >= 0) & (near <= t_max))

    def rays(self, origins, directions, time, sel):
        """The rays sel in object space at their times (RayTimes or (n,) times): (origins, directions)
        float32, (len(sel), 3)."""

        def make(t):
            return motion.affine_inverse(motion.interpolate(self.motion, t)).astype(np.float32)
        if self.motion is None:
            return (np.ascontiguousarray(np.take(origins, sel, axis=0), np.float32),
                    np.ascontiguousarray(np.take(directions, sel, axis=0), np.float32))
        if hasattr(time, "cached"):   # kernels.accel.RayTimes: once per path
            inverse = np.take(time.cached(("inverse", id(self)), make), sel, axis=0)
        else:
            inverse = make(np.take(time, sel))
        origins, directions = np.take(origins, sel, axis=0), np.take(directions, sel, axis=0)
        linear = inverse[:, :, :3]
        o = np.einsum("nij,nj->ni", linear, origins) + inverse[:, :, 3]
        d = np.einsum("nij,nj->ni", linear, directions)
        return np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32)


def steps_of(deform, ids: np.ndarray) -> np.ndarray | None:
    """(S, n, 3, 3) the deformation steps of triangles ids when every one of them deforms, else None."""
    if deform is None:
        return None
    columns = np.take(deform[0], ids)
    if (columns < 0).any():
        return None
    return np.take(deform[1], columns, axis=1)


def selected_times(time, sel: np.ndarray) -> np.ndarray:
    """(len(sel),) float32 the shutter times of rays sel (RayTimes or an array; 0.5 when none are given)."""
    if time is None:
        return np.full(len(sel), 0.5, np.float32)
    times = getattr(time, "times", time)   # kernels.accel.RayTimes, or an array
    return np.ascontiguousarray(np.take(times, sel), np.float32)


class PacketQueries:
    """embreex's run() interface over kernels.embree packets, where embreex cannot trace our scenes."""

    def __init__(self, scene: "embree.Scene"):
        self._scene = scene

    def run(self, origins, directions, dists=None, query="INTERSECT", output=None, times=None):
        if query == "OCCLUDED":
            return np.where(self._scene.occluded(origins, directions, dists, times), 0, -1).astype(np.int32)
        prim, _, t, u, v = self._scene.intersect(origins, directions, dists, times=times)
        return {"primID": prim, "tfar": t, "u": u, "v": v}
