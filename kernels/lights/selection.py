"""Choosing an emitter: one pmf by power everywhere (distant emitters taking DISTANT_SHARE), or per shading point
among the local ones, by a light tree (kernels.light_tree) or, among a few emissive triangles, by the solid
angle each subtends (SolidAngleChoice). A Choice holds one such way of choosing, over all of a scene's emitters
or over those one light set of Light Linking reaches (kernels.lights.links).
"""
from __future__ import annotations

import numpy as np

from ..geometry import scene_extent
from ..light_tree import LightTree, rows_of
from ..light_tree_cycles import (AREA, MESH, POINT, SPOT as UNIT_SPOT, CyclesLightTree, Units, distant_bounds,
                                 left_probability, merge_cones)
from ..textures import luminance
from ..vec import normalize_floored_xyz
from ..vec import HALF_PI
from .common import DISK, RECT, SPOT
from .triangles import TE1, TE2, TLE, TN, TP0, on_sampled_side, solid_angle

# When a scene has both local and distant emitters, the distant ones (suns, world) get this share of
# the light choices. It cannot come from comparing powers: a sun's or the world's power is per unit
# area, and turning it into watts takes an arbitrary area (the scene's bounding sphere made a 1 km floor
# starve the lamps). Cycles' light tree weighs distant lights at its root by their own importance,
# not by the scene's size, too; a fixed half is never more than 2x from the best split for either side.
DISTANT_SHARE = 0.5
# The measurements behind these numbers are in docs/architecture.md (Lights).
# With at least this many local emitters (point, spot and area lights, emissive triangles, with power)
# the local ones may be chosen per shading point by a light tree (kernels.light_tree), as Cycles always
# does; a single one needs no choice. Even a few lamps gain far more variance than the walk costs time.
TREE_MIN_EMITTERS = 2
# From two to this many local emitters, all emissive triangles (a lamp modelled as a quad, say), each
# shading point chooses among them in proportion to the light each sends it: luminance times the solid
# angle it subtends there, computed exactly (SolidAngleChoice), instead of by the tree's bounds. The power
# pmf sends half the samples of a point beside the lamp's near half to its far half.
SOLID_ANGLE_MAX_EMITTERS = 4
# ... and, for the triangles of a single emissive object, only where its choices differ from the power
# pmf's: at probe points in the scene's box, the total variation distance between the two pmfs (estimated
# from the tree's own samples) must reach this; below it the tree costs more time than it saves variance.
# Several lights, or lights and emissive objects, always get the tree, as in Cycles: over a large floor the
# probes miss the few places where a lamp must win against the emissive mesh beside it.
TREE_MIN_DIVERGENCE = 0.1
# Probe points and tree samples per probe for that estimate (fixed seed: the choice is deterministic).
_TREE_PROBES, _TREE_PROBE_SAMPLES = 256, 64


class Choice:
    """One way of choosing among emitters with power (power (L + E + 1,) float64, zero for those not to be
    chosen): select_pmf (float64) and pmf32 the global pmf, cdf its cumulative sum, and the per-point choice
    among the local emitters (tree: a LightTree, a SolidAngleChoice or None, with the distant emitters' own
    distribution: local_choice)."""

    def __init__(self, sampler, power: np.ndarray, scene, tree: bool = True):
        """tree: False for Cycles' light distribution (distribution_pmf) everywhere, without a per-point choice."""
        self.has_lights = bool(power.sum() > 0)
        self.select_pmf = power_pmf(power, sampler.distant_mask()) if tree else \
            distribution_pmf(power, sampler.light_count, sampler.tri_area)
        self.cdf = np.cumsum(self.select_pmf)
        if self.has_lights:
            self.cdf /= self.cdf[-1]
        self.pmf32 = self.select_pmf.astype(np.float32)
        self.tree_divergence = 0.0
        # Cycles' root between the local emitters and the distant ones, in a clamped render (cycles_root): the
        # distant node's energy and cone; None: the fixed local_share.
        self.root = None
        # Cycles' distant leaf in a clamped render with two or more distant emitters (distant_leaf): their
        # (emitters, energies, cones), weighed per point; None: their fixed pmf.
        self.leaf = distant_leaf(sampler, power) if self.has_lights and tree else None
        self.tree = local_choice(sampler, self, power, scene) if self.has_lights and tree else None


