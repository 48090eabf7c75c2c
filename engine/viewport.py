"""The viewport's rendered mode: a progressive render that starts over when the scene or the view changes.

Three layers, so that everything but the last few GPU calls runs headless in tests:

    export.camera     region_camera: the 3D view's projection (Blender's BKE_camera_params_from_view3d) as
                      a kernels.Camera, which compares by value: equal cameras render equal images
    ViewportSession   a worker thread that restarts a session.ProgressiveSession on every change and
                      publishes Frames, a quick low-resolution preview first; no bpy anywhere
    ViewportRender    the RenderEngine's view_update / view_draw: reads bpy on the main thread, hands the
                      session arrays and numbers, and draws the latest Frame with the gpu module

Sync once, snapshot, let go (as in session.py): the worker sees only SceneArrays, RenderSettings and
kernels.Camera values. It never touches bpy, and bpy never waits for it except in stop().

Edits update incrementally, as Cycles' Blender sync tracks what changed: view_update has
depsgraph.updates sorted into parts (engine/export/updates.py, per data type). A moved object re-reads only the instances' transforms and
object rows, and the worker moves its Renderer's instances (the top level of the BVH is recommitted, no
mesh BVH is rebuilt); a shader, image or world edit re-reads the materials and the world, and the
worker rebuilds shading, environment and light sampler; a light edit re-reads the lights, and the worker
rebuilds the light sampler (ProgressiveSession.load applies them). Anything else, or a partial read that
no longer lines up with the last export (engine/export/updates.py), is a full export and a new Renderer.
To make moves cheap the viewport exports every mesh as an instance of itself
(export_scene(..., instance_everything=True)), as Cycles' viewport does: its dynamic BVH type skips
apply_static_transforms, so every object keeps its own BVH and its transform; final renders copy single
meshes into world space, which traces faster (about 20% here, bench/viewport_updates.py). An update
restarts from sample 0 and renders what a full export of the edited scene would, bit for bit
(tests/test_viewport_updates.py).
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import weakref
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..kernels import Camera, Renderer, RenderSettings, SceneArrays
from .export import ExportError, export_scene
from .export.camera import region_camera, stand_in_camera, view_camera_object
from .export.updates import FULL, export_changes, scene_changes, visibility_key
from .session import PreviewDenoiser, ProgressiveSession, render_settings, render_threads

# The largest finite half float: the texture is RGBA16F and an inf there turns the viewport black.
HALF_MAX = 65504.0
# scene.ember.preview_samples = 0 means "until the view changes"; this is the property's own maximum.
UNLIMITED_SAMPLES = 1 << 24
# A restart first renders one sample at a resolution with about this many pixels, so that orbiting
# the view answers at once even when a full-resolution sample takes seconds.
PREVIEW_PIXELS = 1 << 14
# The worker publishes a copy of the image at most this often (the first and the last always go out).
DISPLAY_INTERVAL_S = 0.1
# stop() waits this long for the worker; it finishes the waves in flight, which take milliseconds.
STOP_TIMEOUT_S = 10.0


# ====================================================================== images for the display
class Frame(NamedTuple):
    """One published image. image : (H, W, 4) float32, read-only, row 0 at the top, finite and within
    the half-float range. samples_done counts full-resolution samples (0 for the quick preview)."""
    image: np.ndarray
    samples_done: int
    samples_total: int
    generation: int


def display_pixels(image: np.ndarray) -> np.ndarray:
    """A float32 copy that an RGBA16F texture can hold: NaN -> 0, everything clamped to +-HALF_MAX."""
    out = np.nan_to_num(np.asarray(image, np.float32), nan=0.0, posinf=HALF_MAX, neginf=-HALF_MAX)
    return np.clip(out, -HALF_MAX, HALF_MAX, out=out)


def gpu_pixels(image: np.ndarray) -> np.ndarray:
    """(H*W*4,) float32, contiguous, bottom row first: the order gpu.types.GPUTexture reads."""
    return np.ascontiguousarray(image[::-1], np.float32).reshape(-1)


def preview_size(width: int, height: int, pixels: int) -> tuple[int, int] | None:
    """Film size of the quick first pass (same aspect, about `pixels` pixels); None when the full
    resolution is already that small."""
    scale = math.sqrt(width * height / max(pixels, 1))
    if scale < 2.0:
        return None
    return max(1, round(width / scale)), max(1, round(height / scale))


def upsample(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """Nearest-neighbour resize of (h, w, C) to (height, width, C)."""
    rows = np.arange(height) * image.shape[0] // height
    cols = np.arange(width) * image.shape[1] // width
    return image[rows][:, cols]


def status_text(frame: Frame | None, busy: bool, error: str | None) -> str:
    """The line Blender shows in the viewport's corner, in Cycles' words."""
    if error:
        return f"Ember: {error}"
    if frame is None:
        return "Ember: preparing" if busy else ""
    if frame.samples_done == 0:
        return "Ember: preview"
    if frame.samples_total >= UNLIMITED_SAMPLES:
        return f"Sample {frame.samples_done}"
    return f"Sample {frame.samples_done}/{frame.samples_total}"


# ====================================================================== the worker
@dataclass(frozen=True)
class _Job:
    generation: int
    scene: SceneArrays
    scene_version: int
    settings: RenderSettings
    camera: Camera
    denoise: tuple | None = None   # (quality, prefilter) of the previews' denoiser, or None
    updates: tuple = ()            # ((part, arguments), ...) to apply to the renderer of scene_version


_live_sessions: "weakref.WeakSet[ViewportSession]" = weakref.WeakSet()


def stop_all_sessions() -> None:
    """Stop every viewport worker (add-on unregister: no thread may outlive the code it runs)."""
    for session in list(_live_sessions):
        session.stop()


class ViewportSession:
    """Renders the latest scene, settings and view progressively on a worker thread.

    Every change bumps a generation: the running render stops after the waves in flight (its
    should_stop compares generations) and the worker starts over from sample 0 with the newest
    state. Changes that arrive while the worker is busy coalesce, so dragging a slider costs one
    restart per wave at most, not one per event. One session per engine instance (quad view has four).

        session.update_scene(scene_arrays, settings)   # after an export: the worker builds a new Renderer
        session.update_instances(world_from_object, objects)   # objects moved: the built one is updated,
        session.update_materials(materials, textures, srgb, world)  # ... shaders edited
        session.update_lights(lights)                  # ... lights changed
        session.update_view(camera)                    # every draw, a kernels.Camera: restarts if it differs
        frame = session.snapshot()                     # latest Frame or None, never blocks on the render
        session.stop()                                 # joins the worker

    The partial updates are queued (the newest of each part wins: each carries that whole part) and the
    worker's ProgressiveSession applies them to its Renderer before the next render (load: update_instances
    and friends); the session's scene takes them at once, so that a rebuild, whenever one is needed (no
    renderer yet, an update that does not fit it), renders the same scene.
    """

    def __init__(self, threads: int = 0, *, preview_pixels: int = PREVIEW_PIXELS,
                 display_interval_s: float = DISPLAY_INTERVAL_S):
        self._threads = threads
        self._preview_pixels = preview_pixels
        self._display_interval_s = display_interval_s
        self._cond = threading.Condition()
        # State shared with the worker; every access holds self._cond.
        self._scene: SceneArrays | None = None
        self._scene_version = 0       # bumped by update_scene only: the worker then builds a new Renderer
        self._pending: dict[str, tuple] = {}   # part -> the newest arguments of its Renderer.update_*
        self._settings: RenderSettings | None = None
        self._denoise: tuple | None = None
        self._camera: Camera | None = None
        self._generation = 0          # bumped by every restart; the worker compares it to its job's
        self._started = -1            # generation the worker last picked up
        self._busy = False            # the current generation is not finished yet
        self._stopping = False
        self._samples_done = 0
        self._frame: Frame | None = None
        self._taken: Frame | None = None   # the frame snapshot() last handed out
        self._error: str | None = None
        self._thread: threading.Thread | None = None
        _live_sessions.add(self)

    # ------------------------------------------------------------------ main thread
    def update_scene(self, scene: SceneArrays, settings: RenderSettings, denoise: tuple | None = None) -> bool:
        """A new export: always restarts (the arrays are new even when the edit changed nothing)."""
        with self._cond:
            self._scene = scene
            self._scene_version += 1
            self._pending.clear()
            self._settings, self._denoise = settings, denoise
            self._restart()
        return True

    def update_instances(self, world_from_object: np.ndarray, objects: np.ndarray) -> None:
        """Objects moved: (K, 4, 4) world_from_object of the scene's instances and its object table, both
        in the order of the last export (engine/export/updates.export_instances). Restarts."""
        def moved(scene: SceneArrays) -> SceneArrays:
            instances = scene.instances
            if instances is not None:
                instances = dataclasses.replace(instances, world_from_object=world_from_object)
            return dataclasses.replace(scene, instances=instances, objects=objects)
        self._queue("instances", (world_from_object, objects), moved)

    def update_materials(self, materials, textures: tuple, texture_srgb: tuple, world) -> None:
        """Shaders, images or the world edited: the scene's material table (same rows), textures and world
        (engine/export/updates.export_shading). Restarts."""
        self._queue("materials", (materials, textures, texture_srgb, world),
                    lambda scene: dataclasses.replace(scene, materials=materials, textures=tuple(textures),
                                                      texture_srgb=tuple(texture_srgb), world=world))

    def update_lights(self, lights) -> None:
        """Lights moved, edited, added or removed: the scene's whole light table. Restarts."""
        self._queue("lights", (lights,), lambda scene: dataclasses.replace(scene, lights=lights))

    def _queue(self, part: str, arguments: tuple, change) -> None:
        with self._cond:
            if self._scene is None:
                return   # nothing built to update (the export failed): the next export brings it all
            self._scene = change(self._scene)
            self._pending[part] = arguments
            self._restart()

    @contextlib.contextmanager
    def batch(self):
        """Hold the session while several changes are made: the worker starts once, with all of them."""
        with self._cond:
            yield self

    @property
    def scene(self) -> SceneArrays | None:
        """The scene the session renders, with every update so far."""
        with self._cond:
            return self._scene

    def update_settings(self, settings: RenderSettings, denoise: tuple | None = None) -> bool:
        """Restarts only when the settings (or the previews' denoiser: (quality, prefilter) or None)
        differ; returns whether it did."""
        with self._cond:
            if (settings, denoise) == (self._settings, self._denoise):
                return False
            self._settings, self._denoise = settings, denoise
            self._restart()
        return True

    def update_view(self, camera: Camera) -> bool:
        """Restarts only when the view differs (moved, zoomed, resized); returns whether it did."""
        with self._cond:
            if camera == self._camera:
                return False
            self._camera = camera
            self._restart()
        return True

    def fail(self, message: str) -> None:
        """The scene cannot be rendered (export failed): stop rendering and show `message`."""
        with self._cond:
            self._scene = None
            self._pending.clear()
            self._restart()
            self._frame = None
            self._error = message

    def snapshot(self) -> Frame | None:
        """The newest published frame (the same object until a newer one exists), or None."""
        with self._cond:
            self._taken = self._frame
            return self._frame

    @property
    def needs_redraw(self) -> bool:
        """True while the render refines or a frame has not been taken by snapshot() yet."""
        with self._cond:
            return self._busy or self._frame is not self._taken

    @property
    def busy(self) -> bool:
        with self._cond:
            return self._busy

    @property
    def samples_done(self) -> int:
        """Full-resolution samples of the current generation (0 right after a restart)."""
        with self._cond:
            return self._samples_done

    @property
    def generation(self) -> int:
        with self._cond:
            return self._generation

    @property
    def error(self) -> str | None:
        with self._cond:
            return self._error

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stop(self, timeout: float = STOP_TIMEOUT_S) -> bool:
        """Cancel the render and join the worker. Returns True when the worker has ended."""
        with self._cond:
            self._stopping = True
            self._generation += 1
            self._busy = False
            self._cond.notify_all()
            thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout)
        _live_sessions.discard(self)
        return thread is None or not thread.is_alive()

    def _restart(self) -> None:
        """Called with the lock held: cancel the current render and queue the newest state."""
        self._generation += 1
        self._samples_done = 0
        self._error = None
        self._busy = self._ready()
        if self._busy and self._thread is None and not self._stopping:
            self._thread = threading.Thread(target=self._run, name="ember-viewport", daemon=True)
            self._thread.start()
        self._cond.notify_all()

    def _ready(self) -> bool:
        return self._scene is not None and self._settings is not None and self._camera is not None

    # ------------------------------------------------------------------ worker thread
    def _run(self) -> None:
        session = ProgressiveSession(lambda scene: Renderer(scene, self._threads))
        with session:
            while True:
                with self._cond:
                    while not self._stopping and not (self._ready() and self._started != self._generation):
                        self._cond.wait()
                    if self._stopping:
                        return
                    job = _Job(self._generation, self._scene, self._scene_version, self._settings, self._camera,
                               self._denoise, tuple(self._pending.items()))
                    self._pending.clear()
                    self._started = job.generation
                try:
                    session.load(job.scene, job.scene_version, job.updates)
                    self._render(session, job)
                except Exception as err:  # shown in the viewport; the worker waits for the next change
                    with self._cond:
                        if job.generation == self._generation:
                            self._error = f"{type(err).__name__}: {err}"
                            self._busy = False

    def _cancelled(self, job: _Job) -> bool:
        # Read without the lock: an int compare, and a stale answer only delays the stop by one wave.
        return self._stopping or self._generation != job.generation

    def _render(self, session: ProgressiveSession, job: _Job) -> None:
        """One generation: a sample at low resolution first (when the film is large), then the progressive
        render at full resolution, publishing the display (denoised when asked) as it refines."""
        camera = job.camera
        width, height = camera.width, camera.height

        def should_stop() -> bool:
            return self._cancelled(job)

        display = self._first_display(height, width)
        small = preview_size(width, height, self._preview_pixels)
        if small is not None:
            preview = session.render(dataclasses.replace(job.settings, samples=1, time_limit_s=0.0), should_stop,
                                     camera=dataclasses.replace(camera, width=small[0], height=small[1]))
            if should_stop():
                return
            display = upsample(display_pixels(preview.image), height, width)
            self._publish(job, display, 0)
        denoiser = PreviewDenoiser(job.denoise, self._display_interval_s, self._threads) if job.denoise else None

        def on_rows(film, row0: int, row1: int) -> None:
            display[row0:row1] = display_pixels(film.resolve(row0, row1))

        def on_display(film, denoised) -> None:
            self._publish(job, display if denoised is None else display_pixels(denoised), film.samples_done)

        def on_progress(progress, line: str) -> None:
            with self._cond:
                if job.generation == self._generation:
                    self._samples_done = progress.samples_done

        result = session.render(dataclasses.replace(job.settings, time_limit_s=0.0), should_stop, camera=camera,
                                display_s=self._display_interval_s, previews=denoiser, on_rows=on_rows,
                                on_display=on_display, on_progress=on_progress)
        if result.stopped_early or should_stop():
            return
        shown = denoiser.display(result.film, None) if denoiser is not None else None
        self._publish(job, display if shown is None else display_pixels(shown), result.progress.samples_done,
                      finished=True)

    def _first_display(self, height: int, width: int) -> np.ndarray:
        """The image a restart refines: the last one while the size stays (no black flash between
        restarts), else black."""
        with self._cond:
            frame = self._frame
        if frame is not None and frame.image.shape[:2] == (height, width):
            return frame.image.copy()
        return np.zeros((height, width, 4), np.float32)

    def _publish(self, job: _Job, display: np.ndarray, samples_done: int, finished: bool = False) -> None:
        image = display.copy()
        image.flags.writeable = False
        with self._cond:
            if job.generation != self._generation:
                return
            self._frame = Frame(image, int(samples_done), int(job.settings.samples), job.generation)
            self._samples_done = int(samples_done)
            if finished:
                self._busy = False


