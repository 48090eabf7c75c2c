"""Next-event estimation: a light sample for every path at its hit, the shadow ray toward it (through
transparent surfaces, as Cycles' transparent shadows), and the MIS-weighted direct light added to the path; the
world's light samples focused on glossy lobes; the emission of triangles that the light sampler evaluates.
Functions over (scene tables, wave, path state), as the integrator's stages (kernels/integrator.py).
"""
from __future__ import annotations

import itertools

import numpy as np

from .. import light_groups, passes, sampling, visibility
from ..bsdf.focus import glossy_axes
from ..bsdf.light_passes import eval_split
from ..environment import WorldFocus
from ..geometry import NG
from ..geometry.deform import deformed_corners
from ..interaction import RayInfo, SurfaceHit, spawn_offset
from ..rays import unlifted
from ..paths import may_scatter, ray_keys
from ..media import stack as volume_stack
from ..media import tracking
from ..media.march import marching
from ..samples import LIGHT, LIGHT_POINT, LOBE
from ..scene import ALL_SETS
from ..scene.objects import BSDF_RAYS
from . import ray_visibility

# At a shading point whose closures are all one glossy lobe, the share of the world's light samples drawn
# around that lobe (Environment.focus); less in proportion where other closures share the sampling weight.
FOCUS_SHARE = 0.8


# ---- stage: next-event estimation, one shadow ray toward a sampled light
def world_focus(tables, hit, closures):
    """environment.WorldFocus per hit, about its main glossy lobe (bsdf.focus.glossy_axes); None when the world
    is not sampled as a light or cannot focus (a constant world, World.focus off)."""
    if not (tables.environment.focuses and tables.lights.samples_world()):
        return None
    hits, axis, radius, share = glossy_axes(closures)
    if not len(hits):
        return None
    focus = WorldFocus.none(len(hit))
    focus.put(hits, tables.environment.focus(*axis, radius, share * np.float32(FOCUS_SHARE)))
    return focus


def shading_facing(tables, hit, closures):
    """(nx, ny, nz, two_sided) of the hits, what the light tree's choice reads at a surface point (Cycles passes
    sd->N and SD_BSDF_HAS_TRANSMISSION), or None where the light choice reads no normal."""
    if not tables.lights.reads_facing:
        return None
    return (*hit.ns, closures.transmits())


