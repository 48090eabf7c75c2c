"""The world: Blender's World node tree -> kernels.World: a constant colour, an equirectangular HDRI, or a
node program.

Supported, with Cycles as the reference:
- No world: black. A world without a node tree: its colour. A Strength that is not a number reads 0
  (black, as in Cycles); a constant world brighter than lights.MAX_LIGHT_RADIANCE is clamped to it, as
  lights are; both warned.
- World Output <- Background (or Emission) with a constant Color and Strength: a constant world.
- The same with an Environment Texture (equirectangular) as Color, its Vector unlinked, Texture
  Coordinate (Generated or Object), or a Mapping node fed by those, with a constant Mapping and Strength:
  the HDRI world, sampled from the image itself. The Mapping rotation becomes env_from_world: R for the
  Point, Vector and Normal types, R^-1 for Texture (checked against Cycles).
- Any other tree (Mix and Add Shaders of Backgrounds, gradients, Sky Texture, Light Path, a Mapping with
  location or scale, ...): a node program (engine/export/nodes.py) that the kernel evaluates per escaped
  ray, as Cycles evaluates its background shader, and bakes for importance sampling. Nodes it cannot
  evaluate keep their inputs' own values, with a warning. A BSDF adds nothing and a Principled BSDF its
  emission (Cycles' background shader keeps only emission closures); another shader node:
  DEFAULT_WORLD_COLOR, with a warning.
"""
from __future__ import annotations

import dataclasses

import mathutils
import numpy as np

from ...kernels import World
from ...kernels.scene.lights import NO_BOUNCE_LIMIT
from ...kernels.scene.objects import RAY_CAMERA, RAY_DIFFUSE, RAY_GLOSSY, RAY_SCATTER, RAY_SHADOW, RAY_TRANSMIT
from ...kernels.textures import srgb_to_linear
from .graph import indexed_links, invalid_links, node_loop, run_nested, tree_nodes
from .images import ImagePixels, ImageTextures
from .lights import MAX_LIGHT_RADIANCE
from .emission_estimate import SocketReader, surface_estimate
from .materials import read_volume
from .nodes import ProgramBuilder, texture_mapping_matrix
from .shader_emission import emission_of, emits_nothing
from .sockets import BLACK3, MISSING_IMAGE_COLOR, Source, output_node, rgb, socket_has_nan, source_of

DEFAULT_WORLD_COLOR = (0.05, 0.05, 0.05)  # Blender's default world colour
TEXTURE_COORDINATES = ("Generated", "Object")  # both give the view direction on the world


def layer_world(scene, view_layer=None):
    """The world a view layer renders: its World Override (View Layer > Override), else the scene's (Cycles'
    sync_world)."""
    override = getattr(view_layer, "world_override", None) if view_layer is not None else None
    return override if override is not None else scene.world


def fast_gi(scene, viewport: bool = False, view_layer=None) -> dict:
    """Light Paths > Fast GI Approximation (Cycles' own settings, read as Cycles' sync reads them: the AO Bounces
    of the viewport or of renders, the Method; the layer's world's Ambient Occlusion Factor, its Distance via
    World.ao_distance): the RenderSettings fields ao_bounces, ao_factor (Replace) and ao_additive (Add). Off
    without a world."""
    cycles = getattr(scene, "cycles", None)
    world = layer_world(scene, view_layer)
    if cycles is None or world is None or not getattr(cycles, "use_fast_gi", False):
        return {}
    factor = float(world.light_settings.ao_factor)
    if getattr(cycles, "fast_gi_method", "REPLACE") == "ADD":
        return {"ao_additive": factor}
    bounces = int(getattr(cycles, "ao_bounces" if viewport else "ao_bounces_render", 0))
    return {"ao_bounces": max(bounces, 0), "ao_factor": factor} if bounces > 0 and factor else {}


def export_layer_world(depsgraph, warnings: list[str], images=None, layer_attribute=None) -> World:
    """The world of the depsgraph's view layer (layer_world) as export_world reads it, sampled as Cycles does where
    Fast GI's Replace is on; with View Layer > Filter > Environment off, black, with no volume (Cycles then
    renders the background with its empty shader), its Light settings kept."""
    scene, layer = depsgraph.scene_eval, depsgraph.view_layer_eval
    plain = any("ao_factor" in fast_gi(scene, viewport, layer) for viewport in (False, True))
    result = export_world(layer_world(scene, layer), warnings, images, layer_attribute, plain)
    if not bool(getattr(layer, "use_sky", True)):
        result = dataclasses.replace(result, color=np.zeros(3, np.float32), hdri=None, strength=1.0, program=None,
                                     output=None, volume=None)
    return result