# ====================================================================== the RenderEngine's side
def viewport_settings(scene) -> RenderSettings:
    """Kernel settings for the viewport: scene.ember as for F12, with the viewport's sample count (and the
    denoiser's passes when previews are denoised)."""
    samples = int(scene.ember.preview_samples) or UNLIMITED_SAMPLES
    settings = render_settings(scene, None, samples=samples, time_limit=0.0)
    # Cycles' interactive pattern: the first sample blue noise on its own (the first image after every change).
    settings = dataclasses.replace(settings, blue_noise_first=True)
    if viewport_denoise(scene) is not None:
        inputs = scene.ember.denoising_input_passes
        names = ("denoising_albedo",) if inputs == "RGB_ALBEDO" else \
            ("denoising_albedo", "denoising_normal") if inputs == "RGB_ALBEDO_NORMAL" else ()
        settings = dataclasses.replace(settings, passes=names)
    return settings


def viewport_denoise(scene) -> tuple | None:
    """(quality, prefilter) when the viewport's previews are denoised, else None."""
    ember = scene.ember
    return (ember.denoising_quality, ember.denoising_prefilter) if ember.use_preview_denoising else None


def film_size(region_width: int, region_height: int, pixel_size: int) -> tuple[int, int]:
    """The film behind a region: one film pixel per pixel_size x pixel_size screen pixels
    (RenderEngine.get_preview_pixel_size: 2 on high-DPI screens with the Automatic setting)."""
    pixel_size = max(1, int(pixel_size))
    return max(1, round(region_width / pixel_size)), max(1, round(region_height / pixel_size))