def next_event(tables, wave, state, hit, closures, numbers, focus=None, receiver=None):
    """Sample a light for every live path, trace the shadow rays, add the MIS-weighted direct light.
    focus: the world's light samples' (_world_focus), per hit; receiver: the hits' light sets (Light Linking),
    or None."""
    (u_select, _), (u1, u2) = numbers[LIGHT], numbers[LIGHT_POINT]
    # Paths past their last bounce only pass through transparent surfaces: no direct light there; nor
    # where the closures are all singular (a mirror, smooth glass): their evaluation is zero.
    active = np.flatnonzero(may_scatter(wave, state) & closures.evaluable())
    facing = shading_facing(tables, hit, closures)
    if len(active) < len(state):
        if not len(active):
            return
        u_select, u1, u2 = u_select[active], u1[active], u2[active]
        px, py, pz = (c[active] for c in hit.p)
        focus = None if focus is None else focus.take(active)
        facing = None if facing is None else tuple(np.take(c, active) for c in facing)
        receiver = None if receiver is None else receiver[active]
    else:
        px, py, pz = hit.p
    ls = tables.lights.sample(px, py, pz, u_select, u1, u2, focus, receiver, facing, catcher_emitters(wave),
                              _bounces(tables, state, active))
    tables.crew.check_stop()
    le = ls.radiance
    useful = np.flatnonzero((ls.pdf > 0) & ((le[0] > 0) | (le[1] > 0) | (le[2] > 0)))
    if not len(useful):
        return
    f, bsdf_pdf = closures.eval_at(active[useful], (ls.wx[useful], ls.wy[useful], ls.wz[useful]))
    if ls.visibility is not None:
        f = _visible_closures(closures, active[useful], ls, useful, f)
    keep = np.flatnonzero((f[0] > 0) | (f[1] > 0) | (f[2] > 0))
    idx = useful[keep]  # rows of the light sample; active[idx] are the paths
    if not len(idx):
        return
    f, bsdf_pdf = np.take(f, keep, axis=1), bsdf_pdf[keep]
    mis = None   # the samples' MIS weights, where the Light Threshold needed them before the shadow rays
    if LOBE in numbers and termination_scale(tables, wave.settings) > 0:
        mis = _mis_weight(tables, ls, idx, bsdf_pdf)
        kept, f = _terminated(tables, wave.settings, ls, idx, f, mis, numbers[LOBE][0][active[idx]])
        idx, bsdf_pdf, mis = idx[kept], bsdf_pdf[kept], mis[kept]
        if not len(idx):
            return
    gx, gy, gz = (np.take(c, active[idx]) for c in hit.ng)
    wx, wy, wz = np.take(ls.wx, idx), np.take(ls.wy, idx), np.take(ls.wz, idx)
    # Leave from the side of the surface the light is on (a light behind a transmitting surface).
    sign = np.where(wx * gx + wy * gy + wz * gz < 0, np.float32(-1.0), np.float32(1.0))
    sx, sy, sz = np.take(px, idx), np.take(py, idx), np.take(pz, idx)
    lift = terminator_lift(tables, hit, active[idx], (wx, wy, wz), (gx, gy, gz))
    if lift is not None:
        rows, offset = lift
        sx, sy, sz = sx.copy(), sy.copy(), sz.copy()
        sx[rows] += offset[:, 0]
        sy[rows] += offset[:, 1]
        sz[rows] += offset[:, 2]
    eps = spawn_offset(tables.ray_epsilon, sx, sy, sz) * sign
    if hit.shapes is not None:
        eps = unlifted(hit, active[idx], eps)
    dist = np.take(ls.dist, idx)
    ox, oy, oz = sx + gx * eps, sy + gy * eps, sz + gz * eps
    # Aim from the offset origin at the sampled point itself: keeping the direction from the
    # surface point would shift the ray by eps and, at grazing angles, make it cross the
    # emitter's plane before the point (a lamp 1 cm under a ceiling shadowed itself that way).
    finite = np.isfinite(dist)
    safe = np.where(finite, dist, np.float32(0.0))
    # The sampled point is where the light was sampled from, the surface point itself: a ray lifted off a
    # smooth surface (terminator_lift) aims at it from the lifted origin, as Cycles' shadow_ray_setup does
    # (aiming at a point moved by the lift, past a lamp's plane, let the lamp shadow itself).
    if lift is not None:
        sx, sy, sz = np.take(px, idx), np.take(py, idx), np.take(pz, idx)
    ax, ay, az = sx + wx * safe - ox, sy + wy * safe - oy, sz + wz * safe - oz
    to_point = np.sqrt(ax * ax + ay * ay + az * az)
    inv = np.float32(1.0) / np.maximum(to_point, np.float32(1e-30))
    wx, wy, wz = np.where(finite, ax * inv, wx), np.where(finite, ay * inv, wy), np.where(finite, az * inv, wz)
    # Stop short of a sampled point on an emissive triangle, so that the emitter itself does not count as an
    # occluder. A lamp has no geometry: its shadow ray reaches the point, as Cycles' does (shadow_ray_setup,
    # tmax the distance), so a surface lying in the lamp's plane (a lamp flush with a ceiling) stops some rays,
    # as many as the rounding of the two distances decides, as in Cycles, instead of none.
    lamp = np.take(ls.lamp, idx)
    short = np.where(lamp, to_point, to_point * np.float32(1.0 - 1e-4) - np.abs(eps))
    t_max = np.where(finite, short, np.inf).astype(np.float32)
    origins = np.stack([ox, oy, oz], axis=1)
    paths = active[idx]
    dirs = np.stack([wx, wy, wz], axis=1)
    stack = None
    if state.media is not None:
        # A shadow ray that leaves through the surface (toward a light behind it) enters or leaves the
        # medium there, as the path's ray would (Cycles copies the stack and enters or exits for it).
        through = np.where(sign < 0, tables.media.of_hits(np.take(hit.prim, paths)), -1).astype(np.int32)
        stack = volume_stack.enter_exit(np.take(state.media, paths, axis=1), through, np.take(hit.backfacing, paths))
    # Lights with Cast Shadow off are not blocked: no shadow ray, as in Cycles.
    traced = np.flatnonzero(np.take(ls.shadowed, idx))
    masks = shadow_masks(tables, ls, idx)
    # A shadow ray leaving a curve or a point skips it, as Cycles' shadow rays skip the primitive they leave.
    keys = None if tables.shapes is None else tables.triangles.self_keys(np.take(hit.prim, paths))
    if len(traced) == len(idx):
        transmittance = shadow_of(tables, origins, dirs, t_max, wave, state, paths, stack, masks, keys)
    else:
        transmittance = np.ones((3, len(idx)), np.float32)
        if len(traced):
            transmittance[:, traced] = shadow_of(tables, origins[traced], dirs[traced], t_max[traced], wave,
                                                 state, paths[traced], None if stack is None else stack[:, traced],
                                                 None if masks is None else masks[traced],
                                                 None if keys is None else keys[traced])
    if tables.coincident is not None and len(traced):
        # An opaque surface lying on this one (a duplicated face) on the light's side stops the shadow ray at
        # once, as in Cycles, whose shadow rays skip only the triangle they leave; Ember's offset steps over it.
        # (Lights with Cast Shadow off have no shadow ray to stop.)
        met = np.zeros(len(idx), bool)
        met[traced] = tables.coincident.crossing(
            np.take(hit.prim, paths[traced]), np.take(px, idx[traced]), np.take(py, idx[traced]),
            np.take(pz, idx[traced]), among=tables.coincident.opaque,
            side=(gx[traced] * sign[traced], gy[traced] * sign[traced], gz[traced] * sign[traced]))[0] >= 0
        if met.any():
            transmittance = np.where(met, np.float32(0.0), transmittance)
    vis = np.flatnonzero(((transmittance[0] > 0) | (transmittance[1] > 0) | (transmittance[2] > 0)) & (t_max > 0))
    if not len(vis):
        return
    rows = idx[vis]
    paths = active[rows]
    pdf = np.take(ls.pdf, rows)
    w = _mis_weight(tables, ls, rows, bsdf_pdf[vis]) if mis is None else mis[vis]
    contribution = np.take(state.throughput, paths, axis=1) * np.take(f, vis, axis=1) * \
        np.take(transmittance, vis, axis=1) * \
        np.take(ls.radiance, rows, axis=1) * (w / pdf)

    def reflecting(first):  # light reaching the first hit: split by the closures that reflect it there
        wi = (np.take(ls.wx, rows[first]), np.take(ls.wy, rows[first]), np.take(ls.wz, rows[first]))
        return passes.class_shares(*eval_split(closures, paths[first], wi))
    passes.add_light(tables, wave, state, paths, contribution, reflecting, _groups(tables, wave, ls, rows))


