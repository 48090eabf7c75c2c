"""One progressive session for final renders and the viewport, and the final render's adapter over it.

    ProgressiveSession  owns a Renderer (built, or updated in place when the scene changes) and runs its
                        progressive loop: waves of samples, the cadence of display updates, denoised
                        previews (PreviewDenoiser), cancellation and the statistics line. It knows
                        Blender only through callbacks, the way Cycles' session knows it only through
                        an output driver.
    FinalRender         one F12: export, then a ProgressiveSession on the render job's thread streaming
                        rows into Blender's RenderResult (through result_writer.ResultWriter: passes,
                        Cryptomatte metadata) and the final denoise; it takes Persistent Data's kept
                        renderer from persistent.kept.

The viewport (viewport.ViewportSession) runs a ProgressiveSession on its worker thread and publishes
frames. Sync once, snapshot, let go: everything is read from the depsgraph before the kernel starts.
Esc (and the command line's Ctrl-C and SIGTERM, through request_cancel) is polled during export, between
the stages of the scene build, and while the waves render: those in flight then leave at their next bounce.
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

import bpy
import numpy as np

from ..kernels import Camera, Cancelled, Renderer, RenderResult, RenderSettings, SceneArrays, prestart_workers
from ..kernels.accel import capped_threads
from .export import ExportCancelled, ExportError, export_scene
from .export.camera import render_region, rigid_transform
from .export.lights import uses_light_tree
from .export.motion import sample_motion, sample_vector_motion
from .export.world import fast_gi
from . import cryptomatte
from .film_denoise import NonFiniteTile, denoise_film, denoised_film, final_options
from .passes import enabled_passes, kernel_passes, mist_settings, unwritten_passes_warning
from .persistent import kept, persistent_data
from .result_writer import WRITE_CHUNK_PIXELS, ResultWriter
from .version import EMBER_VERSION

# Cycles widens its rays' differentials after rough bounces from Blender 5.2 on (RenderSettings.widen_differentials).
WIDENED_DIFFERENTIALS = (5, 2, 0)

# The Image Editor is refreshed at most this often (Cycles updates a few times a second); the first and
# the last image always go through.
DISPLAY_INTERVAL_S = 0.25
# Denoised progressive display of interactive final renders: at most this often (and at most a quarter of
# the time: PreviewDenoiser).
PREVIEW_DENOISE_INTERVAL_S = 1.0
# In background mode (command line, render farms) a progress line is printed at most this often.
PRINT_INTERVAL_S = 2.0


def seed_for_frame(ember, frame: int) -> int:
    """The user's seed, plus the frame number when the seed is animated (as Cycles does)."""
    return (ember.seed + frame if ember.use_animated_seed else ember.seed) & 0x7FFFFFFF


def render_threads(render) -> int:
    """The threads a render runs: scene.render.threads (which reports the automatic count when threads_mode
    is AUTO) up to the cores this process may use."""
    return capped_threads(int(render.threads))


def threads_warning(render) -> str | None:
    """A line when a fixed thread count (Blender allows up to 1024) is more than the cores this process may
    use; Ember renders with the cores."""
    threads = render_threads(render)
    if render.threads_mode != "FIXED" or int(render.threads) <= threads:
        return None
    return (f"{int(render.threads)} render threads asked for (Performance > Threads), but {threads} "
            f"core{'s' if threads > 1 else ''} can be used here: rendering with {threads}")


