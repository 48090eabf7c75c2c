"""Materials: Blender shader node trees -> kernel Shaders (closures with their inputs), and the material table
of an export (MaterialTable). What feeds a socket is read by sockets.py (as world.py reads it), the nodes
computing closure inputs are compiled by nodes.py, and the images they read are loaded by images.py.

Cycles is the reference for what a material looks like. From the material output's Surface, Mix Shader
and Add Shader nodes are followed down to closure nodes (CLOSURE_NODES: Principled, Diffuse, Glossy,
Glass, Refraction, Metallic, Sheen, Translucent, Transparent, Toon, Ray Portal, Hair, Principled Hair, Emission,
Holdout, Subsurface Scattering); each closure keeps its inputs and the Mix factors above it, and the
kernel builds Cycles' closures from them (kernels.shading.nodes).

- Constant values that are not numbers read 0 (Cycles drops a closure whose weight is not a number), and
  a constant emission brighter than lights.MAX_LIGHT_RADIANCE is clamped to it, as lights are; each warned.
- Inputs: a constant, an RGB or Value node, or an Image Texture's Color or Alpha output looked up with
  the mesh's render UV map. Any other node feeding an input: the socket's own value, with a warning
  naming the material, the node and the input.
- Reroutes, muted links, muted nodes and node groups are seen through, as Blender evaluates them; links
  Blender marks invalid are left out, as Cycles leaves them out, with a warning. A tree holding a loop
  (or reading a group that holds one) renders black, as in Cycles, with a warning naming the loop.
  Chains and nesting of any depth are read (engine/export/graph.py).
- Any other shader node: DEFAULT_ALBEDO grey diffuse, with a warning. Nothing connected to the Surface
  (or no output node): black, as in Cycles. Objects without a material: Cycles' default surface, a
  Principled BSDF with its defaults (DEFAULT_SURFACE). Volume outputs: media (volumes.md). The Displacement output:
  bump on the closures' unlinked normals (methods Bump, Both) and vertices moved (Displacement, Both: displacement.py).
- Normal and Coat Normal inputs: a Normal Map node (Tangent, World or Blender World space; its Color a
  constant, an RGB node or an Image Texture, its Strength a constant or a Value node) becomes a
  kernels.scene.NormalMap. Tangent inputs: a Tangent node in UV Map direction becomes a Tangent. The
  materials that read tangents, and the UV maps they name, are recorded (tangent_uv_maps) for the mesh
  export. Anything else feeding those inputs (a Bump, an Object-space Normal Map, a radial Tangent) is the
  program's vector.

An image that cannot be loaded renders sockets.MISSING_IMAGE_COLOR, as in Cycles, with a warning naming it.
"""
from __future__ import annotations

import math
from dataclasses import replace

import bpy
import numpy as np

from ...kernels import Materials
from ...kernels.programs import Ref
from ...kernels.scene import NORMAL_MAP_SPACES, Closure, NormalMap, Param, Shader, Tangent, diffuse_shader
from ...kernels.shading.hair_nodes import CURVE_NORMAL
from ...kernels.shading.input_ops import UNDEFORMED_POSITION, UNDISPLACED_NORMAL, UNDISPLACED_POSITION
from ...kernels.shading.normals import NORMAL_MAP_OBJECT_FRAME_FROM
from ..version import blender_version
from . import emission_estimate
from .graph import indexed_links, invalid_links, node_loop, run_nested
from .displacement import METHODS, TrueDisplacement
from .images import ImageTextures
from .lights import MAX_LIGHT_RADIANCE
from .nodes import ProgramBuilder, texture_mapping_matrix
from .sockets import MISSING_IMAGE_COLOR, Source, converted, output_node, rgb, socket_has_nan, source_of

DEFAULT_ALBEDO = 0.8
WHITE3 = (1.0, 1.0, 1.0)
GREY3 = (DEFAULT_ALBEDO,) * 3


# ---- Materials --------------------------------------------------------------------------------------