def _mis_weight(tables, ls, rows, bsdf_pdf) -> np.ndarray:
    """(n,) the MIS weights of the light samples rows against BSDF sampling: the power heuristic, but against the
    world's light samples the world's own (Environment.mis_balance: the balance heuristic with a compensated
    distribution; escaped rays use it too); 1 for lights no BSDF ray can hit."""
    pdf = np.take(ls.pdf, rows)
    heuristic = sampling.power_heuristic(pdf, bsdf_pdf)
    if tables.environment.mis_balance:
        heuristic = np.where(np.take(ls.world, rows), sampling.balance_heuristic(pdf, bsdf_pdf), heuristic)
    return np.where(np.take(ls.delta, rows), np.float32(1.0), heuristic)


def termination_scale(tables, settings) -> float:
    """Cycles' light_inv_rr_threshold: the exposure over the Light Threshold where light samples may be left
    untraced (a threshold above 0, and no light tree: scene/integrator.cpp), else 0. The integrator then draws the
    LOBE numbers at every vertex: their first number, unused by NEE_MIS's BSDF sampling, decides."""
    threshold = float(settings.light_threshold)
    if threshold <= 0 or tables.lights.light_tree or settings.mode != "NEE_MIS":
        return 0.0
    return float(settings.exposure) / threshold


