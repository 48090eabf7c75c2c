"""The LightSampler: a scene's emitters (Blender lights, emissive triangles, the world) in one table, the choice
among them (selection.py), sampling a direction toward the chosen one by its kind's module, and the lights
BSDF rays meet (intersect). LightSample and LightHits are what they return.
"""
from __future__ import annotations

import numpy as np

from ..environment import Environment
from ..light_groups import emitter_groups
from ..rng import pcg2d, to_unit_float
from ..geometry import emissive_instanced, lights_of
from ..light_tree import LightTree, rows_of
from ..light_tree_cycles import CyclesLightTree
from ..scene import SceneArrays
from ..textures import luminance
from . import area, point_spot, portals, ray_visibility, selection, sun, triangles, world
from ..scene.lights import NO_BOUNCE_LIMIT
from ..scene.objects import ALL_RAYS, BSDF_RAYS, RAY_CAMERA
from .common import DISK, POINT, RECT, SPOT, SUN
from .links import EmitterLinks, object_links, reaches, set_groups
from .proxies import PROXY_MIN_LIGHTS, LightProxies
from .shaders import LampShaders
from .triangles import TAREA, TE1, TE2, TLE, TN, TP0, TRI_COLUMNS


class LightSample:
    """Per shading point: unit direction (wx, wy, wz), distance (inf for the world and the sun),
    radiance (3, N) arriving along it, pdf (N,) per unit solid angle times the selection probability,
    delta (N,) bool for lights no BSDF ray can hit, world (N,) bool for samples of the world, shadowed (N,)
    bool: surfaces can block the sample (False for a light with Cast Shadow off); emitter (N,) int64 the
    emitters chosen, where the scene links lights (their shadow masks pick the shadow rays' blockers) or puts
    emitters in light groups (their groups' passes), else None; visibility (N,) uint8 the ray visibility of the
    emitters chosen where a lamp has a bounce kind off (kernels/lights/ray_visibility.py), else None; lamp (N,) bool
    the samples of Blender lights (no geometry of theirs in the scene to stop short of)."""
    __slots__ = ("wx", "wy", "wz", "dist", "radiance", "pdf", "delta", "world", "shadowed", "emitter",
                 "visibility", "lamp")

    def __init__(self, n: int):
        self.wx = np.zeros(n, np.float32)
        self.wy = np.zeros(n, np.float32)
        self.wz = np.ones(n, np.float32)
        self.dist = np.full(n, np.inf, np.float32)
        self.radiance = np.zeros((3, n), np.float32)
        self.pdf = np.zeros(n, np.float32)
        self.delta = np.zeros(n, bool)
        self.world = np.zeros(n, bool)
        self.shadowed = np.ones(n, bool)
        self.emitter = None
        self.visibility = None
        self.lamp = np.zeros(n, bool)

    def set(self, idx, wx, wy, wz, dist, radiance, pdf, delta=False):
        if len(idx) == len(self.wx):  # every point chose this kind: no scatter needed
            idx = slice(None)
        self.wx[idx], self.wy[idx], self.wz[idx] = wx, wy, wz
        self.dist[idx] = dist
        self.radiance[:, idx] = radiance
        self.pdf[idx] = pdf
        self.delta[idx] = delta


class LightHits:
    """What BSDF rays meet of the lights with a surface (LightSampler.intersect), per ray: hit (N,) bool,
    radiance (3, N) and pdf (N,) (solid angle, with selection) of the light returned; crossed (N,) int32,
    the lights met (each a transparent bounce); stopped (N,) bool, the path ends at its last light; t (N,)
    float32 the distance to the light returned; light (N,) int64 the lamp returned (where hit)."""
    __slots__ = ("hit", "radiance", "pdf", "crossed", "stopped", "t", "light")

    def __init__(self, n: int):
        self.light = np.zeros(n, np.int64)
        self.hit = np.zeros(n, bool)
        self.radiance = np.zeros((3, n), np.float32)
        self.pdf = np.zeros(n, np.float32)
        self.crossed = np.zeros(n, np.int32)
        self.stopped = np.zeros(n, bool)
        self.t = np.zeros(n, np.float32)


