"""Ray queries through Embree: closest hit and occlusion, chunked over a thread pool.

The static scene is built by kernels.embree (Embree's C API through ctypes: meshes read in place, and
instances of meshes as a two-level BVH); queries that need no instance id run through embreex's `run`
loop on that scene, closest hits of a scene with instances through kernels.embree's 16-ray packets.
Both release the GIL, so chunks of one batch run in parallel on Python threads.
Traps handled here (see PERFORMANCE_NOTES): `dists` is overwritten in place, so a copy is passed;
OCCLUDED with output=1 is broken, so output=None is used (0 = occluded, -1 = visible); tnear is
always 0, so callers offset ray origins themselves.
"""
from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from . import embree, motion
from .moving import Moving, MovingObjects, PacketQueries, selected_times, steps_of
from .scene import same_arrays

# Plain triangles from this many on get Embree's quick (low-quality) BVH first, which builds several times
# faster and traces somewhat slower, so that the first samples come sooner; the render's further waves
# bring the usual (medium) BVH in the background and move to it when it is ready (Accel.refine). The
# hits are the same on either tree. The same bound as the worker processes' (schedule.WORKER_MAX_TRIANGLES).
QUICK_BVH_TRIANGLES = 1 << 18
# ... and the medium BVH is worth building only for a render with at least this many seconds left per
# plain triangle: what the faster tree saves must repay its build beside the render
# (docs/architecture.md, Big scenes).
REFINE_SECONDS_PER_TRIANGLE = 4e-6

# A ray from inside tubes or spheres steps past at most this many of their far walls (Accel._shape_hits).
BACKFACE_SKIPS = 16