def render_settings(scene, region, *, samples: int | None = None, time_limit: float | None = None,
                    viewport: bool = False, view_layer=None) -> RenderSettings:
    """Kernel settings from scene.ember and scene.render (viewport: for the viewport's rendered mode); view_layer:
    the layer a final render renders (its Samples override, its world's Fast GI settings), or None."""
    ember = scene.ember
    return RenderSettings(
        samples=int(samples if samples is not None else layer_samples(scene, view_layer, int(ember.samples))),
        max_bounces=int(ember.max_bounces),
        diffuse_bounces=int(ember.diffuse_bounces),
        glossy_bounces=int(ember.glossy_bounces),
        transmission_bounces=int(ember.transmission_bounces),
        volume_bounces=int(ember.volume_bounces),
        volume_biased=bool(ember.volume_biased),
        volume_step_rate=float(ember.volume_preview_step_rate if viewport else ember.volume_step_rate),
        volume_max_steps=int(ember.volume_max_steps),
        transparent_max_bounces=int(ember.transparent_max_bounces),
        clamp_direct=float(ember.sample_clamp_direct),
        clamp_indirect=float(ember.sample_clamp_indirect),
        filter_glossy=float(ember.blur_glossy),
        caustics_reflective=bool(ember.caustics_reflective),
        caustics_refractive=bool(ember.caustics_refractive),
        adaptive_threshold=float(ember.adaptive_threshold) if ember.use_adaptive_sampling else 0.0,
        adaptive_min_samples=int(ember.adaptive_min_samples),
        mode=ember.sampling_mode,
        seed=seed_for_frame(ember, scene.frame_current),
        sample_offset=int(ember.sample_offset),
        sampling_pattern=ember.sampling_pattern,
        time_limit_s=float(ember.time_limit if time_limit is None else time_limit),
        region=region,
        transparent_background=bool(scene.render.film_transparent),
        transparent_glass=transparent_glass(scene),
        exposure=film_exposure(scene),
        light_threshold=light_threshold(scene),
        widen_differentials=bpy.app.version >= WIDENED_DIFFERENTIALS,
        **fast_gi(scene, viewport, view_layer),
        quick_first_pass=not _background(),
    )


def layer_samples(scene, view_layer, samples: int) -> int:
    """A view layer's Samples (View Layer > Use for Rendering > Samples, 0: none) in place of the scene's, as Cycles'
    Layer Samples (scene.cycles.use_layer_samples) decides: Use takes it, Bounded takes it where it is fewer,
    Ignore never does (blender/session.cpp)."""
    own = int(getattr(view_layer, "samples", 0) or 0) if view_layer is not None else 0
    mode = getattr(getattr(scene, "cycles", None), "use_layer_samples", "USE")
    if own <= 0 or mode == "IGNORE" or (mode == "BOUNDED" and own >= samples):
        return samples
    return own


def light_threshold(scene) -> float:
    """Sampling > Lights > Light Threshold, Cycles' own setting (scene.cycles.light_sampling_threshold), which Cycles
    applies only without the light tree (scene/integrator.cpp): files from before Blender 3.5 open with the tree off
    and the threshold at 0.01."""
    cycles = getattr(scene, "cycles", None)
    if cycles is None or uses_light_tree(scene):
        return 0.0
    value = float(getattr(cycles, "light_sampling_threshold", 0.0))
    return value if value > 0 and math.isfinite(value) else 0.0


def film_exposure(scene) -> float:
    """Film > Exposure, Cycles' own setting (scene.cycles.film_exposure, read so that a file set up for Cycles
    renders alike; 1 without Cycles)."""
    return float(max(getattr(getattr(scene, "cycles", None), "film_exposure", 1.0), 0.0))


def transparent_glass(scene) -> float | None:
    """Film > Transparent > Transparent Glass, Cycles' own setting (scene.cycles, so that a file set up for Cycles
    renders alike): its Roughness Threshold where the film is transparent and the option on, else None."""
    cycles = getattr(scene, "cycles", None)
    if not scene.render.film_transparent or cycles is None or not getattr(cycles, "film_transparent_glass", False):
        return None
    return float(max(getattr(cycles, "film_transparent_roughness", 0.1), 0.0))


def format_time(seconds: float) -> str:
    """Cycles' stats style: MM:SS.ss, with hours when needed."""
    if not math.isfinite(seconds):
        return "--:--"
    minutes, secs = divmod(max(seconds, 0.0), 60.0)
    hours, minutes = divmod(int(minutes), 60)
    return f"{hours:d}:{minutes:02d}:{secs:05.2f}" if hours else f"{minutes:02d}:{secs:05.2f}"


