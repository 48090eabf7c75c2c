"""The scene as plain arrays: what the kernel renders, and the only thing the engine hands it.

Everything is in Blender world space (right-handed, Z up), linear scene-referred RGB.
Shapes use named letters: T triangles, M materials, L lights.

Texture arrays follow Blender's pixel order: row 0 is the bottom of the image (v = 0), so a lookup
at UV (u, v) reads row v * H and column u * W. Rendered images (the film) have row 0 at the top.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

import numpy as np

from .panorama import PANORAMA_PARAMS, POSITIVE_PARAMS
from .programs import Program, Ref
from .vec import matmul

CAMERA_KINDS = ("PERSP", "ORTHO", "PANO")
PIXEL_FILTERS = ("BOX", "GAUSSIAN", "BLACKMAN_HARRIS")
SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


@dataclass(frozen=True, eq=False)
class Camera:
    """A Blender camera: looks down its local -Z with +Y up.

    world_from_camera : (4, 4) float64, rigid transform (scale is removed by validate()).
    fov_rad : full angle across the sensor-fit axis (perspective). 2 * atan(sensor / (2 * lens)).
    sensor_fit : AUTO fits the larger image axis, as Blender does.
    shift_x, shift_y : lens shift in units of the fitted image axis.
    pixel_aspect : pixel width / pixel height (Blender's pixel_aspect_x / pixel_aspect_y).
    ortho_scale : width of the view along the fitted axis (orthographic).
    width, height : full frame resolution in pixels (after the resolution percentage).

    Cameras compare and hash by key(), their fields as plain values: the viewport restarts when its
    camera differs from the last one.
    """
    world_from_camera: np.ndarray = field(default_factory=lambda: np.eye(4))
    kind: str = "PERSP"
    fov_rad: float = 2.0 * np.arctan(36.0 / (2.0 * 50.0))
    sensor_fit: str = "AUTO"
    shift_x: float = 0.0
    shift_y: float = 0.0
    pixel_aspect: float = 1.0
    ortho_scale: float = 6.0
    clip_start: float = 0.1
    clip_end: float = 1000.0
    width: int = 256
    height: int = 256
    # Depth of field, Cycles' thin lens (kernels.lens): aperture_radius 0 is a pinhole. The lens point lies
    # on a disk, or on a regular polygon of aperture_blades >= 3 sides turned by aperture_rotation (radians);
    # its x is divided by aperture_ratio (anamorphic). Sharp at camera depth focus_distance.
    aperture_radius: float = 0.0
    aperture_blades: int = 0
    aperture_rotation: float = 0.0
    aperture_ratio: float = 1.0
    focus_distance: float = 10.0
    # The film's pixel filter (kernels.pixel_filter), importance-sampled: every sample weighs 1 and lands
    # in its own pixel. BOX is one pixel wide whatever filter_width says, as in Cycles.
    filter_type: str = "BOX"
    filter_width: float = 1.0
    # Panoramic cameras (kind PANO): the projection and its parameters (kernels.panorama).
    panorama_type: str = "EQUIRECTANGULAR"
    panorama: dict = field(default_factory=dict)
    # The part of the camera frame the film shows, (u0, u1, v0, v1) in frame units (0..1 from the frame's
    # left and bottom edges), or None for the whole frame: a viewport looking through a panoramic camera
    # shows the frame zoomed and panned inside its region, as Cycles' viewport does.
    panorama_window: tuple | None = None
    # Motion blur: world_from_camera at motion steps evenly spaced over the shutter, (K, 4, 4) rigid,
    # K >= 2, or None for a still camera (world_from_camera is then used at every time).
    motion: np.ndarray | None = None
    # A perspective lens zooming during the shutter: (fov_rad at the shutter's start, at its end), or None.
    fov_motion: tuple | None = None

    def key(self) -> tuple:
        """Every field as hashable plain values (arrays as nested tuples, dicts as sorted items): cameras
        with equal keys render equal images."""
        return tuple(_plain(getattr(self, f.name)) for f in dataclasses.fields(self))

    def __eq__(self, other) -> bool:
        return self.key() == other.key() if isinstance(other, Camera) else NotImplemented

    def __hash__(self) -> int:
        return hash(self.key())

    def validate(self) -> None:
        m = np.asarray(self.world_from_camera)
        _require(m.shape == (4, 4), "camera.world_from_camera", f"must be (4, 4), got {m.shape}")
        _require_finite(m, "camera.world_from_camera")
        _require(abs(np.linalg.det(m[:3, :3])) > 1e-12, "camera.world_from_camera", "is singular")
        _require(self.kind in CAMERA_KINDS, "camera.kind", f"must be one of {CAMERA_KINDS}, got {self.kind!r}")
        _require(self.sensor_fit in SENSOR_FITS, "camera.sensor_fit",
                 f"must be one of {SENSOR_FITS}, got {self.sensor_fit!r}")
        for name in ("fov_rad", "shift_x", "shift_y", "pixel_aspect", "ortho_scale", "clip_start", "clip_end"):
            _require(np.isfinite(getattr(self, name)), f"camera.{name}", "must be finite")
        _require(0.0 < self.fov_rad < np.pi, "camera.fov_rad", f"must be in (0, pi), got {self.fov_rad}")
        _require(self.pixel_aspect > 0, "camera.pixel_aspect", "must be positive")
        _require(self.ortho_scale > 0, "camera.ortho_scale", "must be positive")
        _require(0.0 <= self.clip_start < self.clip_end, "camera.clip_start",
                 f"must satisfy 0 <= clip_start < clip_end, got {self.clip_start}, {self.clip_end}")
        _require(int(self.width) >= 1 and int(self.height) >= 1, "camera.width",
                 f"resolution must be at least 1x1, got {self.width}x{self.height}")
        for name in ("aperture_radius", "aperture_rotation", "aperture_ratio", "focus_distance", "filter_width"):
            _require(np.isfinite(getattr(self, name)), f"camera.{name}", "must be finite")
        _require(self.aperture_radius >= 0, "camera.aperture_radius", "must be non-negative")
        _require(self.aperture_ratio > 0, "camera.aperture_ratio", "must be positive")
        _require(self.focus_distance > 0, "camera.focus_distance", "must be positive")
        _require(self.filter_type in PIXEL_FILTERS, "camera.filter_type",
                 f"must be one of {PIXEL_FILTERS}, got {self.filter_type!r}")
        _require(self.filter_width > 0, "camera.filter_width", "must be positive")
        _require(self.panorama_type in PANORAMA_PARAMS, "camera.panorama_type",
                 f"must be one of {tuple(PANORAMA_PARAMS)}, got {self.panorama_type!r}")
        if self.kind == "PANO":
            needed, given = PANORAMA_PARAMS[self.panorama_type], set(self.panorama)
            _require(given == set(needed), "camera.panorama",
                     f"{self.panorama_type} takes exactly {needed}, got {tuple(sorted(given))}")
            for name in needed:
                value = self.panorama[name]
                _require(isinstance(value, (int, float, np.integer, np.floating)) and np.isfinite(value), f"camera.panorama[{name!r}]",
                         f"must be a finite number, got {value!r}")
                _require(name not in POSITIVE_PARAMS or value > 0, f"camera.panorama[{name!r}]",
                         f"must be positive, got {value}")
        if self.motion is not None:
            motion = np.asarray(self.motion)
            _require(motion.ndim == 3 and motion.shape[0] >= 2 and motion.shape[1:] == (4, 4), "camera.motion",
                     f"must be (K >= 2, 4, 4), got {motion.shape}")
            _require_finite(motion, "camera.motion")


def _plain(value):
    """A value as hashable plain Python: arrays and sequences as tuples, dicts as sorted (key, value) tuples."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return tuple(_plain(v) for v in value)
    if isinstance(value, dict):
        return tuple(sorted((k, _plain(v)) for k, v in value.items()))
    return value


# Closure nodes a material can be made of (Blender's shader nodes, read by the engine's export).
CLOSURE_KINDS = ("DIFFUSE", "PRINCIPLED", "GLOSSY", "GLASS", "REFRACTION", "METALLIC", "SHEEN", "TRANSLUCENT",
                 "TRANSPARENT", "TOON", "PORTAL", "HAIR", "EMISSION", "HOLDOUT")


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

    color : Param of 3 floats, the node's Color (a constant, or a Non-Color image texture), each axis
        stored as (x + 1) / 2.
    strength : Param of 1 float, the node's Strength.
    space : one of NORMAL_MAP_SPACES. TANGENT reads the mesh's tangents (SceneArrays.tangents); without
        them the normal is left unperturbed, as Cycles does without its tangent attribute. WORLD reads
        the colour as a world direction; BLENDER_WORLD negates its y and z first.
    invert_green : the node's DirectX convention (Blender 5.1+): green negated.
    """
    color: Param
    strength: Param = Param((1.0,))
    space: str = "TANGENT"
    invert_green: bool = False

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
        inputs left out take the node's defaults (kernels.shading.nodes). "Normal" and "Coat Normal"
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

    bump_map_correction : Cycles' material setting of that name (on by default): specular closures tilt
        their normal toward the geometric normal until the mirror direction clears the surface.
    program : the material's node program (kernels.programs), which linked Params read.
    aovs : the material's AOV Output nodes, ((name, colour Param (3), value Param (1)), ...): the Shader AOV
        passes read them at the camera rays' first hit.
    """
    closures: tuple = ()
    name: str = ""
    bump_map_correction: bool = True
    program: Program = Program()
    aovs: tuple = ()


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
        _require(len(self.shaders) >= 1, "materials", "needs at least one material")
        for i, shader in enumerate(self.shaders):
            _require(isinstance(shader, Shader), f"materials[{i}]", "must be a Shader")
            _require(isinstance(shader.program, Program), f"materials[{i}]", "program must be a Program")
            shader.program.validate(n_textures)
            for closure in shader.closures:
                where = f"materials[{i}] ({shader.name or 'unnamed'}) {closure.kind}"
                _require(closure.kind in CLOSURE_KINDS, where, f"kind must be one of {CLOSURE_KINDS}")
                for name, value in closure.inputs + tuple(("Fac", p) for p, _ in closure.factors):
                    _check_input(value, f"{where} {name}", name, n_textures)
                if closure.kind == "EMISSION" or closure.kind == "PRINCIPLED":
                    for name in ("Color", "Strength", "Emission Color", "Emission Strength"):
                        p = closure.input(name)
                        _require(p is None or p.link is not None or min(p.value) >= 0, f"{where} {name}",
                                 "must be non-negative")
                for p in closure.params():
                    _require(p.link is None or 0 <= p.link.op < len(shader.program), where,
                             f"reads op {p.link.op if p.link else None} of a program of {len(shader.program)}")


def _check_input(value, where: str, name: str, n_textures: int) -> None:
    """A closure input: a Param, or a node of INPUT_NODES on an input that may hold it."""
    if isinstance(value, Param):
        params = (value,)
    else:
        _require(type(value) in INPUT_NODES, where, f"must be a Param, got {type(value).__name__}")
        _require(name in INPUT_NODES[type(value)], where, f"cannot hold a {type(value).__name__}")
        if isinstance(value, NormalMap):
            _require(value.space in NORMAL_MAP_SPACES, where,
                     f"space must be one of {NORMAL_MAP_SPACES}, got {value.space!r}")
            _require(len(value.color.value) == 3 and len(value.strength.value) == 1, where,
                     "a normal map needs a colour of 3 floats and a strength of 1")
        params = tuple(value.params())
    for p in params:
        _require(len(p.value) in (1, 3) and all(np.isfinite(p.value)), where,
                 f"must be 1 or 3 finite floats, got {p.value}")
        _require(-1 <= p.texture < n_textures, where, f"texture must be -1 or in [0, {n_textures}), got {p.texture}")


@dataclass(frozen=True)
class World:
    """What a ray that leaves the scene sees.

    color : (3,) float32 radiance, used when hdri is None.
    hdri : (H, W, 3) float32 equirectangular map, row 0 at the bottom (Blender's order), or None.
    strength : multiplies color or hdri.
    env_from_world : (3, 3) float32 rotation taking a world direction to the direction the map is
        looked up with: the Mapping node's rotation R for a POINT mapping, R^T for TEXTURE.
    program, output : a node program (kernels.programs) and the Ref of its radiance, for any other world
        tree (a gradient, a sky, a Mix of backgrounds): evaluated per escaped ray, color, hdri and
        strength unused. It reads SceneArrays.textures.
    map_resolution : width of the equirectangular map the program is baked into for importance sampling
        (Cycles' world Map Resolution; the height is half of it).
    mis_compensation : sample the world as a light only where it is brighter than its mean, with the balance
        heuristic against BSDF rays (environment.Environment); False: in proportion to its radiance with the
        power heuristic, as Cycles does (same image, more noise).
    focus : at glossy shading points, draw part of the world's light samples from the map around the
        main glossy lobe's direction (environment.Environment.focus); False: from the whole map, as Cycles
        does (same image, more noise). Neither applies to a world program with a Light Path node.
    """
    color: np.ndarray = field(default_factory=lambda: np.full(3, 0.05, np.float32))
    hdri: np.ndarray | None = None
    strength: float = 1.0
    env_from_world: np.ndarray = field(default_factory=lambda: np.eye(3, dtype=np.float32))
    program: Program | None = None
    output: Ref | None = None
    map_resolution: int = 1024
    mis_compensation: bool = True
    focus: bool = True

    def validate(self) -> None:
        _check_array(self.color, "world.color", (3,), np.float32)
        _require(np.all(self.color >= 0), "world.color", "must be non-negative")
        _require(np.isfinite(self.strength) and self.strength >= 0, "world.strength",
                 f"must be finite and non-negative, got {self.strength}")
        _check_array(self.env_from_world, "world.env_from_world", (3, 3), np.float32)
        if self.hdri is not None:
            h = self.hdri
            _require(h.ndim == 3 and h.shape[2] == 3 and h.shape[0] >= 1 and h.shape[1] >= 1,
                     "world.hdri", f"must be (H, W, 3), got {h.shape}")
            _check_array(h, "world.hdri", h.shape, np.float32)
            _require(np.all(h >= 0), "world.hdri", "must be non-negative")
        _require((self.program is None) == (self.output is None), "world.program", "comes with its output")
        if self.program is not None:
            _require(isinstance(self.output, Ref) and 0 <= self.output.op < len(self.program), "world.output",
                     f"must be a Ref into the world's program of {len(self.program)} ops")
            _require(int(self.map_resolution) >= 4, "world.map_resolution", "must be at least 4")


LIGHT_KINDS = {"POINT": 0, "SPOT": 1, "SUN": 2, "RECT": 3, "DISK": 4}


@dataclass(frozen=True)
class Lights:
    """Blender lights, L rows, converted to radiometric terms by the engine's export.

    kind : (L,) int32, a value of LIGHT_KINDS.
    position : (L, 3) float32, centre (unused for SUN).
    frame : (L, 3, 3) float32, world_from_light rotation: columns are the light's x, y and z axes.
        Blender lights shine down their local -Z.
    radiance : (L, 3) float32. POINT/SPOT/RECT/DISK with size: emitted radiance W/(sr m^2);
        zero-size POINT/SPOT: intensity W/sr; SUN: irradiance W/m^2 on a surface facing it.
    radius : (L,) float32, radius of POINT/SPOT, 0 for a delta light. As in Cycles, a sized point
        light lights each point as a disk of this radius facing that point.
    size : (L, 2) float32, full extents along the light's x and y (RECT, DISK/ellipse).
    spot_cos : (L, 2) float32, cosine of the spot's half angle and of the start of its blend.
    sun_half_angle : (L,) float32, half the sun's angular diameter, radians.
    cast_shadow : (L,) bool or None (every light casts shadows): False for a light whose light no surface
        blocks (Blender's Cast Shadow off; Cycles then traces no shadow ray for it).
    """
    kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    position: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    frame: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3), np.float32))
    radiance: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    radius: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    size: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    spot_cos: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    sun_half_angle: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    cast_shadow: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.kind)

    def shadowed(self) -> np.ndarray:
        """(L,) bool: the lights whose light surfaces block."""
        return np.ones(self.count, bool) if self.cast_shadow is None else self.cast_shadow

    def validate(self) -> None:
        n = len(self.kind)
        _check_array(self.kind, "lights.kind", (n,), np.int32)
        _require(np.all(np.isin(self.kind, list(LIGHT_KINDS.values()))), "lights.kind",
                 f"must be values of {LIGHT_KINDS}")
        shapes = {"position": (n, 3), "frame": (n, 3, 3), "radiance": (n, 3), "radius": (n,),
                  "size": (n, 2), "spot_cos": (n, 2), "sun_half_angle": (n,)}
        for name, shape in shapes.items():
            _check_array(getattr(self, name), f"lights.{name}", shape, np.float32)
        for name in ("radiance", "radius", "size", "sun_half_angle"):
            _require(np.all(getattr(self, name) >= 0), f"lights.{name}", "must be non-negative")
        if self.cast_shadow is not None:
            _check_array(self.cast_shadow, "lights.cast_shadow", (n,), np.bool_, finite=False)