# Shader nodes Ember renders -> kernel closure kinds, with the inputs it reads (Blender 5.0 names).
CLOSURE_NODES = {
    "ShaderNodeBsdfPrincipled": ("PRINCIPLED", (
        "Base Color", "Metallic", "Roughness", "IOR", "Alpha", "Diffuse Roughness", "Subsurface Weight",
        "Specular IOR Level", "Specular Tint", "Anisotropic", "Anisotropic Rotation", "Transmission Weight",
        "Coat Weight", "Coat Roughness", "Coat IOR", "Coat Tint", "Sheen Weight", "Sheen Roughness", "Sheen Tint",
        "Emission Color", "Emission Strength", "Thin Film Thickness", "Thin Film IOR", "Subsurface Radius",
        "Subsurface Scale", "Subsurface IOR", "Subsurface Anisotropy")),
    "ShaderNodeBsdfDiffuse": ("DIFFUSE", ("Color", "Roughness")),
    "ShaderNodeBsdfAnisotropic": ("GLOSSY", ("Color", "Roughness", "Anisotropy", "Rotation")),
    "ShaderNodeBsdfGlass": ("GLASS", ("Color", "Roughness", "IOR", "Thin Film Thickness", "Thin Film IOR")),
    "ShaderNodeBsdfRefraction": ("REFRACTION", ("Color", "Roughness", "IOR")),
    "ShaderNodeBsdfMetallic": ("METALLIC", ("Base Color", "Edge Tint", "IOR", "Extinction", "Roughness",
                                            "Anisotropy", "Rotation", "Thin Film Thickness", "Thin Film IOR")),
    "ShaderNodeBsdfSheen": ("SHEEN", ("Color", "Roughness")),
    "ShaderNodeBsdfTranslucent": ("TRANSLUCENT", ("Color",)),
    "ShaderNodeBsdfTransparent": ("TRANSPARENT", ("Color",)),
    "ShaderNodeBsdfToon": ("TOON", ("Color", "Size", "Smooth")),
    "ShaderNodeBsdfRayPortal": ("PORTAL", ("Color", "Position", "Direction")),
    "ShaderNodeBsdfHair": ("HAIR", ("Color", "Offset", "RoughnessU", "RoughnessV")),
    "ShaderNodeEmission": ("EMISSION", ("Color", "Strength")),
    # A Background node in an object's material emits as an Emission node (Cycles' background_setup and
    # emission_setup are one; output_estimate_emission counts it as one).
    "ShaderNodeBackground": ("EMISSION", ("Color", "Strength")),
    "ShaderNodeHoldout": ("HOLDOUT", ()),
    "ShaderNodeSubsurfaceScattering": ("SUBSURFACE", ("Color", "Scale", "Radius", "IOR", "Roughness", "Anisotropy")),
    # By socket identifier: Blender names the lobe scales Reflection, Transmission and Secondary Reflection.
    "ShaderNodeBsdfHairPrincipled": ("PRINCIPLED_HAIR", (
        "Color", "Melanin", "Melanin Redness", "Tint", "Absorption Coefficient", "Aspect Ratio", "Roughness",
        "Radial Roughness", "Coat", "IOR", "Offset", "Random Color", "Random Roughness", "Random", "R lobe", "TT lobe",
        "TRT lobe")),
}
# Shader nodes a Volume output is made of -> kernel volume kinds (kernels.scene.VOLUME_KINDS), with the inputs
# read (Blender 5.0 names; the phase parameters Blender hides for another phase are read all the same) and the
# string inputs kept as options (attribute names).
VOLUME_NODES = {
    "ShaderNodeVolumeScatter": ("VOLUME_SCATTER", ("Color", "Density", "Anisotropy", "IOR", "Backscatter",
                                                   "Alpha", "Diameter"), ()),
    "ShaderNodeVolumeAbsorption": ("VOLUME_ABSORPTION", ("Color", "Density"), ()),
    "ShaderNodeVolumePrincipled": ("PRINCIPLED_VOLUME", (
        "Color", "Density", "Anisotropy", "Absorption Color", "Emission Strength", "Emission Color",
        "Blackbody Intensity", "Blackbody Tint", "Temperature"),
        ("Color Attribute", "Density Attribute", "Temperature Attribute")),
    "ShaderNodeVolumeCoefficients": ("VOLUME_COEFFICIENTS", (
        "Absorption Coefficients", "Scatter Coefficients", "Emission Coefficients", "Anisotropy", "IOR",
        "Backscatter", "Alpha", "Diameter"), ()),
    "ShaderNodeEmission": ("EMISSION", ("Color", "Strength"), ()),
}
# Why some shader nodes are not rendered (others: "is not supported").
UNSUPPORTED_NODES: dict = {}
# Vector inputs read only when linked: unlinked, they stand for the hit's position or the ray's direction.
LINKED_ONLY_INPUTS = ("Position", "Direction")
# Inputs read where the node has them (the Glass and Metallic BSDFs' thin film came with Blender 5.0).
OPTIONAL_INPUTS = ("Thin Film Thickness", "Thin Film IOR")
# The (colour, strength) inputs of the closures that emit.
EMISSION_INPUTS = {"EMISSION": ("Color", "Strength"), "PRINCIPLED": ("Emission Color", "Emission Strength")}
# Closure inputs that take a direction from a node: a Normal Map (normals) or a Tangent node.
NORMAL_INPUTS = ("Normal", "Coat Normal")
# Inputs Ember does not render yet, each with the value at which it has no effect.
# Inputs a Blender may lack (Thin Wall, dispersion and glass anisotropy came with 5.1 to 5.3) are checked
# where the node has them.
UNSUPPORTED_INPUTS = {
    "PRINCIPLED": (("Thin Wall", False), ("Transmission Dispersion Scale", 0.0)),
    "GLASS": (("Anisotropy", 0.0),),
}


# Cycles' default surface (scene/shader.cpp), for objects and slots without a material: a Principled BSDF
# with its defaults (grey 0.8 base, roughness 0.5, its specular layer), not a plain diffuse.
DEFAULT_SURFACE = Shader((Closure("PRINCIPLED", (("Base Color", Param.of(GREY3)),), (("distribution", "MULTI_GGX"),)),),
                         "default surface")


# Cycles' default volume shader (scene/shader.cpp): a Principled Volume with its defaults, read through the
# volume's density grid; its key in a MaterialTable is no Blender material's name.
DEFAULT_VOLUME = Shader((), "default volume", volume=(Closure("PRINCIPLED_VOLUME", (), (
    ("Color Attribute", ""), ("Density Attribute", "density"), ("Temperature Attribute", "temperature"))),),
    volume_only=True)
