"""The viewport's rendered mode: a progressive render that starts over when the scene or the view changes.

The RenderEngine's view_update / view_draw, on the main thread: export (the whole scene, or only what the
depsgraph says changed: engine/export/updates.py), hand the arrays and the view, a kernels.Camera that
compares by value (export/camera.py's region_camera), to the worker (session.py), and draw its latest
Frame (draw.py). Why every mesh is instanced here and what an update costs: docs/architecture.md.
"""
from __future__ import annotations

import dataclasses
import weakref

from ...kernels import Camera, RenderSettings
from ..export import ExportError, export_scene
from ..export.camera import region_camera, stand_in_camera, view_camera_object
from ..export.updates import FULL, export_changes, scene_changes, visibility_key
from ..session import render_settings, render_threads
from .draw import UNLIMITED_SAMPLES, Display, Frame, status_text
from .session import ViewportSession, stop_all_sessions

__all__ = ["ViewportRender", "film_size", "new_viewport", "stop_all_sessions", "viewport_denoise",
           "viewport_settings"]


def viewport_settings(scene) -> RenderSettings:
    """Kernel settings for the viewport: scene.ember as for F12, with the viewport's sample count (and the
    denoiser's passes when previews are denoised)."""
    samples = int(scene.ember.preview_samples) or UNLIMITED_SAMPLES
    settings = render_settings(scene, None, samples=samples, time_limit=0.0, viewport=True)
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
    """One engine instance's viewport. It holds no reference to the engine (the engine holds it): Blender
    frees the engine, the engine's __del__ calls free(), and the worker stops."""

    def __init__(self, threads: int = 0, **session_options):
        self.session = ViewportSession(threads, **session_options)
        # Should the engine's __del__ never run, the worker still stops when this object goes.
        weakref.finalize(self, self.session.stop)
        self.display = Display()
        self._visibility = None
        self._index = None            # the last full export's ExportIndex (None: export everything next)

    def view_update(self, engine, context, depsgraph) -> None:
        """Export what changed (everything on the first call, when the visible objects changed, or when an
        update is more than a move, a shader or a light edit), then follow the view."""
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
            exported = export_scene(depsgraph, override, width=width, height=height, instance_everything=True,
                                    viewport=True)
        except ExportError as err:
            self.session.fail(str(err))
            return
        self.session.update_scene(exported.scene, settings, viewport_denoise(depsgraph.scene))
        self._index = exported.index

    def _update(self, depsgraph, parts: frozenset, settings: RenderSettings) -> bool:
        """Hand the session the changed parts read again, all in one restart; False, with nothing handed
        over, when only a full export will do."""
        current = self.session.scene
        changes = None if current is None or self._index is None else \
            export_changes(depsgraph, self._index, parts, current)
        if changes is None:
            return False
        with self.session.batch():
            self.session.apply(changes)
            self.session.update_settings(settings, viewport_denoise(depsgraph.scene))
        return True

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
            self.display.draw(engine, depsgraph.scene, frame, context.region.width, context.region.height)

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
        self.display.free()


def new_viewport(scene) -> ViewportRender:
    """The viewport of one engine instance, with the scene's thread count."""
    return ViewportRender(render_threads(scene.render))