@dataclass(frozen=True, eq=False)
class CornerRows:
    """Per-corner values kept once per row and gathered by index: the (T, 3, C) values are rows[index].

    rows : (N, C) float32; index : (T, 3) uint32, each below N. SceneArrays.positions and normals may hold
    one instead of their (T, 3, 3) arrays: the export's world vertices with the triangles' vertex numbers
    (the very arrays Embree builds its BVH from), and each mesh's world normals once per vertex (a mesh
    smooth all over) or face corner: a third or less of the memory, gathered only where they are read (the
    triangle table's rows, validation in blocks, emissive triangles). It reads like the array it stands
    for: len, shape, dtype, triangles by slice, numbers or mask, and np.asarray (which builds the whole
    array)."""
    rows: np.ndarray
    index: np.ndarray

    @property
    def shape(self) -> tuple:
        return (len(self.index), 3, self.rows.shape[1] if self.rows.ndim == 2 else 0)

    @property
    def dtype(self):
        return self.rows.dtype

    ndim = 3

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, key) -> np.ndarray:
        if isinstance(key, slice) or (isinstance(key, np.ndarray) and key.ndim == 1):
            return np.take(self.rows, self.index[key], axis=0)    # triangles: a slice, numbers or a mask
        return self.dense()[key]

    def bounds(self):
        """(lo, hi) float32 (3,) of the values the corners read (rows no corner reads left out)."""
        used = np.zeros(len(self.rows), bool)
        used[self.index.ravel()] = True
        values = self.rows if used.all() else self.rows[used]
        # Column by column: a strided min per column is ~10x faster than min(axis=0) over (N, 3) rows.
        columns = range(values.shape[1])
        return (np.array([values[:, k].min() for k in columns], values.dtype),
                np.array([values[:, k].max() for k in columns], values.dtype))

    def dense(self) -> np.ndarray:
        return np.take(self.rows, self.index, axis=0)

    def __array__(self, dtype=None, copy=None):
        values = self.dense()
        return values if dtype is None else values.astype(dtype)

    def astype(self, dtype) -> np.ndarray:
        return self.dense().astype(dtype)

    def finite_triangles(self) -> np.ndarray:
        """(T,) bool: every value of the triangle's three corners is finite."""
        ok = _finite_rows(self.rows)
        if ok.all():
            return np.ones(len(self.index), bool)
        bad = np.take(~ok, self.index, axis=0)
        return ~(bad[:, 0] | bad[:, 1] | bad[:, 2])