DEFAULT_VOLUME_KEY = "\x00default volume"


def _subsurface_method(node, kind: str) -> str:
    """The node's subsurface method as Cycles of this Blender runs it: up to 5.1, Random Walk is the model that
    Cycles 5.2 renamed Random Walk (Legacy) (radius / (4 pi), the legacy albedo fit)."""
    method = node.subsurface_method if kind == "PRINCIPLED" else node.falloff
    if method == "RANDOM_WALK" and bpy.app.version < (5, 2, 0):
        return "RANDOM_WALK_LEGACY"
    return method


class MaterialTable:
    """The materials of one export. Row 0 is the default surface of objects without a material."""

    def __init__(self, warnings: list[str], layer_attribute=None, frame: int = 1, override=None):
        """layer_attribute : the View Layer attribute lookup node programs fold (nodes.ProgramBuilder); frame: the
        scene frame (image sequences); override: View Layer > Override > Material, which every object's slots
        take instead of their own (Cycles' material_override), or None."""
        self.override = override
        self.images = ImageTextures(warnings, frame)
        self._warnings = warnings
        self._layer_attribute = layer_attribute
        self._rows: list[Shader] = [DEFAULT_SURFACE]
        self._pass_indices: list[int] = [0]
        self.names: list[str] = ["default_surface"]   # per row, for Cryptomatte (Cycles' name for no material)
        self._ids: dict[str, int] = {}
        self._tangent_maps: dict[int, tuple[str, ...]] = {}
        self._attributes: dict[int, frozenset] = {}
        self._displacements: dict[int, TrueDisplacement] = {}

    def material_id(self, material) -> int:
        """Row of a material (None for an empty slot), read on first use."""
        if material is None:
            return 0
        key = material.name_full
        if key not in self._ids:
            row = self._ids[key] = len(self._rows)
            uv_maps: list[str] = []
            attributes: set[str] = set()
            displaced: list = []
            self._rows.append(read_material(material, self.images, self._warnings, uv_maps, attributes,
                                            self._layer_attribute, displaced))
            if displaced:
                self._displacements[row] = displaced[0]
            self._pass_indices.append(int(material.pass_index))
            self.names.append(material.name)
            if uv_maps:
                self._tangent_maps[row] = tuple(dict.fromkeys(uv_maps))
            if attributes:
                self._attributes[row] = frozenset(attributes)
        return self._ids[key]

    def default_volume_id(self) -> int:
        """The row of Cycles' default volume (a Principled Volume with its defaults, scene/shader.cpp), for
        Volume objects without a material."""
        if DEFAULT_VOLUME_KEY not in self._ids:
            self._ids[DEFAULT_VOLUME_KEY] = len(self._rows)
            self._rows.append(DEFAULT_VOLUME)
            self._pass_indices.append(0)
            self.names.append("default_volume")
        return self._ids[DEFAULT_VOLUME_KEY]

    def interpolation(self, rows) -> str:
        """The volume interpolation of the first of these rows with a volume (LINEAR without one)."""
        return next((self._rows[r].interpolation for r in rows if self._rows[r].volume), "LINEAR")

    def has_volume(self, rows) -> bool:
        """Whether any of these rows has a Volume output (the object is a medium)."""
        return any(self._rows[r].volume for r in rows)

    def has_subsurface(self, rows) -> bool:
        """Whether any of these rows scatters below its surface (Cycles' has_surface_bssrdf: a Subsurface
        Scattering node, or a Principled BSDF whose Subsurface Weight is linked or above the closure cutoff and
        that is not Thin Wall)."""
        for row in rows:
            for closure in self._rows[row].closures:
                if closure.kind == "SUBSURFACE":
                    return True
                if closure.kind == "PRINCIPLED":
                    inputs = dict(closure.inputs)
                    thin = inputs.get("Thin Wall")
                    if thin is not None and not thin.varies and thin.value[0] > 0.5:
                        continue
                    weight = inputs.get("Subsurface Weight")
                    if weight is not None and (weight.varies or weight.value[0] > 1e-5):
                        return True
        return False

    def tangent_uv_maps(self, rows) -> tuple[str, ...]:
        """The UV maps whose tangents the materials of these rows read ('' for the render UV map);
        empty when they read none."""
        return tuple(dict.fromkeys(name for row in rows for name in self._tangent_maps.get(row, ())))

    def attribute_names(self, rows) -> tuple[str, ...]:
        """The mesh attributes the node programs of these rows read (kernels.scene.SceneArrays.attributes
        names), and their object attributes (SceneArrays.object_attributes names), sorted."""
        return tuple(sorted(set().union(*(self._attributes.get(row, ()) for row in rows))))

    @property
    def keys(self) -> tuple:
        """Per row, the material's name_full (None for row 0, the default surface): what names a row
        across exports (engine/export/updates.py reads the materials again in this order)."""
        return (None,) + tuple(sorted(self._ids, key=self._ids.get))

    def mesh_needs(self) -> tuple:
        """Per row, what its shader asks of the meshes beyond positions, normals and UVs: (tangent UV
        maps, attribute names, true displacement). A material edit that changes it needs the meshes read again."""
        return tuple((self._tangent_maps.get(row, ()), tuple(sorted(self._attributes.get(row, ()))),
                      self._displacements[row].signature if row in self._displacements else None)
                     for row in range(len(self._rows)))

    def true_displacements(self, rows) -> tuple:
        """Per row of `rows`, the displacement.TrueDisplacement that moves its vertices, or None."""
        return tuple(self._displacements.get(row) for row in rows)

    def slot_ids(self, ob) -> tuple[int, ...]:
        """The rows of an object's material slots; (0,) for an object without slots. With a material override,
        its row in every slot (and for an object without slots)."""
        if self.override is not None:
            return (self.material_id(self.override),) * max(len(ob.material_slots), 1)
        return tuple(self.material_id(slot.material) for slot in ob.material_slots) or (0,)

    @property
    def textures(self) -> tuple:
        """SceneArrays.textures: (H, W, C) uint8 or float32 arrays (images.ImagePixels)."""
        return tuple(image.array for image in self.images.loaded)

    @property
    def texture_srgb(self) -> tuple:
        """SceneArrays.texture_srgb: one flag per texture, True for sRGB-encoded values."""
        return tuple(image.srgb for image in self.images.loaded)

    def to_kernel(self) -> Materials:
        return Materials(tuple(self._rows), pass_indices=tuple(self._pass_indices))