def stats_line(progress, time_limit_s: float = 0.0) -> str:
    """'Sample 12/64 | Elapsed 00:03.10 | Remaining 00:12.40 | 1.02 M paths/s', as Cycles shows it."""
    done_fraction = max(progress.fraction, 1e-9)
    remaining = progress.elapsed_s * (1.0 - done_fraction) / done_fraction
    if time_limit_s > 0:
        remaining = min(remaining, max(time_limit_s - progress.elapsed_s, 0.0))
    current = min(progress.samples_done + 1, progress.samples_total)
    return (f"Sample {current}/{progress.samples_total} | Elapsed {format_time(progress.elapsed_s)} | "
            f"Remaining {format_time(remaining)} | {progress.paths_per_s / 1e6:.2f} M paths/s")


# ====================================================================== the progressive session
class ProgressiveSession:
    """A Renderer and the progressive loop over it, for final renders and the viewport alike.

        session = ProgressiveSession(build)            # build(scene) -> a new Renderer of the SceneArrays
        session.load(scene, version, updates)          # build one, or update the one built for `version`
        result = session.render(settings, should_stop, camera=..., display_s=..., previews=...,
                                on_rows=..., on_display=..., on_progress=...)
        session.close()                                # or: with session: ...

    After every wave of a render: on_rows(film, row0, row1) with the span of region rows it refined; then, at most
    every display_s seconds (the first wave always; never when display_s is None or once should_stop() is
    True), on_display(film, denoised), denoised being the whole film denoised by `previews` when they are
    due (PreviewDenoiser), else None (show the film itself); then on_progress(progress, line), line being
    Cycles' statistics line. should_stop() is polled while the waves render (Renderer.render): the waves in
    flight leave at their next bounce.
    """

    def __init__(self, build: Callable[[SceneArrays], Renderer]):
        self._build = build
        self.renderer: Renderer | None = None
        self._version = None    # what the renderer was built for (the viewport's scene version)

    def load(self, scene: SceneArrays, version=None, updates: tuple = ()) -> Renderer:
        """The renderer of `scene`: the one built for `version` with `updates` applied ((part, arguments),
        ...: Renderer.update_instances, update_materials, update_lights), or else a new one (no version,
        another version, or an update that does not fit: `scene` has them all)."""
        if self.renderer is None or version is None or version != self._version or not self._apply(updates):
            self.close()
            self.renderer = self._build(scene)
            self._version = version
        return self.renderer

    def _apply(self, updates: tuple) -> bool:
        """False when an update does not fit (the renderer is then half updated, and must be built anew)."""
        renderer = self.renderer
        apply = {"instances": renderer.update_instances, "materials": renderer.update_materials,
                 "lights": renderer.update_lights}
        try:
            for part, arguments in updates:
                apply[part](*arguments)
        except Exception:  # any failure is answered by a rebuild, which reports its own errors
            return False
        return True

    def render(self, settings: RenderSettings, should_stop: Callable[[], bool], *, camera: Camera | None = None,
               display_s: float | None = None, previews: "PreviewDenoiser | None" = None,
               on_rows=None, on_display=None, on_progress=None) -> RenderResult:
        """One progressive render of the loaded scene (through `camera` when given)."""
        if camera is not None:
            self.renderer.set_camera(camera)
        last_display = 0.0

        def on_tile(film, row0: int, row1: int) -> None:
            nonlocal last_display
            if on_rows is not None:
                on_rows(film, row0, row1)
            if display_s is None or on_display is None or should_stop():
                return
            now = time.perf_counter()
            if last_display and now - last_display < display_s:
                return
            last_display = now
            on_display(film, previews.display(film, now, should_stop)
                       if previews is not None and film.samples_done > 0 else None)

        def report(progress) -> None:
            on_progress(progress, stats_line(progress, settings.time_limit_s))

        return self.renderer.render(settings, on_tile=on_tile, should_stop=should_stop,
                                    on_progress=None if on_progress is None else report)

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
        self.renderer, self._version = None, None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class PreviewDenoiser:
    """Denoised previews (the viewport's, and a final render's progressive display): the whole film, at most
    so often that denoising takes a quarter of the time; a failure turns it off for this render and the
    noisy image is shown."""

    def __init__(self, options: tuple, interval_s: float, threads: int):
        self.quality, self.prefilter = options
        self.interval_s, self.threads = interval_s, threads
        self.next_s = 0.0
        self.failed: str | None = None

    def display(self, film, now: float | None, should_stop: Callable[[], bool] | None = None) -> np.ndarray | None:
        """The denoised film (H, W, 4), or None (not due yet, failed, or should_stop() during it): now None
        forces it (the end)."""
        if self.failed is not None or (now is not None and now < self.next_s):
            return None
        start = time.perf_counter()
        try:
            image = denoised_film(film, self.quality, self.prefilter, self.threads, should_stop)
        except Exception as err:
            self.failed = f"{type(err).__name__}: {err}"
            print(f"Ember: denoised previews failed, they stay noisy: {self.failed}", flush=True)
            return None
        if image is None:
            return None
        spent = time.perf_counter() - start
        self.next_s = time.perf_counter() + max(self.interval_s, 3.0 * spent)
        return image


