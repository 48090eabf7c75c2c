"""The Renderer: a scene built for rendering (BVH, triangle, shading and light tables), ready to render any
number of times (kernels/schedule.py runs the progressive loop, kernels/integrator.py traces a wave's paths),
updated in place between renders by the viewport's and the next frame's changes, and closed.
"""
from __future__ import annotations

import dataclasses
import functools
import weakref
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import numpy as np

from . import motion, panorama, passes, schedule, shadow_catcher
from .accel import Accel
from .camera import view_plane
from .environment import Environment
from .film import Film, pixel_sums
from .coincident import (Coincident, CopyGroups, InstanceCopies, copy_pairs, exact_copies, overlap_pairs,
                         overlapping_planes)
from .geometry import TriangleTable, prototype_boxes, scene_extent
from .geometry.primitives import PrimitiveTable, ShapeLayout
from .lights import LightSampler
from .lights.links import object_links
from .media.medium import Media
from .memory import kept_heap, small_pages, trim_heap
from .paths import GivenPaths, WavePaths
from .rng import PathRng
from .camera import camera_frame
from .scene import (OBJ_TERMINATOR, TERMINATOR_OFFSET, Camera, Lights, Materials, SceneArrays, World, corner_values,
                    same_arrays, same_triangles, usable_placements)
from .shading import Shading
from .shading.raytrace import ShaderRays
from .shading.world import WorldShader
from .textures import Texture
from .visibility import object_visibility
from . import integrator
from .lights import nee
from .schedule import Progress, RenderResult, WaveCrew, WaveJob, render_passes
from .settings import RenderSettings



class Cancelled(Exception):
    """should_stop() asked a Renderer to stop while it was being built."""


def _forwarded(method):
    """An incremental update that worker processes apply too (after this renderer did, without error), so
    that they stay its twins; updates called by updates are not sent again."""
    @functools.wraps(method)
    def update(self, *args, **kwargs):
        self._update_depth += 1
        try:
            result = method(self, *args, **kwargs)
        finally:
            self._update_depth -= 1
        if self._update_depth == 0 and result is not False:
            self.crew.forward(method.__name__, args, kwargs)
        return result
    return update


