"""The wavefront path tracer: the lecture's path_trace as arrays of live paths per bounce.

A wave is a batch of paths (a band of image rows, one or more samples per pixel). Each bounce runs
named stages over the live paths: intersect, handle escaped rays, shade hits (shading data and
emission), sample the next direction, compact. Paths never recurse; a path leaves the live set when
it escapes, is absorbed, or reaches the path length.

Bounces follow Cycles: max_bounces = 0 is direct light only, so a path scatters at most
max_bounces + 1 times (the lecture's "max path length").
"""
from __future__ import annotations

import dataclasses
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from . import sampling
from .accel import Accel
from .camera import generate_rays
from .environment import Environment
from .film import Film
from .lights import LightSampler
from .rng import PathRng, seed_paths, stratified_2d
from .scene import Camera, SceneArrays
from .textures import Texture, finite_uv

SAMPLING_MODES = ("NEE_MIS", "COSINE", "LECTURE")
# Russian roulette starts once a path has scattered this many times (NEE_MIS only: LECTURE and COSINE
# stay the plain estimators they are, for teaching and as references).
ROULETTE_DEPTH = 3

# Rows of the per-triangle table gathered for every hit (one contiguous row per component).
_P0, _E1, _E2, _NG, _N0, _N1, _N2, _UV0, _UV1, _UV2 = 0, 3, 6, 9, 12, 15, 18, 21, 23, 25
_TABLE_ROWS = 27
# A pass is cut into at least this many waves when the image allows, so that two cores have
# independent work; wave_size then bounds each wave.
_WAVES_PER_PASS = 4


@dataclass(frozen=True)
class RenderSettings:
    """How to render. region is (x0, y0, x1, y1) in full-frame pixels, row 0 at the top, end
    exclusive; None for the whole frame. time_limit_s = 0 means none. A wave holds at most
    wave_size paths, which bounds memory whatever the resolution."""
    samples: int = 64
    max_bounces: int = 8
    mode: str = "NEE_MIS"
    seed: int = 0
    time_limit_s: float = 0.0
    region: tuple | None = None
    transparent_background: bool = False
    wave_size: int = 1 << 16

    def validate(self, width: int, height: int) -> tuple[int, int, int, int]:
        if self.mode not in SAMPLING_MODES:
            raise ValueError(f"mode: must be one of {SAMPLING_MODES}, got {self.mode!r}")
        if int(self.samples) < 1:
            raise ValueError(f"samples: must be at least 1, got {self.samples}")
        if int(self.max_bounces) < 0:
            raise ValueError(f"max_bounces: must be non-negative, got {self.max_bounces}")
        if not (np.isfinite(self.time_limit_s) and self.time_limit_s >= 0):
            raise ValueError(f"time_limit_s: must be finite and non-negative, got {self.time_limit_s}")
        if int(self.wave_size) < 1:
            raise ValueError(f"wave_size: must be positive, got {self.wave_size}")
        x0, y0, x1, y1 = self.region if self.region is not None else (0, 0, width, height)
        if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
            raise ValueError(f"region: {self.region} is empty or outside the {width}x{height} frame")
        return int(x0), int(y0), int(x1), int(y1)


@dataclass
class Progress:
    """What a render has done so far, passed to on_progress after every wave."""
    samples_done: int          # samples every pixel of the region has
    samples_total: int
    fraction: float            # of all paths of the render, 0..1
    elapsed_s: float
    paths: int = 0
    rays: int = 0
    seconds_in_embree: float = 0.0
    nonfinite_paths: int = 0   # paths whose radiance came out NaN or inf and were dropped

    @property
    def paths_per_s(self) -> float:
        return self.paths / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def rays_per_s(self) -> float:
        return self.rays / self.elapsed_s if self.elapsed_s > 0 else 0.0


class Cancelled(Exception):
    """should_stop() asked a Renderer to stop while it was being built."""


