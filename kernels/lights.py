"""Next-event estimation: choosing a light, sampling it, and the pdfs MIS needs.

Three kinds of emitters share one discrete distribution: Blender lights (the Lights table), emissive
triangles (materials with emission) and the world. Local emitters (point, spot and area lights,
triangles) are chosen in proportion to their power (W); distant ones (suns and the world), whose power
is a flux per unit area, share DISTANT_SHARE of the choices, among themselves in proportion to their
irradiance. No scene size enters the choice: a far-away ground plane changes nothing.
With two or more local emitters whose choice per point would differ from that (TREE_MIN_EMITTERS,
TREE_MIN_DIVERGENCE), their share is instead split per shading point by a light tree
(kernels.light_tree): nearby lamps facing the point are chosen more often; among two to
SOLID_ANGLE_MAX_EMITTERS emissive triangles alone (a quad lamp), by the solid angle each subtends at the
point (SolidAngleChoice). The probability of choosing emitter e at point p is then
selection_pmf(e, p), which the MIS pdfs of BSDF rays use with the ray's origin; otherwise it is
select_pmf[e] everywhere.
`sample` returns, per shading point, a direction toward a point on the chosen light, the distance to
it, the radiance arriving along it and its pdf per unit solid angle *including the probability of
choosing that light*, so MIS weights compare like with like. Delta lights (zero-size point and spot,
zero-angle sun) return their irradiance-producing term with pdf = selection probability.

Conventions of the Lights table (see scene.Lights): Blender lights shine down their local -Z, so
the sun lies along +Z and an area light emits toward -Z only. Emissive triangles emit from both sides,
as Cycles' mesh lights do.
"""
from __future__ import annotations

import numpy as np

from . import sampling
from .accel import Accel
from .environment import Environment
from .rng import pcg2d, to_unit_float
from .geometry import emissive_instanced, scene_extent
from .light_tree import LightTree
from .scene import LIGHT_KINDS, SceneArrays
from .textures import luminance
from .vec import PI, cross_xyz, dot_xyz, normalize_floored_xyz

POINT, SPOT, SUN, RECT, DISK = (LIGHT_KINDS[k] for k in ("POINT", "SPOT", "SUN", "RECT", "DISK"))
# An emissive triangle is sampled by the solid angle it subtends from points nearer its plane than its
# longest edge, and by area from farther points, where the two pdfs hardly differ and area sampling costs
# a fifth: the comparison Cycles' comment describes (kernel/light/triangle.h). Cycles' code divides the
# distance by twice the triangle's area as well (N unnormalised), so its reach grows with the triangle's
# size: 0.18 instead of 0.71 from the Cornell box's lamp halves; measured there, 0.5% more variance per
# sample for 3% less time. This rule does not depend on the scene's scale. Below this solid angle a
# triangle is sampled by area whatever the distance: tiny spherical triangles lose float precision.
SPHERICAL_MIN_SR = 1e-3
# When a scene has both local and distant emitters, the distant ones (suns, world) get this share of
# the light choices. It cannot come from comparing powers: a sun's or the world's power is per unit
# area, and turning it into watts takes an arbitrary area (the scene's bounding sphere made a 1 km floor
# starve the lamps). Cycles' light tree weighs distant lights at its root by their own importance,
# not by the scene's size, too; a fixed half is never more than 2x from the best split for either side.
DISTANT_SHARE = 0.5
# With more lights with a surface than this, BSDF rays find the lights they cross through Embree
# (LightProxies) instead of testing every light.
PROXY_MIN_LIGHTS = 8
# A ray crosses at most this many proxy faces (two per light it passes): a ray along which more than
# half this many lights overlap misses the rest.
MAX_PROXY_CROSSINGS = 1024
# With at least this many local emitters (point, spot and area lights, emissive triangles, with power)
# the local ones may be chosen per shading point by a light tree (kernels.light_tree), as Cycles always
# does; a single one needs no choice. The walk costs a few NumPy passes per level (the 200-lamp bench
# scene: 1.5 against 1.6-1.9 M paths/s, for a third of the variance per sample). A few lamps gain the
# most (kernel, 32x32, 128 spp, two bounces, against the power pmf: variance per sample 0.26x with a
# three-point set-up of two area lights and a point light, 0.07x with two point lamps over a floor, 0.09x
# with four area lights; time +10-25%). Until stop 23 the bound was 16, to keep few-light scenes' images.
TREE_MIN_EMITTERS = 2
# From two to this many local emitters, all emissive triangles (a lamp modelled as a quad, say), each
# shading point chooses among them in proportion to the light each sends it: luminance times the solid
# angle it subtends there, computed exactly (SolidAngleChoice), instead of by the tree's bounds. The power
# pmf sends half the samples of a point beside the lamp's near half to its far half. The Cornell box's
# quad lamp: 24% less variance per sample for 4-6% more time.
SOLID_ANGLE_MAX_EMITTERS = 4
# ... and, for the triangles of a single emissive object, only where its choices differ from the power
# pmf's: at probe points in the scene's box, the total variation distance between the two pmfs (estimated
# from the tree's own samples) must reach this. Several lights, or lights and emissive objects, always
# get the tree, as in Cycles: over a large floor the probes miss the few places where a lamp must win
# against the emissive mesh beside it (a lamp inside an emissive glass shade scored 0.09, and the power
# pmf gave the lamp 1% of the samples there against the tree's 19%).
# Measured (1 thread, 16k-path waves, 8 bounces): the Cornell box's lamp cut into 8-200 triangles scores
# 0.06-0.07, and the tree renders it at 0.74-0.98x the efficiency (1 / (variance x time)) of the power
# pmf; a whole-ceiling panel of 8-200 triangles 0.15-0.18, and 1.1x (72 and 200 triangles); 8-200 lamps
# spread over a floor (tests/test_light_tree.py) 0.31-0.35, and 1.4-7x; bench/vs_cycles.py's 200 lamps 0.29.
TREE_MIN_DIVERGENCE = 0.1
# Probe points and tree samples per probe for that estimate (fixed seed: the choice is deterministic).
_TREE_PROBES, _TREE_PROBE_SAMPLES = 256, 64
# Columns of the emissive-triangle table: corner 0, two edges, unit normal, area, mean radiance.
_TP0, _TE1, _TE2, _TN, _TAREA, _TLE = 0, 3, 6, 9, 12, 13
_TRI_ROWS = 16


def smoothstep01(x):
    x = np.clip(x, np.float32(0.0), np.float32(1.0))
    return x * x * (np.float32(3.0) - np.float32(2.0) * x)