def local_choice(sampler, choice: Choice, power, scene):
    """How shading points choose among the local emitters with power, when not by the global pmf: a
    SolidAngleChoice among two to SOLID_ANGLE_MAX_EMITTERS emissive triangles; a LightTree over
    TREE_MIN_EMITTERS or more emitters whose choices differ enough from the global pmf's
    (TREE_MIN_DIVERGENCE, measured at points in the box of the scene's triangles); else None. Also the
    distant emitters' own distribution for the points that choose one (set on `choice`). A clamped render
    (sampler.cycles_shares) takes Cycles' tree wherever Cycles takes one (kernels.light_tree_cycles)."""
    distant = sampler.distant_mask()
    local = np.flatnonzero(~distant & (power > 0))
    cycles = sampler.cycles_shares
    few = 2 <= len(local) <= SOLID_ANGLE_MAX_EMITTERS and bool((local >= sampler.light_count).all()) and not cycles
    rooted = cycles and len(local) >= 1 and bool((distant & (power > 0)).any()) and not sampler.linked
    if len(local) < TREE_MIN_EMITTERS and not few and not rooted:
        return None
    choice.distant_ids = np.flatnonzero(distant & (choice.select_pmf > 0))
    # Exactly 1 without distant emitters: a rounded sum would send a few points to none.
    choice.local_share = float(choice.select_pmf[local].sum()) if len(choice.distant_ids) else 1.0
    choice.tree_ids = local
    choice.tree_slot = np.full(len(power), -1, np.int64)
    choice.tree_slot[local] = np.arange(len(local))
    choice.distant_cdf = np.cumsum(choice.select_pmf[choice.distant_ids])
    if len(choice.distant_cdf):
        choice.distant_cdf /= choice.distant_cdf[-1]
    if few:
        slots = local - sampler.light_count
        return SolidAngleChoice(np.take(sampler.tri_table, slots, axis=0), power[local],
                                None if sampler.tri_half is None else np.take(sampler.tri_half, slots))
    lo, hi = np.zeros((len(local), 3)), np.zeros((len(local), 3))
    axis, spread = np.zeros((len(local), 3)), np.full(len(local), np.pi)
    is_light = local < sampler.light_count
    k = local[is_light]
    c = sampler.position[k].astype(np.float64)
    area = (sampler.kind[k] == RECT) | (sampler.kind[k] == DISK)
    x, y = sampler.axes[k, :, 0].astype(np.float64), sampler.axes[k, :, 1].astype(np.float64)
    half = np.where(area[:, None], np.abs(x) * (0.5 * sampler.size[k, 0:1]) + np.abs(y) * (0.5 * sampler.size[k, 1:2]),
                    sampler.radius[k, None].astype(np.float64))
    lo[is_light], hi[is_light] = c - half, c + half
    # Area lights emit toward their -Z only, spot lights within their cone around it (theta_e, their half angle:
    # the cone's sphere, theta_u, widens it for a sized spot), point lights every way.
    spot = sampler.kind[k] == SPOT
    axis[is_light] = np.where((area | spot)[:, None], -sampler.axes[k, :, 2], np.float64([0, 0, 1]))
    spread[is_light] = np.where(area | spot, 0.0, np.pi)
    emission = np.full(len(local), HALF_PI)
    emission[np.flatnonzero(is_light)[spot]] = np.arccos(np.clip(sampler.spot[k[spot], 0].astype(np.float64), -1, 1))
    if sampler.spread is not None:
        # An area light of Spread s lights nothing beyond s / 2 off its normal (Cycles' theta_e, scene/light_tree.cpp).
        emission[np.flatnonzero(is_light)[area]] = np.minimum(np.take(sampler.spread, k[area]).astype(np.float64) / 2,
                                                              HALF_PI)
    t = np.take(sampler.tri_table, local[~is_light] - sampler.light_count, axis=0).astype(np.float64)
    p0 = t[:, TP0:TP0 + 3]
    corners = np.stack([p0, p0 + t[:, TE1:TE1 + 3], p0 + t[:, TE2:TE2 + 3]])
    lo[~is_light], hi[~is_light] = corners.min(axis=0), corners.max(axis=0)
    axis[~is_light] = t[:, TN:TN + 3]  # two-sided: spread pi, every way
    if sampler.tri_half is not None:   # one-sided (Emission Sampling Front or Back): around the side sampled
        half = np.take(sampler.tri_half, local[~is_light] - sampler.light_count).astype(np.float64)
        axis[~is_light] *= np.where(half == 0, 1.0, half)[:, None]
        spread[np.flatnonzero(~is_light)[half != 0]] = 0.0
    group = np.full(len(local), -1, np.int64)
    group[~is_light] = triangle_groups(sampler, scene, local[~is_light] - sampler.light_count)
    if cycles:
        if rooted:
            choice.root = cycles_root(sampler, power)
        return _cycles_tree(sampler, local, is_light, lo, hi, axis, spread, emission, group, power[local])
    tree = LightTree(lo, hi, power[local], axis, spread, group, emission)
    has_geometry = len(scene.positions) or (scene.instances is not None and scene.instances.count)
    box = scene_extent(scene) if has_geometry else None
    choice.tree_divergence = _divergence(tree, choice.select_pmf[local] / choice.local_share, box)
    return tree if tree.units > 1 or choice.tree_divergence >= TREE_MIN_DIVERGENCE else None


