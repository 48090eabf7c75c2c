"""Shading: a wave's hits and their materials -> the closure mixture, the emission, the transparency.

`Shading` is built once per scene from SceneArrays.materials (one Shader per material: closure nodes
with inputs that are constants or constants times an image texture, weighted by Mix Shader factors).
Per wave it evaluates each material over its hits only: inputs as arrays, then the node's closures
(kernels.shading.nodes) into one ClosureSet. The kernel never sees Blender: the engine's export wrote
the shaders.
"""
from .shader import Shading, SurfaceShading

__all__ = ["Shading", "SurfaceShading"]