class LightSample:
    """Per shading point: unit direction (wx, wy, wz), distance (inf for the world and the sun),
    radiance (3, N) arriving along it, pdf (N,) per unit solid angle times the selection probability,
    delta (N,) bool for lights no BSDF ray can hit, world (N,) bool for samples of the world, shadowed (N,)
    bool: surfaces can block the sample (False for a light with Cast Shadow off)."""
    __slots__ = ("wx", "wy", "wz", "dist", "radiance", "pdf", "delta", "world", "shadowed")

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
    the lights met (each a transparent bounce); stopped (N,) bool, the path ends at its last light."""
    __slots__ = ("hit", "radiance", "pdf", "crossed", "stopped")

    def __init__(self, n: int):
        self.hit = np.zeros(n, bool)
        self.radiance = np.zeros((3, n), np.float32)
        self.pdf = np.zeros(n, np.float32)
        self.crossed = np.zeros(n, np.int32)
        self.stopped = np.zeros(n, bool)


class LightSampler:
    """All emitters of a scene and one power-proportional distribution over them.

    Entities are numbered: Blender lights [0, L), emissive triangles [L, L + E), then the world.
    """

    def __init__(self, scene: SceneArrays, environment: Environment, triangle_emission):
        """triangle_emission: the emissive materials. triangle_emission(tri_ids) -> (3, n) mean emitted radiance
        of those triangles (textures averaged); triangle_emission(tri_ids, b1, b2, toward) -> (3, n) radiance
        at barycentrics (b1, b2) toward -toward; .emissive (M,) bool, the materials that emit;
        .varies (M,) bool, those whose emission changes over the surface or with the direction."""
        lights = scene.lights
        self.environment = environment
        self.light_count = lights.count
        self.kind = lights.kind
        self.shadowed = lights.shadowed()
        self.position = lights.position.astype(np.float32)
        self.axes = lights.frame.astype(np.float32)              # (L, 3, 3): columns x, y, z
        self.radiance_of = lights.radiance.astype(np.float32)
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
        self.sun_discs = np.flatnonzero((self.kind == SUN) & cone & (self.radiance_of.max(axis=1) > 0)) \
            if self.light_count else np.zeros(0, np.int64)
        self.area = np.where(self.kind == RECT, self.size[:, 0] * self.size[:, 1],
                             np.float32(np.pi / 4) * self.size[:, 0] * self.size[:, 1]).astype(np.float32)

        # Emissive triangles: two-sided, uniform over their area.
        emits = np.asarray(triangle_emission.emissive, bool)
        # Triangles of moving objects (motion blur) are left to BSDF rays, which find them where they are
        # at the path's time (with MIS weight 1: their light pdf is 0); the table would place them wrong.
        sampled = emits[scene.material_ids]
        if scene.has_motion and scene.motion_ids is not None:
            sampled &= scene.motion_ids < 0
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
        estimate = _emission_estimates(triangle_emission, candidates,
                                       np.concatenate([scene.material_ids[plain_ids], instanced_materials]), varies)
        keep = np.abs(estimate).max(axis=1, initial=0.0) > 0
        n_plain = len(plain_ids)
        plain_ids, estimate = plain_ids[keep[:n_plain]], estimate[keep]
        instanced_ids, instanced_corners = instanced_ids[keep[n_plain:]], instanced_corners[keep[n_plain:]]
        instanced_materials = instanced_materials[keep[n_plain:]]
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
        self._plain_count = scene.triangle_count
        self._has_instances = scene.instances is not None and scene.instances.count > 0
        self._instanced_emitters = len(instanced_ids) > 0
        # Triangles whose emission varies (a texture, layers above it) are evaluated at the sampled point.
        materials = np.concatenate([scene.material_ids[plain_ids], instanced_materials])
        self.tri_textured = bool(varies[materials].any())
        # One row per emissive triangle, gathered whole (rows of a (E, K) table gather fastest).
        table = np.zeros((len(self.tri_ids), _TRI_ROWS), np.float32)
        table[:, _TP0:_TP0 + 3] = p[:, 0]
        table[:, _TE1:_TE1 + 3] = e1
        table[:, _TE2:_TE2 + 3] = e2
        table[:, _TN:_TN + 3] = cross / np.maximum(2 * tri_area, 1e-300)[:, None]
        table[:, _TAREA] = tri_area
        self._tri_table = table
        # Squared longest edge of each emissive triangle: the reach of its solid-angle sampling.
        self._tri_reach2 = np.max(np.stack([(e1 * e1).sum(1), (e2 * e2).sum(1), ((e2 - e1) ** 2).sum(1)]),
                                  axis=0).astype(np.float32) if len(self.tri_ids) else np.zeros(0, np.float32)
        self.triangle_emission = triangle_emission
        table[:, _TLE:_TLE + 3] = estimate

        surface = ((self.kind == RECT) | (self.kind == DISK) | (((self.kind == POINT) | (self.kind == SPOT))
                                                                 & (self.radius > 0)))
        self.has_surface_lights = bool(surface.any())
        self.surface_ids = np.flatnonzero(surface)
        self._proxy = (LightProxies(self.surface_ids, self.kind, self.position, self.radius, self.size)
                       if len(self.surface_ids) > PROXY_MIN_LIGHTS else None)
        power = np.concatenate([self._light_power(), self._triangle_power(), [self._world_power()]])
        power = np.where(np.isfinite(power) & (power > 0), power, 0.0)
        self.world_index = self.light_count + len(self.tri_ids)
        self.has_lights = power.sum() > 0
        self.select_pmf = _selection_pmf(power, self._distant_mask())
        self._cdf = np.cumsum(self.select_pmf)
        if self.has_lights:
            self._cdf /= self._cdf[-1]
        self.pmf32 = self.select_pmf.astype(np.float32)
        self.tree_divergence = 0.0
        self._tree = self._light_tree(power, scene) if self.has_lights else None

    @property
    def instanced_emitters(self) -> bool:
        """Some emissive triangles belong to instances: the table moves with them (a new sampler then)."""
        return self._instanced_emitters

    # ------------------------------------------------------------------ power estimates
    def _light_power(self) -> np.ndarray:
        lum = luminance(self.radiance_of).astype(np.float64) if self.light_count else np.zeros(0)
        r2 = self.radius.astype(np.float64) ** 2
        # Sized point lights act as a disk of radiance L facing every point: intensity L pi r^2.
        sphere = np.where(r2 > 0, lum * np.pi * r2, lum) * 4 * np.pi
        cone = (1.0 - 0.5 * (self.spot[:, 0] + np.minimum(1.0, self.spot[:, 0] + self.spot[:, 1]))).astype(np.float64)
        spot = sphere * np.clip(cone, 1e-4, 1.0) / 2.0
        sun = lum  # irradiance (W/m^2): compared with the world's only (see DISTANT_SHARE)
        area = lum * self.area * np.pi
        return np.select([self.kind == POINT, self.kind == SPOT, self.kind == SUN], [sphere, spot, sun], area)

    def _triangle_power(self) -> np.ndarray:
        if not len(self.tri_ids):
            return np.zeros(0)
        lum = luminance(self._tri_table[:, _TLE:_TLE + 3]).astype(np.float64)
        return 2.0 * np.pi * self.tri_area * lum

    def _world_power(self) -> float:
        """In the sun's unit (W/m^2): the world's flux into a sphere over the sphere's cross-section. 0 for a
        world of one colour in every direction, which, as in Cycles (LightManager's background light needs a
        spatially varying world), is no light: BSDF rays find it, with MIS weight 1, and next-event
        estimation spends its samples on the lamps (a constant grey world took half of them)."""
        if not self.environment.varies:
            return 0.0
        return float(4 * np.pi * self.environment.mean_luminance())

    def _distant_mask(self) -> np.ndarray:
        """(L + E + 1,) bool: the emitters whose power is per unit area (suns and the world)."""
        return np.concatenate([self.kind == SUN, np.zeros(len(self.tri_ids), bool), [True]])

    # ------------------------------------------------------------------ the light tree
    def _light_tree(self, power, scene):
        """How shading points choose among the local emitters with power, when not by the global pmf: a
        SolidAngleChoice among two to SOLID_ANGLE_MAX_EMITTERS emissive triangles; a LightTree over
        TREE_MIN_EMITTERS or more emitters whose choices differ enough from the global pmf's
        (TREE_MIN_DIVERGENCE, measured at points in the box of the scene's triangles); else None. Also the
        distant emitters' own distribution for the points that choose one."""
        distant = self._distant_mask()
        local = np.flatnonzero(~distant & (power > 0))
        few = 2 <= len(local) <= SOLID_ANGLE_MAX_EMITTERS and bool((local >= self.light_count).all())
        if len(local) < TREE_MIN_EMITTERS and not few:
            return None
        self._distant_ids = np.flatnonzero(distant & (self.select_pmf > 0))
        # Exactly 1 without distant emitters: a rounded sum would send a few points to none.
        self._local_share = float(self.select_pmf[local].sum()) if len(self._distant_ids) else 1.0
        self._tree_ids = local
        self._tree_slot = np.full(len(power), -1, np.int64)
        self._tree_slot[local] = np.arange(len(local))
        self._distant_cdf = np.cumsum(self.select_pmf[self._distant_ids])
        if len(self._distant_cdf):
            self._distant_cdf /= self._distant_cdf[-1]
        if few:
            return SolidAngleChoice(np.take(self._tri_table, local - self.light_count, axis=0), power[local])
        lo, hi = np.zeros((len(local), 3)), np.zeros((len(local), 3))
        axis, spread = np.zeros((len(local), 3)), np.full(len(local), np.pi)
        is_light = local < self.light_count
        k = local[is_light]
        c = self.position[k].astype(np.float64)
        area = (self.kind[k] == RECT) | (self.kind[k] == DISK)
        x, y = self.axes[k, :, 0].astype(np.float64), self.axes[k, :, 1].astype(np.float64)
        half = np.where(area[:, None], np.abs(x) * (0.5 * self.size[k, 0:1]) + np.abs(y) * (0.5 * self.size[k, 1:2]),
                        self.radius[k, None].astype(np.float64))
        lo[is_light], hi[is_light] = c - half, c + half
        # Area lights emit toward their -Z only; point and spot lights (conservatively) every way.
        axis[is_light] = np.where(area[:, None], -self.axes[k, :, 2], np.float64([0, 0, 1]))
        spread[is_light] = np.where(area, 0.0, np.pi)
        t = np.take(self._tri_table, local[~is_light] - self.light_count, axis=0).astype(np.float64)
        p0 = t[:, _TP0:_TP0 + 3]
        corners = np.stack([p0, p0 + t[:, _TE1:_TE1 + 3], p0 + t[:, _TE2:_TE2 + 3]])
        lo[~is_light], hi[~is_light] = corners.min(axis=0), corners.max(axis=0)
        axis[~is_light] = t[:, _TN:_TN + 3]  # two-sided: spread pi, every way
        group = np.full(len(local), -1, np.int64)
        group[~is_light] = self._triangle_groups(scene, local[~is_light] - self.light_count)
        tree = LightTree(lo, hi, power[local], axis, spread, group)
        has_geometry = len(scene.positions) or (scene.instances is not None and scene.instances.count)
        box = scene_extent(scene) if has_geometry else None
        self.tree_divergence = _divergence(tree, self.select_pmf[local] / self._local_share, box)
        return tree if tree.units > 1 or self.tree_divergence >= TREE_MIN_DIVERGENCE else None

    def _triangle_groups(self, scene, rows) -> np.ndarray:
        """(m,) int64 group of the emissive triangles at rows of the table: their object (their material when
        the scene has no object table), or their instance; the light tree keeps each group together."""
        tri = self.tri_ids[rows]
        plain = tri < self._plain_count
        by = scene.object_ids if scene.object_ids is not None else scene.material_ids
        group = np.zeros(len(tri), np.int64)
        group[plain] = np.take(by, tri[plain])
        if not plain.all():
            bases = scene.instances.bases(self._plain_count)
            offset = int(np.max(by, initial=-1)) + 1
            group[~plain] = offset + np.searchsorted(bases, tri[~plain], side="right") - 1
        return group

    @property
    def uses_tree(self) -> bool:
        return isinstance(self._tree, LightTree)

    @property
    def selection(self) -> str:
        """How shading points choose among the local emitters: "power" (one pmf everywhere), "tree" (a
        light tree per point) or "solid angle" (SolidAngleChoice per point)."""
        if self._tree is None:
            return "power"
        return "tree" if isinstance(self._tree, LightTree) else "solid angle"

    def choose_at(self, u_select, px, py, pz):
        """(emitter (n,) int64, selection probability (n,) float32) per shading point p: the light tree
        for the local emitters (their DISTANT_SHARE complement), the distant ones by their fixed pmf.
        Without a tree, choose() and select_pmf."""
        if self._tree is None:
            chosen = self.choose(u_select)
            return chosen, np.take(self.pmf32, chosen)
        u = u_select.astype(np.float64)
        share = self._local_share
        chosen = np.zeros(len(u), np.int64)
        select = np.zeros(len(u), np.float64)
        local = np.flatnonzero(u < share) if share < 1 else np.arange(len(u))
        if len(local):
            e, pmf = self._tree.sample(u[local] / share, px[local], py[local], pz[local])
            chosen[local] = self._tree_ids[e]
            select[local] = share * pmf
        if share < 1:
            far = np.flatnonzero(u >= share)
            if len(far):
                ud = (u[far] - share) / (1.0 - share)
                j = np.minimum(np.searchsorted(self._distant_cdf, ud, side="right"), len(self._distant_ids) - 1)
                chosen[far] = self._distant_ids[j]
                select[far] = self.select_pmf[chosen[far]]
        return chosen, select.astype(np.float32)

    def selection_pmf(self, emitter, px, py, pz):
        """(n,) float32 probability that NEE at point p chooses emitter (any index but the world's)."""
        if self._tree is None:
            return np.take(self.pmf32, emitter)
        slot = np.take(self._tree_slot, emitter)
        local = self._tree.pmf(slot, px, py, pz) * self._local_share
        return np.where(slot >= 0, local, np.take(self.select_pmf, emitter)).astype(np.float32)

    # ------------------------------------------------------------------ sampling
    def choose(self, u_select: np.ndarray) -> np.ndarray:
        """(n,) int64 emitter index per number in [0, 1): lights, then emissive triangles, then the world,
        each with probability select_pmf."""
        if len(self._cdf) == 1:
            return np.zeros(len(u_select), np.int64)
        # float64: a float32 cdf would round the intervals of millions of small emitters.
        return np.minimum(np.searchsorted(self._cdf, u_select.astype(np.float64), side="right"), len(self._cdf) - 1)

    def sample(self, px, py, pz, u_select, u1, u2, focus=None) -> LightSample:
        """Choose an emitter for each shading point p and sample a direction toward it. focus: the world's
        (environment.WorldFocus per shading point) when its light samples focus on glossy lobes."""
        n = len(px)
        out = LightSample(n)
        if not self.has_lights or n == 0:
            return out
        chosen, select = self.choose_at(u_select, px, py, pz)
        if not self.shadowed.all():
            lamp = chosen < self.light_count
            out.shadowed = ~lamp | np.take(self.shadowed, np.where(lamp, chosen, 0))
        if self.light_count:
            for kind, method in ((POINT, self._sample_sphere), (SPOT, self._sample_sphere),
                                 (SUN, self._sample_sun), (RECT, self._sample_area), (DISK, self._sample_area)):
                idx = np.flatnonzero((chosen < self.light_count) & (np.take(self.kind, np.minimum(chosen, self.light_count - 1)) == kind))
                if len(idx):
                    method(out, idx, chosen[idx], px[idx], py[idx], pz[idx], u1[idx], u2[idx])
        tri = np.flatnonzero((chosen >= self.light_count) & (chosen < self.world_index))
        if len(tri):
            self._sample_triangle(out, tri, chosen[tri] - self.light_count, px[tri], py[tri], pz[tri], u1[tri], u2[tri])
        if self.select_pmf[self.world_index] > 0:
            world = np.flatnonzero(chosen == self.world_index)
            if len(world):
                self._sample_world(out, world, u1[world], u2[world], None if focus is None else focus.take(world))
        out.pdf *= select
        return out

    def _axis(self, light, k):
        """(3, n) world direction of the chosen lights' local axis k."""
        return self.axes[light, :, k].T

    def _sample_sphere(self, out, idx, light, px, py, pz, u1, u2):
        """Point and spot lights. With a radius, Cycles lights a point as a uniform disk of that radius
        facing it (checked against Cycles 5.0.1 on and off axis); without, they are delta lights."""
        c = self.position[light].T
        dx, dy, dz = c[0] - px, c[1] - py, c[2] - pz
        d2 = dx * dx + dy * dy + dz * dz
        inv = np.float32(1.0) / np.sqrt(np.maximum(d2, np.float32(1e-30)))
        ax, ay, az = dx * inv, dy * inv, dz * inv            # from the point toward the light
        r = self.radius[light]
        delta = r <= 0
        # A uniform point on the disk through c, perpendicular to the axis.
        ex, ey = sampling.sample_uniform_disk(u1, u2)
        tx, ty, tz, bx, by, bz = sampling.orthonormal_basis(ax, ay, az)
        qx = c[0] + r * (ex * tx + ey * bx)
        qy = c[1] + r * (ex * ty + ey * by)
        qz = c[2] + r * (ex * tz + ey * bz)
        wx, wy, wz, dist = _direction(px, py, pz, qx, qy, qz)
        cos_l = wx * ax + wy * ay + wz * az
        pdf = _area_to_solid_angle(PI * r * r, dist, cos_l)
        # The spot cone is evaluated along the sampled ray, as Cycles does (this softens its edge).
        radiance = self.radiance_of[light].T * self._spot_attenuation(light, -wx, -wy, -wz)[None, :]
        # Delta lights: the exact direction, radiance becomes intensity / distance^2.
        dist_c = np.sqrt(d2)
        wx, wy, wz = np.where(delta, ax, wx), np.where(delta, ay, wy), np.where(delta, az, wz)
        dist = np.where(delta, dist_c, dist)
        radiance = np.where(delta[None, :], radiance / np.maximum(d2, np.float32(1e-30))[None, :], radiance)
        pdf = np.where(delta, np.float32(1.0), pdf)
        out.set(idx, wx, wy, wz, dist, radiance, pdf, delta)

    def _spot_attenuation(self, light, vx, vy, vz):
        """Cycles' spot cone: smoothstep of (cos - cos_half) / (blend width); 1 for point lights.
        v is the unit direction from the light toward the point."""
        is_spot = self.kind[light] == SPOT
        zx, zy, zz = self._axis(light, 2)
        cos = -(vx * zx + vy * zy + vz * zz)
        cos_half, width = self.spot[light, 0], self.spot[light, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            soft = smoothstep01((cos - cos_half) / width)
        att = np.where(width > 0, soft, (cos > cos_half).astype(np.float32))
        return np.where(is_spot, att, np.float32(1.0)).astype(np.float32)

    def _sample_sun(self, out, idx, light, px, py, pz, u1, u2):
        zx, zy, zz = self._axis(light, 2)  # toward the sun
        cos_max = self.sun_cos[light]
        delta = cos_max >= np.float32(1.0)
        lx, ly, lz = sampling.sample_uniform_cone(u1, u2, cos_max)
        wx, wy, wz = sampling.local_to_world(lx, ly, lz, zx, zy, zz)
        wx, wy, wz = np.where(delta, zx, wx), np.where(delta, zy, wy), np.where(delta, zz, wz)
        pdf = np.where(delta, np.float32(1.0), sampling.uniform_cone_pdf(np.minimum(cos_max, np.float32(1 - 1e-7))))
        out.set(idx, wx, wy, wz, np.float32(np.inf), self.sun_radiance[light].T, pdf, delta)

    def _sample_area(self, out, idx, light, px, py, pz, u1, u2):
        """Rectangles uniformly in the solid angle they subtend, disks uniformly in their area, as Cycles
        samples them (kernel/light/area.h): the MIS weights, and so what overlapping lamps add up to
        (intersect), are Cycles'."""
        sx, sy = self.size[light, 0], self.size[light, 1]
        disk = self.kind[light] == DISK
        dx_, dy_ = sampling.sample_uniform_disk(u1, u2)
        a = dx_ * np.float32(0.5) * sx
        b = dy_ * np.float32(0.5) * sy
        c = self.position[light].T
        xa, ya, za = self._axis(light, 0), self._axis(light, 1), self._axis(light, 2)
        qx = c[0] + a * xa[0] + b * ya[0]
        qy = c[1] + a * xa[1] + b * ya[1]
        qz = c[2] + a * xa[2] + b * ya[2]
        rect = np.flatnonzero(~disk)
        if len(rect):
            spherical = self._rectangles(light[rect], px[rect], py[rect], pz[rect])
            q = spherical.sample(u1[rect], u2[rect])
            qx[rect], qy[rect], qz[rect] = q
        wx, wy, wz, dist = _direction(px, py, pz, qx, qy, qz)
        cos_l = wx * za[0] + wy * za[1] + wz * za[2]  # > 0: the point is on the emitting (-Z) side
        pdf = _area_to_solid_angle(self.area[light], dist, cos_l)
        if len(rect):
            pdf[rect] = spherical.pdf(dist[rect], cos_l[rect])
        radiance = np.where(cos_l > 0, self.radiance_of[light].T, np.float32(0.0))
        out.set(idx, wx, wy, wz, dist, radiance, pdf)

    def _rectangles(self, light, px, py, pz) -> sampling.SphericalRectangle:
        """Rectangular lights as seen from points p."""
        c, xa, ya = self.position[light].T, self._axis(light, 0), self._axis(light, 1)
        return sampling.SphericalRectangle((px, py, pz), tuple(c), tuple(xa), tuple(ya),
                                           self.size[light, 0], self.size[light, 1])

    def _sample_triangle(self, out, idx, slot, px, py, pz, u1, u2):
        """A point on an emissive triangle: uniform in the solid angle it subtends from points near it
        (bounded variance next to a light; _spherical_choice), else uniform in its area."""
        g = np.take(self._tri_table, slot, axis=0).T
        spherical, omega, corners = self._spherical_choice(g, slot, px, py, pz)
        n = len(slot)
        wx, wy, wz, dist, pdf, b1, b2 = (np.empty(n, np.float32) for _ in range(7))
        far = np.flatnonzero(~spherical)
        if len(far):
            ga = g[:, far]
            su = np.sqrt(u1[far])
            b1[far] = a1 = np.float32(1.0) - su
            b2[far] = a2 = u2[far] * su
            qx = ga[_TP0] + a1 * ga[_TE1] + a2 * ga[_TE2]
            qy = ga[_TP0 + 1] + a1 * ga[_TE1 + 1] + a2 * ga[_TE2 + 1]
            qz = ga[_TP0 + 2] + a1 * ga[_TE1 + 2] + a2 * ga[_TE2 + 2]
            fx, fy, fz, fd = _direction(px[far], py[far], pz[far], qx, qy, qz)
            wx[far], wy[far], wz[far], dist[far] = fx, fy, fz, fd
            cos_l = np.abs(fx * ga[_TN] + fy * ga[_TN + 1] + fz * ga[_TN + 2])
            pdf[far] = _area_to_solid_angle(ga[_TAREA], fd, cos_l)
        sph = np.flatnonzero(spherical)
        if len(sph):
            a, b, c = corners
            sx, sy, sz = _sample_spherical_triangle(a, b, c, omega, u1[sph], u2[sph])
            nx, ny, nz = g[_TN, sph], g[_TN + 1, sph], g[_TN + 2, sph]
            denom = sx * nx + sy * ny + sz * nz
            rx, ry, rz = (g[_TP0 + k, sph] - (px, py, pz)[k][sph] for k in range(3))
            # A direction grazing the triangle's plane (possible only by rounding) finds no point on it.
            valid = np.abs(denom) > np.float32(1e-7)
            t = (rx * nx + ry * ny + rz * nz) / np.where(valid, denom, np.float32(1.0))
            valid &= t > 0
            wx[sph], wy[sph], wz[sph] = sx, sy, sz
            dist[sph] = np.where(valid, t, np.float32(0.0))
            pdf[sph] = np.where(valid, np.float32(1.0) / omega, np.float32(0.0))
            if self.tri_textured:  # barycentrics of the point hit, for the texture lookup
                b1[sph], b2[sph] = _barycentrics((sx * t - rx, sy * t - ry, sz * t - rz),
                                                 g[_TE1:_TE1 + 3, sph], g[_TE2:_TE2 + 3, sph])
        if self.tri_textured:
            radiance = self.triangle_emission(np.take(self.tri_ids, slot), b1, b2, (wx, wy, wz))
        else:
            radiance = g[_TLE:_TLE + 3]
        out.set(idx, wx, wy, wz, dist, radiance, pdf)

    def _spherical_choice(self, g, slot, px, py, pz):
        """Which points sample their triangle (slot, its table rows g) by solid angle: those nearer its
        plane than its longest edge where it subtends more than SPHERICAL_MIN_SR.
        Returns (spherical (n,) bool, and for the spherical points only, in order: the solid angle and
        the unit vectors toward the three corners, each a tuple of x, y, z arrays)."""
        ax, ay, az = g[_TP0] - px, g[_TP0 + 1] - py, g[_TP0 + 2] - pz
        h = ax * g[_TN] + ay * g[_TN + 1] + az * g[_TN + 2]
        near = np.flatnonzero(h * h < np.take(self._tri_reach2, slot))
        spherical = np.zeros(len(h), bool)
        if not len(near):
            return spherical, np.zeros(0, np.float32), None
        ax, ay, az = ax[near], ay[near], az[near]
        e1, e2 = (tuple(g[k, near] for k in range(r, r + 3)) for r in (_TE1, _TE2))
        a = normalize_floored_xyz((ax, ay, az))
        b = normalize_floored_xyz((ax + e1[0], ay + e1[1], az + e1[2]))
        c = normalize_floored_xyz((ax + e2[0], ay + e2[1], az + e2[2]))
        omega = _solid_angle(a, b, c)
        keep = omega > SPHERICAL_MIN_SR
        spherical[near[keep]] = True
        if not keep.all():
            omega = omega[keep]
            a, b, c = (tuple(comp[keep] for comp in v) for v in (a, b, c))
        return spherical, omega, (a, b, c)

    def _sample_world(self, out, idx, u1, u2, focus=None):
        wx, wy, wz, pdf = self.environment.sample_direction(u1, u2, focus)
        out.set(idx, wx, wy, wz, np.float32(np.inf), self.environment.radiance(wx, wy, wz), pdf)
        out.world[idx] = True

    # ------------------------------------------------------------------ pdfs of what BSDF rays find
    def pdf_triangle_hit(self, tri, dist, cos_l, ox, oy, oz) -> np.ndarray:
        """pdf (solid angle, with selection) with which NEE from the ray origin o would have sampled
        this point of emissive triangle tri (zero for triangles that do not emit)."""
        if not len(self.tri_ids):
            return np.zeros(len(tri), np.float32)
        slot = self._slots(tri)
        ok = slot >= 0
        s = np.maximum(slot, 0)
        pmf = self.selection_pmf(self.light_count + s, ox, oy, oz)
        g = np.take(self._tri_table, s, axis=0).T
        spherical, omega, _ = self._spherical_choice(g, s, ox, oy, oz)
        pdf = _area_to_solid_angle(g[_TAREA], dist, np.abs(cos_l))
        pdf[spherical] = np.float32(1.0) / omega
        return np.where(ok, pmf * pdf, np.float32(0.0))

    def _slots(self, tri: np.ndarray) -> np.ndarray:
        """Each scene triangle's position in the emissive list, -1 for triangles that do not emit."""
        if not self._has_instances:
            return np.take(self.tri_slot, tri)
        plain = tri < self._plain_count
        slot = np.full(len(tri), -1, np.int32)
        if self._plain_count:
            slot = np.where(plain, np.take(self.tri_slot, np.where(plain, tri, 0)), slot)
        if self._instanced_emitters:
            found = np.minimum(np.searchsorted(self.tri_ids, tri), len(self.tri_ids) - 1)
            slot = np.where(~plain & (np.take(self.tri_ids, found) == tri), found, slot)
        return slot.astype(np.int32, copy=False)

    def samples_world(self) -> bool:
        """Whether next-event estimation can choose the world."""
        return self.has_lights and self.select_pmf[self.world_index] > 0

    def suns_seen(self, dx, dy, dz, bsdf_pdf=None):
        """(3, n) radiance of the sun discs that rays leaving the scene along d (x, y, z of (n,)) look into, each
        weighed by MIS (power heuristic) against its own light samples given the pdf of the BSDF sample that
        chose d (None: not weighed, as after a singular bounce), as Cycles' escaped rays see suns; None when
        the scene has no sun with a disc."""
        if not len(self.sun_discs):
            return None
        out = np.zeros((3, len(dx)), np.float32)
        for k in self.sun_discs:
            zx, zy, zz = self.axes[k, :, 2]
            inside = np.flatnonzero(dx * zx + dy * zy + dz * zz >= self.sun_cos[k])
            if not len(inside):
                continue
            weight = np.ones(len(inside), np.float32)
            if bsdf_pdf is not None and self.select_pmf[k] > 0:
                light_pdf = np.float32(self.select_pmf[k]) * sampling.uniform_cone_pdf(self.sun_cos[k])
                weight = sampling.power_heuristic(np.take(bsdf_pdf, inside),
                                                  np.full(len(inside), light_pdf, np.float32))
            out[:, inside] += self.sun_radiance[k][:, None] * weight
        return out

    def pdf_world(self, dx, dy, dz, focus=None) -> np.ndarray:
        """pdf (solid angle, with selection) with which NEE would have sampled world directions d (focus: as
        given to sample())."""
        if not self.samples_world():
            return np.zeros(len(dx), np.float32)
        return self.pmf32[self.world_index] * self.environment.direction_pdf(dx, dy, dz, focus)

    def intersect(self, ox, oy, oz, dx, dy, dz, t_max, budget=None) -> "LightHits":
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
        probability: the expectation is the sum over the lights, each with its own MIS weight."""
        n = len(ox)
        out = LightHits(n)
        if not self.has_surface_lights or n == 0:
            return out
        ray, light = self._candidates(ox, oy, oz, dx, dy, dz, t_max)
        if not len(ray):
            return out
        t, light_pdf, le = self._hit_pairs(ray, light, ox[ray], oy[ray], oz[ray], dx[ray], dy[ray], dz[ray])
        ok = np.flatnonzero((t > 0) & (t < t_max[ray]))
        # Nearest first; of lights at one distance, the first in the scene's order (Cycles' loop keeps
        # a light only when it is strictly nearer than the one it has).
        order = ok[np.lexsort((light[ok], t[ok], ray[ok]))]
        ray, light, t, light_pdf, le = ray[order], light[order], t[order], light_pdf[order], le[:, order]
        met, crossed = _met_in_turn(ray, t, n, budget)
        out.crossed = crossed
        if budget is not None:
            out.stopped = crossed >= np.maximum(budget, 1)
        ray, light, light_pdf, le = ray[met], light[met], light_pdf[met], le[:, met]
        weight = le[0] + le[1] + le[2]
        keep = np.flatnonzero(weight > 0)
        ray, light, light_pdf, le, weight = ray[keep], light[keep], light_pdf[keep], le[:, keep], weight[keep]
        if not len(ray):
            return out
        chosen, share = _choose_per_ray(ray, weight.astype(np.float64), _ray_uniform(ox, oy, oz, dx, dy, dz)[ray])
        rays = ray[chosen]
        out.hit[rays] = True
        out.radiance[:, rays] = le[:, chosen] / share.astype(np.float32)
        out.pdf[rays] = self.selection_pmf(light[chosen], ox[rays], oy[rays], oz[rays]) * light_pdf[chosen]
        return out

    def _candidates(self, ox, oy, oz, dx, dy, dz, t_max):
        """(ray, light) index pairs that may hit: every ray against every surface light, or, with many
        lights, the pairs whose bounding shapes the ray crosses (found by Embree)."""
        if self._proxy is None:
            n, k = len(ox), len(self.surface_ids)
            return np.tile(np.arange(n), k), np.repeat(self.surface_ids, n)
        return self._proxy.candidates(ox, oy, oz, dx, dy, dz, t_max)

    def _hit_pairs(self, ray, light, ox, oy, oz, dx, dy, dz):
        """Per (ray, light) pair: distance (-1 for a miss), pdf per solid angle of that light's
        sampling (without selection) and the radiance arriving (3, P)."""
        p = len(ray)
        t = np.full(p, -1.0, np.float32)
        pdf = np.zeros(p, np.float32)
        le = np.zeros((3, p), np.float32)
        kind = np.take(self.kind, light)
        for sel, method in ((np.flatnonzero((kind == POINT) | (kind == SPOT)), self._hit_spheres),
                            (np.flatnonzero((kind == RECT) | (kind == DISK)), self._hit_areas)):
            if len(sel):
                lk = light[sel]
                t_k, pdf_k, att = method(lk, ox[sel], oy[sel], oz[sel], dx[sel], dy[sel], dz[sel])
                t[sel], pdf[sel] = t_k, pdf_k
                le[:, sel] = self.radiance_of[lk].T * att[None, :]
        return t, pdf, le

    def _hit_spheres(self, k, ox, oy, oz, dx, dy, dz):
        """Rays against sized point lights k: the disk through each centre facing the ray origin."""
        c, r = self.position[k].T, self.radius[k]
        lx, ly, lz = c[0] - ox, c[1] - oy, c[2] - oz
        d2 = lx * lx + ly * ly + lz * lz
        inv = np.float32(1.0) / np.sqrt(np.maximum(d2, np.float32(1e-30)))
        nx, ny, nz = lx * inv, ly * inv, lz * inv
        denom = dx * nx + dy * ny + dz * nz
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (lx * nx + ly * ny + lz * nz) / denom
        hx, hy, hz = ox + t * dx - c[0], oy + t * dy - c[1], oz + t * dz - c[2]
        inside = (hx * hx + hy * hy + hz * hz <= r * r) & (denom > 0) & np.isfinite(t)
        t = np.where(inside, t, np.float32(-1.0))
        pdf = _area_to_solid_angle(PI * r * r, np.abs(t), np.abs(denom))
        att = self._spot_attenuation(k, -dx, -dy, -dz)
        return t, pdf, att

    def _hit_areas(self, k, ox, oy, oz, dx, dy, dz):
        """Rays against area lights k (rectangles and disks, emitting toward their -Z)."""
        c = self.position[k].T
        xa, ya, za = self._axis(k, 0), self._axis(k, 1), self._axis(k, 2)
        denom = dx * za[0] + dy * za[1] + dz * za[2]          # > 0: travelling into the emitting face
        # The plane's distance as Cycles computes it (ray_quad_intersect): coplanar lamps meet a ray at
        # the same float wherever their centres are, and the ray steps over all but the first (intersect).
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((c[0] * za[0] + c[1] * za[1] + c[2] * za[2]) - (ox * za[0] + oy * za[1] + oz * za[2])) / denom
        hx, hy, hz = ox + t * dx - c[0], oy + t * dy - c[1], oz + t * dz - c[2]
        with np.errstate(invalid="ignore"):
            a = (hx * xa[0] + hy * xa[1] + hz * xa[2]) / self.size[k, 0]
            b = (hx * ya[0] + hy * ya[1] + hz * ya[2]) / self.size[k, 1]
        inside = np.where(self.kind[k] == DISK, a * a + b * b <= np.float32(0.25),
                          (np.abs(a) <= np.float32(0.5)) & (np.abs(b) <= np.float32(0.5)))
        valid = inside & (denom > 0) & np.isfinite(t)
        t = np.where(valid, t, np.float32(-1.0))
        pdf = _area_to_solid_angle(self.area[k], np.abs(t), np.abs(denom))
        rect = np.flatnonzero(valid & (self.kind[k] == RECT))
        if len(rect):
            seen = self._rectangles(k[rect], ox[rect], oy[rect], oz[rect])
            pdf[rect] = seen.pdf(t[rect], denom[rect])
        return t, pdf, np.ones(len(k), np.float32)


class LightProxies:
    """Bounding shapes of the lights with a surface, in an Embree scene of their own: an octahedron
    around each light's bounding sphere (a sized point light's own sphere, an area light's circumscribed
    one). BSDF rays collect every proxy they cross (lights are transparent to each other), so the exact
    tests run only on the few (ray, light) pairs that may hit."""

    def __init__(self, ids, kind, position, radius, size):
        area = (kind[ids] == RECT) | (kind[ids] == DISK)
        bound = np.where(area, 0.5 * np.hypot(size[ids, 0], size[ids, 1]), radius[ids]).astype(np.float64)
        # |x| + |y| + |z| <= r sqrt(3) holds the ball of radius r, widened a little for rounding.
        a = bound * np.sqrt(3.0) * 1.01
        # Each octahedron turned its own way: lights on a grid would otherwise share face planes, and
        # of two faces at the same distance a ray would step past the second.
        axes = _random_rotations(len(a)) * a[:, None, None]
        c = position[ids].astype(np.float64)[:, None, :]
        corners = [np.stack([sx * axes[:, :, 0], sy * axes[:, :, 1], sz * axes[:, :, 2]], axis=1) + c
                   for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
        self.owner = np.tile(ids, 8)
        positions = np.concatenate(corners).astype(np.float32)
        self.accel = Accel(positions, threads=1)
        extent = max(float(np.abs(positions).max()), 1e-3)
        # Step past a face just crossed: far below any light's size, far above float32 rounding.
        self.step = np.float32(max(1e-4 * float(np.min(bound[bound > 0], initial=1.0)), extent * 1e-6))

    def candidates(self, ox, oy, oz, dx, dy, dz, t_max):
        """(ray, light) pairs, each once, for every proxy a ray crosses before t_max."""
        n = len(ox)
        live = np.arange(n)
        travelled = np.zeros(n, np.float32)
        dirs = np.stack([dx, dy, dz], axis=1).astype(np.float32)
        rays, lights = [], []
        for _ in range(MAX_PROXY_CROSSINGS):
            if not len(live):
                break
            t0 = travelled[live]
            origins = np.stack([ox[live] + dx[live] * t0, oy[live] + dy[live] * t0, oz[live] + dz[live] * t0],
                               axis=1).astype(np.float32)
            remaining = (t_max[live] - t0).astype(np.float32)
            hits = self.accel.intersect(origins, dirs[live], np.where(remaining > 0, remaining, np.float32(0)),
                                        split=False)
            got = np.flatnonzero((hits.prim >= 0) & (remaining > 0))
            rays.append(live[got])
            lights.append(np.take(self.owner, hits.prim[got]))
            live = live[got]
            travelled[live] += hits.t[got] + self.step
        if not rays:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        ray, light = np.concatenate(rays), np.concatenate(lights)
        key = np.unique(light.astype(np.int64) * n + ray)  # each pair once, grouped by light
        return key % n, key // n


class SolidAngleChoice:
    """A shading point's choice among a few emissive triangles (rows of the emissive-triangle table), in
    proportion to luminance x the solid angle each subtends at the point: the light each would send it,
    but for the point's own cosine and for shadows. Where all subtend nothing (the point in their plane,
    or float32 underflow), in proportion to power. LightTree's interface: slots are row numbers."""

    def __init__(self, rows: np.ndarray, power: np.ndarray):
        rows = np.asarray(rows, np.float32)
        p0 = rows[:, _TP0:_TP0 + 3]
        corners = np.stack([p0, p0 + rows[:, _TE1:_TE1 + 3], p0 + rows[:, _TE2:_TE2 + 3]], axis=1)
        # Corners shared by the triangles (a quad's two) are normalised once per point.
        self._vertices, inverse = np.unique(corners.reshape(-1, 3), axis=0, return_inverse=True)
        self._corners = inverse.reshape(-1, 3)
        self._lum = luminance(rows[:, _TLE:_TLE + 3]).astype(np.float32)
        self._power_pmf = (np.asarray(power, np.float64) / float(np.sum(power))).astype(np.float32)

    def _pmfs(self, px, py, pz) -> np.ndarray:
        """(k, n) float32 probability of each triangle at each point; columns sum to 1."""
        units = [normalize_floored_xyz((v[0] - px, v[1] - py, v[2] - pz)) for v in self._vertices]
        w = np.empty((len(self._corners), len(px)), np.float32)
        for k, (i, j, m) in enumerate(self._corners):
            np.multiply(_solid_angle(units[i], units[j], units[m]), self._lum[k], out=w[k])
        total = w.sum(axis=0)
        ok = np.isfinite(total) & (total > 0)
        if ok.all():
            w /= total
            return w
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(ok, w / np.where(ok, total, np.float32(1.0)), self._power_pmf[:, None])

    def sample(self, u, px, py, pz):
        """(slot (N,) int64, pmf (N,) float32) for numbers u (N,) in [0, 1)."""
        p = self._pmfs(px, py, pz)
        cdf = np.cumsum(p[:-1], axis=0)
        slot = (np.asarray(u)[None, :] >= cdf).sum(axis=0)
        return slot, p[slot, np.arange(len(slot))]

    def pmf(self, slot, px, py, pz):
        """(N,) float32 probability that point i chooses slot[i] (0 for -1: not among them)."""
        slot = np.asarray(slot)
        known = slot >= 0
        p = self._pmfs(px, py, pz)
        return np.where(known, p[np.where(known, slot, 0), np.arange(len(slot))], np.float32(0.0))