def cycles_root(sampler, power) -> tuple:
    """(energy, cone) of Cycles' distant node, the root's other child beside the local emitters' tree
    (scene/light_tree.cpp: all distant lights in one leaf): their energies summed (power: the sampler's Cycles
    measures, LightSampler._cycles_light_power and _world_power) and their cones merged, a sun's along the light it
    sends (theta_o 0, theta_e half its angle), the world's every way (theta_o pi)."""
    cone, energy = None, 0.0
    for k in np.flatnonzero(sampler.distant_mask() & (power > 0)):
        cone = merge_cones(cone, _distant_cone(sampler, k))
        energy += float(power[k])
    return energy, cone


def _distant_cone(sampler, k: int) -> tuple:
    """(axis, theta_o, theta_e) of distant emitter k in Cycles' tree: a sun's along the light it sends (theta_o 0,
    theta_e half its angle), the world's every way (theta_o pi)."""
    if k == sampler.world_index:
        return (0.0, 0.0, 1.0), np.pi, 0.0
    toward = sampler.axes[k, :, 2].astype(np.float64)
    return tuple(float(c) for c in -toward), 0.0, float(np.arccos(np.clip(sampler.sun_cos[k], -1.0, 1.0)))


def distant_leaf(sampler, power):
    """Cycles' distant leaf (scene/light_tree.cpp puts every distant light in one leaf; kernel/light/tree.h
    light_tree_cluster_select_emitter picks among its emitters per shading point, half by their upper importance
    bounds and half by their lower ones): (ids, energies, cones) of the distant emitters with power, in a clamped
    render without Light Linking that has two or more of them (suns and the world), else None. A sun below a
    surface's horizon then gets no samples there: a crowd under a sun and an HDRI had 1.13x Cycles' variance per
    sample where it had 0.64x, its split fixed by the energies."""
    if not sampler.cycles_shares or sampler.linked:
        return None
    ids = np.flatnonzero(sampler.distant_mask() & (power > 0))
    if len(ids) < 2:
        return None
    return ids, power[ids].astype(np.float64), [_distant_cone(sampler, k) for k in ids]