def _terminated(tables, settings, ls, idx, f, w, u):
    """Cycles' light_sample_terminate for the light samples idx (f: (3, n) their closures' value, w their MIS
    weights, u: (n,) a uniform number each): the contribution before the path's throughput, Le f w / pdf, against
    the threshold; a sample whose largest channel times termination_scale, p, is below 1 goes on with probability
    p, its f divided by p, so that the estimate keeps its mean. Returns (kept (k,) indices into idx, f of those)."""
    e = np.abs(f * np.take(ls.radiance, idx, axis=1) * (w / np.take(ls.pdf, idx)))
    probability = np.maximum(np.maximum(e[0], e[1]), e[2]) * np.float32(termination_scale(tables, settings))
    kept = np.flatnonzero((probability >= 1) | (u < probability))
    p = np.minimum(probability[kept], np.float32(1.0))
    return kept, np.take(f, kept, axis=1) / p


def medium_next_event(tables, wave, state, rows, p, d, mixture, numbers, scale=None, chosen=None,
                      receiver=None) -> None:
    """Next-event estimation at points p (m, 3) where the paths rows (state rows) scatter in a medium: a light
    sample, the phase closures' value toward it (mixture: media.scatter.PhaseMixture over the m points; rays
    arrived along d, a 3 tuple of (m,)), the shadow ray's transmittance through surfaces and media, MIS
    against the phase function's own sampling (Cycles' integrate_volume_direct_light). numbers: (u_select,
    u1, u2) (m,) each; scale: (3, m) a factor on the paths' throughput (a distance's weight), or None;
    chosen: (emitters, their probabilities), the lights to sample (u_select unused), without MIS, or None;
    receiver: (m,) uint8 the points' light sets (Light Linking: their media's objects'), or None."""
    u_select, u1, u2 = numbers
    px, py, pz = (np.ascontiguousarray(p[:, k], np.float32) for k in range(3))
    bounce = _bounces(tables, state, rows)
    if chosen is None:
        ls = tables.lights.sample(px, py, pz, u_select, u1, u2, None, receiver, None, catcher_emitters(wave), bounce)
    else:
        ls = tables.lights.sample_chosen(px, py, pz, chosen[0], chosen[1], u1, u2, None, catcher_emitters(wave),
                                         bounce)
    le = ls.radiance
    if ls.visibility is not None:   # lights that volume scattering does not see (Cycles' shade_volume.h)
        le = le * ~ray_visibility.scatter_excluded(ls.visibility)
    f, phase_pdf = mixture.evaluate(d, (ls.wx, ls.wy, ls.wz))
    useful = np.flatnonzero((ls.pdf > 0) & ((le[0] > 0) | (le[1] > 0) | (le[2] > 0)) &
                            ((f[0] > 0) | (f[1] > 0) | (f[2] > 0)))
    if not len(useful):
        return
    paths = rows[useful]
    dist = np.take(ls.dist, useful)
    finite = np.isfinite(dist)
    dirs = np.stack([np.take(c, useful) for c in (ls.wx, ls.wy, ls.wz)], axis=1)
    # (Short of an emissive triangle's point, up to a lamp's: next_event.)
    t_max = np.where(finite, np.where(np.take(ls.lamp, useful), dist, dist * np.float32(1.0 - 1e-4)),
                     np.inf).astype(np.float32)
    origins = np.ascontiguousarray(p[useful], np.float32)
    traced = np.flatnonzero(np.take(ls.shadowed, useful))
    transmittance = np.ones((3, len(useful)), np.float32)
    if len(traced):
        masks = shadow_masks(tables, ls, useful[traced])
        transmittance[:, traced] = shadow_of(tables, origins[traced], dirs[traced], t_max[traced], wave, state,
                                             paths[traced], masks=masks)
    vis = np.flatnonzero((transmittance[0] != 0) | (transmittance[1] != 0) | (transmittance[2] != 0))
    if not len(vis):
        return
    at = useful[vis]
    pdf = np.take(ls.pdf, at)
    heuristic = sampling.power_heuristic(pdf, phase_pdf[at])
    if tables.environment.mis_balance:
        heuristic = np.where(np.take(ls.world, at), sampling.balance_heuristic(pdf, phase_pdf[at]), heuristic)
    w = np.where(np.take(ls.delta, at) | (chosen is not None), np.float32(1.0), heuristic)
    contribution = np.take(state.throughput, rows[at], axis=1) * np.take(f, at, axis=1) * \
        np.take(transmittance, vis, axis=1) * np.take(le, at, axis=1) * (w / pdf)
    if scale is not None:
        contribution *= np.take(scale, at, axis=1)
    passes.add_light(tables, wave, state, rows[at], contribution, _volume_shares, _groups(tables, wave, ls, at))