def corner_values(values, triangles: np.ndarray | None = None) -> np.ndarray:
    """A (T, 3, C) array or CornerRows as an array: all of it, or the triangles numbered `triangles`."""
    if isinstance(values, CornerRows):
        return values.dense() if triangles is None else values[np.asarray(triangles)]
    return values if triangles is None else np.take(values, triangles, axis=0)


@dataclass(frozen=True)
class Prototype:
    """One mesh placed by several instances (SceneArrays.instances), in its object space: each field means
    what the SceneArrays field of the same name means, for the prototype's own t triangles."""
    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    material_ids: np.ndarray
    tangents: np.ndarray | None = None
    attributes: tuple = ()

    @property
    def triangle_count(self) -> int:
        return len(self.positions)


@dataclass(frozen=True)
class Instances:
    """Meshes stored once and placed many times, traced through a two-level BVH as Cycles and Embree do:
    memory grows with the unique meshes, not with the number of instances.

    prototypes : tuple of Prototype.
    prototype : (K,) int32, each instance's prototype.
    world_from_object : (K, 4, 4) float64.
    object_ids : (K,) int32, each instance's row of SceneArrays.objects (None when the scene has none).

    Scene triangle numbers (what ray hits report) go on after the T plain triangles: triangle j of
    instance k is number bases(T)[k] + j.
    """
    prototypes: tuple
    prototype: np.ndarray
    world_from_object: np.ndarray
    object_ids: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.prototype)

    def triangle_counts(self) -> np.ndarray:
        """(K,) int64 triangles of each instance."""
        sizes = np.array([p.triangle_count for p in self.prototypes], np.int64)
        return sizes[self.prototype] if len(sizes) else np.zeros(0, np.int64)

    def bases(self, plain_count: int) -> np.ndarray:
        """(K,) int64 scene number of each instance's first triangle."""
        counts = self.triangle_counts()
        return plain_count + np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if len(counts) \
            else np.zeros(0, np.int64)

    @property
    def triangle_total(self) -> int:
        """Triangles of all instances together (what a flattened copy would hold)."""
        return int(self.triangle_counts().sum())

    def validate(self, materials: int, objects: int | None) -> None:
        k = len(self.prototype)
        _check_array(self.prototype, "instances.prototype", (k,), np.int32)
        _check_array(self.world_from_object, "instances.world_from_object", (k, 4, 4), np.float64, finite=False)
        if k:
            _require(self.prototype.min() >= 0 and self.prototype.max() < len(self.prototypes),
                     "instances.prototype", f"must be in [0, {len(self.prototypes)})")
        _require((objects is None) == (self.object_ids is None), "instances.object_ids",
                 "given exactly when the scene has objects")
        if self.object_ids is not None:
            _check_array(self.object_ids, "instances.object_ids", (k,), np.int32)
            if k:
                _require(self.object_ids.min() >= 0 and self.object_ids.max() < objects, "instances.object_ids",
                         f"must be in [0, {objects})")
        for i, proto in enumerate(self.prototypes):
            _check_triangles(proto, f"instances.prototypes[{i}].", materials)