def leaf_pmfs(choice: Choice, facing, n: int) -> np.ndarray:
    """(n, D) float64: at n points (facing as choose_at's, or None) the probability of each of the leaf's D distant
    emitters among them, as Cycles' light_tree_cluster_select_emitter gives it: half each one's share of the upper
    bounds, half its share of the lower ones (where no lower bound is positive, of those with a positive upper one,
    uniformly). Rows where none can light the point are zero."""
    ids, energies, cones = choice.leaf
    bounds = [distant_bounds(float(e), cone, facing, n) for e, cone in zip(energies, cones)]
    upper = np.stack([b[0] for b in bounds], axis=1)
    lower = np.stack([b[1] for b in bounds], axis=1)
    total_upper, total_lower = upper.sum(axis=1, keepdims=True), lower.sum(axis=1, keepdims=True)
    positive = (upper > 0).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        by_upper = np.where(total_upper > 0, upper / total_upper, 0.0)
        by_lower = np.where(total_lower > 0, lower / np.where(total_lower > 0, total_lower, 1.0),
                            positive / np.maximum(positive.sum(axis=1, keepdims=True), 1.0))
    return 0.5 * (by_upper + by_lower)


def _leaf_pick(choice: Choice, u, facing, n):
    """(emitter (n,), its leaf pmf (n,)) for numbers u (n,) in [0, 1)."""
    pmfs = leaf_pmfs(choice, facing, n)
    cdf = np.cumsum(pmfs, axis=1)
    j = np.minimum((cdf <= (u * cdf[:, -1])[:, None]).sum(axis=1), pmfs.shape[1] - 1)
    return choice.leaf[0][j], pmfs[np.arange(n), j]


def _leaf_pmf_of(choice: Choice, emitter, facing, n):
    """(n,) the leaf pmf of emitter (an index or (n,) indices) at n points; 0 for emitters outside the leaf."""
    ids = choice.leaf[0]
    emitter = np.broadcast_to(np.asarray(emitter, np.int64), (n,))
    slot = np.searchsorted(ids, emitter)
    inside = (slot < len(ids)) & (ids[np.minimum(slot, len(ids) - 1)] == emitter)
    pmfs = leaf_pmfs(choice, facing, n)
    return np.where(inside, pmfs[np.arange(n), np.minimum(slot, len(ids) - 1)], 0.0)


def root_share(choice: Choice, px, py, pz, facing=None):
    """The local emitters' share of the light choices at points p: Cycles' get_left_probability at its root, the
    local tree against the distant node (choice.root), in a clamped render; else the fixed choice.local_share."""
    if choice.root is None:
        return choice.local_share
    upper, lower = choice.tree.root_bounds(px, py, pz, facing)
    d_upper, d_lower = distant_bounds(choice.root[0], choice.root[1], facing, len(px))
    share = left_probability(upper, lower, d_upper, d_lower)
    return np.where(np.isnan(share), choice.local_share, share)


def distant_pmf_at(choice: Choice, emitter: int, px, py, pz, facing=None):
    """(n,) float64 probability that NEE at points p chooses distant emitter (a sun, the world): its share of the
    distant emitters times their share at p (root_share)."""
    share = root_share(choice, px, py, pz, facing) if choice.tree is not None else 0.0
    return _distant(choice, emitter, share, facing, len(px))


def _distant(choice: Choice, emitter, share, facing=None, n: int = 1):
    """The pmf of distant emitters `emitter` where the local ones take `share`: their global pmf with the fixed share;
    with Cycles' root, their part of the distant emitters times 1 - share, that part per point with its distant leaf
    (choice.leaf)."""
    if choice.leaf is not None:
        return _leaf_pmf_of(choice, emitter, facing, n) * (1.0 - share)
    global_pmf = np.take(choice.select_pmf, emitter)
    if choice.root is None:
        return global_pmf
    return global_pmf / max(1.0 - choice.local_share, 1e-300) * (1.0 - share)