class LightSampler:
    """All emitters of a scene and one power-proportional distribution over them.

    Entities are numbered: Blender lights [0, L), emissive triangles [L, L + E), then the world.
    """

    def __init__(self, scene: SceneArrays, environment: Environment, triangle_emission, shading_data=None):
        """shading_data: the shading's scene data (kernels.shading.shader.ShadingData), which the programs of lights
        whose emission varies read (shaders.LampShaders); needed when the scene has such lights.
        triangle_emission: the emissive materials. triangle_emission(tri_ids) -> (3, n) mean emitted radiance
        of those triangles (textures averaged); triangle_emission(tri_ids, b1, b2, toward, dist) -> (3, n) radiance
        at barycentrics (b1, b2) toward -toward, at distance dist; .emissive (M,) bool, the materials that emit;
        .varies (M,) bool, those whose emission changes over the surface or with the direction."""
        lights = scene.lights
        self.environment = environment
        self.light_count = lights.count
        self.kind = lights.kind
        self.shadowed = lights.shadowed()
        # (L,) uint8 each lamp's ray visibility, or None when every lamp sees every bounce.
        self.visibility = lights.visibility
        # The world's Ray Visibility (World.visibility): its bounce kinds (BSDF_RAYS when it sees them all) and
        # whether camera rays see it.
        world_bits = int(getattr(scene.world, "visibility", ALL_RAYS))
        self.world_visibility = np.uint8(world_bits & BSDF_RAYS)
        self.world_camera = bool(world_bits & RAY_CAMERA)
        self.world_restricted = int(self.world_visibility) != BSDF_RAYS
        # (L,) bool the lamps camera rays see (Ray Visibility > Camera), or None when none is.
        self.camera = lights.camera
        # (L,) float32 each lamp's spread (area lights; pi for the others), or None when every one is pi.
        self.spread = lights.spread
        # (L,) bool the sized point and spot lamps that are spheres (Soft Falloff off), or None when none is.
        self.sphere = lights.sphere
        self.position = lights.position.astype(np.float32)
        self.axes = lights.frame.astype(np.float32)              # (L, 3, 3): columns x, y, z
        self.radiance_of = lights.radiance.astype(np.float32)
        # Lights whose node tree's emission varies: evaluated where rays reach them; their power takes an estimate.
        self.lamp_shaders = None
        self.power_scale = np.ones(self.light_count)
        if lights.shader is not None and (lights.shader >= 0).any():
            self.lamp_shaders = LampShaders(lights, shading_data)
            for k in np.flatnonzero(lights.shader >= 0):
                self.power_scale[k] = self.lamp_shaders.estimate(int(k))
        # The world's light portals (portals.Portals), or None: where a shading point is inside one, half of the
        # world's light samples go through them.
        self.portals = None if lights.portals is None or not len(lights.portals) else portals.Portals(lights.portals)
        # Cycles' Light Tree setting (Lights.tree): off, emitters are chosen by its light distribution.
        self.light_tree = bool(lights.tree)
        # A clamped render shares light samples as Cycles' tree does (kernels/light_tree_cycles.py).
        self.cycles_shares = self.light_tree and bool(lights.clamped)
        self.radius = lights.radius.astype(np.float32)
        self.size = lights.size.astype(np.float32)
        self.spot = lights.spot_cos.astype(np.float32)
        self.sun_cos = np.cos(lights.sun_half_angle).astype(np.float32)
        # A sun of angular radius a and radiance L gives E = L pi sin^2(a) facing it: L = E / (pi sin^2 a),
        # with a the cone actually sampled, that of the float32 cosine (Blender's default 0.526 degree sun:
        # float32 rounds its 1 - cos by 0.14%, and the sun read that much bright).
        # Suns whose cone rounds to a single direction in float32 are delta lights and keep E itself.
        cos_sampled = self.sun_cos.astype(np.float64)
        sin2 = (1.0 - cos_sampled) * (1.0 + cos_sampled)
        cone = (self.sun_cos < np.float32(1.0)) & (sin2 > 0)
        self.sun_radiance = np.where(cone[:, None], lights.radiance / (np.pi * np.where(cone, sin2, 1.0))[:, None],
                                     lights.radiance).astype(np.float32)
        # Suns with a disc: rays that leave the scene toward one see it (Cycles' integrate_sun_lights).
        # (L,) bool the lamps with Multiple Importance off (Lights.mis), or None when none has it off: only their
        # light samples see them (at full weight), no BSDF ray nor escaped ray.
        self.mis_off = None if lights.mis is None else ~lights.mis
        self.sun_discs = np.flatnonzero((self.kind == SUN) & cone & (self.radiance_of.max(axis=1) > 0) &
                                        (True if self.mis_off is None else ~self.mis_off)) \
            if self.light_count else np.zeros(0, np.int64)
        self.area = np.where(self.kind == RECT, self.size[:, 0] * self.size[:, 1],
                             np.float32(np.pi / 4) * self.size[:, 0] * self.size[:, 1]).astype(np.float32)

        # Emissive triangles: two-sided (but for Emission Sampling Front or Back), uniform over their area.
        emits = np.asarray(triangle_emission.emissive, bool)
        # Triangles of moving objects (motion blur) are left to BSDF rays, which find them where they are
        # at the path's time (with MIS weight 1: their light pdf is 0); the table would place them wrong.
        sampled = emits[scene.material_ids]
        if scene.has_motion and scene.motion_ids is not None:
            sampled &= scene.motion_ids < 0
        if scene.has_motion and scene.deform_ids is not None:   # deforming ones too
            sampled &= scene.deform_ids < 0
        lit = lights_of(scene)   # objects no BSDF ray sees are no lights (Ray Visibility)
        if lit is not None and scene.object_ids is not None:
            sampled &= lit[scene.object_ids]
        plain_ids = np.flatnonzero(sampled).astype(np.int32)
        # Emissive triangles of instances (kernels.scene.Instances) come after the plain ones, each instance's
        # copy a light of its own, numbered as ray hits report them.
        instanced_ids, instanced_corners, instanced_materials = emissive_instanced(scene, emits)
        # Each triangle's own emission: the material's where it is constant, an estimate from a few points
        # of the triangle where a texture or layers make it vary. Triangles that show none are left to BSDF
        # rays (light pdf 0, so MIS weight 1), as Cycles leaves emitters it estimates weak: an emission map
        # is mostly black (Damaged Helmet: 98% of its triangles), and light samples on the black part are
        # wasted.
        candidates = np.concatenate([plain_ids, instanced_ids]) if len(instanced_ids) else plain_ids
        varies = np.asarray(triangle_emission.varies, bool)
        estimate = selection.emission_estimates(triangle_emission, candidates,
                                       np.concatenate([scene.material_ids[plain_ids], instanced_materials]), varies)
        keep = np.abs(estimate).max(axis=1, initial=0.0) > 0
        materials = np.concatenate([scene.material_ids[plain_ids], instanced_materials]).astype(np.int64)
        self.object_totals, self.tri_estimate = None, None
        if self.cycles_shares:
            # Cycles' estimate of each emitting triangle's material (Shader.emission_estimate; NaN where not known),
            # by which Cycles' tree weighs it (_triangle_power, _object_totals).
            known = np.array([s.emission_estimate if getattr(s, "emission_estimate", None) is not None
                              else (np.nan,) * 3 for s in scene.materials.shaders], np.float64).reshape(-1, 3)
            material_estimate = known[materials] if len(known) else np.full((len(materials), 3), np.nan)
            if len(candidates):
                self.object_totals = _object_totals(scene, candidates, plain_ids, instanced_corners,
                                                    material_estimate, estimate)
            self.tri_estimate = material_estimate[keep]
        n_plain = len(plain_ids)
        plain_ids, estimate = plain_ids[keep[:n_plain]], estimate[keep]
        instanced_ids, instanced_corners = instanced_ids[keep[n_plain:]], instanced_corners[keep[n_plain:]]
        instanced_materials = instanced_materials[keep[n_plain:]]
        materials = materials[keep]
        self.tri_ids = np.concatenate([plain_ids, instanced_ids]) if len(instanced_ids) else plain_ids
        p = scene.positions[plain_ids].astype(np.float64)
        if len(instanced_ids):
            p = np.concatenate([p, instanced_corners])
        e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        cross = np.cross(e1, e2)
        tri_area = 0.5 * np.linalg.norm(cross, axis=1)
        self.tri_area = tri_area.astype(np.float32)
        # Position of each scene triangle in the emissive list (-1 for non-emissive), for MIS on hits.
        # (Instanced ones are looked up in tri_ids, see _slots.)
        self.tri_slot = np.full(scene.triangle_count, -1, np.int32)
        self.tri_slot[plain_ids] = np.arange(len(plain_ids), dtype=np.int32)
        self.plain_count = scene.triangle_count
        self.has_instances = scene.instances is not None and scene.instances.count > 0
        self._instanced = len(instanced_ids) > 0
        # Triangles whose emission varies (a texture, layers above it) are evaluated at the sampled point.
        self.tri_textured = bool(varies[materials].any())
        # One row per emissive triangle, gathered whole (rows of a (E, K) table gather fastest).
        table = np.zeros((len(self.tri_ids), TRI_COLUMNS), np.float32)
        table[:, TP0:TP0 + 3] = p[:, 0]
        table[:, TE1:TE1 + 3] = e1
        table[:, TE2:TE2 + 3] = e2
        table[:, TN:TN + 3] = cross / np.maximum(2 * tri_area, 1e-300)[:, None]
        table[:, TAREA] = tri_area
        self.tri_table = table
        # Squared longest edge of each emissive triangle: the reach of its solid-angle sampling.
        self.tri_reach2 = np.max(np.stack([(e1 * e1).sum(1), (e2 * e2).sum(1), ((e2 - e1) ** 2).sum(1)]),
                                  axis=0).astype(np.float32) if len(self.tri_ids) else np.zeros(0, np.float32)
        self.triangle_emission = triangle_emission
        table[:, TLE:TLE + 3] = estimate
        # Emission Sampling Front or Back: the side each emissive triangle's light samples go to (None: both).
        self.tri_sides, self.tri_half = triangles.one_sided(scene, scene.materials.shaders, materials, plain_ids,
                                                            instanced_ids)

        surface = ((self.kind == RECT) | (self.kind == DISK) | (((self.kind == POINT) | (self.kind == SPOT))
                                                                 & (self.radius > 0)))
        self.has_surface_lights = bool(surface.any())
        self.surface_ids = np.flatnonzero(surface)
        self.proxy = (LightProxies(self.surface_ids, self.kind, self.position, self.radius, self.size)
                       if len(self.surface_ids) > PROXY_MIN_LIGHTS else None)
        power = np.concatenate([self._light_power(), self._triangle_power(), [self._world_power()]])
        power = np.where(np.isfinite(power) & (power > 0), power, 0.0)
        self.world_index = self.light_count + len(self.tri_ids)
        objects = object_links(scene)
        # With Light Linking each light set takes its own choice (links.py), with the fixed distant share.
        self.linked = objects is not None
        self.choice = selection.Choice(self, power, scene, self.light_tree)
        self.has_lights = self.choice.has_lights
        # Light Linking: a choice per light set that receivers use (links.py); None without linking.
        self.links = None if objects is None or not self.has_lights else \
            EmitterLinks(self, objects, scene, power, self._triangle_rows(scene))
        # Light groups: each emitter's group (its light's pass), None when none is in one.
        self.groups = emitter_groups(scene, self.light_count, lambda: self._triangle_rows(scene))
        # (L + E + 1,) int32 each emitter's Max Bounces (lamps' and the world's; triangles have none), or None when
        # none limits: a light sample deeper than its emitter's limit carries no light (sample_chosen).
        self.bounce_limit = None
        world_limit = int(getattr(scene.world, "max_bounces", NO_BOUNCE_LIMIT))
        if scene.lights.max_bounces is not None or world_limit < NO_BOUNCE_LIMIT:
            limit = np.full(self.world_index + 1, NO_BOUNCE_LIMIT, np.int32)
            if scene.lights.max_bounces is not None:
                limit[:self.light_count] = scene.lights.max_bounces
            limit[self.world_index] = world_limit
            self.bounce_limit = limit

    def _triangle_rows(self, scene) -> np.ndarray:
        """(E,) int64 object row of each emissive triangle (0 without an object table)."""
        tri = self.tri_ids
        rows = np.zeros(len(tri), np.int64)
        if scene.object_ids is None or not len(tri):
            return rows
        plain = tri < self.plain_count
        rows[plain] = np.take(scene.object_ids, tri[plain])
        if not plain.all():
            bases = scene.instances.bases(self.plain_count)
            k = np.searchsorted(bases, tri[~plain], side="right") - 1
            rows[~plain] = np.take(scene.instances.object_ids, k)
        return rows

    # The global choice's parts (selection.Choice), as the sampler's own.
    select_pmf = property(lambda self: self.choice.select_pmf)
    pmf32 = property(lambda self: self.choice.pmf32)
    tree = property(lambda self: self.choice.tree)
    tree_divergence = property(lambda self: self.choice.tree_divergence)

    @property
    def instanced_emitters(self) -> bool:
        """Some emissive triangles belong to instances: the table moves with them (a new sampler then)."""
        return self._instanced

    # ------------------------------------------------------------------ power estimates
    def _light_power(self) -> np.ndarray:
        if not self.light_count:
            return np.zeros(0)
        if self.cycles_shares:
            return self._cycles_light_power()
        lum = luminance(self.radiance_of).astype(np.float64) * self.power_scale
        r2 = self.radius.astype(np.float64) ** 2
        # Sized point lights act as a disk of radiance L facing every point: intensity L pi r^2.
        sphere = np.where(r2 > 0, lum * np.pi * r2, lum) * 4 * np.pi
        cone = (1.0 - 0.5 * (self.spot[:, 0] + np.minimum(1.0, self.spot[:, 0] + self.spot[:, 1]))).astype(np.float64)
        spot = sphere * np.clip(cone, 1e-4, 1.0) / 2.0
        sun = lum  # irradiance (W/m^2): compared with the world's only (see DISTANT_SHARE)
        area = lum * self.area * np.pi
        return np.select([self.kind == POINT, self.kind == SPOT, self.kind == SUN], [sphere, spot, sun], area)

    def _cycles_light_power(self) -> np.ndarray:
        """The lamps' weights as Cycles' light tree measures its emitters (scene/light_tree.cpp, LightTreeEmitter:
        the mean of |R|, |G|, |B| of the strength, 1 / (4 pi) of it for point and spot lights, 1 / pi for area
        lights, times the lamp shader's estimate): the mean of L times pi r^2 (1 for a point of no size) or the
        area; a sun's irradiance, which Cycles' root weighs against the world and the local tree (selection.cycles_root)."""
        mean = np.abs(self.radiance_of).astype(np.float64).mean(axis=1) * self.power_scale
        r2 = self.radius.astype(np.float64) ** 2
        punctual = np.where(r2 > 0, mean * np.pi * r2, mean)
        punctual_kind = (self.kind == POINT) | (self.kind == SPOT)
        # A sun's: the mean of |R|, |G|, |B| of its irradiance, as Cycles' (compared with the world's in its root).
        return np.select([punctual_kind, self.kind == SUN], [punctual, mean], mean * self.area)

    def _triangle_power(self) -> np.ndarray:
        if not len(self.tri_ids):
            return np.zeros(0)
        if self.cycles_shares:
            # Area times the mean of |R|, |G|, |B| of its material's estimate, as Cycles' light tree weighs an emissive
            # triangle (the triangle's own emission where the estimate is not known).
            known = ~np.isnan(self.tri_estimate[:, 0])
            emission = np.where(known[:, None], self.tri_estimate, self.tri_table[:, TLE:TLE + 3].astype(np.float64))
            return self.tri_area * np.abs(emission).mean(axis=1)
        # Negative emission (a negative Strength) subtracts light; its triangles are chosen by the size of their
        # emission, as Cycles' light tree measures them (light_tree.cpp: fabs of the emission estimate).
        lum = np.abs(luminance(self.tri_table[:, TLE:TLE + 3]).astype(np.float64))
        return 2.0 * np.pi * self.tri_area * lum

    def _world_power(self) -> float:
        """In the sun's unit (W/m^2): the world's flux into a sphere over the sphere's cross-section. 0 for a
        world of one colour in every direction, which, as in Cycles (LightManager's background light needs a
        spatially varying world), is no light: BSDF rays find it, with MIS weight 1, and next-event
        estimation spends its samples on the lamps (a constant grey world took half of them). With light portals
        every world is one (Cycles' test_enabled_lights: has_portal), sampled through them."""
        if not self.environment.world.light_sampled and self.portals is None:
            return 0.0   # Sampling Method None: BSDF rays alone find it
        if not self.environment.varies and self.portals is None:
            return 0.0
        if self.cycles_shares:
            # As Cycles' light tree measures its background light (scene/light_tree.cpp: the world shader's emission
            # estimate x the average radiance x pi; with a sun disc the average is 0.8 x the map's + 0.2 x the sun's,
            # scene/light.cpp): its share against the lamps in a clamped render (selection.cycles_root).
            world = self.environment.world
            average = self.environment.cycles_average_radiance()
            if world.sun is not None:
                average = 0.8 * average + 0.2 * float(world.sun_radiance)
            estimate = 1.0 if world.emission_estimate is None else float(np.abs(world.emission_estimate).mean())
            return float(average * np.pi * estimate)
        return float(4 * np.pi * self.environment.mean_luminance())

    def distant_mask(self) -> np.ndarray:
        """(L + E + 1,) bool: the emitters whose power is per unit area (suns and the world)."""
        return np.concatenate([self.kind == SUN, np.zeros(len(self.tri_ids), bool), [True]])

    # ------------------------------------------------------------------ the light tree

    @property
    def uses_tree(self) -> bool:
        return isinstance(self.tree, (LightTree, CyclesLightTree))

    @property
    def selection(self) -> str:
        """How shading points choose among the local emitters: "power" (one pmf everywhere), "tree" (a
        light tree per point) or "solid angle" (SolidAngleChoice per point)."""
        if self.tree is None:
            return "power"
        return "tree" if isinstance(self.tree, (LightTree, CyclesLightTree)) else "solid angle"

    def choose_at(self, u_select, px, py, pz, receiver=None, facing=None):
        """(emitter (n,) int64, selection probability (n,) float32) per shading point p (selection.choose_at);
        receiver: (n,) uint8 the points' light sets (Light Linking), or None. A point whose set no emitter
        reaches gets emitter 0 with probability 0. facing: the points' (nx, ny, nz, two_sided), or None."""
        if receiver is None or self.links is None:
            return selection.choose_at(self.choice, u_select, px, py, pz, facing)
        chosen, select = np.zeros(len(px), np.int64), np.zeros(len(px), np.float32)
        for s, idx in set_groups(receiver):
            choice = self.links.choice(s)
            if choice.has_lights:
                chosen[idx], select[idx] = selection.choose_at(choice, u_select[idx], px[idx], py[idx], pz[idx],
                                                               rows_of(facing, idx))
        return chosen, select

    def selection_pmf(self, emitter, px, py, pz, receiver=None, facing=None):
        """(n,) float32 probability that NEE at point p chooses emitter (selection.selection_pmf); receiver and
        facing as for choose_at."""
        if receiver is None or self.links is None:
            return selection.selection_pmf(self.choice, emitter, px, py, pz, facing)
        out = np.empty(len(px), np.float32)
        for s, idx in set_groups(receiver):
            out[idx] = selection.selection_pmf(self.links.choice(s), np.take(emitter, idx), px[idx], py[idx], pz[idx],
                                               rows_of(facing, idx))
        return out

    @property
    def reads_facing(self) -> bool:
        """Whether the choice may depend on the shading point's normal (a light tree, or linking's choices per
        light set): the integrator then keeps the normal of the vertex each ray left (PathState.mis_facing) for
        the MIS pdfs."""
        return isinstance(self.tree, (LightTree, CyclesLightTree)) or self.links is not None or \
            self.choice.leaf is not None

    def distant_pmf(self, emitter: int, n: int, receiver=None, px=None, py=None, pz=None, facing=None):
        """The pmf of a distant emitter (a sun, the world): one float32, or (n,) per receiver set, or per point p
        (facing: as choose_at's) where the choice weighs the distant emitters per point as Cycles' root does
        (selection.root_share: a clamped render)."""
        if receiver is None or self.links is None:
            if self.weighs_distant:
                if px is None:
                    raise ValueError("distant_pmf: this choice needs the points the rays left")
                return selection.distant_pmf_at(self.choice, emitter, px, py, pz, facing).astype(np.float32)
            return self.pmf32[emitter]
        return self.links.pmf(emitter, receiver)

    # ------------------------------------------------------------------ sampling
    def choose(self, u_select: np.ndarray) -> np.ndarray:
        """(n,) int64 emitter index per number in [0, 1): lights, then emissive triangles, then the world,
        each with probability select_pmf."""
        return selection.choose(self.choice, u_select)

    def sample(self, px, py, pz, u_select, u1, u2, focus=None, receiver=None, facing=None,
               allowed=None, bounce=None) -> LightSample:
        """Choose an emitter for each shading point p and sample a direction toward it. focus: the world's
        (environment.WorldFocus per shading point) when its light samples focus on glossy lobes; receiver:
        (n,) uint8 the points' light sets (Light Linking), or None; facing: the points' (nx, ny, nz,
        two_sided) (selection.choose_at). allowed: (L + E + 1,) bool, the emitters these points may take light
        from (a shadow catcher's own paths: kernels/shadow_catcher.py), or None for all; a sample of another
        carries no light, as Cycles' light_sample then gives none, and the choice keeps its probabilities.
        bounce: (n,) the points' bounce counts (PathState.bounce), for the emitters' Max Bounces (bounce_limit):
        a sample of an emitter whose limit is below the point's count carries no light either."""
        n = len(px)
        if not self.has_lights or n == 0:
            return LightSample(n)
        chosen, select = self.choose_at(u_select, px, py, pz, receiver, facing)
        return self.sample_chosen(px, py, pz, chosen, select, u1, u2, focus, allowed, bounce)

    def sample_chosen(self, px, py, pz, chosen, select, u1, u2, focus=None, allowed=None, bounce=None) -> LightSample:
        """sample() with the emitters already chosen (chosen (n,) emitter numbers, select (n,) the probability
        each was chosen with, which the pdf includes)."""
        n = len(px)
        out = LightSample(n)
        if not self.has_lights or n == 0:
            return out
        if not self.shadowed.all():
            lamp = chosen < self.light_count
            out.shadowed = ~lamp | np.take(self.shadowed, np.where(lamp, chosen, 0))
        if self.links is not None or self.groups is not None:
            out.emitter = chosen
        if self.visibility is not None or self.world_restricted:
            out.visibility = ray_visibility.of_emitters(self, chosen)
        if self.light_count:
            out.lamp = chosen < self.light_count
            for kind, method in ((POINT, point_spot.sample), (SPOT, point_spot.sample), (SUN, sun.sample),
                                 (RECT, area.sample), (DISK, area.sample)):
                idx = np.flatnonzero((chosen < self.light_count) & (np.take(self.kind, np.minimum(chosen, self.light_count - 1)) == kind))
                if len(idx):
                    method(self, out, idx, chosen[idx], px[idx], py[idx], pz[idx], u1[idx], u2[idx])
            if self.lamp_shaders is not None:
                self._shade_samples(out, chosen, px, py, pz)
            if self.mis_off is not None:   # MIS weight 1: no BSDF ray finds these lamps
                lamp = chosen < self.light_count
                out.delta |= lamp & np.take(self.mis_off, np.where(lamp, chosen, 0))
        tri = np.flatnonzero((chosen >= self.light_count) & (chosen < self.world_index))
        if len(tri):
            triangles.sample(self, out, tri, chosen[tri] - self.light_count, px[tri], py[tri], pz[tri], u1[tri], u2[tri])
        if self.select_pmf[self.world_index] > 0:
            picked = np.flatnonzero(chosen == self.world_index)
            if len(picked):
                world.sample(self, out, picked, u1[picked], u2[picked], None if focus is None else focus.take(picked),
                             px[picked], py[picked], pz[picked])
        out.pdf *= select
        if allowed is not None:
            out.radiance[:, ~np.take(allowed, chosen)] = 0.0
        if bounce is not None and self.bounce_limit is not None:
            out.radiance[:, np.asarray(bounce) > np.take(self.bounce_limit, chosen)] = 0.0
        return out

    def _shade_samples(self, out, chosen, px, py, pz) -> None:
        """Multiply the light samples that chose a light whose emission varies by its program's emission there."""
        lamp = np.flatnonzero(chosen < self.light_count)
        idx = lamp[self.lamp_shaders.varying(chosen[lamp])]
        if not len(idx):
            return
        light = chosen[idx]
        sphere = None if self.sphere is None else np.take(self.sphere, light) & (np.take(self.radius, light) > 0)
        out.radiance[:, idx] *= self.lamp_shaders.at_sample(light, px[idx], py[idx], pz[idx], out.wx[idx],
                                                            out.wy[idx], out.wz[idx], out.dist[idx], sphere)

    def axis(self, light, k):
        """(3, n) world direction of the chosen lights' local axis k."""
        return self.axes[light, :, k].T

    # ------------------------------------------------------------------ pdfs of what BSDF rays find
    # receiver: (n,) uint8 the light sets of the objects the rays left (Light Linking), or None; facing: the
    # normals of the vertices they left (choose_at), or None.
    def pdf_triangle_hit(self, tri, dist, cos_l, ox, oy, oz, receiver=None, facing=None,
                         backfacing=None) -> np.ndarray:
        """pdf (solid angle, with selection) of NEE from o for this point of emissive triangle tri
        (triangles.pdf_hit)."""
        return triangles.pdf_hit(self, tri, dist, cos_l, ox, oy, oz, receiver, facing, backfacing)

    def pdf_world(self, dx, dy, dz, focus=None, receiver=None, ox=None, oy=None, oz=None, facing=None) -> np.ndarray:
        """pdf (solid angle, with selection) of NEE for world directions d from points o (world.pdf; o and facing
        matter with light portals and where the choice weighs distant emitters per point: weighs_distant)."""
        return world.pdf(self, dx, dy, dz, focus, receiver, ox, oy, oz, facing)

    @property
    def weighs_distant(self) -> bool:
        """Whether the choice of a distant emitter depends on the point and its normal (Cycles' root and distant leaf
        in a clamped render: selection.root_share, selection.distant_leaf): MIS pdfs of the world and suns then need
        the points the rays left."""
        return self.choice.root is not None or self.choice.leaf is not None

    def suns_seen(self, dx, dy, dz, bsdf_pdf=None, receiver=None, shadow_linked: bool = False, parts=None,
                  types=None, points=None):
        """(3, n) radiance of the sun discs that rays leaving the scene along d look into, MIS-weighed
        (sun.seen); None when the scene has no sun with a disc. shadow_linked: count the suns whose light
        dedicated rays count (kernels/shadow_linking.py) too; parts: a list that takes each sun's share;
        types: (n,) uint8 the rays' types (kernels/visibility.py ray_types), or None: a sun that does not see
        a ray's type gives it nothing (kernels/lights/ray_visibility.py)."""
        return sun.seen(self, dx, dy, dz, bsdf_pdf, receiver, shadow_linked, parts, types, points)

    def camera_suns(self, dx, dy, dz, parts=None):
        """(3, n) radiance of the sun discs of Ray Visibility > Camera that camera rays leaving the scene along d
        look into (sun.seen_by_camera); None when no sun is seen by camera rays."""
        return sun.seen_by_camera(self, dx, dy, dz, parts)

    def samples_world(self) -> bool:
        """Whether next-event estimation can choose the world."""
        return self.has_lights and self.select_pmf[self.world_index] > 0

    def intersect(self, ox, oy, oz, dx, dy, dz, t_max, budget=None, receiver=None, facing=None,
                  allowed=None, types=None, camera: bool = False, t_min=None) -> "LightHits":
        """BSDF rays against the lights that have a surface (sphere, rect, disk) before t_max, as Cycles'
        BSDF rays meet them (kernel/light/light.h lights_intersect, integrator/shade_light.h).

        A ray finds the nearest light before the geometry, counts its emission and goes on from there
        with its start just past that distance, as through a transparent surface: each light it meets
        takes one of its transparent bounces, and the light that takes the last one (budget (N,) int,
        the transparent bounces the path has left; at least the first light is counted) ends the path
        there. A light at the distance of the last one found, to the float, is stepped over (Cycles
        moves the ray's start to the next float after the hit): of coincident lamps the first in the
        scene's order is seen, alone. Without a budget every light before t_max is met.

        The caller weights what it gets by MIS with one pdf, so where a ray meets several lights one of
        them is returned, chosen in proportion to its radiance, with its radiance divided by that
        probability: the expectation is the sum over the lights, each with its own MIS weight.

        receiver: (N,) uint8 the light sets of the objects the rays left, or None: with Light Linking a ray
        meets only the lights that reach its set and are not shadow-linked (those take dedicated rays), as
        Cycles' lights_intersect skips the others before counting them (kernel/light/light.h). allowed: (L,)
        bool, the lights the rays see (a shadow catcher's own paths pass the others: Cycles' lights_intersect
        skips lights excluded from them), or None for all. types: (N,) uint8 the rays' types (kernels/visibility.py
        ray_types), or None: a lamp that does not see a ray's type is met and crossed but gives it no light
        (kernels/lights/ray_visibility.py). camera: the rays are camera rays, which see lamps whose Multiple
        Importance is off (other rays pass them unseen). t_min: (N,) float32 or None (0): the lights met lie past
        it (a ray that kept its origin through transparent surfaces, as Cycles' rays do, starts there)."""
        n = len(ox)
        out = LightHits(n)
        if not self.has_surface_lights or n == 0:
            return out
        ray, light = self._candidates(ox, oy, oz, dx, dy, dz, t_max)
        if receiver is not None and self.links is not None and len(ray):
            keep = reaches(self.links.light[light], receiver[ray]) & ~self.links.shadow_linked[light]
            ray, light = ray[keep], light[keep]
        if allowed is not None:
            seen = np.take(allowed, light)
            ray, light = ray[seen], light[seen]
        if self.mis_off is not None and not camera:   # not met, not crossed (Cycles' lights_intersect skips them)
            seen = ~np.take(self.mis_off, light)
            ray, light = ray[seen], light[seen]
        if not len(ray):
            return out
        t, light_pdf, le = self.hit_pairs(ray, light, ox[ray], oy[ray], oz[ray], dx[ray], dy[ray], dz[ray])
        if types is not None and self.visibility is not None:
            le[:, ray_visibility.unseen(np.take(self.visibility, light), np.take(types, ray))] = 0.0
        ok = np.flatnonzero((t > (0 if t_min is None else t_min[ray])) & (t < t_max[ray]))
        # Nearest first; of lights at one distance, the first in the scene's order (Cycles' loop keeps
        # a light only when it is strictly nearer than the one it has).
        order = ok[np.lexsort((light[ok], t[ok], ray[ok]))]
        ray, light, t, light_pdf, le = ray[order], light[order], t[order], light_pdf[order], le[:, order]
        met, crossed = _met_in_turn(ray, t, n, budget)
        out.crossed = crossed
        if budget is not None:
            out.stopped = crossed >= np.maximum(budget, 1)
        ray, light, light_pdf, le, t = ray[met], light[met], light_pdf[met], le[:, met], t[met]
        weight = le[0] + le[1] + le[2]
        keep = np.flatnonzero(weight > 0)
        ray, light, light_pdf, le, weight, t = ray[keep], light[keep], light_pdf[keep], le[:, keep], weight[keep], t[keep]
        if not len(ray):
            return out
        chosen, share = _choose_per_ray(ray, weight.astype(np.float64), _ray_uniform(ox, oy, oz, dx, dy, dz)[ray])
        rays = ray[chosen]
        out.hit[rays] = True
        out.light[rays] = light[chosen]
        out.t[rays] = t[chosen]
        out.radiance[:, rays] = le[:, chosen] / share.astype(np.float32)
        out.pdf[rays] = self.selection_pmf(light[chosen], ox[rays], oy[rays], oz[rays],
                                           None if receiver is None else receiver[rays],
                                           rows_of(facing, rays)) * light_pdf[chosen]
        return out

    def shadow_linked_hits(self, ox, oy, oz, dx, dy, dz, t_max, receiver, facing=None):
        """Every (ray, lamp) pair where a ray meets a shadow-linked lamp with a surface that reaches the ray's
        light set (receiver (N,) uint8) before t_max (Cycles' lights_intersect_shadow_linked): (ray, lamp, t,
        pdf per solid angle with selection, radiance (3, P))."""
        empty = (np.zeros(0, np.int64),) * 2 + (np.zeros(0, np.float32),) * 2 + (np.zeros((3, 0), np.float32),)
        if not self.has_surface_lights or self.links is None or not len(ox):
            return empty
        ray, light = self._candidates(ox, oy, oz, dx, dy, dz, t_max)
        keep = reaches(self.links.light[light], receiver[ray]) & self.links.shadow_linked[light]
        ray, light = ray[keep], light[keep]
        if not len(ray):
            return empty
        t, light_pdf, le = self.hit_pairs(ray, light, ox[ray], oy[ray], oz[ray], dx[ray], dy[ray], dz[ray])
        ok = np.flatnonzero((t > 0) & (t < t_max[ray]))
        ray, light = ray[ok], light[ok]
        pdf = self.selection_pmf(light, ox[ray], oy[ray], oz[ray], receiver[ray], rows_of(facing, ray)) * light_pdf[ok]
        return ray, light, t[ok], pdf, le[:, ok]

    def _candidates(self, ox, oy, oz, dx, dy, dz, t_max):
        """(ray, light) index pairs that may hit: every ray against every surface light, or, with many
        lights, the pairs whose bounding shapes the ray crosses (found by Embree)."""
        if self.proxy is None:
            n, k = len(ox), len(self.surface_ids)
            return np.tile(np.arange(n), k), np.repeat(self.surface_ids, n)
        return self.proxy.candidates(ox, oy, oz, dx, dy, dz, t_max)

    def hit_pairs(self, ray, light, ox, oy, oz, dx, dy, dz):
        """Per (ray, light) pair: distance (-1 for a miss), pdf per solid angle of that light's
        sampling (without selection) and the radiance arriving (3, P)."""
        p = len(ray)
        t = np.full(p, -1.0, np.float32)
        pdf = np.zeros(p, np.float32)
        le = np.zeros((3, p), np.float32)
        kind = np.take(self.kind, light)
        for sel, method in ((np.flatnonzero((kind == POINT) | (kind == SPOT)), point_spot.intersect),
                            (np.flatnonzero((kind == RECT) | (kind == DISK)), area.intersect)):
            if len(sel):
                lk = light[sel]
                t_k, pdf_k, att = method(self, lk, ox[sel], oy[sel], oz[sel], dx[sel], dy[sel], dz[sel])
                t[sel], pdf[sel] = t_k, pdf_k
                le[:, sel] = self.radiance_of[lk].T * att[None, :]
        if self.lamp_shaders is not None:
            sel = np.flatnonzero(t > 0)
            sel = sel[self.lamp_shaders.varying(light[sel])]
            if len(sel):
                lk = light[sel]
                sphere = None if self.sphere is None else np.take(self.sphere, lk) & (np.take(self.radius, lk) > 0)
                le[:, sel] *= self.lamp_shaders.at_sample(lk, ox[sel], oy[sel], oz[sel], dx[sel], dy[sel], dz[sel],
                                                          t[sel], sphere)
        return t, pdf, le