def export_world(world, warnings: list[str], images=None, layer_attribute=None, plain: bool = False) -> World:
    """scene.world (may be None) as a kernels.World. Problems go to `warnings` in one line. images: the
    export's images.ImageTextures, which world programs read their images from. layer_attribute: the View
    Layer attribute lookup (nodes.ProgramBuilder). plain: sample it as Cycles does (Fast GI's Replace is on)."""
    result = _export_world(world, warnings, images, layer_attribute)
    if world is None:
        return result
    # Blender's sync hands Cycles the world's Light Settings > Distance as the integrator's AO distance; World >
    # Ray Visibility (Cycles' own) becomes its background's visibility (scene/background.cpp), read as Cycles reads it.
    result = dataclasses.replace(result, ao_distance=max(float(world.light_settings.distance), 0.0),
                                 visibility=world_visibility(world), emission_estimate=world_estimate(world))
    # World > Settings > Light > Max Bounces (Cycles' own, read as Cycles' sync_world reads it for its background light).
    bounces = int(getattr(getattr(world, "cycles", None), "max_bounces", NO_BOUNCE_LIMIT))
    if bounces < NO_BOUNCE_LIMIT:
        result = dataclasses.replace(result, max_bounces=max(bounces, 0))
    if getattr(getattr(world, "cycles", None), "sampling_method", "AUTOMATIC") == "NONE":
        # Sampling Method None (Cycles' own): no light samples of the world, as Cycles' background light without MIS.
        result = dataclasses.replace(result, light_sampled=False)
    if bounces < NO_BOUNCE_LIMIT or plain:
        # Past the limit (or Fast GI's AO bounces: plain) BSDF rays see the world, weighted by MIS, but its light
        # samples no longer come (or at another strength): what they add then depends on the light sampling's
        # distribution, so it is Cycles' (World.mis_compensation, focus).
        result = dataclasses.replace(result, mis_compensation=False, focus=False)
    return result


def world_visibility(world) -> int:
    """World > Ray Visibility (world.cycles_visibility: Camera, Diffuse, Glossy, Transmission, Volume Scatter) as
    kernels.scene.objects ray bits."""
    settings = getattr(world, "cycles_visibility", None)
    bits = 0
    for name, bit in (("camera", RAY_CAMERA), ("diffuse", RAY_DIFFUSE), ("glossy", RAY_GLOSSY),
                      ("transmission", RAY_TRANSMIT), ("scatter", RAY_SCATTER)):
        if bool(getattr(settings, name, True)):
            bits |= bit
    return bits | RAY_SHADOW


def _export_world(world, warnings: list[str], images, layer_attribute) -> World:
    if world is None:  # Cycles renders black without a world
        return World(color=np.zeros(3, np.float32))
    source = getattr(world, "original", None) or world    # (an evaluated copy does not say where it came from)
    if getattr(source, "is_missing", False):
        library = getattr(source.library, "filepath", "")
        warnings.append(f"World '{world.name}' is linked from a library that is missing ({library}): rendered as "
                        f"Blender's empty placeholder for it, as in Cycles")
    if world.node_tree is None:
        return World(color=np.array(rgb(world.color), np.float32))
    loop = node_loop(world.node_tree)
    if loop is not None:
        warnings.append(f"World '{world.name}': its node tree has a loop ({loop}), which Blender cannot "
                        f"evaluate: rendered black, as in Cycles")
        return World(color=np.zeros(3, np.float32))
    issues: list[str] = []
    images = images if images is not None else ImageTextures(warnings)
    with indexed_links():
        if _needs_program(world.node_tree):
            result = _program_world(world, images, issues, layer_attribute)
        else:
            result = _read_tree(world.node_tree, issues, images)
    issues.extend(invalid_links(world.node_tree))
    volume = read_volume(world.node_tree, world.name, images, issues, layer_attribute)
    if volume is not None:
        # The world's Volume > Step Size is its medium's step rate, as Cycles' sync hands it (blender/shader.cpp).
        step = float(getattr(getattr(world, "cycles", None), "volume_step_size", 1.0))
        result = dataclasses.replace(result, volume=dataclasses.replace(volume, volume_step_rate=step))
    if issues:
        warnings.append(f"World '{world.name}': " + "; ".join(dict.fromkeys(issues)))
    return result