def _visible_closures(closures, paths, ls, rows, f):
    """f of the light samples rows (at the hits paths) with the closures their lamps exclude left out
    (kernels/lights/ray_visibility.py); the BSDF pdf stays that of every closure."""
    vis = np.take(ls.visibility, rows)
    sel = np.flatnonzero((vis & BSDF_RAYS) != BSDF_RAYS)
    if len(sel):
        f = f.copy()
        f[:, sel] = ray_visibility.eval_visible(closures, np.take(paths, sel), tuple(
            np.take(np.take(c, rows), sel) for c in (ls.wx, ls.wy, ls.wz)), np.take(vis, sel))
    return f


def _groups(tables, wave, ls, rows):
    """passes.add_light's light group parts of the light samples rows of ls: each its emitter's group."""
    return None if wave.groups is None else [(None, light_groups.of_samples(tables, ls, rows), None)]


def _bounces(tables, state, rows):
    """The bounce counts of the paths rows (state rows), which lights with a Max Bounces read, or None when no
    light has one."""
    return None if tables.lights.bounce_limit is None else np.take(state.bounce, rows)


def catcher_emitters(wave):
    """The emitters the wave's paths take light from: all (None), but on a shadow catcher's own paths
    (kernels/shadow_catcher.py) the world, lights that are shadow catchers and the emission of shadow catchers."""
    return None if wave.only_catchers is None else wave.only_catchers.emitters


def _volume_shares(first) -> np.ndarray:
    """Light scattered by a medium at a path's first scattering: the Volume passes' (passes.VOLUME_ROW)."""
    shares = np.zeros((passes.VOLUME_ROW + 1, len(first)), np.float32)
    shares[passes.VOLUME_ROW] = 1.0
    return shares


def terminator_lift(tables, hit, hits, light, ng):
    """Cycles' shadow terminator offset (shadow_ray_offset, kernel/light/sample.h): shadow rays toward
    lights near the horizon of a smooth low-poly surface leave from the smooth surface its normals
    describe, lifted off the flat triangle, in proportion as the light nears the horizon, below each
    object's Geometry Offset (Object > Shading > Shadow Terminator; 0.1 by default). Returns (rows of
    the shadow rays lifted, their (m, 3) offsets), or None."""
    if tables.terminator is None:
        return None
    cutoff = tables.terminator if np.ndim(tables.terminator) == 0 else \
        np.take(tables.terminator, tables.triangles.object_rows(np.take(hit.prim, hits)))
    nl = sum(np.take(hit.ns[k], hits) * light[k] for k in range(3))
    turned = np.where(nl < 0, np.float32(-1.0), np.float32(1.0))      # a light on the shading normal's back
    nl = np.abs(nl)
    side = tuple(c * turned for c in ng)
    ngl = sum(side[k] * light[k] for k in range(3))
    with np.errstate(divide="ignore", invalid="ignore"):
        amount = np.where(nl < cutoff, np.clip(2.0 - (ngl + nl) / cutoff, 0.0, 1.0),
                          np.clip(1.0 - ngl / cutoff, 0.0, 1.0))
    rows = np.flatnonzero((amount > 0) & (cutoff > 0))
    if not len(rows):
        return None
    offset = hit.smooth_offset(hits[rows], tuple(c[rows] for c in side))
    return rows, offset * amount[rows, None].astype(np.float32)