def read_material(material, images: ImageTextures, warnings: list[str], uv_maps: list[str] | None = None,
                  attributes: set[str] | None = None, layer_attribute=None,
                  true_displacement: list | None = None) -> Shader:
    """One material's shader. Everything Ember cannot render goes into a single warning line. The UV
    maps whose tangents it reads are appended to uv_maps ('' for the render UV map), the mesh attributes
    its node program reads added to attributes. layer_attribute : nodes.ProgramBuilder's. Its Displacement
    output, when it moves vertices (displacement.TrueDisplacement), is appended to true_displacement."""
    tree = material.node_tree
    if tree is None:  # a material without nodes renders its viewport colour, as in Cycles
        return diffuse_shader(rgb(material.diffuse_color), name=material.name)
    loop = node_loop(tree)
    if loop is not None:
        warnings.append(f"Material '{material.name}': its node tree has a loop ({loop}), which Blender cannot "
                        f"evaluate: rendered black, as in Cycles")
        return Shader((), material.name)
    with indexed_links():
        return _read_tree(material, tree, _MaterialReader(images, material.pass_index, layer_attribute), warnings, uv_maps,
                          attributes, true_displacement)


def _reads_generated(ops) -> bool:
    """Whether a program reads Generated coordinates (a Texture Coordinate's Generated, an unlinked texture Vector, a
    radial Tangent), which on a mesh deformed by its modifiers come from its undeformed positions."""
    for op in ops:
        if op.kind == "ShaderNodeTexCoord" and "Generated" in op.option("outputs", ("Generated",)):
            return True
        if op.kind == "ShaderNodeTangent" and op.option("direction_type", "RADIAL") == "RADIAL":
            return True
    return False


def _read_tree(material, tree, reader, warnings, uv_maps, attributes, true_displacement=None) -> Shader:
    out = output_node(tree)
    displacement = None if out is None else out.inputs.get("Displacement")
    method = getattr(material, "displacement_method", "BUMP")
    if displacement is not None and source_of(displacement).node is not None:
        moves, _, bumps = METHODS.get(method, METHODS["BUMP"])
        if bumps and source_of(out.inputs["Surface"]).node is not None:
            reader.bump_from_displacement(displacement, undisplaced=method == "BOTH")
        if moves and true_displacement is not None:
            true_displacement.append(reader.true_displacement(displacement, method == "BOTH"))
            # Generated coordinates are an attribute of the mesh before it is displaced (Cycles' ATTR_STD_GENERATED):
            # the surface reads them from its undisplaced positions (input_ops.generated).
            reader.attributes.add(UNDISPLACED_POSITION)
    closures = () if out is None else tuple(reader.closures(source_of(out.inputs["Surface"]), ()))
    volume, volume_only = (), False
    if out is not None:
        volume = tuple(reader.volume_closures(source_of(out.inputs["Volume"]), ()))
        # A Volume output and nothing on the Surface: the surface is the volume's invisible boundary (Cycles'
        # SD_HAS_ONLY_VOLUME); a Surface whose shader folds to nothing stays black, as in Cycles.
        volume_only = bool(volume) and source_of(out.inputs["Surface"]).node is None
    reader.issues.extend(invalid_links(tree))
    if reader.issues:
        warnings.append(f"Material '{material.name}': " + "; ".join(dict.fromkeys(reader.issues)))
    if uv_maps is not None:
        uv_maps.extend(reader.tangent_uv_maps)
    if _reads_generated(reader.program.ops):
        reader.attributes.add(UNDEFORMED_POSITION)
    if attributes is not None:
        attributes.update(reader.attributes)
    aovs = tuple((node.aov_name, reader.param(node.inputs["Color"], (), 3, node),
                  reader.param(node.inputs["Value"], (), 1, node))
                 for node in tree.nodes if node.bl_idname == "ShaderNodeOutputAOV" and not node.mute)
    settings = getattr(material, "cycles", None)
    correction = getattr(settings, "use_bump_map_correction", True)
    interpolation = getattr(settings, "volume_interpolation", "LINEAR")
    sampling = getattr(settings, "emission_sampling", "AUTO")
    return Shader(closures, material.name, bool(correction), reader.program.program(), aovs, volume, volume_only,
                  interpolation if interpolation in ("LINEAR", "CLOSEST", "CUBIC") else "LINEAR",
                  float(getattr(settings, "volume_step_rate", 1.0)), reader.set_normal,
                  out is not None and emission_estimate.light_sampled(reader, out.inputs["Surface"], sampling),
                  sampling if sampling in ("FRONT", "BACK") else "BOTH",
                  bool(getattr(material, "use_transparent_shadow", True)),
                  None if out is None else emission_estimate.surface_estimate(reader, out.inputs["Surface"]))


