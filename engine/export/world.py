"""The world: Blender's World node tree -> kernels.World, a constant colour or an equirectangular HDRI.

Supported, with Cycles as the reference:
- No world: black. A world without a node tree: its colour.
- World Output <- Background (or Emission): Color x Strength. Color is a constant, an RGB node or an
  Environment Texture (equirectangular projection).
- The Environment Texture's Vector: unlinked, Texture Coordinate (Generated or Object), or a Mapping node
  fed by those. The Mapping rotation becomes env_from_world: R for the Point, Vector and Normal types,
  R^-1 for Texture (checked against Cycles). Its location and non-uniform scale are ignored with a warning.
- Anything else: the constant DEFAULT_WORLD_COLOR, with one warning.
"""
from __future__ import annotations

import mathutils
import numpy as np

from ...kernels import World
from .materials import (BLACK3, MISSING_IMAGE_COLOR, ImagePixels, Source, float_input, output_node,
                        read_image, rgb, source_of)

DEFAULT_WORLD_COLOR = (0.05, 0.05, 0.05)  # Blender's default world colour
TEXTURE_COORDINATES = ("Generated", "Object")  # both give the view direction on the world


def export_world(world, warnings: list[str]) -> World:
    """scene.world (may be None) as a kernels.World. Problems go to `warnings` in one line."""
    if world is None:  # Cycles renders black without a world
        return World(color=np.zeros(3, np.float32))
    if world.node_tree is None:
        return World(color=np.array(rgb(world.color), np.float32))
    issues: list[str] = []
    result = _read_tree(world.node_tree, issues, warnings)
    if issues:
        warnings.append(f"World '{world.name}': " + "; ".join(dict.fromkeys(issues)))
    return result


def _read_tree(tree, issues: list[str], warnings: list[str]) -> World:
    out = output_node(tree)
    surface = Source(None, None) if out is None else source_of(out.inputs["Surface"])
    if surface.node is None:  # nothing connected: black, as in Cycles
        return World(color=np.zeros(3, np.float32))
    if surface.kind not in ("ShaderNodeBackground", "ShaderNodeEmission"):
        issues.append(f"{surface.node.bl_label} is not supported, rendered as constant grey")
        return World(color=np.array(DEFAULT_WORLD_COLOR, np.float32))
    node, groups = surface.node, surface.groups
    strength = max(float_input(node.inputs["Strength"], groups, issues), 0.0)
    color = source_of(node.inputs["Color"], groups)
    if color.node is None or color.kind == "ShaderNodeRGB":
        return World(color=np.array(rgb(color.socket.default_value), np.float32), strength=strength)
    if color.kind == "ShaderNodeTexEnvironment":
        return _environment(color, strength, issues, warnings)
    issues.append(f"{color.node.bl_label} node feeding the background Color is not supported, "
                  f"rendered as constant grey")
    return World(color=np.array(DEFAULT_WORLD_COLOR, np.float32), strength=strength)


def _environment(texture: Source, strength: float, issues: list[str], warnings: list[str]) -> World:
    node = texture.node
    if node.projection != "EQUIRECTANGULAR":
        issues.append("Environment Texture: only the Equirectangular projection is supported")
    missing = World(color=np.array(MISSING_IMAGE_COLOR, np.float32), strength=strength)  # as Cycles
    if node.image is None:
        issues.append("Environment Texture has no image, rendered magenta")
        return missing
    pixels = read_image(node.image, warnings)
    if pixels is None:
        return missing
    env_from_world = _env_from_world(source_of(node.inputs["Vector"], texture.groups), issues)
    return World(color=np.array(BLACK3, np.float32), hdri=_radiance(pixels), strength=strength,
                 env_from_world=env_from_world)


def _radiance(pixels: ImagePixels) -> np.ndarray:
    """(H, W, 3) float32 linear radiance from an image with 1 or 3 channels."""
    linear = pixels.linear()
    return linear if linear.shape[2] == 3 else np.repeat(linear, 3, axis=2)


def _env_from_world(vector: Source, issues: list[str]) -> np.ndarray:
    """(3, 3) float32 rotation taking a world direction to the Environment Texture's lookup direction."""
    identity = np.eye(3, dtype=np.float32)
    if _is_view_direction(vector):
        return identity
    if vector.kind != "ShaderNodeMapping" or not _is_view_direction(source_of(vector.node.inputs["Vector"],
                                                                              vector.groups)):
        issues.append("Environment Texture Vector: only Texture Coordinate Generated or Object (without an "
                      "object), optionally through a Mapping node, is supported; used the view direction")
        return identity
    return _mapping_rotation(vector.node, vector.groups, issues)


def _is_view_direction(vector: Source) -> bool:
    return vector.node is None or (vector.kind == "ShaderNodeTexCoord"
                                   and vector.socket.identifier in TEXTURE_COORDINATES
                                   and not (vector.socket.identifier == "Object" and vector.node.object))


def _mapping_rotation(mapping, groups: tuple, issues: list[str]) -> np.ndarray:
    """The Mapping node's rotation as a matrix; Point = T R S transforms the vector, Texture inverts it."""
    for name in ("Rotation", "Location", "Scale"):
        if source_of(mapping.inputs[name], groups).node is not None:
            issues.append(f"Mapping {name} driven by a node is not supported, used its own value")
    location = np.asarray(mapping.inputs["Location"].default_value)
    scale = np.asarray(mapping.inputs["Scale"].default_value)
    if mapping.vector_type in ("POINT", "TEXTURE") and np.any(location != 0):
        issues.append("Mapping Location is ignored for the world")
    if np.ptp(scale) != 0:
        issues.append("Mapping non-uniform Scale is ignored for the world")
    rotation = np.array(mathutils.Euler(tuple(mapping.inputs["Rotation"].default_value), "XYZ").to_matrix(),
                        np.float32)
    return rotation.T.copy() if mapping.vector_type == "TEXTURE" else rotation