def _cycles_tree(sampler, local, is_light, lo, hi, axis, spread, emission, group, power) -> CyclesLightTree:
    """Cycles' tree (kernels.light_tree_cycles) over the lamps and the emissive objects among the local emitters
    (slots: their order in local), the arrays as local_choice makes them."""
    slots = np.arange(len(local))
    lamp_slots, tri_slots = slots[is_light], slots[~is_light]
    k = local[is_light]
    kind = sampler.kind[k]
    unit_kind = np.where(kind == SPOT, UNIT_SPOT, np.where((kind == RECT) | (kind == DISK), AREA, POINT))
    theta_o = np.where(unit_kind == POINT, np.pi, 0.0)
    theta_e = np.where(unit_kind == POINT, HALF_PI, emission[lamp_slots])
    sphere = np.zeros(len(k), bool) if sampler.sphere is None else np.take(sampler.sphere, k).astype(bool)
    blend = sampler.spot[k, 1].astype(np.float64)
    with np.errstate(divide="ignore"):
        smooth = np.where(blend > 0, 1.0 / np.where(blend > 0, blend, 1.0), np.inf)
    parts = dict(kind=[unit_kind], energy=[power[lamp_slots]], lo=[lo[lamp_slots]], hi=[hi[lamp_slots]],
                 centroid=[sampler.position[k].astype(np.float64)], axis=[axis[lamp_slots]], theta_o=[theta_o],
                 theta_e=[theta_e], radius=[sampler.radius[k].astype(np.float64)], sphere=[sphere],
                 spot_smooth=[smooth],
                 eu=[sampler.axes[k, :, 0].astype(np.float64) * sampler.size[k, 0:1]],
                 ev=[sampler.axes[k, :, 1].astype(np.float64) * sampler.size[k, 1:2]])
    unit_of_slot = np.zeros(len(local), np.int64)
    unit_of_slot[lamp_slots] = np.arange(len(k))
    tri_tree, unit_group = None, np.full(len(k), -1, np.int64)
    if len(tri_slots):
        # The emissive objects: Ember's tree over their triangles, each object a subtree (LightTree.unit_root);
        # as units, their boxes, energies and the cones of those subtrees.
        tri_tree = LightTree(lo[tri_slots], hi[tri_slots], power[tri_slots], axis[tri_slots], spread[tri_slots],
                             group[tri_slots], emission[tri_slots])
        tri_unit = tri_tree.unit
        m = tri_tree.units
        u_lo, u_hi = np.full((m, 3), np.inf), np.full((m, 3), -np.inf)
        np.minimum.at(u_lo, tri_unit, lo[tri_slots])
        np.maximum.at(u_hi, tri_unit, hi[tri_slots])
        energy = np.bincount(tri_unit, power[tri_slots], minlength=m)
        totals = getattr(sampler, "object_totals", None)
        if totals is not None:
            # The objects as Cycles measures them, their dark triangles included (LightSampler._object_totals).
            keys, t_energy, t_lo, t_hi = totals
            object_of_unit = np.zeros(m, np.int64)
            object_of_unit[tri_unit] = group[tri_slots]
            at = np.minimum(np.searchsorted(keys, object_of_unit), len(keys) - 1)
            found = keys[at] == object_of_unit
            energy = np.where(found, t_energy[at], energy)
            u_lo, u_hi = np.where(found[:, None], t_lo[at], u_lo), np.where(found[:, None], t_hi[at], u_hi)
        cone = _object_cones(sampler, local[tri_slots], tri_tree, axis[tri_slots], spread[tri_slots])
        parts["kind"].append(np.full(m, MESH))
        parts["energy"].append(energy)
        parts["lo"].append(u_lo)
        parts["hi"].append(u_hi)
        parts["centroid"].append(0.5 * (u_lo + u_hi))
        parts["axis"].append(cone[0])
        parts["theta_o"].append(cone[1])
        parts["theta_e"].append(cone[2])
        parts["radius"].append(np.zeros(m))
        parts["sphere"].append(np.zeros(m, bool))
        parts["spot_smooth"].append(np.full(m, np.inf))
        parts["eu"].append(np.zeros((m, 3)))
        parts["ev"].append(np.zeros((m, 3)))
        unit_of_slot[tri_slots] = len(k) + tri_unit
        unit_group = np.concatenate([unit_group, np.arange(m)])
    units = Units(**{name: np.concatenate(v) for name, v in parts.items()})
    return CyclesLightTree(units, unit_of_slot, tri_tree, tri_slots, unit_group)