@dataclass(frozen=True)
class SceneArrays:
    """A whole scene as arrays. Build it, call validate(), hand it to kernels.render().

    positions : (T, 3, 3) float32, world-space corners of each triangle, or a CornerRows standing for them.
        A triangle's front (its geometric normal) is the side cross(p1 - p0, p2 - p0) points to, except on
        the triangles of a mirroring object row (mirrored_objects), which keep their mesh's winding and
        whose front is the other side, as in Blender; an instance with a mirroring transform likewise.
    normals : (T, 3, 3) float32, per-corner shading normals (need not be unit length), or a CornerRows
        standing for that array.
    uvs : (T, 3, 2) float32, per-corner texture coordinates.
    material_ids : (T,) int32, rows of `materials`.
    textures : tuple of (H, W, C) arrays, C in {1, 3, 4}, row 0 at the bottom: float32, or uint8 for 8-bit
        images (k stands for k / 255; a 4-channel one holds straight colour, which the kernel associates
        with alpha texel by texel: kernels.textures.Texture).
    texture_srgb : tuple of bool, one per texture (or empty: all linear). True marks a texture stored
        sRGB-encoded and decoded after filtering, as Cycles does with 8-bit sRGB images.
    tangents : (T, 3, 4) float32 or None: per-corner world-space MikkTSpace tangent (xyz) of the render
        UV map and its bitangent sign (w, +-1: B = sign * N x T); None when no material reads tangents
        (tangent-space normal maps, Tangent nodes). Zero rows mean "no tangent" (Cycles then leaves the
        normal unperturbed).
    attributes : ((name, (T, 3, C) float32), ...) per-corner attributes the node programs read, C in 1..4:
        "uv:<map>" (C = 2), "color:<name>" (vertex colours, C = 4), "attr:<name>" (generic attributes).
    objects : (K, OBJECT_COLUMNS) float32 or None: one row per object instance (OBJ_* columns), for
        the Texture Coordinate (Generated, Object, Normal) and Object Info nodes.
    object_ids : (T,) int32 or None: each triangle's row of `objects` (both or neither are given).
    motion : ((K, 4, 4) float64, ...) world_from_object at K >= 2 motion steps evenly spread over the
        shutter (time 0 to 1), one entry per moving object; motion_reference, one (4, 4) per entry: the
        matrix the triangles' world-space positions were made with. motion_ids : (T,) int32 or None:
        each triangle's entry of `motion`, -1 for static triangles.
    shutter_table : (256,) float32 or None: path time from a uniform number (kernels.motion.shutter_table);
        rolling_shutter : None, or the rolling shutter's duration (Cycles' TOP rolling shutter).
    vector_motion : the Vector pass's neighbours in time, or None: ((K, 3, 4) per object row taking stored
        positions to the previous frame's, (K, 3, 4) to the next frame's, (4, 4) world_from_camera of the
        previous frame, (4, 4) of the next).
    crypto_ids : Cryptomatte ids (kernels.cryptomatte.hash_name of the names), or None: {"object": (K,) and
        "asset": (K,) float32 per row of `objects`, "material": (M,) float32 per material}.
    instances : Instances or None: meshes stored once in object space and placed by transforms, besides
        the T plain triangles above. They never move during the shutter (moving objects are plain).
    bvh_vertices, bvh_indices : (V, 3) float32 and (T, 3) uint32, or None: the plain triangles again as an
        indexed mesh, vertices[indices] equal to positions corner for corner (the export has them at hand);
        Embree builds its BVH from them about 1.5x faster than from the corners. Optional.
    """
    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    material_ids: np.ndarray
    materials: Materials = field(default_factory=Materials)
    textures: tuple = ()
    texture_srgb: tuple = ()
    world: World = field(default_factory=World)
    camera: Camera = field(default_factory=Camera)
    lights: Lights = field(default_factory=Lights)
    tangents: np.ndarray | None = None
    attributes: tuple = ()
    objects: np.ndarray | None = None
    object_ids: np.ndarray | None = None
    motion: tuple = ()
    motion_reference: tuple = ()
    motion_ids: np.ndarray | None = None
    shutter_table: np.ndarray | None = None
    rolling_shutter: float | None = None
    crypto_ids: dict | None = None
    vector_motion: tuple | None = None
    instances: Instances | None = None
    bvh_vertices: np.ndarray | None = None
    bvh_indices: np.ndarray | None = None

    @property
    def has_motion(self) -> bool:
        """Anything moves during the shutter: paths then carry a time."""
        return self.shutter_table is not None and (self.camera.motion is not None or len(self.motion) > 0
                                                   or self.camera.fov_motion is not None)

    @property
    def triangle_count(self) -> int:
        """Plain triangles (instanced ones not counted: see instanced_triangle_count)."""
        return len(self.positions)

    @property
    def instanced_triangle_count(self) -> int:
        return 0 if self.instances is None else self.instances.triangle_total

    def mirrored_triangles(self) -> np.ndarray | None:
        """(T,) bool: the plain triangles whose object mirrors them (mirrored_objects), whose front is the
        side opposite the winding's; None when none is (or the scene has no object table)."""
        if self.objects is None or self.object_ids is None or not len(self.objects):
            return None
        mirrored = mirrored_objects(self.objects)
        return np.take(mirrored, self.object_ids) if mirrored.any() else None

    def validate(self, clean: "SceneArrays | None" = None) -> "ValidatedScene":
        """Check every field; drop degenerate or non-finite triangles.

        Raises ValueError naming the field for wrong shapes, dtypes, indices or non-finite data
        in anything but triangle corners. Returns the cleaned scene and the number of dropped triangles.
        clean : a scene validate() returned before (the last frame's): triangles equal to its own, plain or
        of a prototype, are known clean and not looked at again.
        """
        t = len(self.positions) if hasattr(self.positions, "__len__") else -1
        _check_triangles(self, "", None)
        self.validate_objects()
        _require(len(self.motion) == len(self.motion_reference), "motion_reference", "needs one matrix per motion")
        for i, keys in enumerate(self.motion):
            keys = np.asarray(keys)
            _require(keys.ndim == 3 and keys.shape[0] >= 2 and keys.shape[1:] == (4, 4), f"motion[{i}]",
                     f"must be (K >= 2, 4, 4), got {keys.shape}")
            _require_finite(keys, f"motion[{i}]")
        if self.motion_ids is not None:
            _check_array(self.motion_ids, "motion_ids", (t,), np.int32)
            if t:
                _require(self.motion_ids.min() >= -1 and self.motion_ids.max() < len(self.motion), "motion_ids",
                         f"must be in [-1, {len(self.motion)})")
        if self.shutter_table is not None:
            _check_array(self.shutter_table, "shutter_table", (len(self.shutter_table),), np.float32)
        self.validate_shading()
        if self.instances is not None:
            self.instances.validate(self.materials.count, None if self.objects is None else len(self.objects))
        self.camera.validate()
        self.lights.validate()

        _require((self.bvh_vertices is None) == (self.bvh_indices is None), "bvh_vertices",
                 "bvh_vertices and bvh_indices come together")
        if self.bvh_vertices is not None:
            _check_array(self.bvh_vertices, "bvh_vertices", (len(self.bvh_vertices), 3), np.float32, finite=False)
            _check_array(self.bvh_indices, "bvh_indices", (t, 3), np.uint32)
            if t:
                _require(int(self.bvh_indices.max()) < len(self.bvh_vertices), "bvh_indices",
                         f"must be below {len(self.bvh_vertices)}")
        if clean is not None and same_triangles(self, clean) and same_arrays(self.bvh_indices, clean.bvh_indices):
            changes, dropped, repaired, nonfinite = {}, 0, 0, 0
        else:
            changes, dropped, repaired, nonfinite = _clean_triangles(self, ("object_ids", "motion_ids", "bvh_indices"))
        if self.instances is not None:
            changes["instances"], more_dropped, more_repaired, more_nonfinite = _clean_instances(
                self.instances, clean.instances if clean is not None else None)
            dropped += more_dropped
            nonfinite += more_nonfinite
            repaired += more_repaired
        scene = dataclasses.replace(self, **changes) if changes else self
        return ValidatedScene(scene, dropped, repaired, nonfinite)

    def validate_objects(self) -> None:
        """Check the object table and each triangle's row of it (part of validate(); on its own when the
        viewport moves objects: Renderer.update_instances)."""
        t = len(self.positions) if hasattr(self.positions, "__len__") else -1
        _require((self.objects is None) == (self.object_ids is None), "objects",
                 "objects and object_ids come together")
        if self.objects is not None:
            k = len(self.objects)
            _check_array(self.objects, "objects", (k, OBJECT_COLUMNS), np.float32)
            _check_array(self.object_ids, "object_ids", (t,), np.int32)
            if t:
                _require(self.object_ids.min() >= 0 and self.object_ids.max() < k, "object_ids",
                         f"must be in [0, {k})")

    def validate_shading(self) -> None:
        """Check textures, materials and the world against each other and the triangles' material ids (part
        of validate(); on its own when the viewport edits materials: Renderer.update_materials)."""
        for i, tex in enumerate(self.textures):
            _require(isinstance(tex, np.ndarray) and tex.ndim == 3 and tex.shape[2] in (1, 3, 4)
                     and tex.shape[0] >= 1 and tex.shape[1] >= 1,
                     f"textures[{i}]", f"must be an (H, W, C) array with C in 1, 3, 4, got "
                     f"{getattr(tex, 'shape', type(tex).__name__)}")
            _check_array(tex, f"textures[{i}]", tex.shape, np.uint8 if tex.dtype == np.uint8 else np.float32,
                         finite=tex.dtype != np.uint8)
        _require(len(self.texture_srgb) in (0, len(self.textures)), "texture_srgb",
                 f"needs one flag per texture ({len(self.textures)}), got {len(self.texture_srgb)}")
        self.materials.validate(len(self.textures))
        if self.world.program is not None:
            self.world.program.validate(len(self.textures))
        _check_material_ids(self, "", self.materials.count)
        if self.instances is not None:
            for i, proto in enumerate(self.instances.prototypes):
                _check_material_ids(proto, f"instances.prototypes[{i}].", self.materials.count)
        self.world.validate()