def _random_rotations(n: int) -> np.ndarray:
    """(n, 3, 3) rotation matrices (columns are the rotated axes) from a fixed seed."""
    q = np.random.default_rng(0x5EED).normal(size=(n, 4))
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=1),
        np.stack([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], axis=1),
        np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=1)], axis=2)


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


def _divergence(tree: LightTree, pmf: np.ndarray, box) -> float:
    """Mean over probe points (uniform in box, (lo, hi) corners, with a fixed seed) of the total variation
    distance between the tree's pmf there and pmf (n,), the global one over the same emitters:
    0.5 E_tree |1 - pmf / pmf_tree|, from the tree's own samples. Without a box (no triangles), 1.
    Points in the box, not on the triangles: an instanced scene and its flattened copy score alike."""
    if box is None:
        return 1.0
    rng = np.random.default_rng(0x7EE)
    lo, hi = box
    probes = (lo + (hi - lo) * rng.random((_TREE_PROBES, 3))).astype(np.float32)
    p = np.repeat(probes, _TREE_PROBE_SAMPLES, axis=0).T
    emitter, pmf_tree = tree.sample(rng.random(p.shape[1]), p[0], p[1], p[2])
    ok = pmf_tree > 0
    return float(0.5 * np.mean(np.abs(1.0 - pmf[emitter[ok]] / pmf_tree[ok])))


