"""The light table: Lights, Blender's lights as L rows in radiometric terms, LIGHT_KINDS, and its validation."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .checks import check_array, require

LIGHT_KINDS = {"POINT": 0, "SPOT": 1, "SUN": 2, "RECT": 3, "DISK": 4}
# A light's Max Bounces that limits nothing (Blender's default and maximum, Cycles' Light::max_bounces default).
NO_BOUNCE_LIMIT = 1024
# Columns of a light portal's row (kernels/lights/portals.py).
PORTAL_COLUMNS = 13


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
    light_sets, shadow_sets : (L,) uint64 or None (every set: the light has no linking collection): the masks
        of the light sets the light reaches and of the shadow sets whose objects block it (Light and Shadow
        Linking: kernels.scene.links).
    shadow_catcher : (L,) bool or None (all True): the light object's Visibility > Shadow Catcher, which Blender
        turns on for lights; False leaves the light out of what shadow catchers receive without the synthetic
        objects (Cycles' SHADER_EXCLUDE_SHADOW_CATCHER: kernels/shadow_catcher.py).
    light_groups : (L,) int32 or None (no light is in a group): each light's light group, NO_GROUP (-1) for
        none (View Layer > Light Groups: kernels.scene.light_groups).
    visibility : (L,) uint8 or None (all see every bounce): the light object's Ray Visibility as the object
        table's ray bits (kernels.scene.objects RAY_DIFFUSE, _GLOSSY, _TRANSMIT, _SCATTER): the bounces whose
        light samples may take the light and whose rays see it (kernels/lights/ray_visibility.py).
    camera : (L,) bool or None (no light is): the light object's Ray Visibility > Camera, on for the lights that
        camera rays see (kernels/emitters_seen.py; Cycles' SHADER_EXCLUDE_CAMERA, scene/light.cpp).
    spread : (L,) float32 or None (every area light spreads over pi): an area light's Spread, radians (pi for the
        other kinds): the grid dimming its radiance off its normal (kernels/lights/area.py spread_attenuation) and
        the part of it each point samples (kernels/lights/area_spread.py).
    sphere : (L,) bool or None (none is): a sized point or spot light with Blender's Soft Falloff off, which Cycles
        makes a true sphere of its radius (kernels/lights/point_spot.py) instead of a disk facing each point.
    shader : (L,) int32 or None (no light's emission varies): the light's node program in `shaders`, -1 for a light
        whose node tree gives a constant emission (folded into radiance by the export). Where it varies (a texture,
        a Light Falloff), radiance is the light's strength alone and the program's emission, evaluated where each
        ray meets the light (kernels/lights/shaders.py: Cycles' light shader), multiplies it.
    shaders : ((kernels.programs.Program, Ref), ...) the light programs and the Ref of their emission (RGBA).
    max_bounces : (L,) int32 or None (none limits): the light's Max Bounces (Cycles' own setting, light.cycles): a
        light sample of it at a vertex more than that many bounces deep carries no light, as Cycles'
        light_select_reached_max_bounces drops it (kernel/light/light.h; the choice keeps its probabilities, and
        BSDF rays meeting the light still count, as in Cycles).
    tree : how shading points choose an emitter: True, by the light tree (Cycles' Light Tree, on by default: each
        point's own choice, kernels/light_tree.py); False, by Cycles' light distribution (scene/light.cpp
        device_update_distribution: the emissive triangles by their area and the lamps, suns and a sampled world
        alike, half and half when there are both; kernels/lights/selection.py distribution_pmf), as Cycles renders
        files whose Light Tree is off (older files open so). The image is the same but for clamping, which depends
        on each sample's value and so on how lights are chosen.
    clamped : the render clamps light (Clamping Direct or Indirect above 0; Renderer.render sets it from its settings):
        with the tree on, light samples are then shared among the lights as Cycles' tree shares them
        (kernels/light_tree_cycles.py), since what clamping cuts depends on each sample's value; unclamped, by Ember's
        own tree, which is less noisy.
    portals : (P, PORTAL_COLUMNS) float32 or None (none): the area lamps marked Portal, which emit nothing and guide
        the world's light samples through windows (kernels/lights/portals.py, whose docstring gives the columns);
        not among the L rows.
    mis : (L,) bool or None (all True): the light's Multiple Importance (Cycles' own setting, light.cycles); off,
        only its light samples light the scene, at full weight: BSDF rays pass it without seeing it, and escaped
        rays see no sun that has it off (Cycles' SHADER_USE_MIS: kernel/light/light.h lights_intersect,
        integrator/surface_shader.h, integrator/shade_background.h). Camera rays still see the lamps they see.
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
    light_sets: np.ndarray | None = None
    shadow_sets: np.ndarray | None = None
    shadow_catcher: np.ndarray | None = None
    light_groups: np.ndarray | None = None
    visibility: np.ndarray | None = None
    camera: np.ndarray | None = None
    spread: np.ndarray | None = None
    sphere: np.ndarray | None = None
    shader: np.ndarray | None = None
    shaders: tuple = ()
    max_bounces: np.ndarray | None = None
    mis: np.ndarray | None = None
    portals: np.ndarray | None = None
    tree: bool = True
    clamped: bool = False

    @property
    def count(self) -> int:
        return len(self.kind)

    def shadowed(self) -> np.ndarray:
        """(L,) bool: the lights whose light surfaces block."""
        return np.ones(self.count, bool) if self.cast_shadow is None else self.cast_shadow

    def validate(self) -> None:
        n = len(self.kind)
        check_array(self.kind, "lights.kind", (n,), np.int32)
        require(np.all(np.isin(self.kind, list(LIGHT_KINDS.values()))), "lights.kind",
                f"must be values of {LIGHT_KINDS}")
        shapes = {"position": (n, 3), "frame": (n, 3, 3), "radiance": (n, 3), "radius": (n,),
                  "size": (n, 2), "spot_cos": (n, 2), "sun_half_angle": (n,)}
        for name, shape in shapes.items():
            check_array(getattr(self, name), f"lights.{name}", shape, np.float32)
        for name in ("radiance", "radius", "size", "sun_half_angle"):
            require(np.all(getattr(self, name) >= 0), f"lights.{name}", "must be non-negative")
        if self.cast_shadow is not None:
            check_array(self.cast_shadow, "lights.cast_shadow", (n,), np.bool_, finite=False)
        for name in ("light_sets", "shadow_sets"):
            if getattr(self, name) is not None:
                check_array(getattr(self, name), f"lights.{name}", (n,), np.uint64, finite=False)
        if self.shadow_catcher is not None:
            check_array(self.shadow_catcher, "lights.shadow_catcher", (n,), np.bool_, finite=False)
        if self.light_groups is not None:
            check_array(self.light_groups, "lights.light_groups", (n,), np.int32, finite=False)
            require(not n or int(self.light_groups.min()) >= -1, "lights.light_groups", "must be -1 or more")
        if self.visibility is not None:
            check_array(self.visibility, "lights.visibility", (n,), np.uint8, finite=False)
        if self.camera is not None:
            check_array(self.camera, "lights.camera", (n,), np.bool_, finite=False)
        if self.spread is not None:
            check_array(self.spread, "lights.spread", (n,), np.float32)
            require(np.all((self.spread >= 0) & (self.spread <= np.float32(np.pi))), "lights.spread",
                    "must be within [0, pi]")
        if self.sphere is not None:
            check_array(self.sphere, "lights.sphere", (n,), np.bool_, finite=False)
        if self.mis is not None:
            check_array(self.mis, "lights.mis", (n,), np.bool_, finite=False)
        if self.portals is not None:
            check_array(self.portals, "lights.portals", (len(self.portals), PORTAL_COLUMNS), np.float32)
        if self.max_bounces is not None:
            check_array(self.max_bounces, "lights.max_bounces", (n,), np.int32, finite=False)
            require(not n or int(self.max_bounces.min()) >= 0, "lights.max_bounces", "must be non-negative")
        if self.shader is not None:
            check_array(self.shader, "lights.shader", (n,), np.int32, finite=False)
            require(not n or (int(self.shader.min()) >= -1 and int(self.shader.max()) < len(self.shaders)),
                    "lights.shader", "must be -1 or an index into lights.shaders")
