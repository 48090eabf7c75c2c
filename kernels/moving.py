"""Moving and deforming triangles for motion blur (kernels.accel.Accel's second queries): a moving object's triangles
in object space in their own Embree scene, rays moved into it at their time; deforming triangles (their corners at
each motion step) as Embree's time steps, traced by packets that carry each ray's time."""
from __future__ import annotations

import numpy as np
from embreex import mesh_construction, rtcore_scene

from . import embree, motion


class Moving:
    """One moving object for motion blur: its triangles in object space in their own Embree scene, and
    its motion. A ray at time t is moved into the object's space at t (interpolated as Cycles does)
    without normalising its direction, so the hit distance is the world's.

    Deforming triangles (deformation motion blur) carry steps, (S, n, 3, 3) their corners at S times over the
    shutter in the space of the stored positions: their scene is Embree's triangles with time steps
    (kernels.embree, as Cycles' motion triangles), traced by packets that carry each ray's time. keys None: the
    triangles deform in place (no transform motion), the rays stay as they are."""

    def __init__(self, ids: np.ndarray, positions: np.ndarray, keys: np.ndarray | None,
                 reference: np.ndarray | None, steps: np.ndarray | None = None, device=None):
        self.ids = ids.astype(np.int32)
        self.motion = None if keys is None else motion.decompose(np.asarray(keys, np.float64))
        corners = positions[ids] if steps is None else steps
        if keys is None:
            local = np.asarray(corners, np.float64)
        else:
            object_from_world = np.linalg.inv(np.asarray(reference, np.float64))
            local = np.asarray(corners, np.float64) @ object_from_world[:3, :3].T + object_from_world[:3, 3]
        if steps is None:
            self.scene = rtcore_scene.EmbreeScene(robust=True)
            mesh_construction.TriangleMesh(self.scene, np.ascontiguousarray(local, np.float32))
            self.timed = False
        else:
            local32 = np.ascontiguousarray(local, np.float32).reshape(len(steps), -1, 3)
            self.embree = embree.Scene(device, embree.Triangles(local32[0], steps=local32))
            self.scene = PacketQueries(self.embree)
            self.timed = True
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
        """embreex's run() on the object's scene, the rays' times (n,) given to a scene with time steps."""
        if occluded:
            if self.timed:
                return self.scene.run(o, d, dists=dists, query="OCCLUDED", times=times)
            return self.scene.run(o, d, dists=dists, query="OCCLUDED", output=None)
        if self.timed:
            return self.scene.run(o, d, dists=dists, output=1, times=times)
        return self.scene.run(o, d, dists=dists, output=1)

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