# Below this many rays a batch runs as one call: splitting costs more than it saves.
_MIN_CHUNK = 8192
_CHUNKS_PER_THREAD = 4


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity (taskset, a container's cpuset), else all."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):   # no affinity on this platform
        return max(1, os.cpu_count() or 1)


def capped_threads(requested: int) -> int:
    """The threads a render runs for `requested` (0 or less: automatic): every usable core, and never more,
    since threads beyond the cores (and the worker processes that come with them) only contend."""
    cores = usable_cores()
    return cores if requested <= 0 else min(requested, cores)


class Hits:
    """Closest-hit results for N rays. prim is -1 for a miss; t is the hit distance; (u, v) are
    Embree's barycentrics of corners 1 and 2 (corner 0 has 1 - u - v)."""
    __slots__ = ("prim", "t", "u", "v")

    def __init__(self, prim: np.ndarray, t: np.ndarray, u: np.ndarray, v: np.ndarray):
        self.prim, self.t, self.u, self.v = prim, t, u, v


class RayTimes:
    """The shutter times of a batch of paths (motion blur), with what depends only on them cached: the transform
    of each object that moves and deforms (kernels.moving.Moving) at each path's time is computed once per path,
    not once per ray query."""
    __slots__ = ("times", "_cache")

    def __init__(self, times: np.ndarray):
        self.times = times
        self._cache = {}

    def take(self, idx: np.ndarray) -> "RayTimes":
        kept = RayTimes(np.take(self.times, idx))
        kept._cache = {key: tuple(np.take(v, idx, axis=0) for v in value) if isinstance(value, tuple)
                       else np.take(value, idx, axis=0) for key, value in self._cache.items()}
        return kept

    @staticmethod
    def concat(a: "RayTimes", b: "RayTimes") -> "RayTimes":
        """The times of a's paths, then b's (what is cached is made again when asked for)."""
        return RayTimes(np.concatenate([a.times, b.times]))

    def cached(self, key, make):
        value = self._cache.get(key)
        if value is None:
            value = self._cache[key] = make(self.times)
        return value


class Accel:
    """An Embree scene over world-space triangles (T, 3, 3) float32, and instances of meshes
    (kernels.scene.Instances), with a thread pool. Hits report scene triangle numbers: the plain
    triangles' index, then the instances' numbering (Instances.bases).

    Motion blur: motion_ids (T,) int32 (-1 static) names each triangle's entry of motion (K, 4, 4) keys,
    whose motion_reference matrix made the world positions. Static triangles then form one scene and each
    moving object its own, queried at each ray's time; hits report the scene's triangle index either way."""

    def __init__(self, positions: np.ndarray, threads: int = 0, motion_ids: np.ndarray | None = None,
                 motion: tuple = (), motion_reference: tuple = (), instances=None, reuse: "Accel | None" = None,
                 indexed: tuple | None = None, shapes=None, deform: tuple | None = None):
        """reuse : the Accel of an earlier frame (persistent data): its instanced meshes whose triangles are
        the same, array for array, keep their BVH instead of being built again.
        indexed : (vertices (V, 3) float32, indices (T, 3) uint32), the same triangles as positions shared
        by their vertices (SceneArrays.bvh_vertices): Embree builds from them, about 1.5x faster.
        shapes : kernels.geometry.primitives.ShapeLayout of the scene's curves and points, or None: they join
        the top level (world space) and its instances (prototypes), and hits on them report the numbers the
        layout gives them, after the triangles'.
        deform : (deform_ids (T,) int32, deform_positions (S, D, 3, 3) float32) or None: triangles that deform
        over the shutter (SceneArrays.deform_ids): Embree's time steps, found where they are at each ray's time."""
        self.threads = capped_threads(threads)
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        self.triangle_count = len(positions)
        self.seconds_in_embree = 0.0  # time spent inside run() calls, summed over calls and threads
        self._lock = threading.Lock()
        self.rays_traced = 0
        self._static_ids = None   # scene triangle of each static-scene triangle, when some move
        self._moving = []        # objects that deform (Moving), each its own query
        self._rigid = None       # the objects that move rigidly (MovingObjects), one query for all
        self._device = reuse._device if reuse is not None else embree.Device()
        moves = motion_ids is not None and len(motion) and (motion_ids >= 0).any()
        deforms = deform is not None and (deform[0] >= 0).any()
        if moves or deforms:
            still = np.ones(len(positions), bool)
            if moves:
                still &= motion_ids < 0
            if deforms:
                still &= deform[0] < 0
            self._static_ids = np.flatnonzero(still).astype(np.int32)
            rigid = []
            for i, (keys, ref) in enumerate(zip(motion, motion_reference) if moves else ()):
                ids = np.flatnonzero(motion_ids == i)
                if len(ids):
                    steps = steps_of(deform, ids)
                    if steps is None:
                        rigid.append((ids, keys, ref))
                    else:   # moving and deforming: its own scene with time steps, rays moved into it
                        self._moving.append(Moving(ids, keys, ref, steps, self._device))
            if rigid:
                self._rigid = MovingObjects(self._device, positions, rigid)
            if deforms:
                ids = np.flatnonzero((deform[0] >= 0) & (motion_ids < 0 if moves else True))
                if len(ids):
                    self._moving.append(Moving(ids, None, None, steps_of(deform, ids), self._device))
            positions = positions[self._static_ids]
            if indexed is not None:
                indexed = (indexed[0], indexed[1][self._static_ids])
        self._bases = None        # scene number of each instance's first triangle
        self._packets = None      # the static scene traced by packets (reports instances), or None
        self._scene = None        # the static scene traced by embreex's loop, or None
        self.meshes = []          # (prototype positions, embree.Mesh) of the instanced meshes
        self.meshes_reused = 0
        self._refining = None     # the thread building the medium BVH (refine), once started
        self.refine_error = None  # why that build failed, if it did (the quick BVH then stays)
        self._cancel = threading.Event()   # stops refine's build (close)
        self._layout = shapes
        # Curves or points with motion keys: every query goes through the packets, which carry each ray's time
        # (Embree interpolates their time steps at it).
        self._shape_times = shapes is not None and shapes.moves
        self._shape_geometries = ()   # the Embree Shapes of the world-space curves and points
        placed = []
        if instances is not None and instances.count:
            earlier = reuse.meshes if reuse is not None else []
            for p in instances.prototypes:
                mesh = next((m for old, m in earlier if same_arrays(old, p.positions)), None)
                self.meshes_reused += mesh is not None
                self.meshes.append((p.positions, mesh or embree.Mesh(self._device, p.positions.reshape(-1, 3))))
            meshes = [m for _, m in self.meshes]
            placed = [(meshes[p], m) for p, m in zip(instances.prototype, instances.world_from_object)]
            self._bases = instances.bases(self.triangle_count)
            self.triangle_count += instances.triangle_total
        if shapes is not None:
            placed = self._place_shapes(shapes, placed)
        if len(positions) or placed or self._shape_geometries:
            if not len(positions):
                plain = None
            elif indexed is not None:
                plain = embree.Triangles(*indexed)
            else:
                plain = embree.Triangles(np.asarray(positions, np.float32).reshape(-1, 3))
            quick = not placed and plain is not None and plain.triangle_count >= QUICK_BVH_TRIANGLES
            self._use(embree.Scene(self._device, plain, placed, quality="low" if quick else "medium",
                                   shapes=self._shape_geometries))

    def _place_shapes(self, layout, placed: list) -> list:
        """The curves and points of a ShapeLayout: its world-space records as geometries of the top level, its
        prototypes as scenes of their own placed by the shape instances after the mesh instances. Returns the
        placements of both; sets the tables that turn Embree's hits into the layout's numbers."""
        shapes = layout.embree_shapes()
        self._shape_geometries = tuple(shapes[:layout.plain_count])
        mesh_instances = len(placed)
        inst = layout.instances
        if inst is not None and inst.count:
            scenes = [embree.ShapeScene(self._device, s) for s in shapes[layout.plain_count:]]
            moving = layout.instance_motion   # per shape instance its decomposed motion, or None
            placed = placed + [(scenes[p], m, moving[k]) for k, (p, m) in
                               enumerate(zip(inst.prototype, inst.world_from_object))]
        # Per top-level geometry and per instance: the number of its first primitive (-1: triangles).
        self._geometry_base = np.full(1 + len(placed) + len(self._shape_geometries), -1, np.int64)
        self._geometry_base[1 + len(placed):] = layout.plain_base
        bases = self._bases if self._bases is not None else np.zeros(0, np.int64)
        self._instance_base = np.concatenate([bases[:mesh_instances], layout.instance_base]).astype(np.int64)
        self._ng_motion = [None] * mesh_instances + (list(layout.instance_motion) if inst is not None else [])
        # Only the spheres' and linear curves' Ng is read (_inside_out): moving instances of others skip its transform.
        culled = np.zeros(len(self._ng_motion), bool)
        placed_part = layout.part_instance >= 0
        culled[mesh_instances + layout.part_instance[placed_part]] = layout.part_culled[placed_part]
        self._ng_motion = [m if c else None for m, c in zip(self._ng_motion, culled)]
        linear = np.array([np.asarray(entry[1], np.float64)[:3, :3] for entry in placed]).reshape(-1, 3, 3)
        with np.errstate(all="ignore"):
            self._instance_inverse = np.linalg.inv(linear).astype(np.float32) if len(linear) else linear
        self.primitive_count = layout.total
        return placed

    @property
    def quality(self) -> str | None:
        """The build quality of the BVH queries use now ("low" until refine's BVH is in), None without one."""
        static = getattr(self, "_static", None)
        return static.quality if static is not None else None

    def _use(self, static: "embree.Scene") -> None:
        """Trace `static` from now on. Each query reads the scene once per chunk, so a chunk in flight
        finishes on the scene it started with (its embreex view holds a reference to Embree's scene)."""
        scene = None if self._shape_times else static.embreex()
        packets = static if scene is None or static.instance_count else None
        if scene is None:   # embreex's loop unavailable: packets for everything
            scene = PacketQueries(static)
        self._static, self._packets, self._scene = static, packets, scene

    def refine(self, time_left_s: float | None = None) -> bool:
        """Start building the medium-quality BVH of a scene that has the quick one, on a thread; queries
        move to it when it is built. time_left_s: the render's expected time to go; the build starts only
        when that is at least REFINE_SECONDS_PER_TRIANGLE per plain triangle (None: whatever it is). True
        when started now."""
        if self.quality != "low" or self._refining is not None or self._cancel.is_set():
            return False
        if time_left_s is not None and time_left_s < REFINE_SECONDS_PER_TRIANGLE * self._static.plain.triangle_count:
            return False
        quick = self._static

        def build():
            try:
                better = embree.Scene(self._device, quick.plain, quality="medium", cancel=self._cancel,
                                      shapes=quick.shapes)
            except embree.BuildCancelled:
                return
            except embree.EmbreeError as err:   # out of memory, say: the quick BVH serves on
                self.refine_error = str(err)
                return
            if not self._cancel.is_set():
                self._use(better)

        self._refining = threading.Thread(target=build, name="ember-bvh-refine", daemon=True)
        self._refining.start()
        return True

    @property
    def refine_started(self) -> bool:
        """Whether refine has started building the medium BVH (it may still be building: refining)."""
        return self._refining is not None

    @property
    def refining(self) -> bool:
        """Whether refine's build is running now."""
        return self._refining is not None and self._refining.is_alive()

    def wait_refined(self) -> None:
        """Block until refine's build (if any) is in."""
        if self._refining is not None:
            self._refining.join()

    def move_instances(self, world_from_object: np.ndarray) -> int:
        """Place the instances by new (K, 4, 4) world_from_object (same instances, same order): the top
        level is recommitted, no mesh BVH is rebuilt. Both query paths trace the same Embree scene, so
        both see the move. Returns how many instances moved."""
        if self._bases is None:
            raise ValueError("move_instances: the scene has no instances")
        if self._layout is not None:
            raise ValueError("move_instances: a scene with curves or points is built whole")
        return self._static.set_transforms(world_from_object)

    @property
    def moves(self) -> bool:
        """Some triangles move: queries need each ray's time."""
        return bool(self._moving) or self._rigid is not None

    def close(self) -> None:
        self._cancel.set()
        if self._refining is not None:
            self._refining.join()
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def intersect(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray,
                  split: bool = True, time: np.ndarray | None = None) -> Hits:
        """Closest hits. origins, directions: (N, 3) float32; t_max: (N,) float32; time: (N,) float32
        path times in the shutter, needed when something moves.
        split=False keeps the batch on the calling thread (when the caller already runs in parallel)."""
        n = len(origins)
        prim = np.full(n, -1, np.int32)
        t = np.empty(n, np.float32)
        u = np.zeros(n, np.float32)
        v = np.zeros(n, np.float32)
        if (self._scene is None and not self.moves) or n == 0:
            t[:] = np.inf
            return Hits(prim, t, u, v)
        if self._layout is not None:
            prim = np.full(n, -1, np.int64 if self.primitive_count > np.iinfo(np.int32).max else np.int32)
        elif self._bases is not None:
            prim = np.full(n, -1, np.int64 if self.triangle_count > np.iinfo(np.int32).max else np.int32)

        times = self._times(time, n)

        def job(s: slice) -> None:
            if self._layout is not None:
                prim[s], t[s], u[s], v[s] = self._shape_hits(origins[s], directions[s], t_max[s],
                                                             None if times is None else times[s])
                return
            if self._packets is not None:
                p, inst, t[s], u[s], v[s] = self._packets.intersect(origins[s], directions[s], t_max[s])
                if self._static_ids is not None:
                    plain = (inst < 0) & (p >= 0)
                    p[plain] = self._static_ids[p[plain]]
                prim[s] = np.where(inst >= 0, np.take(self._bases, inst) + p, p) if self._bases is not None else p
                return
            r = self._scene.run(origins[s], directions[s], dists=t_max[s].copy(), output=1)
            prim[s] = r["primID"]
            t[s] = r["tfar"]
            u[s] = r["u"]
            v[s] = r["v"]

        if self._scene is not None:
            self._run(job, n, split)
        else:
            t[:] = t_max
        if self.moves:
            if self._static_ids is not None and self._scene is not None and self._packets is None \
                    and self._layout is None:
                hit = prim >= 0
                prim[hit] = self._static_ids[prim[hit]]
            t[prim < 0] = t_max[prim < 0]
            if self._rigid is not None:
                ray_times = selected_times(time, np.arange(n))

                def job_rigid(s: slice) -> None:
                    p, t2, u2, v2 = self._rigid.intersect(origins[s], directions[s], t[s].copy(), ray_times[s])
                    closer = np.flatnonzero(p >= 0)
                    idx = closer + s.start
                    prim[idx], t[idx], u[idx], v[idx] = p[closer], t2[closer], u2[closer], v2[closer]

                self._run(job_rigid, n, split)
            for moving in self._moving:
                sel = moving.crossing(origins, directions, t)
                if not len(sel):
                    continue
                o, d = moving.rays(origins, directions, time, sel)
                best = t[sel]

                ray_times = selected_times(time, sel)

                def job_moving(s: slice, o=o, d=d, moving=moving, sel=sel, best=best, ray_times=ray_times) -> None:
                    r = moving.query(o[s], d[s], best[s].copy(), ray_times[s])
                    closer = r["primID"] >= 0
                    idx = sel[np.flatnonzero(closer) + s.start]
                    prim[idx] = moving.ids[r["primID"][closer]]
                    t[idx] = r["tfar"][closer]
                    u[idx] = r["u"][closer]
                    v[idx] = r["v"][closer]

                self._run(job_moving, len(sel), split)
            t[prim < 0] = np.inf
        return Hits(prim, t, u, v)

    def _times(self, time, n: int) -> np.ndarray | None:
        """(n,) float32 the rays' shutter times for curves and points with motion keys (RayTimes or an array;
        0.5, the frame's time of a centred shutter, when none are given), None when no curve or point moves."""
        if not self._shape_times:
            return None
        if time is None:
            return np.full(n, 0.5, np.float32)
        return np.ascontiguousarray(time.times if isinstance(time, RayTimes) else time, np.float32)

    def _shape_hits(self, origins, directions, t_max, times=None):
        """(prim, t, u, v) of a scene with curves or points: Embree's hits turned into the layout's numbers
        (triangles as without them), without hits on the inside of spheres and linear curves. Cycles builds its
        Embree with EMBREE_BACKFACE_CULLING_CURVES and _SPHERES (build_files/build_environment/cmake/embree.cmake),
        which its sphere and round linear intersectors honour, so a ray from inside one (a point's root in its
        emitter, two overlapping) does not meet its far wall; embreex's Embree reports it, so such a hit is
        stepped past (BACKFACE_SKIPS at most). (Catmull-Rom tubes report it in both.)"""
        prim, t, u, v, ng = self._numbered_hits(origins, directions, t_max, times)
        live = np.flatnonzero(self._inside_out(prim, ng, directions))
        for _ in range(BACKFACE_SKIPS):
            if not len(live):
                break
            o = origins[live]
            step = t[live] + np.float32(2.0 ** -20) * (np.abs(o).max(axis=1) + t[live]) + np.float32(1e-30)
            left = t_max[live] - step
            prim[live], t[live] = -1, t_max[live]
            go = np.flatnonzero(left > 0)
            live, o, step, left = live[go], o[go], step[go], left[go]
            if not len(live):
                break
            d = np.ascontiguousarray(directions[live])
            p2, t2, u2, v2, ng2 = self._numbered_hits(np.ascontiguousarray(o + d * step[:, None], np.float32), d,
                                                      left.astype(np.float32),
                                                      None if times is None else times[live])
            prim[live] = p2
            t[live] = np.where(p2 >= 0, t2 + step, t_max[live])
            u[live], v[live] = u2, v2
            live = live[self._inside_out(p2, ng2, d)]
        else:
            prim[live], t[live] = -1, t_max[live]
        return prim, t, u, v

    def _inside_out(self, prim, ng, directions) -> np.ndarray:
        """(n,) bool: hits on a sphere or linear curve seen from inside it (Embree's Ng along the ray)."""
        shape = prim >= self._layout.triangle_count
        if not shape.any():
            return shape
        sel = np.flatnonzero(shape)
        culled = np.take(self._layout.part_culled, self._layout.locate(prim[sel])[0])
        facing = np.einsum("ij,ij->i", ng[sel], directions[sel]) > 0
        out = np.zeros(len(prim), bool)
        out[sel] = culled & facing
        return out

    def _numbered_hits(self, origins, directions, t_max, times=None):
        """One query: (prim, t, u, v, Ng) in the layout's numbers (times: the rays' shutter times, or None)."""
        if self._packets is not None:
            p, inst, t, u, v, geom, ng = self._packets.intersect(origins, directions, t_max, geometry=True,
                                                                 times=times)
        else:
            r = self._scene.run(origins, directions, dists=t_max.copy(), output=1)
            p, t, u, v, geom, ng = r["primID"], r["tfar"], r["u"], r["v"], r["geomID"], r["Ng"]
            inst = np.full(len(p), -1, np.int32)
        hit = p >= 0
        plain = hit & (inst < 0)
        base = np.take(self._geometry_base, np.where(plain, geom, 0))
        if len(self._instance_base):
            base = np.where(inst >= 0, np.take(self._instance_base, np.maximum(inst, 0)), base)
        prim = np.where(hit, np.where(base >= 0, base + p, p), -1)
        if self._static_ids is not None:
            moved = np.flatnonzero(plain & (base < 0))
            prim[moved] = self._static_ids[prim[moved]]
        ng = np.asarray(ng, np.float32).reshape(-1, 3)
        placed = np.flatnonzero(hit & (inst >= 0))
        if len(placed):   # Embree's Ng of an instance's hit is in its object space: by the inverse transpose
            ng = ng.copy()
            inverse = np.take(self._instance_inverse, inst[placed], axis=0)
            if times is not None:   # moving instances of spheres and linear curves: their inverse at each ray's time
                for k in np.unique(inst[placed]):
                    decomposed = self._ng_motion[k]
                    if decomposed is not None:
                        sel = np.flatnonzero(inst[placed] == k)
                        m = motion.interpolate(decomposed, np.take(times, placed[sel]).astype(np.float64))
                        inverse[sel] = motion.affine_inverse(m)[:, :, :3].astype(np.float32)
            ng[placed] = np.einsum("nji,nj->ni", inverse, ng[placed])
        return prim, np.array(t, np.float32), np.array(u, np.float32), np.array(v, np.float32), ng

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray,
                 split: bool = True, time: np.ndarray | None = None) -> np.ndarray:
        """(N,) bool: True where something lies between the origin and t_max along the ray (at its time,
        when something moves)."""
        n = len(origins)
        out = np.zeros(n, bool)
        if n == 0:
            return out

        times = self._times(time, n)

        def job(s: slice, scene=self._scene, o=origins, d=directions) -> None:
            if times is not None:   # moving curves or points: packets with the rays' times
                out[s] |= scene.run(o[s], d[s], dists=t_max[s].copy(), query="OCCLUDED", times=times[s]) == 0
                return
            out[s] |= scene.run(o[s], d[s], dists=t_max[s].copy(), query="OCCLUDED", output=None) == 0

        if self._scene is not None:
            self._run(job, n, split)
            if self._layout is not None and self._layout.part_culled.any():
                # Embree's answer counts the inside of spheres and linear curves, which Cycles' does not: the blocked rays
                # are checked by their closest hit (_shape_hits culls such walls).
                rows = np.flatnonzero(out)
                if len(rows):
                    times = None if time is None else time.take(rows) if isinstance(time, RayTimes) else \
                        np.take(time, rows)
                    again = self.intersect(origins[rows], directions[rows], t_max[rows], split, times)
                    out[rows] = again.prim >= 0
        if self._rigid is not None:
            sel = np.flatnonzero(~out)
            if len(sel):
                o, d = np.ascontiguousarray(origins[sel]), np.ascontiguousarray(directions[sel])
                limit, ray_times = t_max[sel], selected_times(time, sel)
                blocked = np.zeros(len(sel), bool)

                def job_rigid(s: slice) -> None:
                    blocked[s] = self._rigid.occluded(o[s], d[s], limit[s].copy(), ray_times[s])

                self._run(job_rigid, len(sel), split)
                out[sel[blocked]] = True
        for moving in self._moving:
            sel = moving.crossing(origins, directions, t_max)
            sel = sel[~out[sel]]
            if not len(sel):
                continue
            o, d = moving.rays(origins, directions, time, sel)
            hit = np.zeros(len(sel), bool)
            limit = t_max[sel]

            ray_times = selected_times(time, sel)

            def job_moving(s: slice, o=o, d=d, moving=moving, hit=hit, limit=limit, ray_times=ray_times) -> None:
                hit[s] = moving.query(o[s], d[s], limit[s].copy(), ray_times[s],
                                      occluded=True) == 0

            self._run(job_moving, len(sel), split)
            out[sel[hit]] = True
        return out

    def count(self, rays: int, seconds: float) -> None:
        """Add rays traced and seconds in Embree elsewhere (a worker process's twin of this scene)."""
        with self._lock:
            self.seconds_in_embree += seconds
            self.rays_traced += rays

    def _run(self, job, n: int, split: bool) -> None:
        start = time.perf_counter()
        chunks = self.threads * _CHUNKS_PER_THREAD
        if not split or self._pool is None or n < 2 * _MIN_CHUNK:
            job(slice(0, n))
        else:
            size = max(_MIN_CHUNK, -(-n // chunks))
            list(self._pool.map(job, [slice(i, min(i + size, n)) for i in range(0, n, size)]))
        elapsed = time.perf_counter() - start
        with self._lock:  # several waves may trace at once
            self.seconds_in_embree += elapsed
            self.rays_traced += n
