"""The RenderEngine Blender calls: thin, it hands final renders to session.FinalRender."""
from __future__ import annotations

import bpy

from .session import FinalRender


class EmberRenderEngine(bpy.types.RenderEngine):
    bl_idname = "EMBER"
    bl_label = "Ember"
    # Ember reads Principled BSDF, Diffuse, Emission and image nodes: show the standard shader nodes.
    bl_use_shading_nodes_custom = False
    # Compositing and sequencer post-processing apply to Ember's result as to any engine's.
    bl_use_postprocess = True
    # Material and world thumbnails stay with EEVEE: a CPU path tracer per thumbnail would stall the UI.
    bl_use_preview = False

    def render(self, depsgraph):
        # Never export in __init__: Blender may create several engine instances for one F12.
        FinalRender(self, depsgraph).run()


CLASSES = (EmberRenderEngine,)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