# Barycentrics (b1, b2) of the points where a triangle of varying emission is looked at for its estimate:
# its centre and a point near each corner.
_ESTIMATE_POINTS = ((1 / 3, 1 / 3), (0.1, 0.1), (0.8, 0.1), (0.1, 0.8))
# Triangles looked at per call (bounds the shading's temporaries).
_ESTIMATE_CHUNK = 1 << 16


def _emission_estimates(triangle_emission, tri: np.ndarray, materials: np.ndarray, varies: np.ndarray) -> np.ndarray:
    """(n, 3) float32 emitted radiance of triangles tri: the material's mean where it is constant; the mean
    over _ESTIMATE_POINTS of the triangle, seen head-on, where it varies."""
    estimate = np.zeros((len(tri), 3), np.float32)
    if not len(tri):
        return estimate
    estimate[:] = triangle_emission(tri).T
    rows = np.flatnonzero(varies[materials])
    for start in range(0, len(rows), _ESTIMATE_CHUNK):
        chunk = rows[start:start + _ESTIMATE_CHUNK]
        total = np.zeros((3, len(chunk)), np.float32)
        for b1, b2 in _ESTIMATE_POINTS:
            total += triangle_emission(tri[chunk], np.full(len(chunk), b1, np.float32),
                                       np.full(len(chunk), b2, np.float32))
        estimate[chunk] = total.T / np.float32(len(_ESTIMATE_POINTS))
    return estimate