# Objects with more emissive triangles than this take the cone of Ember's tree (kernels.light_tree) instead of the
# sequence of Cycles' merges, which is a Python loop.
MAX_MERGED_TRIANGLES = 50_000


def _object_cones(sampler, emitters, tri_tree: LightTree, axis, spread):
    """(axis (m, 3), theta_o (m,), theta_e (m,)) of the emissive objects (tri_tree's units), as Cycles' mesh emitters
    measure them: the merge of their triangles' cones in order (scene/light_tree.cpp: a one-sided triangle's around
    its normal with theta_o 0, a two-sided one's around the direction from its second corner to its first with
    theta_o pi / 2)."""
    unit, m = tri_tree.unit, tri_tree.units
    rows = np.take(sampler.tri_table, emitters - sampler.light_count, axis=0).astype(np.float64)
    edge = -rows[:, TE1:TE1 + 3]
    edge /= np.maximum(np.linalg.norm(edge, axis=1), 1e-30)[:, None]
    two_sided = spread >= np.pi
    cone_axis = np.where(two_sided[:, None], edge, axis)
    theta_o = np.where(two_sided, HALF_PI, 0.0)
    out_axis, out_o, out_e = np.zeros((m, 3)), np.zeros(m), np.full(m, HALF_PI)
    counts = np.bincount(unit, minlength=m)
    fallback = counts > MAX_MERGED_TRIANGLES
    order = np.argsort(unit, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)])
    listed_axis, listed_o = cone_axis.tolist(), theta_o.tolist()
    for g in np.flatnonzero(~fallback & (counts > 0)):
        cone = None
        for i in order[starts[g]:starts[g + 1]].tolist():
            cone = merge_cones(cone, (tuple(listed_axis[i]), listed_o[i], HALF_PI))
        out_axis[g], out_o[g] = cone[0], cone[1]
    if fallback.any():
        big = np.flatnonzero(fallback)
        out_axis[big], out_o[big], out_e[big] = tri_tree.cone_of(tri_tree.unit_root[big])
    return out_axis, out_o, out_e


def triangle_groups(sampler, scene, rows) -> np.ndarray:
    """(m,) int64 group of the emissive triangles at rows of the table: their object (their material when
    the scene has no object table), or their instance; the light tree keeps each group together."""
    return groups_of_triangles(scene, sampler.tri_ids[rows])


def groups_of_triangles(scene, tri) -> np.ndarray:
    """(m,) int64 group (triangle_groups) of triangles tri (numbered as ray hits report them, instances' copies
    after the scene's own triangles)."""
    plain_count = scene.triangle_count
    plain = tri < plain_count
    by = scene.object_ids if scene.object_ids is not None else scene.material_ids
    group = np.zeros(len(tri), np.int64)
    group[plain] = np.take(by, tri[plain])
    if not plain.all():
        bases = scene.instances.bases(plain_count)
        offset = int(np.max(by, initial=-1)) + 1
        group[~plain] = offset + np.searchsorted(bases, tri[~plain], side="right") - 1
    return group


def choose(choice: Choice, u_select: np.ndarray) -> np.ndarray:
    """(n,) int64 emitter index per number in [0, 1), each with probability choice.select_pmf."""
    if len(choice.cdf) == 1:
        return np.zeros(len(u_select), np.int64)
    # float64: a float32 cdf would round the intervals of millions of small emitters.
    return np.minimum(np.searchsorted(choice.cdf, u_select.astype(np.float64), side="right"), len(choice.cdf) - 1)