# Columns of SceneArrays.objects: object_from_world (3 x 4, row-major), world_from_object's linear part
# (3 x 3, row-major), the location, the mesh's texture space (location, size), the object's colour
# (RGBA), its pass index, Cycles' random number (random_id / 0xFFFFFFFF) and its Shadow Terminator
# Geometry Offset (the light-facing share of shading points whose shadow rays leave from a smoothed surface).
OBJ_FROM_WORLD, OBJ_WORLD_LINEAR, OBJ_LOCATION, OBJ_TEXSPACE_LOC, OBJ_TEXSPACE_SIZE = 0, 12, 21, 24, 27
OBJ_COLOR, OBJ_PASS_INDEX, OBJ_RANDOM, OBJ_TERMINATOR = 30, 34, 35, 36
OBJECT_COLUMNS = 37
# Cycles' default Shadow Terminator > Geometry Offset (Object > Shading).
TERMINATOR_OFFSET = 0.1


def object_row(world_from_object, texspace_location=(0.0, 0.0, 0.0), texspace_size=(1.0, 1.0, 1.0),
               color=(1.0, 1.0, 1.0, 1.0), pass_index: int = 0, random: float = 0.0,
               terminator: float = TERMINATOR_OFFSET) -> np.ndarray:
    """One row of SceneArrays.objects (OBJECT_COLUMNS,) float32 from a (4, 4) world_from_object."""
    return object_rows(np.asarray(world_from_object, np.float64)[None], [texspace_location], [texspace_size],
                       [color], [pass_index], [random], [terminator])[0]


