"""Ray queries through Embree (embreex): closest hit and occlusion, chunked over a thread pool.

embreex's `run` releases the GIL, so chunks of one batch run in parallel on Python threads.
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
from embreex import mesh_construction, rtcore_scene

# Below this many rays a batch runs as one call: splitting costs more than it saves.
_MIN_CHUNK = 8192
_CHUNKS_PER_THREAD = 4


def default_threads() -> int:
    return max(1, os.cpu_count() or 1)


class Hits:
    """Closest-hit results for N rays. prim is -1 for a miss; t is the hit distance; (u, v) are
    Embree's barycentrics of corners 1 and 2 (corner 0 has 1 - u - v)."""
    __slots__ = ("prim", "t", "u", "v")

    def __init__(self, prim: np.ndarray, t: np.ndarray, u: np.ndarray, v: np.ndarray):
        self.prim, self.t, self.u, self.v = prim, t, u, v


class Accel:
    """An Embree scene over world-space triangles (T, 3, 3) float32, with a thread pool."""

    def __init__(self, positions: np.ndarray, threads: int = 0):
        self.threads = threads if threads > 0 else default_threads()
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        self.triangle_count = len(positions)
        self.seconds_in_embree = 0.0  # time spent inside run() calls, summed over calls and threads
        self._lock = threading.Lock()
        self.rays_traced = 0
        if self.triangle_count:
            self._scene = rtcore_scene.EmbreeScene(robust=True)
            mesh_construction.TriangleMesh(self._scene, np.ascontiguousarray(positions, np.float32))
        else:
            self._scene = None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def intersect(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray,
                  split: bool = True) -> Hits:
        """Closest hits. origins, directions: (N, 3) float32; t_max: (N,) float32.
        split=False keeps the batch on the calling thread (when the caller already runs in parallel)."""
        n = len(origins)
        prim = np.full(n, -1, np.int32)
        t = np.empty(n, np.float32)
        u = np.zeros(n, np.float32)
        v = np.zeros(n, np.float32)
        if self._scene is None or n == 0:
            t[:] = np.inf
            return Hits(prim, t, u, v)

        def job(s: slice) -> None:
            r = self._scene.run(origins[s], directions[s], dists=t_max[s].copy(), output=1)
            prim[s] = r["primID"]
            t[s] = r["tfar"]
            u[s] = r["u"]
            v[s] = r["v"]

        self._run(job, n, split)
        return Hits(prim, t, u, v)

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray,
                 split: bool = True) -> np.ndarray:
        """(N,) bool: True where something lies between the origin and t_max along the ray."""
        n = len(origins)
        out = np.zeros(n, bool)
        if self._scene is None or n == 0:
            return out

        def job(s: slice) -> None:
            out[s] = self._scene.run(origins[s], directions[s], dists=t_max[s].copy(),
                                     query="OCCLUDED", output=None) == 0

        self._run(job, n, split)
        return out

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