def choose_at(choice: Choice, u_select, px, py, pz, facing=None):
    """(emitter (n,) int64, selection probability (n,) float32) per shading point p: the light tree
    for the local emitters (their DISTANT_SHARE complement), the distant ones by their fixed pmf.
    Without a tree, choose() and select_pmf. facing: the points' (nx, ny, nz, two_sided) for the tree's
    incidence factor (light_tree module docstring), or None."""
    if choice.tree is None:
        if choice.leaf is not None:   # distant emitters alone: Cycles' leaf is its whole tree
            chosen, pmf = _leaf_pick(choice, u_select.astype(np.float64), facing, len(u_select))
            return chosen, pmf.astype(np.float32)
        chosen = choose(choice, u_select)
        return chosen, np.take(choice.pmf32, chosen)
    u = u_select.astype(np.float64)
    share = root_share(choice, px, py, pz, facing)
    shares = np.broadcast_to(np.asarray(share, np.float64), u.shape)
    chosen = np.zeros(len(u), np.int64)
    select = np.zeros(len(u), np.float64)
    local = np.flatnonzero(u < shares) if choice.root is not None or share < 1 else np.arange(len(u))
    if len(local):
        s = shares[local]
        e, pmf = choice.tree.sample(u[local] / s, px[local], py[local], pz[local],
                                    None if facing is None else tuple(c[local] for c in facing))
        chosen[local] = choice.tree_ids[e]
        select[local] = s * pmf
    if choice.root is not None or share < 1:
        far = np.flatnonzero(u >= shares)
        if len(far):
            s = shares[far]
            ud = (u[far] - s) / (1.0 - s)
            if choice.leaf is not None:
                chosen[far], pmf = _leaf_pick(choice, ud, rows_of(facing, far), len(far))
                select[far] = pmf * (1.0 - s)
            else:
                j = np.minimum(np.searchsorted(choice.distant_cdf, ud, side="right"), len(choice.distant_ids) - 1)
                chosen[far] = choice.distant_ids[j]
                select[far] = _distant(choice, chosen[far], s)
    return chosen, select.astype(np.float32)


def selection_pmf(choice: Choice, emitter, px, py, pz, facing=None):
    """(n,) float32 probability that NEE at point p (facing as choose_at's) chooses emitter (any index but the
    world's)."""
    if choice.tree is None:
        if choice.leaf is not None:
            return _distant(choice, emitter, 0.0, facing, len(px)).astype(np.float32)
        return np.take(choice.pmf32, emitter)
    slot = np.take(choice.tree_slot, emitter)
    share = root_share(choice, px, py, pz, facing)
    n = len(px)
    out = np.array(np.broadcast_to(choice.tree.pmf(slot, px, py, pz, facing) * share, (n,)), np.float64)
    far = np.flatnonzero(np.broadcast_to(slot, (n,)) < 0)
    if len(far):   # the distant ones' pmf (a leaf per point) only where they are asked for
        emitter = np.broadcast_to(np.asarray(emitter, np.int64), (n,))
        out[far] = _distant(choice, emitter[far], np.broadcast_to(share, (n,))[far], rows_of(facing, far), len(far))
    return out.astype(np.float32)


