"""A light's node tree: Cycles' light shader, the emission its Light Output's Surface gives, which multiplies the
light's strength (colour x power).

Cycles' sync (blender/shader.cpp sync_lights) builds a light's shader from its node tree when Use Nodes is on
and the light has a tree (Blender 5.3 gives every light one and keeps Use Nodes on), else an Emission of
colour 1 and strength 1. The emission is that of the Emission (or Background) nodes reaching the Surface
through Add and Mix Shaders (other shaders emit nothing); nothing connected, or no output node, emits nothing.
Where the tree folds to a constant (colours, strengths, a Blackbody, math on constants) Cycles takes it as its
constant emission (scene/shader.cpp estimate_emission) and so does Ember: it multiplies the light's radiance.
Where it varies (textures over the light's normal or position, a Light Falloff, Light Path), the light keeps a
node program that the kernel evaluates wherever a ray reaches the light (kernels/lights/shaders.py).
"""
from __future__ import annotations

import warnings as _warnings

import numpy as np

from .graph import indexed_links, invalid_links, node_loop, run_nested
from .images import ImageTextures
from .nodes import ProgramBuilder
from .shader_emission import emission_of
from .sockets import BLACK3, output_node, source_of

ONE = np.ones(3)


class LightShaders:
    """The light trees of one export, each read once (instances of a light share its program)."""

    def __init__(self, images: ImageTextures | None = None, layer_attribute=None):
        self.images, self.layer_attribute = images, layer_attribute
        self.programs: tuple = ()        # (Program, Ref) of the lights whose emission varies
        self._read: dict = {}

    def of(self, light, name: str, warnings: list[str]):
        """(factor (3,) float64, shader): the constant emission of the light's tree (ONE for a light without
        one), and the index of its program in `programs` where its emission varies (the factor is then 1),
        else -1. Problems go to `warnings`, naming the light object `name`."""
        tree = getattr(light, "node_tree", None)
        if tree is None or not _uses_nodes(light):
            return ONE, -1
        key = light.name_full
        if key not in self._read:
            issues: list[str] = []
            factor, shader = self._compile(tree, issues)
            self._read[key] = (factor, shader, issues)
        factor, shader, issues = self._read[key]
        if issues:
            warnings.append(f"Light '{name}': " + "; ".join(dict.fromkeys(issues)))
        return factor, shader

    def _compile(self, tree, issues: list[str]):
        loop = node_loop(tree)
        if loop is not None:
            issues.append(f"its node tree has a loop ({loop}), which Blender cannot evaluate: it emits nothing, "
                          f"as in Cycles")
            return np.zeros(3), -1
        out = output_node(tree)
        if out is None:
            return np.zeros(3), -1
        images = self.images if self.images is not None else ImageTextures(issues)
        builder = ProgramBuilder(images, issues, set(), [], layer_attribute=self.layer_attribute, traces=False)
        with indexed_links():
            value = run_nested(emission_of(builder, source_of(out.inputs["Surface"]), issues, "a light", BLACK3))
        issues.extend(invalid_links(tree))
        if isinstance(value, tuple):
            return np.array(value, np.float64), -1
        self.programs += ((builder.program(), value),)
        return ONE, len(self.programs) - 1


def _uses_nodes(light) -> bool:
    """Light.use_nodes, which Blender 5.3 keeps on (reading it warns of its removal)."""
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", DeprecationWarning)
        return bool(getattr(light, "use_nodes", False))