def read_volume(tree, name: str, images: ImageTextures, issues: list[str], layer_attribute=None) -> Shader | None:
    """The Volume output of a node tree (a world's) as a Shader of volume closures and their program, or None
    when nothing feeds it. What it cannot render goes to issues."""
    out = output_node(tree)
    if out is None or "Volume" not in out.inputs or source_of(out.inputs["Volume"]).node is None:
        return None
    reader = _MaterialReader(images, layer_attribute=layer_attribute)
    with indexed_links():
        volume = tuple(reader.volume_closures(source_of(out.inputs["Volume"]), ()))
    issues.extend(reader.issues)
    if not volume:
        return None
    return Shader((), name, program=reader.program.program(), volume=volume)


class _MaterialReader:
    """Reads one material's node tree into closures, collecting what it cannot render in `issues`."""

    def __init__(self, images: ImageTextures, pass_index: int = 0, layer_attribute=None):
        self.images = images
        self.issues: list[str] = []
        self.tangent_uv_maps: list[str] = []  # UV maps whose tangents the closures read ('' = render map)
        self.attributes: set[str] = set()     # mesh attributes the node program reads
        self.program = ProgramBuilder(images, self.issues, self.attributes, self.tangent_uv_maps, pass_index,
                                      layer_attribute=layer_attribute)
        self.set_normal: Ref | None = None  # the normal bump from displacement sets (Shader.set_normal)

    def bump_from_displacement(self, socket, undisplaced: bool = False) -> None:
        """Cycles' bump from displacement (ShaderGraph::bump_from_displacement, scene/shader_graph.cpp): the
        Displacement output's component along the normal as the height of a Bump node (Distance 1, Filter
        Width 0.1, Strength 1) whose normal becomes the shading normal (SetNormal: Shader.set_normal). undisplaced
        ("Displacement and Bump"): on the undisplaced surface, in object space (kernels/shading/bump.py), which
        reads the meshes' undisplaced positions and normals."""
        value = self.program.input(socket, (), "VECTOR")
        if not isinstance(value, Ref):
            return   # a constant offset has no gradient: the normal stays
        normal = Ref(self.program.add("ShaderNodeNewGeometry", {}, outputs=("Normal",)), "Normal", "VECTOR", "VECTOR")
        height = self.program.result(self.program.add("ShaderNodeVectorMath", {"Vector": value, "Vector_001": normal},
                                                      {"operation": "DOT_PRODUCT"}), "Value", "VALUE", "VALUE")
        bump = self.program.add("ShaderNodeBump", {"Height": height, "Distance": (1.0,), "Filter Width": (0.1,),
                                                   "Strength": (1.0,)}, {"invert": False, "undisplaced": True}
                                if undisplaced else {"invert": False})
        if undisplaced:
            self.attributes.update((UNDISPLACED_POSITION, UNDISPLACED_NORMAL))
        self.set_normal = Ref(bump, "Normal", "VECTOR", "VECTOR")

    def true_displacement(self, socket, keeps_normals: bool) -> TrueDisplacement:
        """The Displacement output compiled into a program of its own, for the mesh's vertices."""
        attributes: set[str] = set()
        uv_maps: list[str] = []
        builder = ProgramBuilder(self.images, self.issues, attributes, uv_maps, self.program.material_pass_index,
                                 layer_attribute=self.program.layer_attribute, traces=False)
        value = builder.input(socket, (), "VECTOR")
        return TrueDisplacement(builder.program(), value, keeps_normals, frozenset(attributes),
                                tuple(dict.fromkeys(uv_maps)))

    def closures(self, source: Source, factors: tuple) -> list[Closure]:
        """The closures of the shader tree feeding a shader socket, with their Mix Shader factors."""
        return run_nested(self._closures(source, factors))

    def _closures(self, source: Source, factors: tuple):
        """Step (engine/export/graph.py) of closures()."""
        node, groups = source.node, source.groups
        if node is None:  # nothing connected: Cycles renders black
            return []
        kind = source.kind
        if kind == "ShaderNodeMixShader":
            fac = self.param(node.inputs[0], groups, 1, node)
            first, second = (source_of(node.inputs[i], groups) for i in (1, 2))
            out = []
            if fac.varies or fac.value[0] < 1.0:
                out += yield self._closures(first, factors + ((fac, False),))
            if fac.varies or fac.value[0] > 0.0:
                out += yield self._closures(second, factors + ((fac, True),))
            return out
        if kind == "ShaderNodeAddShader":
            out = []
            for i in (0, 1):
                out += yield self._closures(source_of(node.inputs[i], groups), factors)
            return out
        if kind not in CLOSURE_NODES:
            emission = self.auto_emission(source, "EMISSION")
            if emission is not None:
                return [replace(emission, factors=factors)]
            why = UNSUPPORTED_NODES.get(kind, "is not supported")
            self.issues.append(f"{node.bl_label} '{node.name}' {why}, rendered grey ({DEFAULT_ALBEDO})")
            return [Closure("DIFFUSE", (("Color", Param.of(GREY3)),), (), factors)]
        closure_kind, names = CLOSURE_NODES[kind]
        sockets = {s.identifier: s for s in node.inputs}  # unavailable sockets are not found by name
        names = tuple(n for n in names if n in sockets or n not in OPTIONAL_INPUTS)
        names = tuple(n for n in names if n not in LINKED_ONLY_INPUTS or source_of(sockets[n], groups).node is not None)
        inputs = tuple((name, self.param(sockets[name], groups, _channels(sockets[name]), node)) for name in names)
        inputs = self.limit_emission(node, closure_kind, inputs) + self.directions(node, groups)
        self.check_unsupported(node, closure_kind, groups)
        self.check_direction(node, dict(inputs).get("Direction"))
        return [Closure(closure_kind, inputs, self.options(node, closure_kind), factors)]

    def auto_emission(self, source: Source, kind: str) -> Closure | None:
        """A colour, vector or value output linked into a shader socket: an Emission of it, as Cycles' ShaderGraph
        connects a non-closure output to a closure input through an Emission node (a value into its Strength under
        a white Color, a colour or vector into its Color at Strength 1). None for a shader output or one that is not
        linked where its links can be read."""
        fed = converted(source)
        if fed is None:
            return None
        consumer, socket_type = fed
        value = socket_type == "VALUE"
        read = self.program.input(consumer, source.groups, socket_type)
        param = Param.of(read) if isinstance(read, tuple) else Param.of((1.0,) * (1 if value else 3), link=read)
        white, one = Param.of((1.0, 1.0, 1.0)), Param.of((1.0,))
        inputs = (("Color", white), ("Strength", param)) if value else (("Color", param), ("Strength", one))
        return Closure(kind, inputs, (), ())

    def volume_closures(self, source: Source, factors: tuple) -> list[Closure]:
        """The volume closures of the shader tree feeding a Volume output, with their Mix Shader factors."""
        return run_nested(self._volume_closures(source, factors))

    def _volume_closures(self, source: Source, factors: tuple):
        """Step (engine/export/graph.py) of volume_closures()."""
        node, groups = source.node, source.groups
        if node is None:
            return []
        kind = source.kind
        if kind in ("ShaderNodeMixShader", "ShaderNodeAddShader"):
            out = []
            fac = self.volume_param(node.inputs[0], groups, 1, node) if kind == "ShaderNodeMixShader" else None
            for i, second in ((1, False), (2, True)) if fac is not None else ((0, None), (1, None)):
                if fac is not None and not fac.varies and fac.value[0] == (0.0 if second else 1.0):
                    continue
                below = factors if fac is None else factors + ((fac, second),)
                out += yield self._volume_closures(source_of(node.inputs[i], groups), below)
            return out
        if kind not in VOLUME_NODES and source.socket.type != "SHADER":
            emission = self.auto_emission(source, "EMISSION")
            if emission is not None:
                return [replace(emission, factors=factors)]
        if kind not in VOLUME_NODES:
            self.issues.append(f"{node.bl_label} '{node.name}' is not a volume shader: the Volume output ignores it, "
                               f"as Cycles does")
            return []
        volume_kind, names, strings = VOLUME_NODES[kind]
        inputs = tuple((name, self.volume_param(node.inputs[name], groups, _channels(node.inputs[name]), node))
                       for name in names if name in node.inputs)
        options = tuple((name, str(node.inputs[name].default_value)) for name in strings if name in node.inputs)
        phase = getattr(node, "phase", None)
        if phase is not None:
            options += (("phase", phase),)
        return [Closure(volume_kind, inputs, options, factors)]

    def volume_param(self, socket, groups, channels: int, node) -> Param:
        """A volume closure's input: a constant, or the node program's value at each point of the medium
        (image lookups included: a volume has no UVs, the program reads what Cycles reads there)."""
        source = source_of(socket, groups)
        if source.node is None or source.kind in ("ShaderNodeRGB", "ShaderNodeValue"):
            return Param.of(self.constant(source.socket, channels, source.node or node))
        return self.program_param(socket, groups, channels)

    def options(self, node, kind: str) -> tuple:
        options = []
        distribution = getattr(node, "distribution", None)
        if distribution is not None:
            options.append(("distribution", distribution))
        if kind == "METALLIC":
            options.append(("fresnel", node.fresnel_type))
        if kind in ("TOON", "HAIR"):
            options.append(("component", node.component))
        if kind == "PRINCIPLED_HAIR":
            options += [("model", node.model), ("parametrization", node.parametrization)]
            if not node.inputs["Random"].is_linked:   # on curves it reads the curve's (Cycles' attributes())
                self.attributes.add("std:curve_random")
            aspect = node.inputs.get("Aspect Ratio")
            if node.model == "HUANG" and aspect is not None and (aspect.is_linked or aspect.default_value != 1.0):
                # An elliptical fibre's major axis: the curves' normals (has_surface_transparent, attributes()).
                self.attributes.add(CURVE_NORMAL)
        if kind in ("PRINCIPLED", "SUBSURFACE"):
            method = _subsurface_method(node, kind)
            if method != "RANDOM_WALK":  # the default, read as such
                options.append(("subsurface_method", method))
        return tuple(options)

    def directions(self, node, groups) -> tuple:
        """The node's linked Normal, Coat Normal and Tangent inputs Ember renders: ((name, NormalMap or
        Tangent), ...). Other nodes feeding them are ignored with a warning."""
        out = []
        for name in NORMAL_INPUTS + ("Tangent",):
            socket = node.inputs.get(name)
            if socket is None or not socket.enabled:
                continue
            source = source_of(socket, groups)
            if source.node is None:
                continue
            if name in NORMAL_INPUTS:
                value = self.normal_map(source, socket, groups)
            else:
                value = self.tangent(source, socket, groups)
            if value is not None:
                out.append((name, value))
        return tuple(out)

    def normal_map(self, source: Source, socket, groups) -> NormalMap | Param | None:
        """A Normal or Coat Normal input: a Normal Map node as the kernel's NormalMap, any other node (an
        Object-space map too: its op takes the hit's object transform) as the program's
        vector. A program that folds to a constant gives that
        normal, as Cycles loads a constant-folded input (svm.cpp stack_assign_if_linked: constant_folded_in);
        a zero one is no direction: the shading normal, with a warning."""
        if source.kind != "ShaderNodeNormalMap" or source.node.space not in NORMAL_MAP_SPACES:
            return self._direction(self.program_param(socket, groups, 3), socket)
        node = source.node
        color = self.param(node.inputs["Color"], source.groups, 3, node)
        strength = self.param(node.inputs["Strength"], source.groups, 1, node)
        if node.space == "TANGENT":
            self.tangent_uv_maps.append(node.uv_map)
        return NormalMap(color, strength, node.space, getattr(node, "convention", "OPENGL") == "DIRECTX",
                         blender_version() >= NORMAL_MAP_OBJECT_FRAME_FROM)

    def tangent(self, source: Source, socket, groups) -> Tangent | Param | None:
        """A Tangent input: a UV Map Tangent node as the kernel's Tangent, any other node (a radial Tangent,
        a Geometry tangent, a vector program) as the program's vector, a constant one too (as normal_map)."""
        if source.kind == "ShaderNodeTangent" and source.node.direction_type == "UV_MAP":
            self.tangent_uv_maps.append(source.node.uv_map)
            return Tangent()
        return self._direction(self.program_param(socket, groups, 3), socket)

    def _direction(self, param: Param, socket) -> Param | None:
        """A linked Normal or Tangent input's program: itself, or None for a constant of length zero (warned)."""
        if param.link is not None or any(v != 0 for v in param.value):
            return param
        node = socket.node
        self.issues.append(f"{node.bl_label} '{node.name}' {socket.name} is linked to a zero vector: the "
                           f"{'shading normal' if 'Normal' in socket.name else 'default tangent'} is used")
        return None

    def check_unsupported(self, node, kind: str, groups) -> None:
        label = f"{node.bl_label} '{node.name}'"
        for name, neutral in UNSUPPORTED_INPUTS.get(kind, ()):
            if name in node.inputs and self.is_set(node.inputs[name], neutral, groups):
                self.issues.append(f"{label} {name} is not supported, ignored")
        if kind == "SHEEN" and node.distribution not in ("MICROFIBER", "ASHIKHMIN"):
            self.issues.append(f"{label} {node.distribution.title()} sheen rendered as Microfiber")

    def check_direction(self, node, direction: Param | None) -> None:
        """A Ray Portal's Direction is normalised; Cycles traces a constant one of another length as given, which
        its next hit sees as a viewer direction that is not of unit length either: say so."""
        if direction is None or direction.varies:
            return
        length = math.sqrt(sum(v * v for v in direction.value))
        if length > 0 and abs(length - 1.0) > 1e-3:
            self.issues.append(f"{node.bl_label} '{node.name}' Direction has length {length:g}: normalised (Cycles "
                               f"traces it as given)")

    def limit_emission(self, node, kind: str, inputs: tuple) -> tuple:
        """The closure's inputs, a constant emission brighter than MAX_LIGHT_RADIANCE clamped to it (with a
        warning), as the light export clamps lamps: past it float32 arithmetic overflows (Cycles then
        drops the sample's light, or its pixel sums become inf) and the denoiser returns black."""
        names = EMISSION_INPUTS.get(kind)
        params = dict(inputs)
        if names is None or params[names[1]].link is not None:
            return inputs
        color, strength = params[names[0]], params[names[1]]
        scale = max(abs(v) for v in color.value) if color.link is None else 1.0
        if not abs(strength.value[0]) * scale > MAX_LIGHT_RADIANCE:
            return inputs
        limited = replace(strength, value=(math.copysign(MAX_LIGHT_RADIANCE / scale, strength.value[0]),))
        self.issues.append(f"{node.bl_label} '{node.name}' {names[1]} {strength.value[0]:g} is too bright for "
                           f"Ember's float32 arithmetic: clamped to {MAX_LIGHT_RADIANCE:g} W/(sr m^2)")
        return tuple((name, limited if name == names[1] else p) for name, p in inputs)

    def constant(self, socket, channels: int, owner) -> tuple:
        """A socket's own value (socket_value), saying so when part of it is not a number (read as 0, as
        Cycles drops a closure whose weight is not a number)."""
        if socket_has_nan(socket):
            self.issues.append(f"{owner.bl_label} '{owner.name}' {socket.name} is not a number, read as 0")
        return _socket_value(socket, channels)

    def param(self, socket, groups, channels: int, node) -> Param:
        """An input as a constant, or a constant times an Image Texture's Color or Alpha."""
        return run_nested(self._param(socket, groups, channels, node))

    def _param(self, socket, groups, channels: int, node):
        """Step (engine/export/graph.py) of param()."""
        source = source_of(socket, groups)
        if source.node is None or source.kind in ("ShaderNodeRGB", "ShaderNodeValue"):
            return Param.of(self.constant(source.socket, channels, source.node or node))
        if source.kind == "ShaderNodeTexImage" and _plain_image(source):
            return self.image_param(source)
        if source.kind in ("ShaderNodeSeparateColor", "ShaderNodeSeparateRGB") and \
                getattr(source.node, "mode", "RGB") == "RGB":
            # One channel of an image (glTF's packed metallic-roughness and occlusion maps) or a constant.
            channel = ("Red", "Green", "Blue", "R", "G", "B").index(source.socket.identifier) % 3
            inner = yield self._param(source.node.inputs[0], source.groups, 3, source.node)
            if inner.link is not None:
                return self.program_param(socket, groups, channels)
            if inner.texture < 0:
                return Param.of(inner.value[channel])
            return Param.of(inner.value[channel], inner.texture, unassociate=inner.unassociate, channel=channel)
        return self.program_param(socket, groups, channels)

    def program_param(self, socket, groups, channels: int) -> Param:
        """An input computed by the node program (kernels/programs.py)."""
        want = "VALUE" if channels == 1 else "VECTOR" if socket.type == "VECTOR" else "RGBA"
        value = self.program.input(socket, groups, want)
        if isinstance(value, tuple):  # folded to a constant
            return Param.of(value if len(value) == channels else _socket_value(socket, channels))
        return Param.of(_socket_value(socket, channels), link=value)

    def image_param(self, source: Source) -> Param:
        """An Image Texture's Color or Alpha output."""
        color = source.socket.identifier == "Color"
        value, texture = self.image_texture(source.node, source.groups)
        # Cycles unassociates the colour when the node's Alpha output is used.
        image = source.node.image
        unassociate = (color and source.node.outputs["Alpha"].is_linked and image is not None
                       and not image.colorspace_settings.is_data
                       and image.alpha_mode not in ("CHANNEL_PACKED", "NONE"))
        return Param.of(value if color or texture < 0 else (1.0,), texture, alpha=not color, unassociate=unassociate)

    def image_texture(self, node, groups) -> tuple[tuple, int]:
        self.check_uv(node, groups)
        if node.interpolation != "Linear" or node.projection != "FLAT" or node.extension != "REPEAT":
            self.issues.append(f"Image Texture '{node.name}': only Linear interpolation, Flat projection "
                               f"and Repeat extension are supported")
        if node.image is None:
            self.issues.append(f"Image Texture '{node.name}' has no image, rendered magenta")
            return MISSING_IMAGE_COLOR, -1
        index = self.images.index(node.image, node.image_user)
        return (WHITE3, index) if index is not None else (MISSING_IMAGE_COLOR, -1)

    def check_uv(self, node, groups) -> None:
        vector = source_of(node.inputs["Vector"], groups)
        uv = (vector.node is None
              or (vector.kind == "ShaderNodeTexCoord" and vector.socket.identifier == "UV")
              or (vector.kind == "ShaderNodeUVMap" and not vector.node.uv_map))
        if not uv:
            self.issues.append(f"Image Texture '{node.name}': coordinates from {vector.node.bl_label} are "
                               f"not supported, used the render UV map")

    def is_set(self, socket, neutral: float, groups) -> bool:
        source = source_of(socket, groups)
        return source.node is not None or float(source.socket.default_value) != neutral