class SolidAngleChoice:
    """A shading point's choice among a few emissive triangles (rows of the emissive-triangle table), in
    proportion to luminance x the solid angle each subtends at the point: the light each would send it,
    but for the point's own cosine and for shadows; none from the side of a one-sided one that is not sampled
    (half: triangles.one_sided's, or None). Where all subtend nothing (the point in their plane, or float32
    underflow), in proportion to power. LightTree's interface: slots are row numbers."""

    def __init__(self, rows: np.ndarray, power: np.ndarray, half: np.ndarray | None = None):
        rows = np.asarray(rows, np.float32)
        self._rows = rows if half is not None and half.any() else None
        self._half = half
        p0 = rows[:, TP0:TP0 + 3]
        corners = np.stack([p0, p0 + rows[:, TE1:TE1 + 3], p0 + rows[:, TE2:TE2 + 3]], axis=1)
        # Corners shared by the triangles (a quad's two) are normalised once per point.
        self._vertices, inverse = np.unique(corners.reshape(-1, 3), axis=0, return_inverse=True)
        self._corners = inverse.reshape(-1, 3)
        self._lum = luminance(rows[:, TLE:TLE + 3]).astype(np.float32)
        self._power_pmf = (np.asarray(power, np.float64) / float(np.sum(power))).astype(np.float32)

    def _pmfs(self, px, py, pz) -> np.ndarray:
        """(k, n) float32 probability of each triangle at each point; columns sum to 1."""
        units = [normalize_floored_xyz((v[0] - px, v[1] - py, v[2] - pz)) for v in self._vertices]
        w = np.empty((len(self._corners), len(px)), np.float32)
        for k, (i, j, m) in enumerate(self._corners):
            np.multiply(solid_angle(units[i], units[j], units[m]), self._lum[k], out=w[k])
        if self._rows is not None:
            g = self._rows.T
            for k in np.flatnonzero(self._half):
                w[k] *= on_sampled_side(self._half, np.full(len(px), k), g[:, k:k + 1], px, py, pz)
        total = w.sum(axis=0)
        ok = np.isfinite(total) & (total > 0)
        if ok.all():
            w /= total
            return w
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(ok, w / np.where(ok, total, np.float32(1.0)), self._power_pmf[:, None])

    def sample(self, u, px, py, pz, facing=None):
        """(slot (N,) int64, pmf (N,) float32) for numbers u (N,) in [0, 1)."""
        p = self._pmfs(px, py, pz)
        cdf = np.cumsum(p[:-1], axis=0)
        slot = (np.asarray(u)[None, :] >= cdf).sum(axis=0)
        return slot, p[slot, np.arange(len(slot))]

    def pmf(self, slot, px, py, pz, facing=None):
        """(N,) float32 probability that point i chooses slot[i] (0 for -1: not among them)."""
        slot = np.asarray(slot)
        known = slot >= 0
        p = self._pmfs(px, py, pz)
        return np.where(known, p[np.where(known, slot, 0), np.arange(len(slot))], np.float32(0.0))


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


def emission_estimates(triangle_emission, tri: np.ndarray, materials: np.ndarray, varies: np.ndarray) -> np.ndarray:
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


def distribution_pmf(power: np.ndarray, light_count: int, tri_area: np.ndarray) -> np.ndarray:
    """(L + E + 1,) float64 Cycles' light distribution, its choice without the light tree (scene/light.cpp
    device_update_distribution): the emissive triangles in proportion to their area, the lamps (suns among them)
    and the world alike, each group half of the choices when there are both. Emitters without power get none."""
    pmf = np.zeros(len(power), np.float64)
    tri = slice(light_count, len(power) - 1)
    area = np.where(power[tri] > 0, np.asarray(tri_area, np.float64), 0.0)
    lamps = np.flatnonzero(np.r_[power[:light_count] > 0, np.zeros(len(area), bool), power[-1:] > 0])
    total = area.sum()
    triangle_share = 0.0 if total <= 0 else (0.5 if len(lamps) else 1.0)
    if total > 0:
        pmf[tri] = area / total * triangle_share
    if len(lamps):
        pmf[lamps] = (1.0 - triangle_share) / len(lamps)
    return pmf


def power_pmf(power: np.ndarray, distant: np.ndarray) -> np.ndarray:
    """(K,) float64 probabilities of choosing each emitter: by power within the local and within the
    distant group; the distant group as a whole gets DISTANT_SHARE when both groups can emit."""
    local_total, distant_total = power[~distant].sum(), power[distant].sum()
    if local_total > 0 and distant_total > 0:
        share = np.where(distant, DISTANT_SHARE / distant_total, (1.0 - DISTANT_SHARE) / local_total)
        return (power * share).astype(np.float64)
    total = local_total + distant_total
    return (power / total if total > 0 else power).astype(np.float64)