def _read_tree(tree, issues: list[str], images: ImageTextures) -> World:
    """The worlds _needs_program leaves: nothing, an unsupported shader, a constant, or a plain HDRI."""
    out = output_node(tree)
    surface = Source(None, None) if out is None else source_of(out.inputs["Surface"])
    if surface.node is None:  # nothing connected: black, as in Cycles
        return World(color=np.zeros(3, np.float32))
    if emits_nothing(surface.kind):   # a BSDF: no emission closure, black in Cycles
        return World(color=np.zeros(3, np.float32))
    if surface.kind not in ("ShaderNodeBackground", "ShaderNodeEmission"):
        issues.append(f"{surface.node.bl_label} is not supported, rendered as constant grey")
        return World(color=np.array(DEFAULT_WORLD_COLOR, np.float32))
    node, groups = surface.node, surface.groups
    strength = _strength(source_of(node.inputs["Strength"], groups).socket, node, issues)
    color = source_of(node.inputs["Color"], groups)
    if color.node is None or color.kind == "ShaderNodeRGB":
        if socket_has_nan(color.socket):
            issues.append(f"{node.bl_label} Color is not a number, read as 0")
        value = np.array(rgb(color.socket.default_value), np.float32)
        return World(color=value, strength=_limited(strength, float(value.max()), node, issues))
    return _environment(color, strength, node, issues, images)


def _strength(socket, node, issues: list[str]) -> float:
    """A Background's constant Strength, >= 0; one that is not a number reads 0 (Cycles renders such a
    world black), with a warning."""
    if socket_has_nan(socket):
        issues.append(f"{node.bl_label} Strength is not a number, read as 0")
        return 0.0
    return max(float(socket.default_value), 0.0)


def _limited(strength: float, peak: float, node, issues: list[str]) -> float:
    """strength, clamped (with a warning) so that strength x peak (the brightest colour it scales) stays
    within MAX_LIGHT_RADIANCE, as the lights and materials are clamped."""
    if not strength * peak > MAX_LIGHT_RADIANCE:
        return strength
    issues.append(f"{node.bl_label} Strength {strength:g} is too bright for Ember's float32 arithmetic: "
                  f"clamped to {MAX_LIGHT_RADIANCE:g} W/(sr m^2)")
    return MAX_LIGHT_RADIANCE / peak


def _needs_program(tree) -> bool:
    """Whether the world is more than a constant or a plain HDRI (those keep their own fast paths)."""
    out = output_node(tree)
    surface = Source(None, None) if out is None else source_of(out.inputs["Surface"])
    if surface.node is None:    # no output, or nothing linked into it (an empty tree): black, _read_tree
        return False
    if surface.kind not in ("ShaderNodeBackground", "ShaderNodeEmission"):
        # Mix and Add Shaders, a Principled BSDF (its emission), and a colour or value linked into the Surface
        # (emitted, as Cycles converts it)
        return surface.kind in ("ShaderNodeMixShader", "ShaderNodeAddShader", "ShaderNodeBsdfPrincipled") or \
            surface.socket.type != "SHADER"
    node, groups = surface.node, surface.groups
    strength = source_of(node.inputs["Strength"], groups)
    if strength.node is not None and strength.kind != "ShaderNodeValue":
        return True
    color = source_of(node.inputs["Color"], groups)
    if color.node is None or color.kind == "ShaderNodeRGB":
        return False
    if color.kind != "ShaderNodeTexEnvironment" or color.socket.identifier != "Color":
        return True
    if texture_mapping_matrix(color.node.texture_mapping) is not None:   # its Texture Mapping panel moves it
        return True
    vector = source_of(color.node.inputs["Vector"], color.groups)
    if _is_view_direction(vector):
        return color.node.projection != "EQUIRECTANGULAR"
    if vector.kind != "ShaderNodeMapping" or not _is_view_direction(source_of(vector.node.inputs["Vector"],
                                                                              vector.groups)):
        return True
    mapping = vector.node
    constant = all(source_of(mapping.inputs[k], vector.groups).node is None for k in ("Location", "Rotation", "Scale"))
    location = np.asarray(mapping.inputs["Location"].default_value)
    scale = np.asarray(mapping.inputs["Scale"].default_value)
    moved = bool(np.any(location != 0)) and mapping.vector_type in ("POINT", "TEXTURE")
    return not constant or moved or np.ptp(scale) != 0