class ViewportRender:
    """One engine instance's viewport: view_update exports (the whole scene, or only the parts the
    depsgraph says changed), view_draw follows the view and draws.

    It holds no reference to the engine (the engine holds it): Blender frees the engine, the
    engine's __del__ calls free(), and the worker stops.
    """

    def __init__(self, threads: int = 0, **session_options):
        self.session = ViewportSession(threads, **session_options)
        # Should the engine's __del__ never run, the worker still stops when this object goes.
        weakref.finalize(self, self.session.stop)
        self._visibility = None
        self._index = None            # the last full export's ExportIndex (None: export everything next)
        self._texture = None
        self._texture_frame = None

    # ------------------------------------------------------------------ view_update
    def view_update(self, engine, context, depsgraph) -> None:
        """Main thread: export what changed (everything on the first call, when the visible objects
        changed, or when an update is more than a move, a shader or a light edit), then follow the view."""
        scene = depsgraph.scene
        settings = viewport_settings(scene)
        visibility = visibility_key(depsgraph)
        parts = scene_changes(depsgraph.updates)
        if self._visibility is None or visibility != self._visibility or FULL in parts \
                or (parts and not self._update(depsgraph, parts, settings)):
            self._export(engine, context, depsgraph, settings)
            self._visibility = visibility
        elif not parts:
            self.session.update_settings(settings, viewport_denoise(scene))
        self.session.update_view(self.view_camera(engine, context, depsgraph))

    def _export(self, engine, context, depsgraph, settings: RenderSettings) -> None:
        """The whole scene, every mesh instanced (so that moving objects later only moves instances)."""
        width, height = self._film_size(engine, context, depsgraph)
        override = None if depsgraph.scene_eval.camera is not None else stand_in_camera()
        self._index = None
        try:
            exported = export_scene(depsgraph, override, width=width, height=height, instance_everything=True)
        except ExportError as err:
            self.session.fail(str(err))
            return
        self.session.update_scene(exported.scene, settings, viewport_denoise(depsgraph.scene))
        self._index = exported.index

    def _update(self, depsgraph, parts: frozenset, settings: RenderSettings) -> bool:
        """Read only the changed parts of the scene again (engine/export/updates.py) and hand them to the
        session, all in one restart. False, with nothing handed over, when a part no longer lines up with
        the last export: then only a full export will do."""
        current = self.session.scene
        changes = None if current is None or self._index is None else \
            export_changes(depsgraph, self._index, parts, current)
        if changes is None:
            return False
        with self.session.batch():
            if changes.instances is not None:
                self.session.update_instances(*changes.instances)
            if changes.shading is not None:
                shading = changes.shading
                self.session.update_materials(shading.materials, shading.textures, shading.texture_srgb,
                                              shading.world)
            if changes.lights is not None:
                self.session.update_lights(changes.lights)
            self.session.update_settings(settings, viewport_denoise(depsgraph.scene))
        return True

    # ------------------------------------------------------------------ view_draw
    def prepare_draw(self, engine, context, depsgraph) -> Frame | None:
        """Everything view_draw does but the GPU calls: follow settings and view, report, ask for
        the next draw while refining, and return the frame to show."""
        scene = depsgraph.scene
        # Editing scene.ember does not always reach view_update: compare here too (a few RNA reads).
        self.session.update_settings(viewport_settings(scene), viewport_denoise(scene))
        self.session.update_view(self.view_camera(engine, context, depsgraph))
        frame = self.session.snapshot()
        engine.update_stats("", status_text(frame, self.session.busy, self.session.error))
        if self.session.needs_redraw:
            engine.tag_redraw()
        return frame

    def view_draw(self, engine, context, depsgraph) -> None:
        frame = self.prepare_draw(engine, context, depsgraph)
        if frame is not None:
            self._draw(engine, depsgraph.scene, frame, context.region.width, context.region.height)

    def _draw(self, engine, scene, frame: Frame, region_width: int, region_height: int) -> None:
        """The only code that needs a GPU (headless tests run it against a recording stand-in for
        the gpu module): upload each new frame once, draw it over the region through Blender's
        display transform."""
        import gpu
        from gpu_extras.presets import draw_texture_2d

        if frame is not self._texture_frame:
            height, width = frame.image.shape[:2]
            pixels = gpu_pixels(frame.image)
            buffer = gpu.types.Buffer("FLOAT", pixels.size, pixels)
            self._texture = gpu.types.GPUTexture((width, height), format="RGBA16F", data=buffer)
            self._texture_frame = frame
        gpu.state.blend_set("ALPHA_PREMULT")
        engine.bind_display_space_shader(scene)
        draw_texture_2d(self._texture, (0, 0), region_width, region_height)
        engine.unbind_display_space_shader()
        gpu.state.blend_set("NONE")

    # ------------------------------------------------------------------ shared
    def view_camera(self, engine, context, depsgraph) -> Camera:
        width, height = self._film_size(engine, context, depsgraph)
        space, region_data = context.space_data, context.region_data
        camera_object = None
        if region_data.view_perspective == "CAMERA":
            camera_object = view_camera_object(space, depsgraph.scene)
            if camera_object is not None:
                camera_object = camera_object.evaluated_get(depsgraph)
        return region_camera(space, region_data, width, height, camera_object, depsgraph.scene)

    @staticmethod
    def _film_size(engine, context, depsgraph) -> tuple[int, int]:
        return film_size(context.region.width, context.region.height,
                         engine.get_preview_pixel_size(depsgraph.scene))

    def free(self) -> None:
        """Stop and join the worker; drop the GPU texture."""
        self.session.stop()
        self._texture = None
        self._texture_frame = None


def new_viewport(scene) -> ViewportRender:
    """The viewport of one engine instance, with the scene's thread count."""
    return ViewportRender(render_threads(scene.render))
