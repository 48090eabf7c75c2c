"""The viewport's background render session: a worker thread that restarts a session.ProgressiveSession on
every change and publishes Frames (draw.py), a quick low-resolution preview first.

Sync once, snapshot, let go (as in engine/session.py): the worker sees only SceneArrays, RenderSettings and
kernels.Camera values. It never touches bpy, and bpy never waits for it except in stop(). Partial updates
(engine/export/updates.py) reach its ProgressiveSession, which applies them to the Renderer it built: a
moved object recommits the top level of the BVH, a shader edit rebuilds shading, environment and light
sampler, a light edit the light sampler; a new export builds a new Renderer.
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import weakref
from dataclasses import dataclass

import numpy as np

from ...kernels import Camera, Renderer, RenderSettings, SceneArrays
from ..session import PreviewDenoiser, ProgressiveSession
from .draw import Frame, display_pixels, upsample

# A restart first renders one sample at a resolution with about this many pixels, so that orbiting
# the view answers at once even when a full-resolution sample takes seconds.
PREVIEW_PIXELS = 1 << 14
# The worker publishes a copy of the image at most this often (the first and the last always go out).
DISPLAY_INTERVAL_S = 0.1
# stop() waits this long for the worker; it finishes the waves in flight, which take milliseconds.
STOP_TIMEOUT_S = 10.0


def preview_size(width: int, height: int, pixels: int) -> tuple[int, int] | None:
    """Film size of the quick first pass (same aspect, about `pixels` pixels); None when the full
    resolution is already that small."""
    scale = math.sqrt(width * height / max(pixels, 1))
    if scale < 2.0:
        return None
    return max(1, round(width / scale)), max(1, round(height / scale))


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
        session.apply(changes)                         # the three above, as export/updates.export_changes read them
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

    def apply(self, changes) -> None:
        """The parts of the scene an edit changed, read again (engine/export/updates.Changes: None where a
        part is unchanged), in one restart."""
        with self.batch():
            if changes.instances is not None:
                self.update_instances(*changes.instances)
            if changes.shading is not None:
                shading = changes.shading
                self.update_materials(shading.materials, shading.textures, shading.texture_srgb, shading.world)
            if changes.lights is not None:
                self.update_lights(changes.lights)

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