def _ray_uniform(ox, oy, oz, dx, dy, dz) -> np.ndarray:
    """(N,) float32 in [0, 1): a hash of each ray's bits. Deterministic (every thread count gives the
    same image) and independent of the path's own random numbers for the purpose it serves."""
    bits = [np.ascontiguousarray(a, np.float32).view(np.uint32) for a in (ox, oy, oz, dx, dy, dz)]
    x, y = pcg2d(bits[0] ^ bits[3], bits[1] ^ bits[4])
    x, y = pcg2d(x ^ bits[2], y ^ bits[5])
    return to_unit_float(x)


def _met_in_turn(ray, t, n: int, budget):
    """Candidates sorted by ray, then distance t (float32): which a ray meets in turn (mask), and how many
    each of the n rays meets, (N,) int32. A candidate is met when it lies beyond the next float after the
    last one met; a ray stops meeting lights at max(budget, 1) (None: no limit)."""
    met = np.zeros(len(ray), bool)
    crossed = np.zeros(n, np.int32)
    if not len(ray):
        return met, crossed
    starts = np.flatnonzero(np.r_[True, ray[1:] != ray[:-1]])
    sizes = np.diff(np.r_[starts, len(ray)])
    rays = ray[starts]
    limit = sizes if budget is None else np.minimum(sizes, np.maximum(np.take(budget, rays), 1))
    last = np.full(len(starts), -np.inf, np.float32)
    count = np.zeros(len(starts), np.int64)
    group = np.arange(len(starts))
    rank = 0
    while len(group):
        at = starts[group] + rank
        beyond = t[at] > np.nextafter(last[group], np.float32(np.inf))
        met[at[beyond]] = True
        took = group[beyond]
        last[took] = t[at[beyond]]
        count[took] += 1
        rank += 1
        group = group[(rank < sizes[group]) & (count[group] < limit[group])]
    crossed[rays] = count
    return met, crossed