class Renderer:
    """A validated scene with its acceleration structure, ready to render any number of times; between
    renders, moved instances, edited materials and lights can be swapped in without building it again
    (update_instances, update_materials, update_lights: the viewport's incremental updates)."""

    @small_pages()  # a scene's arrays written once: no huge-page compaction stalls (kernels.memory)
    def __init__(self, scene: SceneArrays, threads: int = 0, should_stop: Callable[[], bool] | None = None,
                 reuse: "Renderer | None" = None, processes: bool | None = None):
        """should_stop() is polled between the stages of the build (each stage is one long C or NumPy
        call that cannot be interrupted); Cancelled is raised when it returns True.
        reuse : the renderer of an earlier frame (persistent data): its instanced meshes whose triangles
        have not changed keep their BVH (see also update_scene, which keeps everything).
        processes : whether waves may run in worker processes (threads - 1 of them, kernels/workers.py):
        None starts them when a render has WORKER_START_PATHS paths, or WORKER_START_S left by its rate
        after a wave; True now; False never. The image is the same bit for bit wherever its waves run."""
        self._update_depth = 0
        self.crew: WaveCrew | None = None   # where the waves run (kernels.schedule), once the BVH says the threads
        def poll():
            if should_stop is not None and should_stop():
                raise Cancelled()
        poll()
        checked = scene.validate()
        self.scene = checked.scene
        self.dropped_triangles = checked.dropped_triangles
        self.nonfinite_triangles = checked.nonfinite_triangles
        self.dropped_shapes = checked.dropped_shapes
        poll()
        moving = self.scene.has_motion and self.scene.motion_ids is not None
        # Curves and points follow the triangles in the numbering of hits (kernels/geometry/primitives.py).
        self.shapes = ShapeLayout(self.scene, self.scene.triangle_count + self.scene.instanced_triangle_count) \
            if self.scene.has_shapes else None
        # Embree builds its BVH (C code, the GIL released) while NumPy builds the shading tables.
        with ThreadPoolExecutor(1, "ember-bvh") as builder:
            accel = builder.submit(Accel, self.scene.positions, threads,
                                   *((self.scene.motion_ids, self.scene.motion, self.scene.motion_reference)
                                     if moving else (None, (), ())), instances=self.scene.instances,
                                   reuse=reuse.accel if reuse is not None and reuse.accel is not None else None,
                                   indexed=(self.scene.bvh_vertices, self.scene.bvh_indices)
                                   if self.scene.bvh_vertices is not None else None, shapes=self.shapes,
                                   deform=(self.scene.deform_ids, self.scene.deform_positions)
                                   if self.scene.has_motion and self.scene.deform_ids is not None else None)
            try:
                poll()
                # Triangles near float32's limits overflow in their normals: paths that hit them are
                # dropped and counted like any non-finite path, so NumPy need not print about them.
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    self._build_tables(poll)
            except BaseException:
                error = accel.exception()
                if error is None:
                    accel.result().close()
                raise
            self.accel = accel.result()
        self._give_shader_rays()
        self._build_media()
        trim_heap()
        self.crew = WaveCrew(self.accel.threads, processes)
        if self.crew.processes:
            self.start_workers()

    def start_workers(self) -> bool:
        """Start the worker processes now (they join the waves as they become ready); False when this
        renderer does not use them (one thread, processes=False, no Python to start, a big scene: its triangles,
        curve segments and points counted together, since a child builds its own BVH of them all)."""
        primitives = len(self.triangles.material_ids)
        if self.shapes is not None:
            primitives += self.shapes.total - self.shapes.triangle_count
        return self.crew.start_workers(self.scene, primitives, f"{type(self).__module__}:{type(self).__qualname__}")

    @property
    def stop_waves(self):
        """Set while the waves of the render in progress are to leave at their next bounce."""
        return self.crew.stop_waves

    def _build_tables(self, poll) -> None:
        self.triangles = TriangleTable(self.scene, deferred=True)
        if self.shapes is not None:   # hits on curves and points answered beside the triangles'
            self.triangles = PrimitiveTable(self.triangles, self.scene, self.shapes)
        # Motion blur: each moving object's decomposed motion and the inverse of the matrix its stored
        # positions were made with (hits are moved from there to where the object is at the path's time).
        self.motion = motion.decompose_many([np.asarray(keys, np.float64) for keys in self.scene.motion])
        self.motion_inverse = np.array([np.linalg.inv(np.asarray(ref, np.float64)) for ref in self.scene.motion_reference],
                                       np.float64).reshape(-1, 4, 4)
        # Hits move by them all at once (integrator._hit_motion): each object's stack and its place in it.
        self.motion_stacks = motion.stack_by_steps(self.motion)
        self.motion_stack_of = np.zeros(len(self.motion), np.int64)
        self.motion_place = np.zeros(len(self.motion), np.int64)
        for k, (members, _) in enumerate(self.motion_stacks):
            self.motion_stack_of[members], self.motion_place[members] = k, np.arange(len(members))
        poll()
        self._build_shading()
        self.pixel_size = _pixel_spread(self.scene.camera)
        self.camera_frame = camera_frame(self.scene.camera)
        self.prototype_boxes = prototype_boxes(self.scene)
        self.ray_epsilon = _ray_epsilon(*scene_extent(self.scene, self.prototype_boxes))
        self.lights = self._light_sampler()
        # The copies and overlaps depend on the triangles and on which stop rays: kept for material edits
        # (update_materials).
        self._blocking = blocking_triangles(self.scene, self.shading)
        self._copies = static_copies(self.scene, self.ray_epsilon, self._blocking)
        self._copy_groups = static_copy_groups(self.scene, self._blocking)
        self._opaque = opaque_triangles(self.scene, self.shading)
        self._overlaps = static_overlaps(self.scene, self.ray_epsilon, self._opaque)
        self.coincident = coincident_partners(self.scene, self.shading, self.ray_epsilon, self._opaque,
                                              self._copies, self._overlaps, self._copy_groups)
        self.terminator = terminator_offsets(self.scene)
        self.visibility = object_visibility(self.scene)
        self.links = object_links(self.scene)   # Light and Shadow Linking (None: none)
        poll()

    def _build_shading(self) -> None:
        """Textures, materials and the world: what a material edit rebuilds (update_materials)."""
        srgb = self.scene.texture_srgb or (False,) * len(self.scene.textures)
        self.textures = [Texture(t, bool(flag)) for t, flag in zip(self.scene.textures, srgb)]
        self.shading = Shading(self.scene.materials, self.textures, self.scene, self.triangles)
        world = self.scene.world
        self.environment = Environment(world, WorldShader(world, self.shading.data) if world.program else None)
        # Smooth glass finds the world along both branches (glass_escapes.py) unless the world's radiance
        # depends on the ray, which the branch not taken has no path state for.
        self.glass_escapes_on = not self.environment.varies_with_ray
        self.emissive = bool(self.shading.emissive.any())
        # Whether a material that triangles use mixes lobes (the automatic wave size; rows nothing uses,
        # such as the default material's, do not count).
        layered = self.shading.layered
        used = np.bincount(self.triangles.material_ids, minlength=len(layered))[:len(layered)] > 0
        if self.shapes is not None:
            used[self.triangles.shape_materials()] = True
        self.layered = bool((layered & used).any())

    def _give_shader_rays(self) -> None:
        """What the Ambient Occlusion and Bevel nodes trace with (raytrace.ShaderRays): the BVH, the triangle
        table, the ray offset's scale; again when any of these or the shading changes."""
        self.shading.data.rays = ShaderRays(self.accel, self.triangles, self.ray_epsilon,
                                            self.scene.world.ao_distance, self.visibility)

    def _build_media(self) -> None:
        """The participating media (kernels.media) and the stack camera paths start with; None without."""
        self.media, self.camera_media = None, None
        if not (any(s.volume for s in self.scene.materials.shaders) or self.scene.world.volume is not None):
            return
        self.triangles.wait_rows()
        self.media = Media(self.shading, self.triangles, self.scene.world.volume,
                           scene_extent(self.scene, self.prototype_boxes), self.shading.data, self.scene.volumes,
                           self.scene.instances)
        eye, _ = self.camera_frame
        self.camera_media = self.media.start_stack(1, self.accel, eye)[:, 0]
        # Smooth glass's second branch (glass_escapes.py) does not know the media along it.
        self.glass_escapes_on = False

    def _light_sampler(self) -> LightSampler:
        return LightSampler(self.scene, self.environment, _Emitters(self), self.shading.data)

    def wave_size(self, settings: RenderSettings) -> int:
        """The paths per wave a render with these settings uses (their wave_size, or the automatic one)."""
        if settings.wave_size is not None:
            return int(settings.wave_size)
        return schedule.WAVE_SPAN * self._live_paths()

    def live_paths(self, settings: RenderSettings) -> int:
        """The most paths a wave traces at once (what bounds its memory)."""
        return min(self.wave_size(settings), self._live_paths())

    def _live_paths(self) -> int:
        return schedule.LAYERED_WAVE_SIZE if self.layered else schedule.WAVE_SIZE

    @_forwarded
    def set_camera(self, camera: Camera) -> None:
        """Look through another camera without rebuilding anything (the viewport's view changes).
        Call between renders, never during one."""
        camera.validate()
        self.scene = dataclasses.replace(self.scene, camera=camera)
        self.pixel_size = _pixel_spread(camera)
        self.camera_frame = camera_frame(camera)
        self.shading.data.set_camera(camera)
        if self.media is not None:   # the media the eye is in
            self.camera_media = self.media.start_stack(1, self.accel, self.camera_frame[0])[:, 0]

    # ---------------------------------------------------------------- incremental updates
    # The viewport changes a built scene in place rather than building it again (Cycles' Blender sync
    # tags what changed the same way). Each update leaves the renderer as a new Renderer of the changed
    # scene would be, table for table, so the images are the same bit for bit. They raise ValueError
    # before changing anything when the change does not fit the built scene (the caller then builds a
    # new Renderer). Call them between renders, never during one.

    @_forwarded
    def update_instances(self, world_from_object: np.ndarray, objects: np.ndarray | None = None,
                         lights: bool = True) -> None:
        """Move the scene's instances (kernels.scene.Instances): world_from_object (K, 4, 4) float64, one per
        instance of the built scene, in its order; objects: the object table with the moved objects' rows
        (SceneArrays.objects, the same rows), None to keep it. The plain triangles stay where they are.

        Rebuilt: the top level of the BVH (the meshes' BVHs are kept), the triangle table's instance
        matrices, the object table, which instances lie on each other (InstanceCopies), the ray offset's scene
        scale, and the light sampler when an emissive
        instance moved (lights=False leaves that to the caller, which rebuilds it anyway). Nothing else
        depends on where instances are."""
        inst = self.scene.instances
        if inst is None or not inst.count:
            raise ValueError("update_instances: the scene has no instances")
        if self.shapes is not None:
            raise ValueError("update_instances: a scene with curves or points is built whole")
        if self.scene.has_motion or self.scene.vector_motion is not None:
            raise ValueError("update_instances: a scene with motion blur or a Vector pass is built whole")
        m = np.asarray(world_from_object, np.float64)
        if m.shape != inst.world_from_object.shape:
            raise ValueError(f"update_instances: {m.shape[0] if m.ndim else 0} transforms for {inst.count} instances")
        if not usable_placements(m).all():
            raise ValueError("update_instances: a transform is not finite or flattens its mesh")
        emitters_moved = self._emitters_moved(inst, m)
        moved = dataclasses.replace(inst, world_from_object=np.ascontiguousarray(m))
        scene = dataclasses.replace(self.scene, instances=moved,
                                    objects=self.scene.objects if objects is None else objects)
        rows = None if self.scene.objects is None else self.scene.objects.shape
        if (None if scene.objects is None else scene.objects.shape) != rows:
            raise ValueError("update_instances: the object table must keep its rows")
        scene.validate_objects()
        self.scene = scene
        self.accel.move_instances(moved.world_from_object)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            self.triangles.place(moved, scene.objects)
        self.coincident = instance_copies(self.coincident, scene, self.shading, self._opaque)
        self.shading.data.set_objects(scene.objects)
        self.terminator = terminator_offsets(self.scene)
        self.ray_epsilon = _ray_epsilon(*scene_extent(scene, self.prototype_boxes))
        self._give_shader_rays()
        if emitters_moved and lights:
            self.lights = self._light_sampler()
        if self.media is not None:
            self._build_media()

    def _emitters_moved(self, instances, world_from_object: np.ndarray) -> bool:
        """Whether an instance whose prototype has emissive triangles gets another transform."""
        if not self.lights.instanced_emitters:
            return False
        emits = np.array([self.shading.emissive[p.material_ids].any() for p in instances.prototypes])
        moved = (world_from_object != instances.world_from_object).any(axis=(1, 2))
        return bool(emits[instances.prototype[moved]].any())

    @_forwarded
    def update_materials(self, materials: Materials, textures: tuple = (), texture_srgb: tuple = (),
                         world: World | None = None) -> None:
        """New materials, textures and world (None: keep it): a material, node tree, image or world edit.
        The material table keeps its rows (triangles keep their material ids). Rebuilt: the textures, the
        shading tables and node programs, the environment and the light sampler; geometry and BVHs are
        kept."""
        scene = dataclasses.replace(self.scene, materials=materials, textures=tuple(textures),
                                    texture_srgb=tuple(texture_srgb),
                                    world=self.scene.world if world is None else world)
        scene.validate_shading()
        self.scene = scene
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            self._build_shading()
            self._give_shader_rays()
            self.lights = self._light_sampler()
            blocking = blocking_triangles(self.scene, self.shading)
            if not np.array_equal(blocking, self._blocking):
                self._blocking, self._copies = blocking, static_copies(self.scene, self.ray_epsilon, blocking)
                self._copy_groups = static_copy_groups(self.scene, blocking)
            opaque = opaque_triangles(self.scene, self.shading)
            if not np.array_equal(opaque, self._opaque):
                self._opaque, self._overlaps = opaque, static_overlaps(self.scene, self.ray_epsilon, opaque)
            self.coincident = coincident_partners(self.scene, self.shading, self.ray_epsilon, self._opaque,
                                                  self._copies, self._overlaps, self._copy_groups)
            self._build_media()

    @_forwarded
    def update_scene(self, scene: SceneArrays) -> bool:
        """The next frame of an animation with persistent data: when its geometry is this renderer's (the
        plain triangles and the instanced meshes equal array for array, the same instances in the same
        order, nothing moving during the shutter), swap in what a frame may change (the instances'
        transforms and the object table, materials, textures and world, lights, camera, Cryptomatte ids)
        and return True: the renderer is then as a new Renderer of `scene` would be, and its images the
        same bit for bit. Otherwise return False, changing nothing (build a new Renderer, with reuse=self to
        keep the BVHs of unchanged meshes). Raises ValueError for invalid data, as Renderer() does."""
        checked = scene.validate(clean=self.scene)
        new, old = checked.scene, self.scene
        if new.has_motion or old.has_motion or new.vector_motion is not None or old.vector_motion is not None:
            return False
        if new.volumes or old.volumes:   # voxel grids (a VDB sequence's frame) are read again with the scene
            return False
        if new.has_shapes or old.has_shapes:   # curves and points (hair that grows, points that move) are built again
            return False
        if not (same_triangles(new, old) and _same_instances(new.instances, old.instances)
                and (new.objects is None) == (old.objects is None)
                and (new.objects is None or new.objects.shape == old.objects.shape)):
            return False
        if new.instances is not None and new.instances.count:
            self.update_instances(new.instances.world_from_object, new.objects, lights=False)
        elif new.objects is not None:
            self.scene = dataclasses.replace(self.scene, objects=new.objects)
            self.shading.data.set_objects(new.objects)
            self.terminator = terminator_offsets(self.scene)
        self.scene = dataclasses.replace(self.scene, object_visibility=new.object_visibility,
                                         light_links=new.light_links, light_groups=new.light_groups)
        self.visibility = object_visibility(self.scene)
        # The lights go in first: update_materials then builds the light sampler once, for everything.
        self.scene = dataclasses.replace(self.scene, lights=new.lights)
        self.links = object_links(self.scene)
        self.update_materials(new.materials, new.textures, new.texture_srgb, new.world)
        self.set_camera(new.camera)
        self.scene = dataclasses.replace(self.scene, crypto_ids=new.crypto_ids)
        self.dropped_triangles = checked.dropped_triangles
        self.nonfinite_triangles = checked.nonfinite_triangles
        return True

    @_forwarded
    def update_lights(self, lights: Lights) -> None:
        """New Blender lights (moved, edited, added or removed): only the light sampler is rebuilt."""
        lights.validate()
        self.scene = dataclasses.replace(self.scene, lights=lights)
        self.links = object_links(self.scene)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            self.lights = self._light_sampler()

    def close(self) -> None:
        """Stop the threads and drop the big arrays now: the light sampler calls back into this
        renderer, a reference cycle that plain reference counting would never free."""
        if self.crew is not None:
            self.crew.close()
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

        on_tile(film, row0, row1) runs after each wave with the span of region rows it refined (a wave's band
        is every few rows of the span: kernels.schedule.plan_pass);
        on_progress(progress) reports after each wave. should_stop() is polled after each wave, every
        STOP_POLL_S while the render waits for one, and between the bounces of waves on the render's own
        thread; once it is True the waves in flight (worker processes' too) leave at their next bounce, and
        what they had done is dropped.
        """
        # A clamped render chooses lights as Cycles' tree does (Lights.clamped): its lights follow the settings.
        clamped = settings.clamp_direct > 0 or settings.clamp_indirect > 0
        if clamped != bool(self.scene.lights.clamped):
            self.update_lights(dataclasses.replace(self.scene.lights, clamped=clamped))
        # A scene with shadow catchers records their planes, whatever passes were asked for (Cycles' film.cpp).
        settings = shadow_catcher.with_planes(settings, self.visibility)
        with kept_heap():   # the waves' arrays are freed and made again at every bounce
            return render_passes(self, self.crew, settings, on_tile, should_stop, on_progress)

    def prepare_pass(self) -> None:
        """More than a quick first pass is to come: a big scene's deferred triangle table is built (until then,
        gathers compute the rows they need)."""
        self.triangles.build_rows()

    def render_wave(self, settings: RenderSettings, job: WaveJob):
        """One wave (kernels.schedule.WaveJob: its band of rows, samples, pixels and live paths).
        Returns ((rows, W, 4) float64 sums, (rows, W, 3) sums of the odd samples, (rows, W) sample counts,
        count of dropped non-finite paths, the passes' planes or None, the seconds of the wave's tail
        (integrator.trace's timing)). Paths are pixel-major so each pixel's samples are adjacent; what
        each path starts from (pixel, sample, random numbers) is made as its batch starts, so that the wave
        holds only its radiance and alpha per path."""
        x0, y0, width, band = job.x0, job.y0, job.width, job.rows
        first_sample, spp, split, active, live = job.first_sample, job.spp, job.split, job.active, job.live
        rows = len(band)
        npix = rows * width
        pixels = np.arange(npix, dtype=np.int64) if active is None else np.flatnonzero(active)
        image_rows = range(y0 + band.start, y0 + band.stop, band.step)
        paths = WavePaths(settings, self.scene.camera, x0, image_rows, width, pixels, first_sample, spp)
        n = len(paths)
        # Overflow and invalid values are expected at the edges of float32 (huge lights, degenerate
        # geometry): the paths they spoil are dropped and counted below, not printed by NumPy. errstate
        # is per thread, so it is set here, in the thread that runs the wave.
        aux = passes.wave_buffers(settings, n)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
            timing = {}
            radiance, alpha = integrator.trace(self, paths, settings, split, aux=aux,
                                               live=self.live_paths(settings) if live is None else live,
                                               timing=timing)
        bad = ~np.isfinite(radiance).all(axis=0)
        n_bad = int(np.count_nonzero(bad))
        if n_bad:
            radiance[:, bad] = 0.0
            for values in (passes.wave_groups(aux) or {}).values():   # the groups add up to the image still
                values[:, bad] = 0.0
        del bad
        sums, half = pixel_sums(radiance, alpha, pixels, npix, first_sample, spp, settings.adaptive_threshold > 0)
        counts = np.zeros(npix, np.int64)
        counts[pixels] = spp
        if half is not None:
            half = half.reshape(rows, width, 3)
        aux_out = None if aux is None else passes.wave_planes(aux, settings, *paths.pixel_and_sample(), pixels, spp,
                                                              rows, width, radiance)
        return sums.reshape(rows, width, 4), half, counts.reshape(rows, width), n_bad, aux_out, timing["tail_s"]

    # ---------------------------------------------------------------- one wave of paths
    def trace_paths(self, rng: PathRng, row: np.ndarray, col: np.ndarray, settings: RenderSettings,
                    split: bool = True, strata=None, aux: dict | None = None, live: int | None = None):
        """Trace one path per (row, col) entry. Returns radiance (3, N) float32 and alpha (N,) float32.

        strata = (pixel, sample, index) per path (samples.sample_strata): in NEE_MIS mode the camera
        jitter and the first vertex's light and BSDF numbers then come from the stratified sequence (the
        rest of the path, and the LECTURE and COSINE modes, use the PCG2D stream alone). live: see _trace."""
        return integrator.trace(self, GivenPaths(rng, row, col, strata), settings, split, aux, live)


def _same_instances(a, b) -> bool:
    """The same prototypes (array for array), placed by the same number of instances in the same order
    (their transforms may differ)."""
    if a is None or b is None or not a.count or not b.count:
        return (a is None or not a.count) and (b is None or not b.count)
    return (len(a.prototypes) == len(b.prototypes) and same_arrays(a.prototype, b.prototype)
            and same_arrays(a.object_ids, b.object_ids)
            and all(same_triangles(p, q) for p, q in zip(a.prototypes, b.prototypes)))

def terminator_offsets(scene: SceneArrays):
    """Each object row's Shadow Terminator Geometry Offset (SceneArrays.objects), one for all without an
    object table, or None when every object has it off."""
    objects = scene.objects
    if objects is None or not len(objects):
        return np.float32(TERMINATOR_OFFSET)
    values = objects[:, OBJ_TERMINATOR]
    return values if (values > 0).any() else None


# Scenes with more static opaque triangles than this do not look for faces overlapping in part (coincident_partners).
OVERLAP_SCENE_LIMIT = 250_000
# Scenes with more static triangles that stop shadow rays than this do not look for copies by their edges
# (static_copies): the search sorts three keys a triangle, which for 10M triangles takes longer than Cycles takes to
# its first sample. Up to EXACT_COPY_SCENE_LIMIT they look for exact copies alone (one key a triangle: about 1 s for
# 19M triangles without copies, 2.3 s with 10M in groups), kept as groups (coincident.CopyGroups).
COPY_SCENE_LIMIT = 2_000_000
EXACT_COPY_SCENE_LIMIT = 64_000_000


def coincident_offset(ray_epsilon):
    """offset(|p|max) for Coincident.find: the distance spawned rays move off a surface (interaction.spawn_offset)."""
    return lambda size: ray_epsilon + np.float32(2.0 ** -16) * size


def opaque_triangles(scene: SceneArrays, shading) -> np.ndarray:
    """(T,) bool: the triangles whose material neither transmits nor lets shadows through (those a ray meets and
    stops at)."""
    return ~np.take(shading.transmissive | shading.shadow_transparent, scene.material_ids)


def blocking_triangles(scene: SceneArrays, shading) -> np.ndarray:
    """(T,) bool: the triangles whose material stops shadow rays (all but those whose shadows pass: a Transparent
    BSDF, alpha, Transparent Shadows): a copy of one of them is met by rays leaving the other, glass or not."""
    return ~np.take(shading.shadow_transparent, scene.material_ids)


def static_copies(scene: SceneArrays, ray_epsilon, blocking: np.ndarray) -> np.ndarray:
    """coincident.copy_pairs among the plain triangles that stop shadow rays (blocking_triangles: Cycles' rays, which
    skip only the triangle they leave, meet a copy of it at once, and its shadow rays stop there, an opaque copy or
    a glass one; the pairs of a doubled face whose shadows pass would cost time and do nothing), without those that
    move or deform during the shutter (where a copy lies then is not where it lies at the frame). None found in
    scenes of more than COPY_SCENE_LIMIT of them."""
    rows = np.flatnonzero(blocking & still_triangles(scene))
    if len(rows) < 2 or len(rows) > COPY_SCENE_LIMIT:
        return np.zeros(0, np.int64)
    t, m = len(scene.material_ids), len(rows)
    if m == t:   # all of them (most scenes): no gathered copy of the positions
        return copy_pairs(scene.positions, coincident_offset(ray_epsilon))
    pairs = copy_pairs(corner_values(scene.positions, rows), coincident_offset(ray_epsilon))
    return rows[pairs // m] * t + rows[pairs % m]


def static_copy_groups(scene: SceneArrays, blocking: np.ndarray) -> CopyGroups | None:
    """coincident.exact_copies among the still plain triangles that stop shadow rays, in scenes of more than
    COPY_SCENE_LIMIT and at most EXACT_COPY_SCENE_LIMIT of them (where static_copies finds none), or None."""
    rows = np.flatnonzero(blocking & still_triangles(scene))
    if len(rows) <= COPY_SCENE_LIMIT or len(rows) > EXACT_COPY_SCENE_LIMIT:
        return None
    every = len(rows) == len(scene.material_ids)
    members, starts = exact_copies(scene.positions if every else corner_values(scene.positions, rows))
    if not len(members):
        return None
    return CopyGroups(members if every else rows[members], starts, scene.positions)


def still_triangles(scene: SceneArrays, deforming: bool = True) -> np.ndarray:
    """(T,) bool: the triangles that do not move during the shutter (nor deform, with deforming): where they lie at
    the frame is where rays meet them."""
    still = np.ones(len(scene.material_ids), bool)
    if scene.has_motion:
        for ids in (scene.motion_ids, scene.deform_ids if deforming else None):
            if ids is not None:
                still &= ids < 0
    return still


def static_overlaps(scene: SceneArrays, ray_epsilon, opaque: np.ndarray) -> np.ndarray | None:
    """coincident.overlap_pairs among the still opaque triangles (opaque_triangles): faces overlapping in part in
    one plane, which Cycles' rays leaving one meet at once; None in scenes of more than OVERLAP_SCENE_LIMIT of them
    (the search costs about a second per million triangles whatever it finds: a big scene's first sample took
    0.2 s before it)."""
    candidates = opaque & still_triangles(scene)
    if np.count_nonzero(candidates) > OVERLAP_SCENE_LIMIT:
        return None
    offset = coincident_offset(ray_epsilon)
    across, asking, within = overlapping_planes(scene.positions, candidates, offset, scene.object_ids)
    return overlap_pairs(scene.positions, offset, scene.object_ids, across, asking, within,
                         scene.mirrored_triangles())


def coincident_partners(scene: SceneArrays, shading, ray_epsilon, opaque: np.ndarray, copies: np.ndarray,
                        overlaps: np.ndarray | None, groups: CopyGroups | None = None) -> Coincident | None:
    """The coincident partners (kernels.coincident) of the still plain triangles rays may pass through, the
    overlaps (static_overlaps' pairs: a wall's end face on the floor's rim or on its own mesh's next face, met where
    they overlap) and the copies (static_copies' pairs, met whatever their material, as in Cycles: a duplicated face
    shades its copy; groups: static_copy_groups' in scenes too large for pairs), and the instances placed twice at
    one transform (InstanceCopies); with `opaque` (opaque_triangles: the other partners a ray leaving their partner meets and
    stops at)."""
    through = np.take(shading.transmissive, scene.material_ids) if len(scene.material_ids) else np.zeros(0, bool)
    through &= still_triangles(scene, deforming=False)
    found = Coincident.find(scene.positions, through, coincident_offset(ray_epsilon), scene.object_ids,
                            copies=copies, overlaps=overlaps)
    if groups is not None:
        found = Coincident.empty(scene.positions, scene.object_ids) if found is None else found
        found.groups = groups
    if found is not None:
        found.opaque = opaque
    return instance_copies(found, scene, shading, opaque)


def instance_copies(found: Coincident | None, scene: SceneArrays, shading, opaque: np.ndarray) -> Coincident | None:
    """found (coincident_partners' plain partners, or None) with the scene's instances placed twice at one
    transform (InstanceCopies), or without any where none are: a Coincident of no plain partners when need be."""
    placed_twice = InstanceCopies.find(scene.instances, len(scene.material_ids),
                                       ~(shading.transmissive | shading.shadow_transparent))
    if placed_twice is None:
        if found is not None and not len(found.partners) and found.groups is None:
            return None
        if found is not None:
            found.instances = None
        return found
    if found is None:
        found = Coincident.empty(scene.positions, scene.object_ids)
        found.opaque = opaque
    found.instances = placed_twice
    return found


class _Emitters:
    """The light sampler's view of the emissive materials (see LightSampler)."""

    def __init__(self, renderer: "Renderer"):
        # Materials that emit and are light-sampled (not Emission Sampling None).
        self.emissive = renderer.shading.emissive & np.array(
            [shader.light_sampled for shader in renderer.scene.materials.shaders], bool)
        self.varies = renderer.shading.emission_varies
        self._renderer = weakref.proxy(renderer)

    def __call__(self, tri, b1=None, b2=None, toward=None, dist=None):
        return nee.triangle_emission(self._renderer, tri, b1, b2, toward, dist)


def _pixel_spread(camera: Camera) -> float:
    """View-plane units per pixel: the spread of camera rays (perspective: radians at the centre;
    panoramas: Cycles' differential at the frame's centre)."""
    if camera.kind == "PANO":
        return float(panorama.pixel_spread(camera))
    xmin, xmax, _, _ = view_plane(camera)
    return float(xmax - xmin) / max(camera.width, 1)


def _ray_epsilon(lo: np.ndarray, hi: np.ndarray) -> np.float32:
    """The absolute part of the offset of spawned rays (the relative part, 2^-16 |p|, is in _offset):
    scaled down with tiny scenes, and never above Cycles' 2^-16 near the origin, so that a huge ground
    plane far away does not lift every ray in the scene off its surface."""
    extent = float(max(np.max(np.abs(lo)), np.max(np.abs(hi))))
    return np.float32(min(max(extent, 1e-3) * 1e-6, 2.0 ** -16))


def render(scene: SceneArrays, settings: RenderSettings = RenderSettings(), threads: int = 0,
           **callbacks) -> RenderResult:
    """Validate, build and render in one call. See Renderer.render for the callbacks."""
    with Renderer(scene, threads) as renderer:
        return renderer.render(settings, **callbacks)