def _program_world(world, images, issues: list[str], layer_attribute=None) -> World:
    """The world's shader tree as a program whose output is the background radiance."""
    builder = ProgramBuilder(images, issues, set(), [], layer_attribute=layer_attribute, traces=False)
    out = output_node(world.node_tree)
    radiance = run_nested(emission_of(builder, source_of(out.inputs["Surface"]), issues, "a world",
                                      DEFAULT_WORLD_COLOR))
    if isinstance(radiance, tuple):  # folded: a constant world after all
        color = np.maximum(np.array(radiance, np.float64), 0.0)
        if color.max() > MAX_LIGHT_RADIANCE:
            issues.append(f"its radiance {color.max():g} is too bright for Ember's float32 arithmetic: clamped "
                          f"to {MAX_LIGHT_RADIANCE:g} W/(sr m^2)")
            color *= MAX_LIGHT_RADIANCE / color.max()
        return World(color=color.astype(np.float32))
    program = builder.program()
    suns = sun_discs(program)
    one = len(suns) == 1
    return World(color=np.zeros(3, np.float32), program=program, output=radiance,
                 map_resolution=map_resolution(world, len(suns)), sun=suns[0][0] if one else None,
                 sun_radiance=suns[0][1] if one else 0.0)


def world_estimate(world) -> np.ndarray | None:
    """(3,) float32 Cycles' emission estimate of the world's Surface (Shader::estimate_emission, as a material's:
    engine/export/emission_estimate.py, read from the sockets alone, no image decoded for it), which its light tree
    multiplies the world's measure by; the world's colour without a node tree (Blender's sync makes a Background of
    it); None without an output."""
    tree = getattr(world, "node_tree", None)
    if tree is None:
        return np.array(rgb(world.color), np.float32)
    out = output_node(tree)
    if out is None or "Surface" not in out.inputs:
        return None
    return np.array(surface_estimate(SocketReader(), out.inputs["Surface"]), np.float32)


def sun_discs(program) -> list[tuple]:
    """The sun discs of the Sky Textures a world program evaluates, each ((4,) float32, float): the world direction
    toward the sun and half its angular diameter, as Cycles' device_update_background finds them for its background
    light to aim at (scene/light.cpp: latitude the elevation, longitude the rotation + pi/2, both as Cycles'
    simplify_settings stores them, through the inverse of the node's Texture Mapping), and the disc's average
    radiance as Cycles estimates it (sun_average_radiance). Only the scattering models draw a disc."""
    suns = []
    for op in program.ops:
        sky = op.option("precomputed") if op.kind == "ShaderNodeTexSky" else None
        if sky is None or sky.angular_diameter is None or float(sky.angular_diameter) < 0:
            continue
        latitude, longitude = float(sky.sun_elevation), float(sky.sun_rotation) + 0.5 * np.pi
        direction = np.array([np.cos(latitude) * np.cos(longitude), np.cos(latitude) * np.sin(longitude),
                              np.sin(latitude)])
        vector = dict(op.inputs).get("Vector")
        mapping = program.ops[vector.op] if hasattr(vector, "op") else None
        if mapping is not None and mapping.kind == "TEXTURE_MAPPING":
            matrix = np.asarray(mapping.option("matrix"), np.float64).reshape(3, 4)[:, :3]
            direction = np.linalg.solve(matrix, direction)
        norm = np.linalg.norm(direction)
        if not np.isfinite(norm) or norm == 0:
            continue
        half = 0.5 * float(sky.angular_diameter)
        suns.append((np.array([*(direction / norm), half], np.float32), sun_average_radiance(sky)))
    return suns


def sun_average_radiance(sky) -> float:
    """Cycles' SkyTextureNode::get_sun_average_radiance (scene/shader_nodes.cpp): the mean of X, Y, Z at the disc's
    middle (halfway between its lowest and highest point) x its intensity x its angular diameter squared, scaled
    down for discs wider than 0.8 degrees (1 up to 0.8, 0.8 at 1 degree, toward 0.45 at 90 degrees, linearly)."""
    diameter = float(sky.angular_diameter)
    xyz = 0.5 * (np.asarray(sky.sun_bottom, np.float64) + np.asarray(sky.sun_top, np.float64)) * float(sky.sun_intensity)
    value = float(xyz.mean()) * diameter ** 2
    first, second, third = np.radians(0.8), np.radians(1.0), 0.5 * np.pi
    if diameter < first:
        return value
    if diameter < second:
        return value * (1.0 + (0.8 - 1.0) / (second - first) * (diameter - first))
    return value * (0.8 + (0.45 - 0.8) / (third - second) * (diameter - second))