def shadow_of(tables, origins, dirs, t_max, wave, state, paths, stack=None, masks=None, keys=None) -> np.ndarray:
    """_shadow for shadow rays leaving the paths `paths` (state rows); stack: their volume stacks (K, n) when
    they differ from the paths' (None: the paths' own, when the scene has media); masks: the shadow masks of
    the emitters they go to (shadow linking), or None; keys: the curve or point each leaves
    (PrimitiveTable.self_keys), or None."""
    seeds = None
    if state.media is not None:
        stack = np.take(state.media, paths, axis=1) if stack is None else stack
        seeds = ray_keys(state, paths)
    return shadow(tables, origins, dirs, t_max, wave, np.take(state.bounce, paths),
                  None if state.lobes is None else np.take(state.lobes, paths, axis=1),
                  None if state.time is None else state.time.take(paths),
                  None if state.portal is None else np.take(state.portal, paths), stack, seeds, masks, keys,
                  np.take(state.transparent, paths))


def shadow(tables, origins, dirs, t_max, wave, depth, lobes=None, times=None, portal=None, stack=None,
           seeds=None, masks=None, keys=None, transparent=None) -> np.ndarray:
    """(3, n) transmittance of shadow rays: 0 where an opaque surface blocks them; through
    transparent surfaces, the product of their transparency (Cycles' transparent shadows); through media
    (stack: the rays' volume stacks (K, n), seeds their paths' PCG2D states, or None), their transmittance,
    the stacks changing where the rays pass a surface with a volume.
    depth : (n,) the bounce of the path each shadow ray leaves from, lobes its PathState.lobes (or None),
    portal its Ray Portals passed (or None): what the Light Path node reads. masks: (n,) uint64 the shadow
    masks of the emitters the rays go to (Shadow Linking: they pass objects whose blocker set is not in it,
    kernels/lights/links.py), or None. keys : (n,) the curve or point each ray leaves, which it skips
    (PrimitiveTable.self_keys, -1 none), or None. transparent : (n,) the transparent surfaces the path of each ray
    has passed (None: none), as Cycles' shadow path starts its transparent_bounce: a ray passes what its path has
    left of Transparent Max Bounces (integrate_shadow_max_transparent_hits; a medium's invisible boundary does not
    count), one more blocks it, and the Light Path node's Transparent Depth reads it plus the surfaces passed."""
    n = len(origins)
    split = wave.split
    if stack is not None and not (stack >= 0).any() and not tables.media.has_volume.any():
        stack = None
    # A shadow catcher's own paths are shadowed by shadow catchers only (Cycles' SHADOW_CATCHER_PATH_VISIBILITY).
    skipped = _passed_objects(tables, masks, wave.only_catchers is not None)
    if keys is not None and not (keys >= 0).any():
        keys = None
    if not tables.shading.shadow_transparent.any():
        if skipped is None and keys is not None:
            # Rays leaving a curve or a point meet it or their neighbours mostly: their closest hits, traced below,
            # answer at once, without an occlusion query first (on fur and in a dense cloud most are blocked).
            rows = np.flatnonzero(keys >= 0)
            others = np.flatnonzero(keys < 0)
            blocked = np.zeros(n, bool)
            if len(others):
                blocked[others] = tables.accel.occluded(origins[others], dirs[others], t_max[others], split,
                                                        None if times is None else times.take(others))
        else:
            blocked = tables.accel.occluded(origins, dirs, t_max, split, times)
            rows = np.flatnonzero(blocked) if skipped is not None or keys is not None else None
        if rows is not None:
            # What blocks them may be an object they pass, or the curve a ray leaves: the closest one that counts.
            hits = tables.accel.intersect(origins[rows], dirs[rows], t_max[rows], split,
                                          None if times is None else times.take(rows))
            visibility.skip_hidden(tables, origins[rows], dirs[rows], t_max[rows], hits, None, split,
                                   None if times is None else times.take(rows), None if keys is None else keys[rows],
                                   rule=None if skipped is None else (lambda prim, r: skipped(prim, rows[r])))
            blocked[rows] = hits.prim >= 0
        out = np.broadcast_to(np.where(blocked, np.float32(0.0), np.float32(1.0)), (3, n))
        if stack is None:
            return out
        open_ = np.flatnonzero(~blocked & (stack >= 0).any(axis=0))
        out = np.array(out)
        if len(open_):
            out[:, open_] *= tracking.transmittance(tables.media, stack[:, open_], origins[open_], dirs[open_],
                                                    t_max[open_], tuple(np.take(s, open_) for s in seeds),
                                                    march=marching(wave.settings))
        return out
    out = np.ones((3, n), np.float32)
    live = np.arange(n)
    origins, t_left = origins.copy(), t_max.copy()
    limit = int(wave.settings.transparent_max_bounces)
    before = np.zeros(n, np.int32) if transparent is None else np.asarray(transparent, np.int32)
    budget = np.maximum(limit - before, 0)
    crossed = np.zeros(n, np.int32)   # transparent surfaces passed (media boundaries not counted, as in Cycles)
    surfaces = np.zeros(n, np.int32)  # surfaces passed (Cycles' shadow transparent_bounce counts every one)
    boundary = None if tables.media is None else tables.media.boundary
    for crossing in itertools.count():
        hits = tables.accel.intersect(origins, dirs[live], t_left, split, None if times is None else times.take(live))
        if skipped is not None or keys is not None:
            visibility.skip_hidden(tables, origins, dirs[live], t_left, hits, None, split,
                                   None if times is None else times.take(live), None if keys is None else keys[live],
                                   rule=None if skipped is None else (lambda prim, r, live=live: skipped(prim, live[r])))
        found = np.flatnonzero(hits.prim >= 0)
        if stack is not None:
            # The media along the segment to the surface met (or to the light).
            inside = np.flatnonzero((stack[:, live] >= 0).any(axis=0))
            if len(inside):
                end = np.where(hits.prim[inside] >= 0, hits.t[inside], t_left[inside]).astype(np.float32)
                out[:, live[inside]] *= tracking.transmittance(
                    tables.media, stack[:, live[inside]], origins[inside], dirs[live[inside]], end,
                    tuple(np.take(s, live[inside]) for s in seeds), salt=1 + crossing, march=marching(wave.settings))
        if not len(found):
            break
        d = dirs[live[found]]
        hit = SurfaceHit(tables.triangles, hits.prim[found], hits.u[found], hits.v[found],
                         (d[:, 0], d[:, 1], d[:, 2]), tables.shading.needs_uv,
                         ray=None if tables.shapes is None else
                         (origins[found], hits.t[found], None if times is None else times.take(live[found]).times),
                         deform=None if tables.scene.deform_ids is None else deformed_corners(
                             tables.scene, hits.prim[found], None if times is None else times.take(live[found]).times))
        passed = before[live[found]] + surfaces[live[found]]
        hit.ray = RayInfo(depth[live[found]], passed, hits.t[found], shadow=True,
                          lobes=None if lobes is None else lobes[:, live[found]],
                          portal=None if portal is None else portal[live[found]])
        passes = tables.shading.transparency(hit)
        out[:, live[found]] *= passes
        through = found[(passes[0] > 0) | (passes[1] > 0) | (passes[2] > 0)]
        counted = through if boundary is None else through[~np.take(boundary, hit.mat[np.searchsorted(found, through)])]
        crossed[live[counted]] += 1
        surfaces[live[through]] += 1
        over = crossed[live[through]] > budget[live[through]]
        if over.any():   # more transparent surfaces than the ray's budget: opaque, as in Cycles
            out[:, live[through[over]]] = 0.0
            through = through[~over]
        if not len(through):
            break
        if stack is not None:
            prim = hits.prim[through]
            medium = tables.media.of_hits(prim)
            g = tables.triangles.gather(prim)
            d = dirs[live[through]]
            behind = g[NG] * d[:, 0] + g[NG + 1] * d[:, 1] + g[NG + 2] * d[:, 2] > 0
            stack = stack.copy()
            stack[:, live[through]] = volume_stack.enter_exit(stack[:, live[through]], medium, behind)
        # Continue just past the transparent surface.
        t = hits.t[through]
        step = t + spawn_offset(tables.ray_epsilon, *(origins[through, k] for k in range(3)))
        origins = origins[through] + dirs[live[through]] * step[:, None]
        t_left = t_left[through] - step
        live = live[through]
        keep = t_left > 0
        origins, t_left, live = origins[keep], t_left[keep], live[keep]
        if not len(live):
            break
    return out