def object_rows(world_from_object, texspace_location, texspace_size, color, pass_index, random,
                terminator=TERMINATOR_OFFSET) -> np.ndarray:
    """(K, OBJECT_COLUMNS) float32 rows of SceneArrays.objects: world_from_object (K, 4, 4), texture spaces
    (K, 3) and (K, 3), colours (K, 4), pass indices (K,), random numbers (K,) and Shadow Terminator
    Geometry Offsets (K,) or one for all. A singular matrix gets its pseudo-inverse."""
    m = np.asarray(world_from_object, np.float64).reshape(-1, 4, 4)
    k = len(m)
    rows = np.zeros((k, OBJECT_COLUMNS), np.float64)
    try:
        inv = np.linalg.inv(m)
    except np.linalg.LinAlgError:
        inv = np.empty_like(m)
        for i in range(k):
            try:
                inv[i] = np.linalg.inv(m[i])
            except np.linalg.LinAlgError:
                inv[i] = np.linalg.pinv(m[i])
    rows[:, OBJ_FROM_WORLD:OBJ_FROM_WORLD + 12] = inv[:, :3, :4].reshape(k, 12)
    rows[:, OBJ_WORLD_LINEAR:OBJ_WORLD_LINEAR + 9] = m[:, :3, :3].reshape(k, 9)
    rows[:, OBJ_LOCATION:OBJ_LOCATION + 3] = m[:, :3, 3]
    rows[:, OBJ_TEXSPACE_LOC:OBJ_TEXSPACE_LOC + 3] = texspace_location
    rows[:, OBJ_TEXSPACE_SIZE:OBJ_TEXSPACE_SIZE + 3] = texspace_size
    rows[:, OBJ_COLOR:OBJ_COLOR + 4] = color
    rows[:, OBJ_PASS_INDEX] = pass_index
    rows[:, OBJ_RANDOM] = random
    rows[:, OBJ_TERMINATOR] = terminator
    return np.nan_to_num(rows).astype(np.float32)


def mirrored_objects(objects: np.ndarray) -> np.ndarray:
    """(K,) bool: the rows of SceneArrays.objects whose world_from_object mirrors (a negative determinant:
    an odd number of negative scale axes). Their triangles keep the winding of the object's own mesh, so
    their front, Blender's face normal, is the other side from the winding's (Cycles flips Ng for
    SD_OBJECT_NEGATIVE_SCALE in triangle_normal)."""
    linear = objects[:, OBJ_WORLD_LINEAR:OBJ_WORLD_LINEAR + 9].reshape(-1, 3, 3).astype(np.float64)
    return np.linalg.det(linear) < 0 if len(linear) else np.zeros(0, bool)


@dataclass(frozen=True)
class ValidatedScene:
    """A SceneArrays that passed validate(), with what cleaning it took."""
    scene: SceneArrays
    dropped_triangles: int
    repaired_normals: int
    nonfinite_triangles: int = 0    # of the dropped: corners not finite (NaN, or beyond float32)


def padded_triangles(count: int) -> np.ndarray:
    """An uninitialised (count, 3, 3) float32 positions array followed by one spare vertex in its
    buffer, which lets Embree read the corners in place (kernels.embree.padded_vertices)."""
    return np.empty(count * 9 + 3, np.float32)[:count * 9].reshape(count, 3, 3)