def map_resolution(world, suns: int = 0) -> int:
    """Width of the map a world program is baked into for importance sampling. Cycles' world settings:
    Manual takes Map Resolution; Automatic (the default) takes the widest Environment Texture image in
    the tree, so that the bake's texel centres fall on the image's and the sampler, bilinear between
    them, follows the lookup exactly (Cycles then raises its point-sampled map to 4096 x 2048), else 1024; a
    Sky Texture's sun disc (suns: how many) asks for at least 512 (one, which the light samples aim at besides) or
    4096 (several), as Cycles' device_update_background."""
    settings = getattr(world, "cycles", None)
    if settings is not None and getattr(settings, "sampling_method", "AUTOMATIC") == "MANUAL":
        return max(int(settings.sample_map_resolution), 4)
    widths = [int(node.image.size[0]) for node in tree_nodes(world.node_tree)
              if node.bl_idname == "ShaderNodeTexEnvironment" and node.image is not None and node.image.size[0] > 0]
    if suns:
        widths.append(512 if suns == 1 else 4096)
    return int(np.clip(max(widths), 256, 8192)) if widths else 1024


def _environment(texture: Source, strength: float, background, issues: list[str], images: ImageTextures) -> World:
    """A plain equirectangular Environment Texture (feeding the node `background`): the HDRI world,
    sampled from the image itself."""
    node = texture.node
    missing = World(color=np.array(MISSING_IMAGE_COLOR, np.float32), strength=strength)  # as Cycles
    if node.image is None:
        issues.append("Environment Texture has no image, rendered magenta")
        return missing
    pixels = images.read(node.image, user=node.image_user)
    if pixels is None:
        return missing
    env_from_world = _env_from_world(source_of(node.inputs["Vector"], texture.groups))
    hdri, peak = _radiance(pixels)
    return World(color=np.array(BLACK3, np.float32), hdri=hdri, hdri_srgb=pixels.srgb,
                 hdri_interpolation=node.interpolation, strength=_limited(strength, peak, background, issues),
                 env_from_world=env_from_world)


def _radiance(pixels: ImagePixels) -> tuple[np.ndarray, float]:
    """(the map as the kernel keeps it, its brightest linear value) from an image with 1 or 3 channels: an 8- or
    16-bit image as it is stored (grey as one channel; sRGB-encoded where pixels.srgb, decoded after filtering as
    Cycles does), float images as (H, W, 3) float32 linear radiance."""
    if pixels.array.dtype in (np.uint8, np.uint16):
        peak = float(pixels.array.max()) / np.iinfo(pixels.array.dtype).max
        return pixels.array, float(srgb_to_linear(np.float32(peak))) if pixels.srgb else peak
    linear = np.maximum(pixels.linear(), 0.0)  # light cannot be negative (out-of-gamut texels)
    linear = linear if linear.shape[2] == 3 else np.repeat(linear, 3, axis=2)
    return linear, float(linear.max())


def _env_from_world(vector: Source) -> np.ndarray:
    """(3, 3) float32 rotation taking a world direction to the Environment Texture's lookup direction:
    the view direction itself, or through a constant Mapping (what _needs_program leaves here)."""
    if _is_view_direction(vector):
        return np.eye(3, dtype=np.float32)
    return _mapping_rotation(vector.node)


def _is_view_direction(vector: Source) -> bool:
    return vector.node is None or (vector.kind == "ShaderNodeTexCoord"
                                   and vector.socket.identifier in TEXTURE_COORDINATES
                                   and not (vector.socket.identifier == "Object" and vector.node.object))


def _mapping_rotation(mapping) -> np.ndarray:
    """The Mapping node's rotation as a matrix; Point = T R S transforms the vector, Texture inverts it.
    Its location (moving a direction nowhere for Vector and Normal) and a uniform scale do not turn the
    direction; the others go to a program."""
    rotation = np.array(mathutils.Euler(tuple(mapping.inputs["Rotation"].default_value), "XYZ").to_matrix(),
                        np.float32)
    return rotation.T.copy() if mapping.vector_type == "TEXTURE" else rotation