def _choose_per_ray(ray, weight, u):
    """Candidates sorted by ray, weight > 0 each, u one uniform per candidate (its ray's): one candidate
    per ray, chosen with probability weight / (sum of its ray's weights). Returns (indices of the
    chosen candidates, their probabilities)."""
    starts = np.flatnonzero(np.r_[True, ray[1:] != ray[:-1]])
    counts = np.diff(np.r_[starts, len(ray)])
    cum = np.cumsum(weight)
    before = np.repeat(np.r_[0.0, cum[starts[1:] - 1]], counts)   # sum of the weights of earlier rays
    total = np.repeat(np.add.reduceat(weight, starts), counts)
    below = (cum - weight - before) <= u * total                    # True, ..., True, False, ... per ray
    chosen = starts + np.maximum(np.add.reduceat(below.astype(np.int64), starts) - 1, 0)
    return chosen, weight[chosen] / total[chosen]


def _object_totals(scene, candidates, plain_ids, instanced_corners, material_estimate, own):
    """(group (G,), energy (G,), lo (G, 3), hi (G, 3)) float64 of each emitting object (selection.groups_of_triangles)
    over all its light-sampled triangles, dark texels included, as Cycles' tree measures a mesh emitter: the sum of
    area x the mean of |R|, |G|, |B| of the material's estimate (each triangle's own emission where not known), and
    the box of its triangles. Light samples still go to the triangles that emit only (LightSampler)."""
    corners = scene.positions[plain_ids].astype(np.float64)
    if len(instanced_corners):
        corners = np.concatenate([corners, instanced_corners])
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    emission = np.where(np.isnan(material_estimate[:, :1]), own, material_estimate)
    group = selection.groups_of_triangles(scene, candidates)
    keys, inverse = np.unique(group, return_inverse=True)
    energy = np.bincount(inverse, area * np.abs(emission).mean(axis=1), minlength=len(keys))
    lo, hi = np.full((len(keys), 3), np.inf), np.full((len(keys), 3), -np.inf)
    np.minimum.at(lo, inverse, corners.min(axis=1))
    np.maximum.at(hi, inverse, corners.max(axis=1))
    return keys, energy, lo, hi
