"""The world: World, what a ray that leaves the scene sees (a colour, an equirectangular map or a node
program), how it is sampled as a light, and its validation."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..programs import Program, Ref
from .checks import check_array, require
from .lights import NO_BOUNCE_LIMIT
from .objects import ALL_RAYS
from .materials import Materials, Shader


@dataclass(frozen=True)
class World:
    """What a ray that leaves the scene sees.

    color : (3,) float32 radiance, used when hdri is None.
    hdri : (H, W, 3) equirectangular map, row 0 at the bottom (Blender's order), or None: float32 linear
        radiance, or an 8- or 16-bit image as it is stored (uint8, uint16; (H, W, 1) for grey).
    strength : multiplies color or hdri.
    hdri_srgb, hdri_interpolation : the hdri's values are sRGB-encoded (an 8- or 16-bit image: decoded after
        filtering, as Cycles does) and the Environment Texture's Interpolation (Linear, Closest, Cubic; Smart
        reads Cubic, as Cycles' CPU does).
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
    volume : the world's Volume output as a materials.Shader (its volume closures and their program), or
        None: a medium filling the whole scene, as Cycles' world volume (kernels.media).
    ao_distance : the world's Ambient Occlusion distance (World > Light Settings > Distance; 10 without a
        world, as Blender's sync sets Cycles' integrator), read by Ambient Occlusion nodes whose Distance is an
        unlinked 0 (Cycles' NODE_AO_GLOBAL_RADIUS, kernel/svm/ao.h).
    visibility : the world's Ray Visibility as kernels.scene.objects ray bits (ALL_RAYS: every ray): camera rays
        and escaped rays of an excluded kind see nothing, and its light samples light only the closures of the
        kinds it keeps, as a lamp's (Cycles' background visibility: kernel/light/common.h
        is_light_shader_visible_to_path; kernels/lights/ray_visibility.py).
    light_sampled : whether next-event estimation samples the world (Cycles' World > Settings > Surface > Sampling
        Method Auto or Manual: its background light's use_mis); False (None): BSDF rays alone find it, with MIS
        weight 1, and with light portals their samples alone light the points inside them, a uniform direction
        elsewhere (kernel/light/background.h: map_weight 0).
    sun : (4,) float32 or None: the sun disc of the world's one Sky Texture (its world direction and half its
        angular diameter in radians), which the world's light samples aim at directly as Cycles' background light
        does (kernel/light/background.h background_sun_sample: 4 parts in 5 against the map's 1, scene/light.cpp);
        None without such a sky, or with several.
    sun_radiance : with sun, Cycles' average radiance of that disc (SkyTextureNode::get_sun_average_radiance), which
        its light tree counts a fifth of in the world's measure (scene/light.cpp).
    emission_estimate : (3,) float32 Cycles' emission estimate of the world's Surface (Shader::estimate_emission: a
        Background's Color, white where linked, times its Strength), which its light tree multiplies the world's
        measure by; None: 1.
    max_bounces : the world's Max Bounces (World > Settings > Light): its light samples light only the vertices
        at most that many bounces deep (NO_BOUNCE_LIMIT: all), as a lamp's (Lights.max_bounces).
    """
    color: np.ndarray = field(default_factory=lambda: np.full(3, 0.05, np.float32))
    hdri: np.ndarray | None = None
    strength: float = 1.0
    hdri_srgb: bool = False
    hdri_interpolation: str = "Linear"
    env_from_world: np.ndarray = field(default_factory=lambda: np.eye(3, dtype=np.float32))
    program: Program | None = None
    output: Ref | None = None
    map_resolution: int = 1024
    mis_compensation: bool = True
    focus: bool = True
    volume: object = None
    ao_distance: float = 10.0
    max_bounces: int = NO_BOUNCE_LIMIT
    visibility: int = ALL_RAYS
    light_sampled: bool = True
    sun: np.ndarray | None = None
    sun_radiance: float = 0.0
    emission_estimate: np.ndarray | None = None

    def validate(self) -> None:
        check_array(self.color, "world.color", (3,), np.float32)
        require(np.all(self.color >= 0), "world.color", "must be non-negative")
        require(np.isfinite(self.strength) and self.strength >= 0, "world.strength",
                f"must be finite and non-negative, got {self.strength}")
        check_array(self.env_from_world, "world.env_from_world", (3, 3), np.float32)
        require(self.ao_distance >= 0, "world.ao_distance", f"must be non-negative, got {self.ao_distance}")
        require(int(self.max_bounces) >= 0, "world.max_bounces", f"must be non-negative, got {self.max_bounces}")
        require(0 <= int(self.visibility) <= ALL_RAYS, "world.visibility", f"must be ray bits, got {self.visibility}")
        if self.hdri is not None:
            h = self.hdri
            require(h.ndim == 3 and h.shape[2] in (1, 3) and h.shape[0] >= 1 and h.shape[1] >= 1,
                    "world.hdri", f"must be (H, W, 3) or (H, W, 1), got {h.shape}")
            integer = h.dtype in (np.uint8, np.uint16)
            check_array(h, "world.hdri", h.shape, h.dtype if integer else np.float32, finite=not integer)
            require(integer or bool(np.all(h >= 0)), "world.hdri", "must be non-negative")
            require(integer or not self.hdri_srgb, "world.hdri_srgb", "is for 8- and 16-bit images")
            require(self.hdri_interpolation in ("Linear", "Closest", "Cubic", "Smart"), "world.hdri_interpolation",
                    f"must be Linear, Closest, Cubic or Smart, got {self.hdri_interpolation!r}")
        require((self.program is None) == (self.output is None), "world.program", "comes with its output")
        if self.program is not None:
            require(isinstance(self.output, Ref) and 0 <= self.output.op < len(self.program), "world.output",
                    f"must be a Ref into the world's program of {len(self.program)} ops")
            require(int(self.map_resolution) >= 4, "world.map_resolution", "must be at least 4")
        if self.sun is not None:
            check_array(self.sun, "world.sun", (4,), np.float32)
            require(abs(float(np.linalg.norm(self.sun[:3])) - 1.0) < 1e-3 and 0 < self.sun[3] < np.pi / 2, "world.sun",
                    "must be a unit direction and a half-angle in (0, pi/2)")
        if self.volume is not None:
            require(isinstance(self.volume, Shader) and self.volume.volume, "world.volume",
                    "must be a Shader with volume closures")
            Materials((self.volume,)).validate(1 << 30)