def same_arrays(a, b) -> bool:
    """Equal arrays (None only equals None), at once when they are the same memory seen the same way;
    CornerRows equal CornerRows of the same rows and index."""
    if a is None or b is None:
        return a is b
    if isinstance(a, CornerRows) or isinstance(b, CornerRows):
        return (isinstance(a, CornerRows) and isinstance(b, CornerRows) and same_arrays(a.rows, b.rows)
                and same_arrays(a.index, b.index))
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.__array_interface__["data"][0] == b.__array_interface__["data"][0] and a.strides == b.strides:
        return True
    return np.array_equal(a, b)


def same_triangles(a, b) -> bool:
    """Whether two SceneArrays (or Prototypes) hold the same triangles, array for array."""
    for name in ("positions", "normals", "uvs", "material_ids", "tangents", "object_ids", "motion_ids"):
        if hasattr(a, name) and not same_arrays(getattr(a, name), getattr(b, name)):
            return False
    return len(a.attributes) == len(b.attributes) and all(
        na == nb and same_arrays(va, vb) for (na, va), (nb, vb) in zip(a.attributes, b.attributes))


def _check_triangles(tris, prefix: str, materials: int | None) -> None:
    """Shapes and dtypes of a SceneArrays' or Prototype's per-triangle fields (and, given the material
    count, their material ids)."""
    t = len(tris.positions) if hasattr(tris.positions, "__len__") else -1
    for name in ("positions", "normals"):
        values = getattr(tris, name)
        if isinstance(values, CornerRows):
            rows, index = values.rows, values.index
            _check_array(rows, f"{prefix}{name}.rows", (-1, 3), np.float32, finite=False)
            _check_array(index, f"{prefix}{name}.index", (t, 3), np.uint32)
            _require(not index.size or int(index.max()) < len(rows), f"{prefix}{name}.index",
                     f"must be below {len(rows)}")
        else:
            _check_array(values, prefix + name, (t, 3, 3), np.float32, finite=False)
    _check_array(tris.uvs, prefix + "uvs", (t, 3, 2), np.float32, finite=False)
    _check_array(tris.material_ids, prefix + "material_ids", (t,), np.int32)
    if tris.tangents is not None:
        _check_array(tris.tangents, prefix + "tangents", (t, 3, 4), np.float32, finite=False)
    for name, values in tris.attributes:
        _require(isinstance(name, str), prefix + "attributes", "names must be strings")
        c = values.shape[2] if getattr(values, "ndim", 0) == 3 else 0
        _require(1 <= c <= 4, f"{prefix}attributes[{name!r}]", "must be (T, 3, C) with C in 1..4")
        _check_array(values, f"{prefix}attributes[{name!r}]", (t, 3, c), np.float32)
    if materials is not None:
        _check_material_ids(tris, prefix, materials)


def _check_material_ids(tris, prefix: str, m: int) -> None:
    if len(tris.material_ids):
        _require(tris.material_ids.min() >= 0 and tris.material_ids.max() < m, prefix + "material_ids",
                 f"must be in [0, {m}), got {tris.material_ids.min()}..{tris.material_ids.max()}")


def _clean_triangles(tris, extra: tuple = ()) -> tuple[dict, int, int, int]:
    """Degenerate or non-finite triangles of a SceneArrays or Prototype dropped (with the per-triangle
    fields named in extra), non-finite normals, UVs and tangents of the others repaired: (the changed
    fields, for dataclasses.replace; dropped count; repaired normals count; how many of the dropped have
    corners that are not finite)."""
    t = len(tris.positions)
    keep = _usable_triangles(tris.positions)
    # A non-finite normal or UV on a usable triangle falls back to the geometric normal / zero UV.
    normals = tris.normals
    uvs = tris.uvs
    bad_n = ~(normals.finite_triangles() if isinstance(normals, CornerRows) else _finite_rows(normals))
    bad_uv = ~_finite_rows(uvs)
    # A non-finite tangent on a usable triangle becomes "no tangent".
    tangents = tris.tangents
    bad_t = ~_finite_rows(tangents) if tangents is not None else np.zeros(t, bool)
    dropped = int(t - np.count_nonzero(keep))
    repaired = int(np.count_nonzero(bad_n & keep))
    if not (dropped or bad_n.any() or bad_uv.any() or bad_t.any()):
        return {}, 0, 0, 0
    nonfinite = int(np.count_nonzero(~np.isfinite(np.asarray(tris.positions[~keep])).all(axis=(1, 2)))) \
        if dropped else 0
    normals = np.array(normals)   # a copy (CornerRows: the whole array, which the repairs write into)
    uvs = uvs.copy()
    if bad_n.any():
        p = np.nan_to_num(tris.positions[bad_n])
        ng = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        mirrored = tris.mirrored_triangles() if isinstance(tris, SceneArrays) else None
        if mirrored is not None:
            ng[mirrored[bad_n]] *= -1
        normals[bad_n] = ng[:, None, :]
    uvs[bad_uv] = 0.0
    if tangents is not None:
        tangents = tangents.copy()
        tangents[bad_t] = 0.0
        tangents = np.ascontiguousarray(tangents[keep])
    positions = padded_triangles(int(np.count_nonzero(keep)))
    np.compress(keep, tris.positions, axis=0, out=positions)
    changes = dict(positions=positions, normals=np.ascontiguousarray(normals[keep]),
                   uvs=np.ascontiguousarray(uvs[keep]), material_ids=np.ascontiguousarray(tris.material_ids[keep]),
                   tangents=tangents,
                   attributes=tuple((name, np.ascontiguousarray(np.nan_to_num(v[keep]))) for name, v in tris.attributes))
    for name in extra:
        values = getattr(tris, name)
        changes[name] = None if values is None else np.ascontiguousarray(values[keep])
    return changes, dropped, repaired, nonfinite


