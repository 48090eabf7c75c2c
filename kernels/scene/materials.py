"""The material table: Materials of Shaders, each a sum of Closures (Blender's closure nodes) whose inputs are
Params (a constant, an image texture or a node program's output), NormalMaps or Tangents; and its validation."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..programs import Program, Ref
from .checks import require

# Closure nodes a material can be made of (Blender's shader nodes, read by the engine's export).
CLOSURE_KINDS = ("DIFFUSE", "PRINCIPLED", "GLOSSY", "GLASS", "REFRACTION", "METALLIC", "SHEEN", "TRANSLUCENT",
                 "TRANSPARENT", "TOON", "PORTAL", "HAIR", "EMISSION", "HOLDOUT", "SUBSURFACE", "PRINCIPLED_HAIR")
# Closure nodes a Volume output can be made of (an Emission node there emits light per unit length).
VOLUME_KINDS = ("VOLUME_SCATTER", "VOLUME_ABSORPTION", "PRINCIPLED_VOLUME", "VOLUME_COEFFICIENTS", "EMISSION")


@dataclass(frozen=True)
class Param:
    """One input of a closure node: a constant, or a constant times an image texture.

    value : tuple of 1 (float inputs) or 3 (colours and vectors) floats.
    texture : index into SceneArrays.textures, -1 for none; the value multiplies the texture.
    alpha : read the texture's alpha channel (the Image Texture's Alpha output) instead of its colour.
    unassociate : divide the texture's (associated) colour by its alpha, as Cycles does for an Image
        Texture whose Alpha output is linked.
    channel : 0, 1 or 2: one channel of the texture's colour (a Separate Color node), -1 for all.
    link : a Ref to an output of the material's node program (Shader.program): the input is that output at
        each hit, and value is only the input's own value (kept for estimates and messages).
    """
    value: tuple
    texture: int = -1
    alpha: bool = False
    unassociate: bool = False
    channel: int = -1
    link: Ref | None = None

    @classmethod
    def of(cls, value, texture: int = -1, alpha: bool = False, unassociate: bool = False,
           channel: int = -1, link: Ref | None = None) -> "Param":
        values = tuple(float(v) for v in np.atleast_1d(np.asarray(value, np.float64)))
        return cls(values, int(texture), bool(alpha), bool(unassociate), int(channel), link)

    @property
    def varies(self) -> bool:
        """Whether the input differs from hit to hit (a texture or a program output)."""
        return self.texture >= 0 or self.link is not None


# Spaces of a Normal Map node the kernel renders (Blender also has OBJECT and BLENDER_OBJECT, which need the
# instance transform: the engine's export warns and leaves the input unlinked).
NORMAL_MAP_SPACES = ("TANGENT", "WORLD", "BLENDER_WORLD")


@dataclass(frozen=True)
class NormalMap:
    """A Normal Map node feeding a closure's Normal or Coat Normal input (Cycles' `svm_node_normal_map`).

    color : Param, the node's Color (a constant, or a Non-Color image texture), each axis stored as (x + 1) / 2
        (1 float: a grey, as an image's Alpha output feeding it).
    strength : Param, the node's Strength (3 floats: a colour feeding it, read as its luminance).
    space : one of NORMAL_MAP_SPACES. TANGENT reads the mesh's tangents (SceneArrays.tangents); without
        them the normal is left unperturbed, as Cycles does without its tangent attribute. WORLD reads
        the colour as a world direction; BLENDER_WORLD negates its y and z first.
    invert_green : the node's DirectX convention (Blender 5.1+): green negated.
    object_frame : TANGENT's frame normal at unit length, as the Cycles of Blender 5.1 and later reads it
        (kernels.shading.normals).
    """
    color: Param
    strength: Param = Param((1.0,))
    space: str = "TANGENT"
    invert_green: bool = False
    object_frame: bool = False

    def params(self):
        yield self.color
        yield self.strength


@dataclass(frozen=True)
class Tangent:
    """A Tangent node (UV Map direction) feeding a closure's Tangent input: the interpolated tangent of
    SceneArrays.tangents, made orthogonal to the shading normal (Cycles' `svm_node_tangent`)."""

    def params(self):
        return iter(())


# What a closure input may hold besides a Param, and the inputs that may hold it.
INPUT_NODES = {NormalMap: ("Normal", "Coat Normal"), Tangent: ("Tangent",)}


@dataclass(frozen=True)
class Closure:
    """A closure node of a material, with its inputs and where it sits in the Mix/Add shader tree.

    kind : one of CLOSURE_KINDS.
    inputs : ((socket name, Param), ...) by Blender's input names ("Base Color", "Roughness", ...);
        inputs left out take the node's defaults (kernels.shading.node_context.DEFAULTS). "Normal" and "Coat Normal"
        may hold a NormalMap, "Tangent" a Tangent (INPUT_NODES); left out, they are the shading normal
        and an arbitrary tangent.
    options : ((name, value), ...) the node's enum settings, e.g. ("distribution", "MULTI_GGX").
    factors : ((Param, second), ...) the Mix Shader factors above the node: its weight is the product
        of fac (when it is the Mix's second input) or 1 - fac (first input), each fac clamped to [0, 1].
    """
    kind: str
    inputs: tuple = ()
    options: tuple = ()
    factors: tuple = ()

    def input(self, name: str) -> Param | NormalMap | Tangent | None:
        return next((p for n, p in self.inputs if n == name), None)

    def option(self, name: str, default=None):
        return next((v for n, v in self.options if n == name), default)

    def params(self):
        """Every Param the closure reads, those of its normal maps included."""
        for _, p in self.inputs:
            if isinstance(p, Param):
                yield p
            else:
                yield from p.params()
        yield from (p for p, _ in self.factors)

    def uses_tangents(self) -> bool:
        """Whether the closure reads SceneArrays.tangents (a tangent-space normal map or a Tangent node)."""
        return any(isinstance(p, Tangent) or (isinstance(p, NormalMap) and p.space == "TANGENT")
                   for _, p in self.inputs)


@dataclass(frozen=True)
class Shader:
    """A material: the sum of its closures, each weighted by its Mix Shader factors.

    light_sampled : whether next-event estimation samples the material's emitting triangles (False: Cycles' Emission
        Sampling None; BSDF rays alone find them, with MIS weight 1).
    emission_sides : which sides of its emitting triangles light samples go to: BOTH, or Cycles' Emission Sampling
        FRONT or BACK (the other side is left to BSDF rays, with MIS weight 1).
    bump_map_correction : Cycles' material setting of that name (on by default): specular closures tilt
        their normal toward the geometric normal until the mirror direction clears the surface.
    transparent_shadow : the material's Settings > Surface > Transparent Shadows (Material.use_transparent_shadow,
        on by default): off, shadow rays stop at its surface whatever its transparency, as Cycles' shader loses
        SD_HAS_TRANSPARENT_SHADOW (scene/shader.cpp), unless it has a volume; camera and BSDF rays still pass it.
    emission_estimate : Cycles' estimate of the material's emission (3 floats: a linked colour counting as white, a
        linked strength as 1; engine/export/emission_estimate.py), by which Cycles' light tree weighs its emitting
        triangles (kernels/light_tree_cycles.py); None where not known (each triangle's own emission is taken).
    program : the material's node program (kernels.programs), which linked Params read.
    aovs : the material's AOV Output nodes, ((name, colour Param (3), value Param (1)), ...): the Shader AOV
        passes read them at the camera rays' first hit.
    volume : the closures of the material's Volume output (kinds VOLUME_KINDS; their Params read the same
        program): the medium inside the closed meshes that wear the material (kernels.media).
    volume_only : the Surface output is empty and the Volume output is not: the surface is an invisible
        boundary (Cycles' SD_HAS_ONLY_VOLUME), not a black one.
    interpolation : the material's Volume > Interpolation (LINEAR, CLOSEST, CUBIC), for voxel grids.
    volume_step_rate : the material's Volume > Step Rate (the world's Volume > Step Size), on the steps the Biased
        option marches its medium with (kernels/media/march.py).
    set_normal : None, or a Ref into the program: the normal that becomes the hits' shading normal before the
        material is evaluated (Cycles' SetNormal, the bump its Displacement output makes under the Bump and
        "Displacement and Bump" methods).
    """
    closures: tuple = ()
    name: str = ""
    bump_map_correction: bool = True
    program: Program = Program()
    aovs: tuple = ()
    volume: tuple = ()
    volume_only: bool = False
    interpolation: str = "LINEAR"
    volume_step_rate: float = 1.0
    set_normal: object = None
    light_sampled: bool = True
    emission_sides: str = "BOTH"
    transparent_shadow: bool = True
    emission_estimate: tuple | None = None


def diffuse_shader(albedo=(0.8, 0.8, 0.8), albedo_texture: int = -1, emission=(0.0, 0.0, 0.0),
                   emission_texture: int = -1, name: str = "") -> Shader:
    """A diffuse surface of colour albedo (times a texture) that also emits `emission` (times a texture)."""
    closures = [Closure("DIFFUSE", (("Color", Param.of(albedo, albedo_texture)),))]
    if np.any(np.asarray(emission) > 0):
        closures.append(Closure("EMISSION", (("Color", Param.of(emission, emission_texture)),
                                             ("Strength", Param.of(1.0)))))
    return Shader(tuple(closures), name)


@dataclass(frozen=True)
class Materials:
    """The material table: M shaders; a triangle's material id indexes it. pass_indices: each material's
    Pass Index (the Material Index pass), or () for all 0."""
    shaders: tuple = (diffuse_shader(),)
    pass_indices: tuple = ()

    @classmethod
    def diffuse(cls, albedo, albedo_texture=None, emission=None, emission_texture=None) -> "Materials":
        """M diffuse materials from (M, 3) albedo and emission (W/(sr m^2)), each optionally textured."""
        albedo = np.atleast_2d(np.asarray(albedo, np.float32))
        m = len(albedo)
        emission = np.zeros((m, 3), np.float32) if emission is None else np.atleast_2d(emission)
        at = np.full(m, -1) if albedo_texture is None else np.asarray(albedo_texture)
        et = np.full(m, -1) if emission_texture is None else np.asarray(emission_texture)
        return cls(tuple(diffuse_shader(albedo[i], at[i], emission[i], et[i]) for i in range(m)))

    @property
    def count(self) -> int:
        return len(self.shaders)

    def validate(self, n_textures: int) -> None:
        require(len(self.shaders) >= 1, "materials", "needs at least one material")
        for i, shader in enumerate(self.shaders):
            require(isinstance(shader, Shader), f"materials[{i}]", "must be a Shader")
            require(isinstance(shader.program, Program), f"materials[{i}]", "program must be a Program")
            shader.program.validate(n_textures)
            for closure in shader.closures + shader.volume:
                where = f"materials[{i}] ({shader.name or 'unnamed'}) {closure.kind}"
                kinds = VOLUME_KINDS if closure in shader.volume else CLOSURE_KINDS
                require(closure.kind in kinds, where, f"kind must be one of {kinds}")
                for name, value in closure.inputs + tuple(("Fac", p) for p, _ in closure.factors):
                    _check_input(value, f"{where} {name}", name, n_textures)
                for p in closure.params():
                    require(p.link is None or 0 <= p.link.op < len(shader.program), where,
                            f"reads op {p.link.op if p.link else None} of a program of {len(shader.program)}")


def _check_input(value, where: str, name: str, n_textures: int) -> None:
    """A closure input: a Param, or a node of INPUT_NODES on an input that may hold it."""
    if isinstance(value, Param):
        params = (value,)
    else:
        require(type(value) in INPUT_NODES, where, f"must be a Param, got {type(value).__name__}")
        require(name in INPUT_NODES[type(value)], where, f"cannot hold a {type(value).__name__}")
        if isinstance(value, NormalMap):
            require(value.space in NORMAL_MAP_SPACES, where,
                    f"space must be one of {NORMAL_MAP_SPACES}, got {value.space!r}")
            # (A colour feeding the Strength, an Alpha feeding the Color: the kernel converts them as Blender does.)
        params = tuple(value.params())
    for p in params:
        require(len(p.value) in (1, 3) and all(np.isfinite(p.value)), where,
                f"must be 1 or 3 finite floats, got {p.value}")
        require(-1 <= p.texture < n_textures, where, f"texture must be -1 or in [0, {n_textures}), got {p.texture}")
