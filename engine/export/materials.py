"""Materials and images: Blender shader node trees -> rows of kernels.Materials, images -> texture arrays.

This module owns the reading of shader node trees (also used by world.py) and of image pixels.
Cycles is the reference for what a material looks like:

- Diffuse BSDF: Color -> albedo.
- Principled BSDF: Base Color -> albedo, rendered as a diffuse surface (its specular layer and roughness
  are ignored); Emission Color x Emission Strength -> emission. Metallic, Transmission, Coat, Sheen,
  Subsurface, Alpha < 1 and normal maps are ignored with a warning.
- Emission: Color x Strength -> emission, on a black surface.
- Colour inputs: a constant, an RGB node or an Image Texture's Color output, looked up with the mesh's
  render UV map. Strength inputs: a constant or a Value node.
- Reroutes, muted links, muted nodes and node groups are seen through, as Blender evaluates them.
- Any other shader node, or any other node feeding a supported input: DEFAULT_ALBEDO grey, with one
  warning per material naming the nodes.
- Nothing connected to the Surface (or no output node): black, as in Cycles.
- Objects without a material: DEFAULT_ALBEDO grey, as Cycles' default surface.

Images: 8-bit images come back from Blender undecoded. Those in an sRGB space are handed to the kernel
sRGB-encoded and flagged, so it decodes them after filtering as Cycles does (the world's HDRI is decoded
here); Non-Color and linear ones are used as stored. Float images come back already scene linear. An image
that cannot be loaded renders MISSING_IMAGE_COLOR, as in Cycles, with a warning naming it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...kernels import Materials
from ...kernels.textures import srgb_to_linear

DEFAULT_ALBEDO = 0.8
MISSING_IMAGE_COLOR = (1.0, 0.0, 1.0)
BLACK3 = (0.0, 0.0, 0.0)
WHITE3 = (1.0, 1.0, 1.0)
GREY3 = (DEFAULT_ALBEDO,) * 3

# Principled BSDF inputs Ember does not render, each with the value at which it has no effect.
PRINCIPLED_IGNORED = (("Metallic", 0.0), ("Transmission Weight", 0.0), ("Coat Weight", 0.0),
                      ("Sheen Weight", 0.0), ("Subsurface Weight", 0.0), ("Alpha", 1.0))

# Byte images in these colour spaces (besides data ones such as Non-Color) hold linear values already.
LINEAR_BYTE_SPACES = ("Linear Rec.709", "scene_linear")


# ---- Node trees -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Source:
    """What feeds an input socket, once reroutes, muted links, muted nodes and groups are seen through.

    node : the node computing the value, or None when the value is a constant.
    socket : the node's output socket; when node is None, the input socket whose default_value applies.
    groups : the group nodes the node sits inside, outermost first (needed to follow the node's inputs).
    """
    node: object
    socket: object
    groups: tuple = ()

    @property
    def kind(self) -> str | None:
        return self.node.bl_idname if self.node is not None else None


def source_of(socket, groups: tuple = ()) -> Source:
    """Follow the links into an input socket to the node that computes its value."""
    while True:
        link = _live_link(socket)
        if link is None:
            return Source(None, socket, groups)
        node, output = link.from_node, link.from_socket
        if node.bl_idname == "NodeReroute":
            step = node.inputs[0], groups
        elif node.mute:
            step = _passed_through(node, output), groups
        elif node.bl_idname == "ShaderNodeGroup":
            step = _by_identifier(_group_output(node.node_tree), output.identifier), groups + (node,)
        elif node.bl_idname == "NodeGroupInput" and groups:
            step = _by_identifier(groups[-1], output.identifier), groups[:-1]
        else:
            return Source(node, output, groups)
        if step[0] is None:  # nothing passes through (muted node, empty group): the input's own value
            return Source(None, socket, groups)
        socket, groups = step


def output_node(tree):
    """The output node Cycles renders from (its own target first, then 'All'), or None."""
    return tree.get_output_node("CYCLES") or tree.get_output_node("ALL")


def _live_link(socket):
    return next((lk for lk in socket.links if lk.is_valid and not lk.is_muted), None)


def _passed_through(node, output):
    """The input a muted node passes to `output`, or None."""
    return next((lk.from_socket for lk in node.internal_links if lk.to_socket == output), None)


def _group_output(tree):
    if tree is None:
        return None
    outputs = [n for n in tree.nodes if n.bl_idname == "NodeGroupOutput"]
    return next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)


def _by_identifier(node, identifier: str):
    """The node's input socket with that identifier (group sockets match by identifier, not name)."""
    if node is None:
        return None
    return next((s for s in node.inputs if s.identifier == identifier), None)


def rgb(value) -> tuple:
    """A colour socket value as a non-negative, finite RGB triple (alpha dropped)."""
    c = np.nan_to_num(np.asarray(value[:3], np.float64))
    return tuple(float(x) for x in np.maximum(c, 0.0))


def float_input(socket, groups: tuple, issues: list[str]) -> float:
    """A float input's value: a constant or a Value node; any other node keeps the socket's own value."""
    source = source_of(socket, groups)
    if source.node is not None and source.kind != "ShaderNodeValue":
        issues.append(f"{source.node.bl_label} node feeding {socket.name} is not supported")
        return float(socket.default_value)
    return float(source.socket.default_value)


# ---- Images -----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ImagePixels:
    """An image's pixels as Blender holds them.

    array : (H, W, C) float32, C in {1, 3} (alpha dropped), row 0 at the bottom, finite and non-negative.
    srgb : the values are sRGB-encoded (an 8-bit image in an sRGB space); the kernel decodes them after
        filtering, as Cycles does. Otherwise they are linear.
    """
    array: np.ndarray
    srgb: bool

    def linear(self) -> np.ndarray:
        return srgb_to_linear(self.array) if self.srgb else self.array


def read_image(image, warnings: list[str]) -> ImagePixels | None:
    """An image's pixels; None (with a warning) when Blender cannot load it."""
    n = len(image.pixels)  # asking for the pixels loads the image (file, packed or generated)
    width, height = image.size
    if n == 0 or width * height == 0:
        warnings.append(f"Image '{image.name}' could not be loaded ({image.filepath or 'no file'}): "
                        f"rendered magenta")
        return None
    flat = np.empty(n, np.float32)
    image.pixels.foreach_get(flat)
    channels = n // (width * height)
    pixels = flat.reshape(height, width, channels)[:, :, :3 if channels >= 3 else 1]
    if image.is_float:  # float files (EXR, HDR) may hold negative or non-finite values; light cannot
        return ImagePixels(np.where(np.isfinite(pixels) & (pixels > 0), pixels, np.float32(0)), False)
    return ImagePixels(np.ascontiguousarray(pixels), _is_srgb(image, warnings))


def _is_srgb(image, warnings: list[str]) -> bool:
    """Whether an 8-bit image holds sRGB-encoded values (Blender returns them undecoded)."""
    settings = image.colorspace_settings
    if settings.is_data or settings.name in LINEAR_BYTE_SPACES:
        return False
    if settings.name != "sRGB":
        warnings.append(f"Image '{image.name}': colour space '{settings.name}' is not supported, "
                        f"read as sRGB")
    return True


class ImageTextures:
    """The texture list of one export: one array per image, shared by every material using it."""

    def __init__(self, warnings: list[str]):
        self.loaded: list[ImagePixels] = []
        self._index: dict[str, int | None] = {}
        self._warnings = warnings

    def index(self, image) -> int | None:
        """The image's texture index, None when it cannot be loaded."""
        key = image.name_full
        if key not in self._index:
            pixels = read_image(image, self._warnings)
            self._index[key] = None if pixels is None else len(self.loaded)
            if pixels is not None:
                self.loaded.append(pixels)
        return self._index[key]


# ---- Materials --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Surface:
    """One row of the material table: a diffuse albedo and an emission, each optionally textured."""
    albedo: tuple = GREY3
    albedo_texture: int = -1
    emission: tuple = BLACK3
    emission_texture: int = -1


DEFAULT_SURFACE = Surface()
BLACK_SURFACE = Surface(albedo=BLACK3)


class MaterialTable:
    """The materials of one export. Row 0 is the default surface of objects without a material."""

    def __init__(self, warnings: list[str]):
        self.images = ImageTextures(warnings)
        self._warnings = warnings
        self._rows: list[Surface] = [DEFAULT_SURFACE]
        self._ids: dict[str, int] = {}

    def material_id(self, material) -> int:
        """Row of a material (None for an empty slot), read on first use."""
        if material is None:
            return 0
        key = material.name_full
        if key not in self._ids:
            self._ids[key] = len(self._rows)
            self._rows.append(read_material(material, self.images, self._warnings))
        return self._ids[key]

    def slot_ids(self, ob) -> tuple[int, ...]:
        """The rows of an object's material slots; (0,) for an object without slots."""
        return tuple(self.material_id(slot.material) for slot in ob.material_slots) or (0,)

    @property
    def textures(self) -> tuple:
        """SceneArrays.textures: (H, W, C) float32 arrays."""
        return tuple(image.array for image in self.images.loaded)

    @property
    def texture_srgb(self) -> tuple:
        """SceneArrays.texture_srgb: one flag per texture, True for sRGB-encoded values."""
        return tuple(image.srgb for image in self.images.loaded)

    def to_kernel(self) -> Materials:
        rows = self._rows
        return Materials(
            albedo=np.array([r.albedo for r in rows], np.float32).reshape(-1, 3),
            albedo_texture=np.array([r.albedo_texture for r in rows], np.int32),
            emission=np.array([r.emission for r in rows], np.float32).reshape(-1, 3),
            emission_texture=np.array([r.emission_texture for r in rows], np.int32))


def read_material(material, images: ImageTextures, warnings: list[str]) -> Surface:
    """One material's row. Everything Ember cannot render goes into a single warning line."""
    reader = _MaterialReader(images)
    tree = material.node_tree
    if tree is None:  # a material without nodes renders its viewport colour, as in Cycles
        surface = Surface(albedo=_albedo(material.diffuse_color))
    else:
        out = output_node(tree)
        surface = BLACK_SURFACE if out is None else reader.shader(source_of(out.inputs["Surface"]))
    if reader.issues:
        warnings.append(f"Material '{material.name}': " + "; ".join(dict.fromkeys(reader.issues)))
    return surface


def _albedo(value) -> tuple:
    # A surface cannot reflect more light than it receives.
    return tuple(min(c, 1.0) for c in rgb(value))


class _MaterialReader:
    """Reads one material's node tree, collecting what it cannot render in `issues`."""

    def __init__(self, images: ImageTextures):
        self.images = images
        self.issues: list[str] = []

    def shader(self, source: Source) -> Surface:
        if source.node is None:  # nothing connected: Cycles renders black
            return BLACK_SURFACE
        read = {"ShaderNodeBsdfDiffuse": self.diffuse,
                "ShaderNodeBsdfPrincipled": self.principled,
                "ShaderNodeEmission": self.emission_shader}.get(source.kind)
        if read is None:
            self.issues.append(f"{source.node.bl_label} is not supported, rendered grey ({DEFAULT_ALBEDO})")
            return DEFAULT_SURFACE
        return read(source.node, source.groups)

    def diffuse(self, node, groups) -> Surface:
        albedo, texture = self.color(node.inputs["Color"], groups)
        self.check_normal(node, groups)
        return Surface(_albedo(albedo), texture)

    def principled(self, node, groups) -> Surface:
        albedo, texture = self.color(node.inputs["Base Color"], groups)
        ignored = [name for name, neutral in PRINCIPLED_IGNORED
                   if self.is_set(node.inputs[name], neutral, groups)]
        if ignored:
            self.issues.append(f"Principled BSDF {', '.join(ignored)} not supported, rendered as diffuse "
                               f"Base Color")
        self.check_normal(node, groups)
        emission, emission_texture = self.emission(node.inputs["Emission Color"],
                                                   node.inputs["Emission Strength"], groups)
        return Surface(_albedo(albedo), texture, emission, emission_texture)

    def emission_shader(self, node, groups) -> Surface:
        emission, texture = self.emission(node.inputs["Color"], node.inputs["Strength"], groups)
        return Surface(BLACK3, -1, emission, texture)

    def emission(self, color_socket, strength_socket, groups) -> tuple[tuple, int]:
        strength = float_input(strength_socket, groups, self.issues)
        if not strength > 0.0:  # also catches NaN; an unlit emission needs no texture
            return BLACK3, -1
        color, texture = self.color(color_socket, groups)
        return tuple(c * strength for c in color), texture

    def color(self, socket, groups) -> tuple[tuple, int]:
        """(rgb, texture index): a constant colour, or white times a texture."""
        source = source_of(socket, groups)
        if source.node is None or source.kind == "ShaderNodeRGB":
            return rgb(source.socket.default_value), -1
        if source.kind == "ShaderNodeTexImage" and source.socket.identifier == "Color":
            return self.image_texture(source.node, source.groups)
        self.issues.append(f"{source.node.bl_label} node feeding {socket.name} is not supported, "
                           f"used grey ({DEFAULT_ALBEDO})")
        return GREY3, -1

    def image_texture(self, node, groups) -> tuple[tuple, int]:
        self.check_uv(node, groups)
        if node.interpolation != "Linear" or node.projection != "FLAT" or node.extension != "REPEAT":
            self.issues.append(f"Image Texture '{node.name}': only Linear interpolation, Flat projection "
                               f"and Repeat extension are supported")
        if node.image is None:
            self.issues.append(f"Image Texture '{node.name}' has no image, rendered magenta")
            return MISSING_IMAGE_COLOR, -1
        index = self.images.index(node.image)
        return (WHITE3, index) if index is not None else (MISSING_IMAGE_COLOR, -1)

    def check_uv(self, node, groups) -> None:
        vector = source_of(node.inputs["Vector"], groups)
        uv = (vector.node is None
              or (vector.kind == "ShaderNodeTexCoord" and vector.socket.identifier == "UV")
              or (vector.kind == "ShaderNodeUVMap" and not vector.node.uv_map))
        if not uv:
            self.issues.append(f"Image Texture '{node.name}': coordinates from {vector.node.bl_label} are "
                               f"not supported, used the render UV map")

    def check_normal(self, node, groups) -> None:
        if source_of(node.inputs["Normal"], groups).node is not None:
            self.issues.append(f"{node.bl_label} Normal input (normal/bump maps) not supported")

    def is_set(self, socket, neutral: float, groups) -> bool:
        source = source_of(socket, groups)
        return source.node is not None or float(source.socket.default_value) != neutral