def shadow_hidden(tables) -> bool:
    """Some object is not seen by shadow rays (Ray Visibility > Shadow off): they step past it."""
    vis = tables.visibility
    return vis is not None and bool(((vis & visibility.SHADOW) == 0).any())


def _passed_objects(tables, masks, catchers: bool = False):
    """The rule by which shadow rays pass objects, skipped(prim (m,), rays (m,)) -> (m,) bool (objects shadow
    rays do not see, or with catchers every object but the shadow catchers; objects outside the shadow masks
    (n,) of the emitters the rays go to), or None when they pass none."""
    hidden = catchers or shadow_hidden(tables)

    def unseen(prim):
        return visibility.hidden(tables, prim, visibility.SHADOW, catchers)
    if masks is None or tables.links is None:
        return (lambda prim, rays: unseen(prim)) if hidden else None
    links = tables.links

    def skipped(prim, rays):
        out = links.passes(links.rows(tables.triangles, prim), np.take(masks, rays))
        return out | unseen(prim) if hidden else out
    return skipped


def shadow_masks(tables, ls, rows):
    """(m,) uint64 shadow masks of the emitters the light samples rows chose, or None when all are every set."""
    if ls.emitter is None or tables.lights.links is None:   # (light groups alone also keep the emitters)
        return None
    masks = np.take(tables.lights.links.shadow, np.take(ls.emitter, rows))
    return None if (masks == ALL_SETS).all() else masks