# ====================================================================== final renders
@dataclass
class Region:
    """Where the render result sits: (x0, y0, x1, y1) in full-frame pixels with row 0 at the top."""
    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def width(self) -> int:
        return self.x1 - self.x0

    @property
    def height(self) -> int:
        return self.y1 - self.y0


class FinalRender:
    """One F12 (or one frame of an animation, or one view layer): export, render, stream, finish.

    A ProgressiveSession renders; this adapter streams its rows into Blender's result as sub-results of at
    most WRITE_CHUNK_PIXELS pixels: only the rows a wave changed, at most every DISPLAY_INTERVAL_S, and
    none before the end in background mode (nobody sees them). Ember's memory is then the film plus a
    bounded working set, whatever the resolution.
    """

    def __init__(self, engine, depsgraph):
        self.engine = engine
        self.depsgraph = depsgraph
        self.scene = depsgraph.scene
        self._last_print = 0.0
        self._region: Region | None = None
        self._dirty: tuple[int, int] | None = None  # region rows changed since they were last written
        self.cancelled = False
        self._result = ResultWriter(engine, depsgraph.view_layer.name)
        self._denoise = False
        self._previews = None       # denoised progressive display (interactive final renders)
        self._crypto_names = {}     # Cryptomatte kind -> names (the manifests)
        self.denoise_seconds = None

    def should_stop(self) -> bool:
        """Esc in Blender, or an interrupt of the command line."""
        return bool(self.engine.test_break()) or _cancel.is_set()

    def run(self) -> None:
        engine, scene = self.engine, self.scene
        width, height = engine.resolution_x, engine.resolution_y
        engine.update_stats("", "Ember: exporting scene")
        try:
            camera_ob = engine.camera_override or self.depsgraph.scene.camera
            motion = sample_motion(engine, self.depsgraph, camera_ob) if camera_ob is not None else None
            vector = sample_vector_motion(engine, self.depsgraph, camera_ob) if camera_ob is not None else None
            persistent = persistent_data(scene) and motion is None and vector is None
            if not (persistent and kept.renderer is not None):   # a kept renderer has its workers
                prestart_workers(capped_threads(render_threads(scene.render)),
                                 width * height * int(scene.ember.samples))
            exported = export_scene(self.depsgraph, engine.camera_override, width=width, height=height,
                                    should_stop=self.should_stop, motion=motion, vector=vector,
                                    instance_everything=persistent, mesh_cache=kept.meshes if persistent else None)
        except ExportCancelled:
            return self._cancel()
        except ExportError as err:
            engine.report({"ERROR"}, f"Ember: {err}")
            return
        self._warn(exported.warnings)
        self._region = self._find_region(width, height)
        view_layer = self.depsgraph.view_layer
        settings = render_settings(scene, (self._region.x0, self._region.y0, self._region.x1, self._region.y1),
                                   view_layer=view_layer)
        self._result.passes = enabled_passes(scene, view_layer)
        self._denoise = bool(scene.ember.use_denoising)
        if self._denoise and not _background():
            self._previews = PreviewDenoiser((scene.ember.denoising_quality, scene.ember.denoising_prefilter),
                                             PREVIEW_DENOISE_INTERVAL_S, render_threads(scene.render))
        settings = dataclasses.replace(
            settings, mist=mist_settings(scene), pass_alpha_threshold=float(view_layer.pass_alpha_threshold),
            passes=kernel_passes(scene, view_layer, scene.ember.denoising_input_passes if self._denoise else None),
            cryptomatte=cryptomatte.enabled_kinds(view_layer), cryptomatte_depth=cryptomatte.levels(view_layer))
        self._crypto_names = exported.crypto_names or {}
        engine.update_stats("", "Ember: building the scene")
        threads = render_threads(scene.render)
        self._warn(filter(None, [threads_warning(scene.render), unwritten_passes_warning(view_layer)]))
        session = ProgressiveSession(lambda arrays: self._build(arrays, threads, persistent))
        try:
            renderer = session.load(exported.scene)
        except Cancelled:
            return self._cancel()
        except ValueError as err:
            engine.report({"ERROR"}, f"Ember: invalid scene data: {err}")
            return
        finally:
            if not persistent:
                kept.drop()    # Persistent Data turned off: let the kept scene go
        if persistent:
            kept.set(renderer)
        failures = len(renderer.crew.worker_failures)   # a kept renderer's earlier frames were warned about
        with kept if persistent else session:
            # Zero-area triangles (bevels, text) are dropped silently: no ray can hit them, in Cycles either.
            if renderer.nonfinite_triangles:
                self._warn([f"skipped {renderer.nonfinite_triangles} triangles whose corners are not finite "
                            f"numbers (NaN, or beyond float32's range: an object scaled or placed too far)"])
            if getattr(renderer, "dropped_shapes", 0):
                self._warn([f"skipped {renderer.dropped_shapes} curves or points whose keys, centres or radii are not "
                            f"finite numbers or whose radius is negative"])
            for view, camera in self._views(exported.scene.camera):
                self._result.view = view
                result = session.render(settings, self.should_stop, camera=camera, previews=self._previews,
                                        display_s=None if _background() else DISPLAY_INTERVAL_S,
                                        on_rows=self._on_rows, on_display=self._on_display,
                                        on_progress=self._on_progress)
                self.cancelled = result.stopped_early and _cancel.is_set()
                if self._previews is not None:
                    self._dirty = (0, result.film.height)  # denoised previews wrote Combined alone: every row again
                self._flush(result.film)
                options = final_options(scene.ember, result.stopped_early, self.should_stop())
                denoised = options is not None and result.film.samples_done > 0 and \
                    self._denoise_final(result.film, options)
                self._result.stamp_metadata(result.film, denoised, scene.ember, self._crypto_names)
                if self.should_stop():
                    break
        if len(renderer.crew.worker_failures) > failures:  # the image is whole (their waves ran here), only slower
            self._warn(["a worker process failed, its waves ran in this process: "
                        + renderer.crew.worker_failures[failures]])
        self._finish_message(result, exported)

    def _views(self, camera):
        """(view name, kernels.Camera or None) per view to render: ("", None) alone without Stereoscopy; with it,
        each view of Blender's result, its camera moved and shifted as Blender places that view's camera
        (RenderEngine.camera_model_matrix and camera_shift_x, as Cycles' sync_camera reads them; no spherical
        stereo)."""
        engine = self.engine
        camera_ob = engine.camera_override or self.depsgraph.scene.camera
        if not self.scene.render.use_multiview or camera_ob is None:
            return [("", None)]
        probe = engine.begin_result(0, 0, 1, 1, layer=self.depsgraph.view_layer.name)
        names = [view.name for view in probe.views]
        engine.end_result(probe, cancel=True)
        out = []
        for name in names:
            engine.active_view_set(name)
            matrix = rigid_transform(engine.camera_model_matrix(camera_ob, use_spherical_stereo=False))
            mono = np.asarray(camera.world_from_camera, np.float64)
            moved = dataclasses.replace(camera, world_from_camera=matrix,
                                        shift_x=float(engine.camera_shift_x(camera_ob, use_spherical_stereo=False)))
            if camera.motion is not None:   # the view's offset at every motion step too
                offset = matrix @ np.linalg.inv(mono)
                moved = dataclasses.replace(moved, motion=np.einsum("ij,kjl->kil", offset, np.asarray(camera.motion)))
            out.append((name, moved))
        return out

    def _build(self, scene: SceneArrays, threads: int, persistent: bool) -> Renderer:
        """With Persistent Data the kept renderer updated to `scene` when it can be, else a new one (reusing
        the kept one's unchanged meshes)."""
        updated = kept.take(scene, threads) if persistent else None
        return updated if updated is not None else Renderer(scene, threads=threads, should_stop=self.should_stop,
                                                            reuse=kept.renderer if persistent else None)

    def _denoise_final(self, film, options: tuple) -> bool:
        """Denoise the finished image with options (quality, prefilter), each tile written to Blender as it
        comes, with progress; Esc stops it. Stopped, failed or non-finite, the rows written are put back
        noisy (a failure with a warning): a finished frame is never lost. True when denoised."""
        start = time.perf_counter()
        written = 0   # region rows [0, written) hold denoised tiles: tiles come in rows top-down

        def write(rows, cols, pixels, passes):
            nonlocal written
            step = max(1, WRITE_CHUNK_PIXELS // max(pixels.shape[1], 1))
            for r0 in range(rows.start, rows.stop, step):
                r1 = min(rows.stop, r0 + step)
                band = slice(r0 - rows.start, r1 - rows.start)
                self._result.write_rows(film, r0, r1, cols, pixels[band],
                                        {name: values[band] for name, values in passes.items()})
            written = max(written, rows.stop)

        self._last_print = -math.inf   # the denoise's first line is printed at once
        finished = False
        try:
            finished = denoise_film(film, write, options, render_threads(self.scene.render),
                                    lambda fraction: self._report_denoise(fraction, start, options))
        except NonFiniteTile as err:
            self._warn([f"denoising failed, the image is not denoised: {err}"])
        except Exception as err:  # the library missing, OIDN's own error, a bug: keep the noisy image
            self._warn([f"denoising failed, the image is not denoised: {type(err).__name__}: {err}"])
        if not finished:
            self._dirty = (0, written) if written else None
            self._flush(film)
            return False
        self.denoise_seconds = time.perf_counter() - start
        return True

    def _report_denoise(self, fraction: float, start: float, options: tuple) -> bool:
        """The denoise's progress as the render's own (stats, progress bar, a line every PRINT_INTERVAL_S in
        background mode); False once the user stops it."""
        elapsed = time.perf_counter() - start
        remaining = elapsed * (1.0 - fraction) / fraction if fraction > 0 else math.inf
        line = (f"Denoising ({options[0].title()}) {fraction:.0%} | Elapsed {format_time(elapsed)} | "
                f"Remaining {format_time(remaining)}")
        self.engine.update_stats("", line)
        self.engine.update_progress(min(fraction, 1.0))
        now = time.perf_counter()
        if _background() and now - self._last_print >= PRINT_INTERVAL_S:
            self._last_print = now
            print(f"Ember | Frame {self.scene.frame_current} | {line}", flush=True)
        return not self.should_stop()

    def _cancel(self) -> None:
        """Stopped before rendering: hand Blender an empty result all the same (saving a render that
        never began a result crashes Blender 5.0)."""
        self.cancelled = True
        engine = self.engine
        engine.end_result(engine.begin_result(0, 0, engine.resolution_x, engine.resolution_y,
                                              layer=self.depsgraph.view_layer.name))
        engine.update_stats("", "Ember: cancelled")

    def _warn(self, lines) -> None:
        """Warnings as they happen: printed at once in background mode (Blender would print reports
        only after the operator, after its 'Saved:' line), reported in the interface."""
        for line in lines:
            if _background():
                print(f"Ember | Frame {self.scene.frame_current} | Warning: {line}", flush=True)
            else:
                self.engine.report({"WARNING"}, f"Ember: {line}")

    def _find_region(self, width: int, height: int) -> Region:
        """The border region in full-frame pixels. Blender decides the border's pixel size: a result
        begun for the whole frame has it; it is ended unmerged (it holds no pixels)."""
        probe = self.engine.begin_result(0, 0, width, height, layer=self.depsgraph.view_layer.name)
        rw, rh = probe.resolution_x, probe.resolution_y
        self.engine.end_result(probe, cancel=True)
        border = render_region(self.scene, width, height)
        if border is None or (rw, rh) == (width, height):
            return Region(0, 0, width, height)
        # Keep Blender's size and our corner, inside the frame.
        x0 = min(max(border[0], 0), width - rw)
        y0 = min(max(border[1], 0), height - rh)
        return Region(x0, y0, x0 + rw, y0 + rh)

    # ------------------------------------------------------------------ the session's callbacks
    def _on_rows(self, film, row0: int, row1: int) -> None:
        self._dirty = (row0, row1) if self._dirty is None else (min(self._dirty[0], row0), max(self._dirty[1], row1))

    def _on_display(self, film, denoised: np.ndarray | None) -> None:
        if denoised is None:
            self._flush(film)
        else:  # the whole region, denoised: Cycles' progressive display does the same
            self._dirty = None
            self._result.write_combined(denoised, film)

    def _on_progress(self, progress, line: str) -> None:
        self.engine.update_stats("", line)
        self.engine.update_progress(min(progress.fraction, 1.0))
        now = time.perf_counter()
        if _background() and now - self._last_print >= PRINT_INTERVAL_S:
            self._last_print = now
            print(f"Ember | Frame {self.scene.frame_current} | {line}", flush=True)

    def _flush(self, film) -> None:
        """Write the changed rows to Blender, in chunks."""
        if self._dirty is None:
            return
        row0, row1 = self._dirty
        self._dirty = None
        step = max(1, WRITE_CHUNK_PIXELS // max(film.width, 1))
        for r0 in range(row0, row1, step):
            self._result.write_rows(film, r0, min(row1, r0 + step))

    def _finish_message(self, result, exported) -> None:
        p = result.progress
        if p.nonfinite_paths:
            self._warn([f"dropped {p.nonfinite_paths} paths with NaN or infinite radiance"])
        state = "cancelled" if self.cancelled else "stopped" if result.stopped_early else "done"
        message = (f"Ember {EMBER_VERSION} {state}: {p.samples_done}/{p.samples_total} samples in {format_time(p.elapsed_s)}, "
                   f"{p.paths_per_s / 1e6:.2f} M paths/s, {exported.triangle_count} triangles "
                   f"(export {exported.seconds:.2f} s)")
        if p.workers:
            message += f", {p.workers} worker process{'es' if p.workers > 1 else ''}"
        self.engine.update_stats("", message)
        if _background():
            print(f"Ember | Frame {self.scene.frame_current} | {message}", flush=True)


# Set by the command line's interrupt handler; every final render polls it with Esc.
_cancel = threading.Event()


def request_cancel() -> None:
    """Ask the running final render (and the ones after it) to stop: Ctrl-C on the command line."""
    _cancel.set()


def clear_cancel() -> None:
    _cancel.clear()


def cancel_requested() -> bool:
    return _cancel.is_set()


def _background() -> bool:
    return bool(bpy.app.background)
