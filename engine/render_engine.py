"""The RenderEngine Blender calls: thin, it hands final renders to session.FinalRender and the
viewport's rendered mode to viewport.ViewportRender (one per engine instance: one per 3D view), both
adapters over one session.ProgressiveSession; bakes to bake.bake."""
from __future__ import annotations

import traceback

import bpy

from .bake import bake, drop_scene
from .passes import register_passes
from .persistent import drop_kept_scene
from .session import FinalRender
from .viewport import new_viewport, stop_all_sessions


class EmberRenderEngine(bpy.types.RenderEngine):
    bl_idname = "EMBER"
    bl_label = "Ember"
    # Ember reads Principled BSDF, Diffuse, Emission and image nodes: show the standard shader nodes.
    bl_use_shading_nodes_custom = False
    # Compositing and sequencer post-processing apply to Ember's result as to any engine's.
    bl_use_postprocess = True
    # Material and world thumbnails stay with EEVEE: a CPU path tracer per thumbnail would stall the UI.
    bl_use_preview = False
    # Rendered viewport shading is Ember's own (view_update / view_draw), not EEVEE's.
    bl_use_eevee_viewport = False

    def render(self, depsgraph):
        # Never export in __init__: Blender may create several engine instances for one F12.
        try:
            FinalRender(self, depsgraph).run()
        except Exception as err:  # a bug of Ember's: report it in one line; an escaping error crashes Blender
            traceback.print_exc()
            self.report({"ERROR"}, f"Ember: internal error, render abandoned: {type(err).__name__}: {err}")

    def bake(self, depsgraph, obj, pass_type, pass_filter, width, height):
        # Blender's bake operator, once per image: Ember's kernels bake it (engine/bake.py).
        bake(self, depsgraph, obj, pass_type, pass_filter, width, height)

    def update_render_passes(self, scene=None, renderlayer=None):
        register_passes(self, scene, renderlayer)

    def view_update(self, context, depsgraph):
        viewport = getattr(self, "_viewport", None)
        if viewport is None:
            viewport = self._viewport = new_viewport(depsgraph.scene)
        viewport.view_update(self, context, depsgraph)

    def view_draw(self, context, depsgraph):
        viewport = getattr(self, "_viewport", None)
        if viewport is not None:
            viewport.view_draw(self, context, depsgraph)

    def __del__(self):
        # The viewport's worker must not outlive the engine, nor a bake's scene. The RNA may already be gone here.
        try:
            viewport = getattr(self, "_viewport", None)
        except ReferenceError:
            return
        if viewport is not None:
            viewport.free()
        drop_scene(self)


CLASSES = (EmberRenderEngine,)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    stop_all_sessions()
    drop_kept_scene()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
