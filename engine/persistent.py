"""Persistent Data: the final render's scene kept between frames (kept), and whether the user asked for it.

FinalRender (engine/session.py) takes the kept renderer and the meshes the export read for the last frame
(engine/export/geometry.MeshCache); the RenderEngine drops them when Ember is unregistered.
"""
from __future__ import annotations

from ..kernels import Renderer
from ..kernels.accel import capped_threads
from .export.geometry import MeshCache


def persistent_data(scene) -> bool:
    """Blender's Persistent Data (Render Properties > Performance > Final Render, as for Cycles): keep the
    built scene between final renders, so the frames of an animation reuse what did not change."""
    return bool(scene.render.use_persistent_data)


class _KeptScene:
    """The renderer of the last final render, kept while Persistent Data is on (one per process: frames
    render one after another). The next frame takes it when only transforms, materials, lights or the
    camera changed (Renderer.update_scene), or else builds anew reusing the BVHs of the meshes that did not
    change (Renderer(reuse=...)). With every mesh an instance (export_scene(instance_everything=True)), a
    moved object changes only its transform, as in the viewport."""

    def __init__(self):
        self.renderer: Renderer | None = None
        self.meshes = MeshCache()     # the meshes the export read for the last frame (export.geometry.MeshCache)
        self.updated = 0     # frames that took the kept renderer, and frames that built one (tests read them)
        self.built = 0

    def take(self, scene, threads: int) -> Renderer | None:
        """The kept renderer updated to `scene`, or None when it cannot be (then build one)."""
        renderer = self.renderer
        if renderer is None or renderer.accel.threads != capped_threads(threads):
            return None
        if not renderer.update_scene(scene):
            return None
        self.updated += 1
        return renderer

    def set(self, renderer: Renderer) -> None:
        if renderer is not self.renderer:
            if self.renderer is not None:
                self.renderer.close()
            self.renderer = renderer
            self.built += 1

    def drop(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None
        self.meshes = MeshCache()

    def __enter__(self):
        return self.renderer

    def __exit__(self, kind, *exc):
        if kind is not None:   # a failed render keeps nothing
            self.drop()


kept = _KeptScene()


def drop_kept_scene() -> None:
    """Free the renderer Persistent Data kept (unregister, or Persistent Data turned off)."""
    kept.drop()