def _plain_image(source: Source) -> bool:
    """An Image Texture the closure inputs read directly: render UVs, Linear, Flat, Repeat, no Texture Mapping."""
    node = source.node
    vector = source_of(node.inputs["Vector"], source.groups)
    uv = (vector.node is None
          or (vector.kind == "ShaderNodeTexCoord" and vector.socket.identifier == "UV")
          or (vector.kind == "ShaderNodeUVMap" and not vector.node.uv_map))
    return uv and node.interpolation == "Linear" and node.projection == "FLAT" and node.extension == "REPEAT" \
        and (node.image is None or node.image.source != "TILED") \
        and texture_mapping_matrix(node.texture_mapping) is None   # UDIM tiles, a moved Vector: the program's


def _channels(socket) -> int:
    return 1 if socket.type == "VALUE" else 3


def _socket_value(socket, channels: int) -> tuple:
    """A socket's value: finite floats, colours without alpha."""
    value = socket.default_value
    values = np.atleast_1d(np.nan_to_num(np.asarray(value[:3] if hasattr(value, "__len__") else value, np.float64)))
    if channels == 1:
        return (float(values[0]),) if len(values) == 1 else (float(np.dot(values[:3], (0.2126, 0.7152, 0.0722))),)
    return tuple(float(v) for v in (values if len(values) == 3 else np.repeat(values[:1], 3)))