def _selection_pmf(power: np.ndarray, distant: np.ndarray) -> np.ndarray:
    """(K,) float64 probabilities of choosing each emitter: by power within the local and within the
    distant group; the distant group as a whole gets DISTANT_SHARE when both groups can emit."""
    local_total, distant_total = power[~distant].sum(), power[distant].sum()
    if local_total > 0 and distant_total > 0:
        share = np.where(distant, DISTANT_SHARE / distant_total, (1.0 - DISTANT_SHARE) / local_total)
        return (power * share).astype(np.float64)
    total = local_total + distant_total
    return (power / total if total > 0 else power).astype(np.float64)


def _direction(px, py, pz, qx, qy, qz):
    dx, dy, dz = qx - px, qy - py, qz - pz
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    inv = np.float32(1.0) / np.maximum(dist, np.float32(1e-30))
    return dx * inv, dy * inv, dz * inv, dist


def _area_to_solid_angle(area, dist, cos_l):
    """pdf per solid angle of a point sampled uniformly on `area`, seen at dist under cos_l."""
    with np.errstate(divide="ignore", invalid="ignore"):
        pdf = dist * dist / (area * cos_l)
    return np.where((cos_l > 0) & np.isfinite(pdf), pdf, np.float32(0.0)).astype(np.float32)


