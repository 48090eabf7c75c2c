"""The progressive final render: export once, run the kernel, stream rows into Blender's result.

Sync once, snapshot, let go: everything is read from the depsgraph before the kernel starts; the
kernel sees only arrays and reaches Blender through three callbacks (on_tile, should_stop,
on_progress), the way Cycles' session knows Blender only through an output driver.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import bpy
import numpy as np

from ..kernels import Renderer, RenderSettings
from .export import ExportError, export_scene
from .export.camera import render_region
from .version import EMBER_VERSION

# The Image Editor is refreshed at most this often; the first and the last image always go through.
DISPLAY_INTERVAL_S = 0.25
# In background mode (command line, render farms) a progress line is printed at most this often.
PRINT_INTERVAL_S = 2.0


def seed_for_frame(ember, frame: int) -> int:
    """The user's seed, plus the frame number when the seed is animated (as Cycles does)."""
    return (ember.seed + frame if ember.use_animated_seed else ember.seed) & 0x7FFFFFFF


def render_threads(render) -> int:
    """scene.render.threads already reports the automatic count when threads_mode is AUTO."""
    return max(1, int(render.threads))


def render_settings(scene, region, *, samples: int | None = None, time_limit: float | None = None) -> RenderSettings:
    """Kernel settings from scene.ember and scene.render."""
    ember = scene.ember
    return RenderSettings(
        samples=int(samples if samples is not None else ember.samples),
        max_bounces=int(ember.max_bounces),
        transparent_max_bounces=int(ember.transparent_max_bounces),
        mode=ember.sampling_mode,
        seed=seed_for_frame(ember, scene.frame_current),
        time_limit_s=float(ember.time_limit if time_limit is None else time_limit),
        region=region,
        transparent_background=bool(scene.render.film_transparent),
    )


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
    """One F12 (or one frame of an animation, or one view layer): export, render, stream, finish."""

    def __init__(self, engine, depsgraph):
        self.engine = engine
        self.depsgraph = depsgraph
        self.scene = depsgraph.scene
        self._last_display = 0.0
        self._last_print = 0.0
        self._result = None
        self._rect = None

    def run(self) -> None:
        engine, scene = self.engine, self.scene
        width, height = engine.resolution_x, engine.resolution_y
        engine.update_stats("", "Ember: exporting scene")
        try:
            exported = export_scene(self.depsgraph, engine.camera_override, width=width, height=height)
        except ExportError as err:
            engine.report({"ERROR"}, f"Ember: {err}")
            return
        for warning in exported.warnings:
            engine.report({"WARNING"}, f"Ember: {warning}")

        # The result covers the border region when there is one; its size tells us the region's.
        self._result = engine.begin_result(0, 0, width, height, layer=self.depsgraph.view_layer.name)
        try:
            region = self._region(width, height)
            settings = render_settings(scene, (region.x0, region.y0, region.x1, region.y1))
            try:
                renderer = Renderer(exported.scene, threads=render_threads(scene.render))
            except ValueError as err:
                engine.report({"ERROR"}, f"Ember: invalid scene data: {err}")
                return
            with renderer:
                if renderer.dropped_triangles:
                    engine.report({"WARNING"}, f"Ember: skipped {renderer.dropped_triangles} degenerate or "
                                               f"non-finite triangles")
                self._rect = self._result.layers[0].passes["Combined"].rect
                result = renderer.render(settings, on_tile=self._on_tile, should_stop=engine.test_break,
                                         on_progress=self._on_progress)
            self._write(result.image)
            self._finish_message(result, exported)
        finally:
            self.engine.end_result(self._result)

    def _region(self, width: int, height: int) -> Region:
        border = render_region(self.scene, width, height)
        rw, rh = self._result.resolution_x, self._result.resolution_y
        if border is None or (rw, rh) == (width, height):
            return Region(0, 0, width, height)
        x0, y0 = border[0], border[1]
        # Blender decides the border's pixel size; keep its size and our corner, inside the frame.
        x0 = min(max(x0, 0), width - rw)
        y0 = min(max(y0, 0), height - rh)
        return Region(x0, y0, x0 + rw, y0 + rh)

    # ------------------------------------------------------------------ kernel callbacks
    def _on_tile(self, film, row0: int, row1: int) -> None:
        now = time.perf_counter()
        if now - self._last_display < DISPLAY_INTERVAL_S and self._last_display:
            return
        self._last_display = now
        self._write(film.resolve())

    def _on_progress(self, progress) -> None:
        line = stats_line(progress, self.scene.ember.time_limit)
        self.engine.update_stats("", line)
        self.engine.update_progress(min(progress.fraction, 1.0))
        now = time.perf_counter()
        if _background() and now - self._last_print >= PRINT_INTERVAL_S:
            self._last_print = now
            print(f"Ember | Frame {self.scene.frame_current} | {line}", flush=True)

    def _write(self, image: np.ndarray) -> None:
        """image: (H, W, 4) float32, row 0 at the top -> Blender's bottom-up rect."""
        flipped = np.ascontiguousarray(image[::-1], dtype=np.float32)
        self._rect.foreach_set(flipped.ravel())
        self.engine.update_result(self._result)

    def _finish_message(self, result, exported) -> None:
        p = result.progress
        if p.nonfinite_paths:
            self.engine.report({"WARNING"}, f"Ember: dropped {p.nonfinite_paths} paths with NaN or infinite radiance")
        state = "stopped" if result.stopped_early else "done"
        message = (f"Ember {EMBER_VERSION} {state}: {p.samples_done}/{p.samples_total} samples in {format_time(p.elapsed_s)}, "
                   f"{p.paths_per_s / 1e6:.2f} M paths/s, {exported.triangle_count} triangles "
                   f"(export {exported.seconds:.2f} s)")
        self.engine.update_stats("", message)
        if _background():
            print(f"Ember | Frame {self.scene.frame_current} | {message}", flush=True)


def _background() -> bool:
    return bool(bpy.app.background)