# ---------------------------------------------------------------- emitters for the light sampler
def triangle_emission(tables, tri, b1=None, b2=None, toward=None, dist=None) -> np.ndarray:
    """(3, n) emitted radiance of triangles tri at barycentrics (b1, b2) seen from direction
    -toward (the direction from the receiver to the light) at distance dist ((n,); 1 where None, for power
    estimates); without barycentrics, the material's mean (textures averaged), for power estimates.
    The programs see a light sample's path state, as Cycles' light_sample_shader_eval: the emission is
    evaluated (not a camera ray) at the sample's ray length (Light Falloff, Light Path's Ray Length)."""
    mat = tables.triangles.materials(tri)
    if b1 is None:
        return tables.shading.mean_emission(mat)
    if toward is None:  # seen head-on, along the triangle's normal
        g = tables.triangles.gather(tri)
        toward = (-g[NG], -g[NG + 1], -g[NG + 2])
    hit = SurfaceHit(tables.triangles, tri, b1, b2, toward, tables.shading.needs_uv)
    zeros = np.zeros(len(tri), np.int32)
    hit.ray = RayInfo(zeros, zeros, np.ones(len(tri), np.float32) if dist is None else dist, emission=True,
                      camera=False)
    return tables.shading.surface(hit, closures=False).emission