def _clean_instances(instances: Instances, clean: Instances | None = None) -> tuple[Instances, int, int, int]:
    """Each prototype cleaned once (not those equal to clean's, known clean); instances whose transform is
    not finite or flattens them dropped (their triangles counted as dropped, as a flattened copy's would be,
    and as non-finite where the transform is)."""
    dropped = repaired = nonfinite = 0
    prototypes = []
    known = clean.prototypes if clean is not None else ()
    for i, proto in enumerate(instances.prototypes):
        if i < len(known) and same_triangles(proto, known[i]):
            prototypes.append(proto)
            continue
        changes, d, r, f = _clean_triangles(proto)
        prototypes.append(dataclasses.replace(proto, **changes) if changes else proto)
        # Every instance drops the prototype's bad triangles, as its flattened copy would.
        uses = int(np.count_nonzero(instances.prototype == len(prototypes) - 1))
        dropped += d * uses
        repaired += r * uses
        nonfinite += f * uses
    m = instances.world_from_object
    usable = usable_placements(m)
    counts = np.array([p.triangle_count for p in prototypes], np.int64)
    dropped += int(counts[instances.prototype[~usable]].sum()) if len(counts) else 0
    unbounded = ~(np.isfinite(m).all(axis=(1, 2)) & (np.abs(np.nan_to_num(m[:, :3, :])) < 3e38).all(axis=(1, 2)))
    nonfinite += int(counts[instances.prototype[unbounded]].sum()) if len(counts) else 0
    kept = Instances(tuple(prototypes), np.ascontiguousarray(instances.prototype[usable]),
                     np.ascontiguousarray(m[usable]),
                     None if instances.object_ids is None else np.ascontiguousarray(instances.object_ids[usable]))
    return kept, dropped, repaired, nonfinite


def usable_placements(world_from_object: np.ndarray) -> np.ndarray:
    """(K,) bool: which (K, 4, 4) instance transforms place their mesh somewhere (finite, within float32,
    not flattening it); validate() drops the instances of the others."""
    m = world_from_object
    linear = np.nan_to_num(m[:, :3, :3])
    with np.errstate(over="ignore", invalid="ignore"):
        det = np.linalg.det(linear) if len(m) else np.zeros(0)
    return np.isfinite(m).all(axis=(1, 2)) & np.isfinite(det) & (np.abs(det) > 0) \
        & (np.abs(m[:, :3, :]) < 3e38).all(axis=(1, 2))


# Meshes of at least this many triangles are checked in slices on threads (NumPy releases the GIL), each
# slice in blocks of _BLOCK_TRIANGLES.
_PARALLEL_TRIANGLES = 1 << 19
_BLOCK_TRIANGLES = 1 << 15


def _usable_triangles(positions: np.ndarray) -> np.ndarray:
    """(T,) bool: finite corners and non-zero area, relative to the triangle's own size (area x 2 above
    1e-12 x its longer edge squared, in float64).

    Sorted in float32 first: a triangle whose float32 area clears the bound by a factor 1e8 clears it in
    float64 too (float32 rounding moves the cross product by a few 1e-7 of |e1| |e2|); only the others
    (slivers, non-finite and overflowing corners) are measured again in float64. Same answer, 5x faster
    on a million triangles. Big meshes are checked in slices on threads, row by row the same answer."""
    t = len(positions)
    usable = np.empty(t, bool)

    def blocks(lo: int, hi: int) -> None:
        # Blocks of _BLOCK_TRIANGLES keep the temporaries small: the allocator reuses them, hot in cache,
        # instead of faulting in fresh pages for every one of a million rows.
        for start in range(lo, hi, _BLOCK_TRIANGLES):
            end = min(start + _BLOCK_TRIANGLES, hi)
            usable[start:end] = _usable_slice(positions[start:end])

    threads = min(os.cpu_count() or 1, t // (_PARALLEL_TRIANGLES // 2))
    if t >= _PARALLEL_TRIANGLES and threads > 1:
        from concurrent.futures import ThreadPoolExecutor
        bounds = np.linspace(0, t, threads + 1).astype(int)
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda i: blocks(bounds[i], bounds[i + 1]), range(threads)))
    else:
        blocks(0, t)
    return usable


def _usable_slice(positions: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore"):
        e1 = positions[:, 1] - positions[:, 0]
        e2 = positions[:, 2] - positions[:, 0]
        cx = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
        cy = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
        cz = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        area_sq = cx * cx + cy * cy + cz * cz
        scale = np.maximum(np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e2, e2))
        clear = area_sq > np.float32(1e-8) * scale * scale   # area > 1e-4 x scale, squared
    usable = clear & np.isfinite(area_sq)
    doubt = np.flatnonzero(~usable)
    if len(doubt):
        usable[doubt] = _usable_exact(positions[doubt])
    return usable


def _finite_rows(a: np.ndarray) -> np.ndarray:
    """(T,) bool: every value of each row a[i] is finite. A row's sum (one BLAS product) is finite when all
    its values are, unless finite values overflow it: only rows whose sum is not are looked at value by
    value. Six times faster than isfinite().all() on a million triangles."""
    if not a.size:
        return np.ones(len(a), bool)
    if a.strides[0] == 0:   # one row seen len(a) times (a mesh without UVs)
        return np.full(len(a), bool(np.isfinite(a[0]).all()))
    flat = a.reshape(len(a), -1)
    with np.errstate(over="ignore", invalid="ignore"):
        ok = np.isfinite(matmul(flat, np.ones(flat.shape[1], flat.dtype)))
    doubt = np.flatnonzero(~ok)
    if len(doubt):
        ok[doubt] = np.isfinite(flat[doubt]).all(axis=1)
    return ok


def _usable_exact(positions: np.ndarray) -> np.ndarray:
    finite = np.isfinite(positions).all(axis=(1, 2))
    p = np.where(finite[:, None, None], positions, 0).astype(np.float64)
    e1 = p[:, 1] - p[:, 0]
    e2 = p[:, 2] - p[:, 0]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    scale = np.maximum(np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e2, e2))
    return finite & (area2 > 1e-12 * scale) & (area2 > 0)


def _require(ok, name: str, message: str) -> None:
    if not ok:
        raise ValueError(f"{name}: {message}")


def _require_finite(a: np.ndarray, name: str) -> None:
    _require(np.all(np.isfinite(a)), name, "contains NaN or infinite values")


def _check_array(a, name: str, shape: tuple, dtype, finite: bool = True) -> None:
    _require(isinstance(a, np.ndarray), name, f"must be a numpy array, got {type(a).__name__}")
    _require(a.dtype == dtype, name, f"must be {np.dtype(dtype).name}, got {a.dtype.name}")
    _require(a.ndim == len(shape) and all(s == -1 or s == d for s, d in zip(shape, a.shape)), name,
             f"must have shape {_shape_str(shape)}, got {a.shape}")
    if finite:
        _require_finite(a, name)


def _shape_str(shape: tuple) -> str:
    return "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