@dataclass
class RenderResult:
    """What a render made. The image is resolved from the film when asked for (a full-frame float32
    copy): a caller that streams the result can read it in bands with film.resolve(row0, row1)."""
    film: Film = field(repr=False)
    progress: Progress
    stopped_early: bool
    dropped_triangles: int = 0

    @property
    def image(self) -> np.ndarray:
        """(H, W, 4) float32 linear RGBA of the region, row 0 at the top."""
        return self.film.resolve()


class Renderer:
    """A validated scene with its acceleration structure, ready to render any number of times."""

    def __init__(self, scene: SceneArrays, threads: int = 0, should_stop: Callable[[], bool] | None = None):
        """should_stop() is polled between the stages of the build (each stage is one long C or NumPy
        call that cannot be interrupted); Cancelled is raised when it returns True."""
        def poll():
            if should_stop is not None and should_stop():
                raise Cancelled()
        poll()
        checked = scene.validate()
        self.scene = checked.scene
        self.dropped_triangles = checked.dropped_triangles
        poll()
        self.accel = Accel(self.scene.positions, threads)
        try:
            poll()
            # Triangles near float32's limits overflow in their normals: paths that hit them are
            # dropped and counted like any non-finite path, so NumPy need not print about them.
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                self._build_tables(poll)
        except BaseException:
            self.accel.close()
            raise

    def _build_tables(self, poll) -> None:
        self.environment = Environment(self.scene.world)
        srgb = self.scene.texture_srgb or (False,) * len(self.scene.textures)
        self.textures = [Texture(t, bool(flag)) for t, flag in zip(self.scene.textures, srgb)]
        self._tri_table = _triangle_table(self.scene)
        poll()
        self._material_ids = self.scene.material_ids
        mats = self.scene.materials
        self._albedo = np.ascontiguousarray(mats.albedo.T)          # (3, M)
        self._emission = np.ascontiguousarray(mats.emission.T)      # (3, M)
        self._albedo_tex = mats.albedo_texture
        self._emission_tex = mats.emission_texture
        self._material_emits = np.any(mats.emission > 0, axis=1)
        self._emissive = bool(self._material_emits.any())
        lo, hi = _extent(self.scene.positions)
        self._ray_epsilon = _ray_epsilon(lo, hi)
        self._texture_means = [t.channels.mean(axis=1) for t in self.textures]
        self.lights = LightSampler(self.scene, self.environment, self._triangle_emission)
        poll()
        threads = self.accel.threads
        self._wave_pool = ThreadPoolExecutor(threads, "ember-wave") if threads > 1 else None

    def set_camera(self, camera: Camera) -> None:
        """Look through another camera without rebuilding anything (the viewport's view changes).
        Call between renders, never during one."""
        camera.validate()
        self.scene = dataclasses.replace(self.scene, camera=camera)

    def close(self) -> None:
        """Stop the threads and drop the big arrays now: the light sampler calls back into this
        renderer, a reference cycle that plain reference counting would never free."""
        if self._wave_pool is not None:
            self._wave_pool.shutdown(wait=True)
            self._wave_pool = None
        self.accel.close()
        self.lights = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ---------------------------------------------------------------- progressive loop
    def render(self, settings: RenderSettings,
               on_tile: Callable[[Film, int, int], None] | None = None,
               should_stop: Callable[[], bool] | None = None,
               on_progress: Callable[[Progress], None] | None = None) -> RenderResult:
        """Render sample passes over the region in waves of rows.

        on_tile(film, row0, row1) runs after each wave with the region rows it refined;
        should_stop() is polled between waves; on_progress(progress) reports after each wave.
        """
        cam = self.scene.camera
        x0, y0, x1, y1 = settings.validate(cam.width, cam.height)
        width, height = x1 - x0, y1 - y0
        film = Film(width, height)
        total = int(settings.samples)
        start = time.perf_counter()
        embree_start = self.accel.seconds_in_embree
        rays_start = self.accel.rays_traced
        progress = Progress(0, total, 0.0, 0.0)
        stopped = False
        done = 0
        while done < total and not stopped:
            if done and self._out_of_time(settings, start):
                stopped = True  # a pass never starts after the limit: the image stays evenly sampled
                break
            spp, bands = _plan_pass(width, height, done, total, settings.wave_size)
            # Waves of one pass run concurrently (NumPy and Embree release the GIL); their results
            # are added to the film in order, so the image does not depend on the thread count.
            split = len(bands) < self.accel.threads
            in_flight = []
            next_band = 0
            while next_band < len(bands) or in_flight:
                while next_band < len(bands) and len(in_flight) < self.accel.threads:
                    r0, r1 = bands[next_band]
                    in_flight.append((r0, r1, self._submit(self._render_rows, settings, x0, y0, width,
                                                           r0, r1, done, spp, split)))
                    next_band += 1
                r0, r1, future = in_flight.pop(0)
                sums, bad = future.result()
                film.add_rows(r0, sums, spp)
                progress.paths += (r1 - r0) * width * spp
                progress.nonfinite_paths += bad
                progress.elapsed_s = time.perf_counter() - start
                progress.rays = self.accel.rays_traced - rays_start
                progress.seconds_in_embree = self.accel.seconds_in_embree - embree_start
                progress.samples_done = film.samples_done
                progress.fraction = progress.paths / (width * height * total)
                if on_tile is not None:
                    on_tile(film, r0, r1)
                if on_progress is not None:
                    on_progress(progress)
                # A time limit always lets the first full pass finish, as Cycles' does.
                if not stopped and ((should_stop is not None and should_stop()) or (
                        film.samples_done > 0 and self._out_of_time(settings, start))):
                    stopped = True
                    next_band = len(bands)  # finish the waves in flight, start no more
            if stopped and film.samples_done == done + spp and done + spp >= total:
                stopped = False  # the stop came with the last wave: the render is complete
            done += spp
        return RenderResult(film, progress, stopped, self.dropped_triangles)

    @staticmethod
    def _out_of_time(settings: RenderSettings, start: float) -> bool:
        return settings.time_limit_s > 0 and time.perf_counter() - start >= settings.time_limit_s

    def _submit(self, fn, *args):
        if self._wave_pool is None:
            future = Future()
            future.set_result(fn(*args))
            return future
        return self._wave_pool.submit(fn, *args)

    def _render_rows(self, settings, x0, y0, width, r0, r1, first_sample, spp, split):
        """One wave: region rows [r0, r1), spp samples per pixel. Returns ((rows, W, 4) float64 sums,
        count of dropped non-finite paths). Paths are pixel-major so each pixel's samples are adjacent."""
        cam = self.scene.camera
        rows = r1 - r0
        npix = rows * width
        pix = np.repeat(np.arange(npix, dtype=np.int64), spp)
        sample = np.tile(np.arange(first_sample, first_sample + spp, dtype=np.uint32), npix)
        row = (pix // width + (y0 + r0)).astype(np.int32)
        col = (pix % width + x0).astype(np.int32)
        pixel_index = row.astype(np.uint32) * np.uint32(cam.width) + col.astype(np.uint32)
        rng = PathRng(*seed_paths(pixel_index, sample, settings.seed))
        # Overflow and invalid values are expected at the edges of float32 (huge lights, degenerate
        # geometry): the paths they spoil are dropped and counted below, not printed by NumPy. errstate
        # is per thread, so it is set here, in the thread that runs the wave.
        with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
            radiance, alpha = self.trace_paths(rng, row, col, settings, split, strata=(pixel_index, sample))
        bad = ~np.isfinite(radiance).all(axis=0)
        n_bad = int(np.count_nonzero(bad))
        if n_bad:
            radiance[:, bad] = 0.0
        rgba = np.empty((4, len(pix)), np.float64)
        rgba[:3] = radiance
        rgba[3] = alpha
        sums = rgba.reshape(4, npix, spp).sum(axis=2)
        return sums.T.reshape(rows, width, 4), n_bad

    # ---------------------------------------------------------------- one wave of paths
    def trace_paths(self, rng: PathRng, row: np.ndarray, col: np.ndarray, settings: RenderSettings,
                    split: bool = True, strata=None):
        """Trace one path per (row, col) entry. Returns radiance (3, N) float32 and alpha (N,) float32.

        strata = (pixel_index, sample_index) per path: in NEE_MIS mode the camera jitter and the first
        vertex's light and BSDF numbers then come from each pixel's stratified sequence (the rest of
        the path, and the LECTURE and COSINE modes, use the PCG2D stream alone)."""
        n = len(row)
        radiance = np.zeros((3, n), np.float32)
        alpha = np.ones(n, np.float32)
        first = None  # the first vertex's stratified numbers: light choice, light point, BSDF
        if strata is not None and settings.mode == "NEE_MIS":
            jx, jy = stratified_2d(*strata, settings.seed, 0)
            first = [stratified_2d(*strata, settings.seed, d) for d in (1, 2, 3)]
        else:
            jx, jy = rng.next_2d()
        origins, dirs, t_max = generate_rays(self.scene.camera, row, col, jx, jy)
        # Path state, one entry per live path:
        path = np.arange(n)                          # wave index of the path
        throughput = np.ones((3, n), np.float32)     # product of BSDF weights (and 1/q of roulette)
        bsdf_pdf = np.full(n, np.inf, np.float32)    # pdf of the direction that led here; inf = camera ray
        nee = settings.mode == "NEE_MIS" and self.lights.has_lights
        max_scatters = int(settings.max_bounces) + 1
        for depth in range(max_scatters + 1):
            # ---- intersect
            hits = self.accel.intersect(origins, dirs, t_max, split)
            dx, dy, dz = dirs[:, 0], dirs[:, 1], dirs[:, 2]
            # ---- lights with a surface, found by BSDF rays (Blender lights are invisible to the camera)
            if depth > 0 and self.lights.has_surface_lights:
                ox, oy, oz = origins[:, 0], origins[:, 1], origins[:, 2]
                lit, le, light_pdf = self.lights.intersect(ox, oy, oz, dx, dy, dz, hits.t)
                if lit.any():
                    idx = np.flatnonzero(lit)
                    le = np.take(throughput * le, idx, axis=1)
                    if nee:
                        le = le * sampling.power_heuristic(np.take(bsdf_pdf, idx), np.take(light_pdf, idx))
                    _accumulate(radiance, path[idx], le)
            # ---- escaped rays: the world
            miss = np.flatnonzero(hits.prim < 0)
            if len(miss):
                if depth == 0 and settings.transparent_background:
                    alpha[path[miss]] = 0.0
                else:
                    mx, my, mz = dx[miss], dy[miss], dz[miss]
                    env = np.take(throughput, miss, axis=1) * self.environment.radiance(mx, my, mz)
                    if nee and depth > 0:
                        env = env * sampling.power_heuristic(bsdf_pdf[miss], self.lights.pdf_world(mx, my, mz))
                    _accumulate(radiance, path[miss], env)
            hit = np.flatnonzero(hits.prim >= 0)
            if not len(hit):
                break
            path, throughput, bsdf_pdf, rng = _compact(hit, path, throughput, bsdf_pdf, rng)
            if depth == 0 and first is not None:
                first = [(np.take(u, hit), np.take(v, hit)) for u, v in first]
            prim = np.take(hits.prim, hit)
            dx, dy, dz = np.take(dx, hit), np.take(dy, hit), np.take(dz, hit)
            # ---- shading data: the slide's barycentric interpolation
            sd = self._shading_data(prim, np.take(hits.u, hit), np.take(hits.v, hit), dx, dy, dz)
            # ---- emission on hit (MIS-weighted when NEE could have found the same point)
            if self._emissive:
                lit = np.flatnonzero(np.take(self._material_emits, sd["mat"]))
                if len(lit):
                    le = self._emitted(np.take(sd["mat"], lit), _take(sd["u"], lit), _take(sd["v"], lit))
                    le = np.take(throughput, lit, axis=1) * le
                    if nee and depth > 0:
                        gx, gy, gz = (np.take(c, lit) for c in sd["ng"])
                        cos_l = gx * np.take(dx, lit) + gy * np.take(dy, lit) + gz * np.take(dz, lit)
                        ray = hit[lit]  # index of these rays before compaction
                        light_pdf = self.lights.pdf_triangle_hit(
                            np.take(prim, lit), np.take(hits.t, ray), cos_l,
                            np.take(origins[:, 0], ray), np.take(origins[:, 1], ray), np.take(origins[:, 2], ray))
                        le = le * sampling.power_heuristic(np.take(bsdf_pdf, lit), light_pdf)
                    _accumulate(radiance, path[lit], le)
            if depth == max_scatters:
                break
            albedo = self._albedo_at(sd["mat"], sd["u"], sd["v"])
            # ---- next-event estimation: one shadow ray toward a sampled light
            strat = first if depth == 0 else None
            if nee:
                u_roulette = self._next_event(radiance, path, throughput, albedo, sd, rng, split,
                                              strat[:2] if strat else None)
            # ---- sample the next direction (diffuse BSDF)
            ux, uy = strat[2] if strat else rng.next_2d()
            nx, ny, nz = sd["ns"]
            if settings.mode == "LECTURE":
                lx, ly, lz, sin_t = sampling.sample_lecture_hemisphere(ux, uy)
                weight = albedo * (sampling.PI * lz * sin_t)  # pi^2 sin * (albedo/pi) * cos
                next_pdf = sampling.lecture_hemisphere_pdf(sin_t)
            else:
                lx, ly, lz = sampling.sample_cosine_hemisphere(ux, uy)
                weight = albedo                               # (albedo/pi) cos / (cos/pi)
                next_pdf = sampling.cosine_hemisphere_pdf(lz)
            wx, wy, wz = sampling.local_to_world(lx, ly, lz, nx, ny, nz)
            gx, gy, gz = sd["ng"]
            # A direction below the true surface would pass through it: absorb the path.
            above = (wx * gx + wy * gy + wz * gz) > 0
            throughput = throughput * weight
            alive = above & ((throughput[0] > 0) | (throughput[1] > 0) | (throughput[2] > 0))
            # ---- Russian roulette: after a few bounces, continue with probability q, re-weighted by 1/q
            if nee and depth + 1 >= ROULETTE_DEPTH:
                q = np.minimum(np.maximum(np.maximum(throughput[0], throughput[1]), throughput[2]), np.float32(1.0))
                alive &= u_roulette < q
                throughput = throughput / np.where(q > 0, q, np.float32(1.0))
            alive = np.flatnonzero(alive)
            if not len(alive):
                break
            path, throughput, bsdf_pdf, rng = _compact(alive, path, throughput, next_pdf, rng)
            px, py, pz = (np.take(c, alive) for c in sd["p"])
            gx, gy, gz = np.take(gx, alive), np.take(gy, alive), np.take(gz, alive)
            wx, wy, wz = np.take(wx, alive), np.take(wy, alive), np.take(wz, alive)
            # ---- spawn: offset the origin off the surface (Embree's tnear is always 0)
            eps = self._offset(px, py, pz)
            origins = np.stack([px + gx * eps, py + gy * eps, pz + gz * eps], axis=1)
            dirs = np.stack([wx, wy, wz], axis=1)
            t_max = np.full(len(alive), np.inf, np.float32)
        return radiance, alpha

    def _offset(self, px, py, pz):
        """Distance to move a spawned ray's origin along the normal: scene scale plus float32 ulps."""
        return self._ray_epsilon + np.float32(2.0 ** -16) * np.maximum(np.maximum(np.abs(px), np.abs(py)), np.abs(pz))

    def _next_event(self, radiance, path, throughput, albedo, sd, rng, split, numbers=None):
        """Sample a light for every live path, trace the shadow rays, add the MIS-weighted direct light.
        numbers: ((u_select, u_spare), (u1, u2)) to use instead of the PCG2D stream.
        Returns a spare uniform number per path (used for Russian roulette)."""
        (u_select, u_spare), (u1, u2) = numbers if numbers is not None else (rng.next_2d(), rng.next_2d())
        px, py, pz = sd["p"]
        ls = self.lights.sample(px, py, pz, u_select, u1, u2)
        nx, ny, nz = sd["ns"]
        gx, gy, gz = sd["ng"]
        cos_s = ls.wx * nx + ls.wy * ny + ls.wz * nz
        cos_g = ls.wx * gx + ls.wy * gy + ls.wz * gz
        le = ls.radiance
        useful = (ls.pdf > 0) & (cos_s > 0) & (cos_g > 0) & ((le[0] > 0) | (le[1] > 0) | (le[2] > 0))
        idx = np.flatnonzero(useful)
        if not len(idx):
            return u_spare
        sx, sy, sz = np.take(px, idx), np.take(py, idx), np.take(pz, idx)
        ngx, ngy, ngz = np.take(gx, idx), np.take(gy, idx), np.take(gz, idx)
        wx, wy, wz = np.take(ls.wx, idx), np.take(ls.wy, idx), np.take(ls.wz, idx)
        eps = self._offset(sx, sy, sz)
        dist = np.take(ls.dist, idx)
        ox, oy, oz = sx + ngx * eps, sy + ngy * eps, sz + ngz * eps
        # Aim from the offset origin at the sampled point itself: keeping the direction from the
        # surface point would shift the ray by eps and, at grazing angles, make it cross the
        # emitter's plane before the point (a lamp 1 cm under a ceiling shadowed itself that way).
        finite = np.isfinite(dist)
        safe = np.where(finite, dist, np.float32(0.0))
        ax, ay, az = sx + wx * safe - ox, sy + wy * safe - oy, sz + wz * safe - oz
        to_point = np.sqrt(ax * ax + ay * ay + az * az)
        inv = np.float32(1.0) / np.maximum(to_point, np.float32(1e-30))
        wx, wy, wz = np.where(finite, ax * inv, wx), np.where(finite, ay * inv, wy), np.where(finite, az * inv, wz)
        # Stop short of the sampled point so that the emitter itself does not count as an occluder.
        t_max = np.where(finite, to_point * np.float32(1.0 - 1e-4) - eps, np.inf).astype(np.float32)
        origins = np.stack([ox, oy, oz], axis=1)
        blocked = self.accel.occluded(origins, np.stack([wx, wy, wz], axis=1), t_max, split)
        vis = idx[~blocked & (t_max > 0)]
        if not len(vis):
            return u_spare
        pdf = np.take(ls.pdf, vis)
        cos = np.take(cos_s, vis)
        w = np.where(np.take(ls.delta, vis), np.float32(1.0),
                     sampling.power_heuristic(pdf, sampling.cosine_hemisphere_pdf(cos)))
        scale = cos * sampling.INV_PI * w / pdf
        contribution = np.take(throughput, vis, axis=1) * np.take(albedo, vis, axis=1) * \
            np.take(ls.radiance, vis, axis=1) * scale
        _accumulate(radiance, path[vis], contribution)
        return u_spare

    # ---------------------------------------------------------------- shading stages
    def _shading_data(self, prim, u, v, dx, dy, dz) -> dict:
        """Position, normals facing the incoming ray, UV and material at each hit."""
        # Gathering whole rows of a (T, 27) table is ~9x faster than columns of a (27, T) one.
        g = np.take(self._tri_table, prim, axis=0).T  # (27, N) view, one row per component
        w1, w2 = u, v
        w0 = np.float32(1.0) - w1 - w2
        p = tuple(g[_P0 + k] + w1 * g[_E1 + k] + w2 * g[_E2 + k] for k in range(3))
        ns = [w0 * g[_N0 + k] + w1 * g[_N1 + k] + w2 * g[_N2 + k] for k in range(3)]
        gx, gy, gz = g[_NG], g[_NG + 1], g[_NG + 2]
        len2 = ns[0] * ns[0] + ns[1] * ns[1] + ns[2] * ns[2]
        inv = np.float32(1.0) / np.sqrt(np.maximum(len2, np.float32(1e-12)))
        ns = [c * inv for c in ns]
        degenerate = len2 < np.float32(1e-12)
        if degenerate.any():  # opposing corner normals cancel: use the face normal
            ns = [np.where(degenerate, gk, c) for c, gk in zip(ns, (gx, gy, gz))]
        # Face the geometric normal towards the side the ray came from, and the shading normal with
        # it (as Cycles does for back-facing hits): near a smooth object's silhouette the shading
        # normal may lean away from the viewer while the face looks at it, and stays so.
        g_sign = np.where(gx * dx + gy * dy + gz * dz > 0, np.float32(-1.0), np.float32(1.0))
        s_sign = g_sign
        if self.textures:
            uu = w0 * g[_UV0] + w1 * g[_UV1] + w2 * g[_UV2]
            vv = w0 * g[_UV0 + 1] + w1 * g[_UV1 + 1] + w2 * g[_UV2 + 1]
        else:
            uu = vv = None  # only textures read UVs
        return {
            "p": p,
            "ng": (gx * g_sign, gy * g_sign, gz * g_sign),
            "ns": (ns[0] * s_sign, ns[1] * s_sign, ns[2] * s_sign),
            "u": uu, "v": vv,
            "mat": np.take(self._material_ids, prim),
        }

    def _triangle_emission(self, tri, b1=None, b2=None) -> np.ndarray:
        """(3, n) emitted radiance of triangles tri at barycentrics (b1, b2); without them, the
        triangle's mean (textures averaged), for power estimates."""
        mat = np.take(self._material_ids, tri)
        if b1 is None:
            value = np.take(self._emission, mat, axis=1)
            tex = np.take(self._emission_tex, mat)
            for t in np.unique(tex[tex >= 0]):
                sel = tex == t
                value[:, sel] *= self._texture_means[t][:, None]
            return value
        g = np.take(self._tri_table, tri, axis=0).T
        u = v = None
        if self.textures:
            b0 = np.float32(1.0) - b1 - b2
            u = b0 * g[_UV0] + b1 * g[_UV1] + b2 * g[_UV2]
            v = b0 * g[_UV0 + 1] + b1 * g[_UV1 + 1] + b2 * g[_UV2 + 1]
        return self._emitted(mat, u, v)

    def _albedo_at(self, mat, u, v) -> np.ndarray:
        return self._material_value(self._albedo, self._albedo_tex, mat, u, v)

    def _emitted(self, mat, u, v) -> np.ndarray:
        return self._material_value(self._emission, self._emission_tex, mat, u, v)

    def _material_value(self, table, tex_ids, mat, u, v) -> np.ndarray:
        """(3, N) constant colour per material, times its texture where it has one."""
        value = np.take(table, mat, axis=1)
        if not len(self.textures):
            return value
        tex = np.take(tex_ids, mat)
        for t in np.unique(tex[tex >= 0]):
            sel = np.flatnonzero(tex == t)
            su, sv = finite_uv(np.take(u, sel), np.take(v, sel))
            value[:, sel] *= self.textures[t].lookup(su, sv)
        return value


def _compact(idx, path, throughput, bsdf_pdf, rng):
    """Keep only the paths idx of the state that travels with every path."""
    return path[idx], np.take(throughput, idx, axis=1), np.take(bsdf_pdf, idx), rng.take(idx)


def _take(a: np.ndarray | None, idx: np.ndarray) -> np.ndarray | None:
    return None if a is None else np.take(a, idx)


def _accumulate(radiance: np.ndarray, paths: np.ndarray, value: np.ndarray) -> None:
    """radiance[:, paths] += value, one channel at a time (3x faster than the 2-D fancy index)."""
    for k in range(3):
        channel = radiance[k]
        channel[paths] += value[k]


def _plan_pass(width: int, height: int, done: int, total: int, wave_size: int):
    """Samples per pixel of the next pass and its bands of rows, one wave each.

    The first pass takes one sample, for a quick first image; later passes take enough samples to
    fill _WAVES_PER_PASS waves. The plan depends only on the image and the settings, never on the
    thread count, so every thread count sums the same numbers in the same order.
    """
    if done == 0:
        spp = 1
    else:
        spp = int(np.clip(wave_size * _WAVES_PER_PASS // (width * height), 1, total - done))
    rows_per_wave = max(1, min(wave_size // (width * spp), -(-height // _WAVES_PER_PASS)))
    bands = [(r, min(height, r + rows_per_wave)) for r in range(0, height, rows_per_wave)]
    return spp, bands


def _triangle_table(scene: SceneArrays) -> np.ndarray:
    """(T, 27) float32: p0, e1, e2, unit geometric normal, three corner normals, three corner UVs.
    Built column by column in float32, straight in the row layout the renderer gathers from."""
    p = scene.positions
    t = len(p)
    table = np.empty((t, _TABLE_ROWS), np.float32)
    e1 = p[:, 1] - p[:, 0]
    e2 = p[:, 2] - p[:, 0]
    ng = np.stack(_unit_rows(e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1],
                             e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2],
                             e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]), axis=1)
    table[:, _P0:_P0 + 3] = p[:, 0]
    table[:, _E1:_E1 + 3] = e1
    table[:, _E2:_E2 + 3] = e2
    table[:, _NG:_NG + 3] = ng
    for k, col in enumerate((_N0, _N1, _N2)):
        nk = scene.normals[:, k]
        x, y, z = nk[:, 0], nk[:, 1], nk[:, 2]
        length2 = x * x + y * y + z * z
        inv = np.float32(1.0) / np.sqrt(np.maximum(length2, np.float32(1e-37)))
        # A zero-length corner normal falls back to the face normal.
        zero = length2 < np.float32(1e-30)
        for j, c in enumerate((x, y, z)):
            table[:, col + j] = np.where(zero, ng[:, j], c * inv)
    for k, col in enumerate((_UV0, _UV1, _UV2)):
        table[:, col:col + 2] = scene.uvs[:, k]
    return table


def _unit_rows(x, y, z):
    inv = np.float32(1.0) / np.sqrt(np.maximum(x * x + y * y + z * z, np.float32(1e-37)))
    return x * inv, y * inv, z * inv


def _extent(positions: np.ndarray):
    """(lo, hi) corners of the geometry's bounding box, float64 (3,) each."""
    if not len(positions):
        return np.zeros(3), np.zeros(3)
    lo = np.array([positions[:, :, k].min() for k in range(3)], np.float64)
    hi = np.array([positions[:, :, k].max() for k in range(3)], np.float64)
    return lo, hi


def _ray_epsilon(lo: np.ndarray, hi: np.ndarray) -> np.float32:
    """Offset for spawned rays, scaled to the scene's extent (float32 keeps about 7 digits)."""
    extent = float(max(np.max(np.abs(lo)), np.max(np.abs(hi))))
    return np.float32(max(extent, 1e-3) * 1e-6)


def render(scene: SceneArrays, settings: RenderSettings = RenderSettings(), threads: int = 0,
           **callbacks) -> RenderResult:
    """Validate, build and render in one call. See Renderer.render for the callbacks."""
    with Renderer(scene, threads) as renderer:
        return renderer.render(settings, **callbacks)
