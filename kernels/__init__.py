"""Ember's path tracer: NumPy + Embree, no Blender. The engine builds a SceneArrays and calls render().

    from kernels import SceneArrays, RenderSettings, render
    result = render(scene, RenderSettings(samples=64))
    result.image  # (H, W, 4) float32 linear RGBA, row 0 at the top
"""
from .renderer import Cancelled, Renderer, render
from .schedule import Progress, RenderResult, prestart_workers
from .settings import SAMPLING_MODES, RenderSettings
from .scene import LIGHT_KINDS, Camera, Lights, Materials, SceneArrays, World

__all__ = ["SAMPLING_MODES", "LIGHT_KINDS", "Camera", "Cancelled", "Lights", "Materials", "Progress", "Renderer",
           "RenderResult", "RenderSettings", "SceneArrays", "World", "prestart_workers", "render"]