def _solid_angle(a, b, c):
    """Solid angle of the spherical triangle with unit corners a, b, c (Van Oosterom and Strackee)."""
    triple = np.abs(dot_xyz(a, cross_xyz(b, c)))
    return np.float32(2.0) * np.arctan2(triple, np.float32(1.0) + dot_xyz(a, b) + dot_xyz(b, c) + dot_xyz(c, a))


def _sample_spherical_triangle(a, b, c, omega, u1, u2):
    """Unit directions uniform over the spherical triangle a, b, c (Arvo 1995), per component."""
    n_ab = normalize_floored_xyz(cross_xyz(a, b))
    n_ac = normalize_floored_xyz(cross_xyz(a, c))
    cos_alpha = np.clip(dot_xyz(n_ab, n_ac), np.float32(-1.0), np.float32(1.0))
    sin_alpha = np.sqrt(np.maximum(np.float32(1.0) - cos_alpha * cos_alpha, np.float32(0.0)))
    alpha = np.arccos(cos_alpha)
    cos_c = dot_xyz(a, b)
    area = u1 * omega
    s, t = np.sin(area - alpha), np.cos(area - alpha)
    u = t - cos_alpha
    v = s + sin_alpha * cos_c
    with np.errstate(divide="ignore", invalid="ignore"):
        q = ((v * t - u * s) * cos_alpha - v) / ((v * s + u * t) * sin_alpha)
    q = np.clip(np.nan_to_num(q, nan=1.0), np.float32(-1.0), np.float32(1.0))
    ca = dot_xyz(c, a)
    perp = normalize_floored_xyz((c[0] - ca * a[0], c[1] - ca * a[1], c[2] - ca * a[2]))
    sq = np.sqrt(np.maximum(np.float32(1.0) - q * q, np.float32(0.0)))
    c_hat = (q * a[0] + sq * perp[0], q * a[1] + sq * perp[1], q * a[2] + sq * perp[2])
    cb = dot_xyz(c_hat, b)
    z = np.float32(1.0) - u2 * (np.float32(1.0) - cb)
    perp = normalize_floored_xyz((c_hat[0] - cb * b[0], c_hat[1] - cb * b[1], c_hat[2] - cb * b[2]))
    sz = np.sqrt(np.maximum(np.float32(1.0) - z * z, np.float32(0.0)))
    return z * b[0] + sz * perp[0], z * b[1] + sz * perp[1], z * b[2] + sz * perp[2]


def _barycentrics(d, e1, e2):
    """(b1, b2) of the point p0 + d on the triangle with edges e1, e2 (each x, y, z)."""
    d11, d12, d22 = dot_xyz(e1, e1), dot_xyz(e1, e2), dot_xyz(e2, e2)
    d1, d2 = dot_xyz(d, e1), dot_xyz(d, e2)
    det = d11 * d22 - d12 * d12
    det = np.where(det != 0, det, np.float32(1e-30))
    return (d22 * d1 - d12 * d2) / det, (d11 * d2 - d12 * d1) / det
