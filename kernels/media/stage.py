"""The path loop's medium stages (kernels/integrator.py runs them in `step`): the segment of each ray inside
media (distance sampling, tracking.py: a scattering event before the ray's hit, or the medium's transmittance
and emission on the way to it), the vertex where a path scatters (next-event estimation with the phase
function, then a phase sample, as Cycles' integrate_volume_direct_light and integrate_volume_phase_scatter),
and the volume stack's changes where rays go through surfaces (stack.py)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import light_groups, passes
from ..lights import nee
from ..paths import DIFFUSE_ANCESTOR, VOLUME_SCATTER, may_scatter, ray_keys, roulette_verdict
from ..geometry import NG
from ..lights.common import SPOT
from ..lights.links import media_emission_reaches, medium_receivers
from ..rng import keyed_uniforms as uniforms
from ..samples import BSDF, LIGHT, LIGHT_POINT, VOLUME_DISTANCE, VOLUME_LIGHT
from ..vec import F32, ONE, ZERO
from ..shading.volume import PhaseClosure
from . import equiangular
from . import stack as volume_stack
from .march import marching
from .scatter import PhaseMixture
from .tracking import track, transmittance

# The direction pdf a scattering vertex records when its segment's light sample took no MIS: MIS then weighs
# what its phase ray finds to 0 against any light that sampling can choose, and to 1 where none can.
NO_MIS_PDF = F32(1e-30)
MAX_CONES = 64             # spot lights whose cones a segment's light sample looks at
VOLUME_BOUNDS_MAX = 1024   # volume boundaries a path may pass (Cycles' VOLUME_BOUNDS_MAX, a guard)
# rng.keyed_uniforms salts: the segment's collisions, the phase closure pick, the segment's light sample.
SEGMENT_SALT, PICK_SALT, DIRECT_SALT, LIGHT_HIT_SALT = 0, 7, 11, 13


@dataclass
class Scattered:
    """The paths (of a step's N) that scatter in a medium before their rays' hits.

    mask : (N,) bool; rows : their indices; t : (m,) distances along their rays; origins, dirs : (m, 3);
    lit : (m,) bool, their segment took its light sample already (direct_light), the vertex takes none;
    shade_t : (m,) distances of the points whose phase closures they take (a marched step's, march.py), or None:
    their own."""
    mask: np.ndarray
    rows: np.ndarray
    t: np.ndarray
    origins: np.ndarray
    dirs: np.ndarray
    lit: np.ndarray
    shade_t: np.ndarray | None = None


def segments(tables, wave, state, rays, hits, ended=None, first: bool = False) -> Scattered | None:
    """Track the rays of the paths inside media to their hits (or out of the scene): what their media emit
    toward them is added, their throughput takes the segment's weight; the paths that scatter first are
    returned (None when none does)."""
    inside = (state.media >= 0).any(axis=0)
    if ended is not None:
        inside &= ~ended
    missed = np.flatnonzero(inside & (hits.prim < 0))
    if len(missed):
        # A ray that meets nothing (it leaves the scene, or a camera ray ends at the far clip plane) keeps the
        # world's medium alone, without end: Cycles' volume_stack_clean for background rays (shade_volume.h).
        state.media[:, missed] = -1
        if tables.media.world >= 0:
            state.media[0, missed] = tables.media.world
        inside &= (state.media >= 0).any(axis=0)
    inside = np.flatnonzero(inside)
    if not len(inside):
        return None
    prim = np.take(hits.prim, inside)
    t_end = np.where(prim >= 0, np.take(hits.t, inside), np.float32(np.inf)).astype(F32)
    may = may_scatter(wave, state)[inside]
    if state.continuation is not None:
        may &= np.take(state.continuation, inside) > 0
    origins, dirs = rays.origins[inside], rays.dirs[inside]
    # A camera ray whose scattering could only end it (no volume bounce allowed after it: the segment's light
    # sample already has the light it scatters toward the camera) scatters rarely, and the surface behind the
    # medium keeps most of its samples (Cycles guides camera rays' scattering probability alike).
    rare = (np.take(state.bounce, inside) == 0) if int(wave.settings.volume_bounces) == 0 and wave.nee else None
    seg = track(tables.media, state.media[:, inside], origins, dirs, t_end, ray_keys(state, inside), may,
                salt=SEGMENT_SALT, march=marching(wave.settings), rare=rare)
    throughput = np.take(state.throughput, inside, axis=1)
    lit = np.zeros(len(inside), bool)
    if wave.nee:
        lit = direct_light(tables, wave, state, inside, origins, dirs, t_end, may, first)
    if np.any(seg.emission != 0):
        le = throughput * seg.emission
        if state.link_set is not None:   # Light Linking: the paths whose receiver the emitting object reaches
            le = le * media_emission_reaches(tables, state.media[:, inside], np.take(state.link_set, inside))
        bounce = np.take(state.bounce, inside)
        le = passes.clamp(wave, le, bounce > 1)
        passes.accumulate(wave.radiance, state.path[inside], le)
        if wave.groups is not None:   # the group of the medium's object
            light_groups.write(wave, state.path[inside], le, light_groups.of_media(tables, state.media[:, inside]))
        if wave.aux is not None and "emission" in wave.aux:
            seen = np.flatnonzero(bounce == 0)
            wave.aux["emission"][:, state.path[inside[seen]]] += le[:, seen]
        if state.pass_weights is not None:
            later = np.flatnonzero(bounce > 0)
            passes.write_light(tables, wave, state, inside[later], le[:, later])
    state.throughput[:, inside] = throughput * seg.weight
    if not seg.scattered.any():
        return None
    picked = np.flatnonzero(seg.scattered)
    mask = np.zeros(len(state), bool)
    mask[inside[picked]] = True
    return Scattered(mask, inside[picked], seg.t[picked], origins[picked], dirs[picked], lit[picked],
                     None if seg.shade_t is None else seg.shade_t[picked])


def direct_light(tables, wave, state, inside, origins, dirs, t_end, may, first: bool = False) -> np.ndarray:
    """A light sample taken somewhere along each segment of the paths inside (state rows) through homogeneous
    media, as Cycles takes one per segment (volume_integrate_null_scattering): a light is chosen from the
    segment's middle, the distance is drawn by one-sample MIS (balance heuristic) of equiangular sampling
    toward the chosen light's point and distance sampling (Cycles' MULTIPLE_IMPORTANCE volume sampling, 50/50;
    distance alone toward a light at infinity), and at that distance the same light is sampled again
    (nee.medium_next_event with its choice), weighted by the transmittance to it over the distance's pdf. Camera rays
    (first) take their numbers from the stratified sequence, deeper rays from their paths' streams hashed.
    Returns the (len(inside),) mask of the segments that took it: their scattering vertices take none."""
    media = tables.media
    rows = np.flatnonzero(may & media.stack_homogeneous(state.media[:, inside]))
    done = np.zeros(len(inside), bool)
    if not len(rows):
        return done
    paths = inside[rows]
    o, dvec, end = origins[rows], dirs[rows], t_end[rows].astype(np.float64)
    c = media.stack_coefficients(state.media[:, paths], o, dvec, emission=False)
    sigma_t = c.sigma_t.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        albedo = np.where(sigma_t > 0, c.sigma_s / np.where(sigma_t > 0, sigma_t, 1.0), 0.0)
    total = albedo.sum(axis=0)
    scatters = total > 0
    done[rows] = True   # a medium that does not scatter reflects no light: nothing to sample
    keep = np.flatnonzero(scatters)
    if not len(keep):
        return done
    rows, paths, o, dvec, end = rows[keep], paths[keep], o[keep], dvec[keep], end[keep]
    sigma_t, prob = sigma_t[:, keep], (albedo[:, keep] / total[keep])
    phases = _phases_of(c.phases, keep)
    seeds = ray_keys(state, paths)
    mean_free = 1.0 / np.maximum(sigma_t.max(axis=0), 1e-30)
    reach = np.where(np.isfinite(end), end, 2.0 * mean_free)
    ref = (o + dvec * (reach / 2)[:, None]).astype(F32)
    if first:
        ua, ub = (np.take(u, paths) for u in state.samples.camera_extra(VOLUME_LIGHT))
        us, ut = (np.take(u, paths) for u in state.samples.camera_extra(VOLUME_DISTANCE))
    else:
        ua, ub = uniforms(seeds, 0, DIRECT_SALT)
        us, ut = uniforms(seeds, 2, DIRECT_SALT)
    uc, _ = uniforms(seeds, 1, DIRECT_SALT)
    lights = tables.lights
    rx, ry, rz = (np.ascontiguousarray(ref[:, k]) for k in range(3))
    receiver = None if state.link_set is None else medium_receivers(tables, state.media[:, paths])
    chosen, select = lights.choose_at(ua, rx, ry, rz, receiver)
    chosen, select = np.array(chosen), np.asarray(select, np.float64).copy()
    ls = lights.sample_chosen(rx, ry, rz, chosen, select.astype(F32), ub, uc,
                              bounce=None if lights.bounce_limit is None else np.take(state.bounce, paths))
    point = ref + np.stack([ls.wx, ls.wy, ls.wz], axis=1) * np.where(np.isfinite(ls.dist), ls.dist, 0.0)[:, None]
    aimed = np.isfinite(ls.dist) & (ls.pdf > 0)
    lo, hi = np.zeros(len(rows)), end.copy()
    spots = np.flatnonzero(lights.kind[:lights.light_count] == SPOT)[:MAX_CONES] if lights.light_count else ()
    if len(spots):
        _toward_spots(lights, spots, chosen, select, point, aimed, lo, hi, o, dvec, end, (rx, ry, rz),
                      uniforms(seeds, 5, DIRECT_SALT)[0], receiver)
    t_eq, _ = equiangular.sample(o, dvec, point, lo, hi, ut.astype(np.float64))
    # Both strategies from one number: the first half of us picks equiangular sampling, then its own rescaled.
    use_eq = aimed & (us < 0.5)
    ud = np.where(aimed, np.where(use_eq, us * 2.0, us * 2.0 - 1.0), us).astype(np.float64)
    channel = np.minimum((ud[None] >= np.cumsum(prob, axis=0)).sum(axis=0), 2)
    # Distance sampling is bounded to the part of the segment the light reaches, [lo, hi), as Cycles bounds it
    # (volume_integrate_homogeneous: sample_exponential_distribution over the light's valid ray segment): in
    # thin fog an unbounded distance lands past the segment's end, and the sample is lost, most of the time.
    t_dist = _bounded_exponential(ut.astype(np.float64), sigma_t[channel, np.arange(len(rows))], lo, hi)
    t = np.where(use_eq, t_eq, t_dist)
    decay = np.exp(-sigma_t * t)
    pdf_dist = (prob * _bounded_exponential_pdf(t, sigma_t, lo, hi)).sum(axis=0)
    pdf_eq = np.where(aimed & (t >= lo) & (t < hi), equiangular.pdf(o, dvec, point, lo, hi, t), 0.0)
    # One-sample MIS with the power heuristic, as volume_direct_scatter_mis: 2 p_s^2 / (p_eq^2 + p_dist^2) / p_s.
    own = np.where(use_eq, pdf_eq, pdf_dist)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_pdf = np.where(aimed, 2.0 * own / (pdf_eq * pdf_eq + pdf_dist * pdf_dist), 1.0 / pdf_dist)
    valid = np.flatnonzero((t < end) & (own > 0) & np.isfinite(t) & np.isfinite(inv_pdf) & (hi > lo))
    if not len(valid):
        return done
    scale = (decay[:, valid] * inv_pdf[valid]).astype(F32)
    p = (o[valid] + dvec[valid] * t[valid, None]).astype(F32)
    ue, uf = uniforms(seeds, 3, DIRECT_SALT)
    # The light chosen for the segment is sampled again from the distance drawn (Cycles samples "the same
    # light again" there), with the probability it was chosen with: no MIS against the phase function, whose
    # rays from these segments' scattering vertices count no light the segment's sample could find.
    nee.medium_next_event(tables, wave, state, paths[valid], p, tuple(np.ascontiguousarray(dvec[valid, k]) for k in
                                                                       range(3)),
                          PhaseMixture(_phases_of(phases, valid), len(valid)),
                          (None, ue[valid], uf[valid]), scale, (chosen[valid], select[valid].astype(F32)),
                          None if receiver is None else receiver[valid])
    return done


def _bounded_exponential(u, sigma, lo, hi):
    """Distances in [lo, hi) (hi may be inf) of density sigma exp(-sigma t) / (exp(-sigma lo) - exp(-sigma hi))
    (Cycles' sample_exponential_distribution over an interval, kernel/sample/mapping.h)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        kept = -np.expm1(-sigma * (hi - lo))
        t = lo - np.log1p(-u * kept) / sigma
    return np.clip(np.where(np.isfinite(t), t, lo), lo, hi)


def _bounded_exponential_pdf(t, sigma, lo, hi):
    """The density of _bounded_exponential at t, per row of sigma (C, n): 0 where sigma is."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = sigma * np.exp(-sigma * (t - lo)) / -np.expm1(-sigma * (hi - lo))
    return np.where((sigma > 0) & np.isfinite(out), out, 0.0)


def _toward_spots(lights, spots, chosen, select, point, aimed, lo, hi, o, dvec, end, ref, u, receiver=None):
    """Narrow the segments' equiangular sampling toward spot lights to their cones (distance sampling covers
    the rest), in place. A segment whose chosen spot's cone it misses takes one of the spots whose cones it
    crosses instead, at random: a light is then chosen with probability P(L) + P(missed) / (cones crossed) for
    the spots it crosses (select), 0 for those it misses (they do not light it), P(L) for other lights.
    receiver: the segments' light sets (Light Linking), or None."""
    n = len(chosen)
    ranges = [_cone_range(lights, int(j), o, dvec, end) for j in spots]
    crossed = np.stack([r[2] for r in ranges])
    pmf = np.stack([lights.selection_pmf(np.full(n, j), *ref, receiver).astype(np.float64) for j in spots])
    missed = (pmf * ~crossed).sum(axis=0)
    count = crossed.sum(axis=0)
    share = np.where(count > 0, missed / np.maximum(count, 1), 0.0)
    slot = np.full(n, -1)
    for k, j in enumerate(spots):
        slot[chosen == j] = k
    on_spot = slot >= 0
    hit = on_spot & crossed[np.maximum(slot, 0), np.arange(n)]
    repick = on_spot & ~hit & (count > 0)
    if repick.any():
        rows = np.flatnonzero(repick)
        rank = np.minimum((u[rows] * count[rows]).astype(np.int64), count[rows] - 1)
        order = np.cumsum(crossed[:, rows], axis=0) - 1
        slot[rows] = np.argmax((order == rank[None]) & crossed[:, rows], axis=0)
        chosen[rows] = spots[slot[rows]]
        point[rows] = lights.position[chosen[rows]]
    dark = on_spot & ~hit & ~repick   # a spot whose cone the segment misses: no light to sample (Cycles: none)
    aimed[dark] = False
    hi[dark] = lo[dark]
    picked = np.flatnonzero(hit | repick)
    for k in np.unique(slot[picked]):
        rows = picked[slot[picked] == k]
        lo[rows], hi[rows] = ranges[k][0][rows], ranges[k][1][rows]
        select[rows] = pmf[k, rows] + share[rows]
        aimed[rows] = True


def _cone_range(lights, j: int, o, dvec, end):
    """(t0, t1, crossed) of the rays (o, dvec, [0, end)) in spot light j's cone; a sized spot shines from a disk:
    its cone's apex moves back so that the cone holds the disk's."""
    cos_half = float(np.clip(lights.spot[j, 0], 0.0, 1.0 - 1e-6))
    axis = -lights.axis(np.array([j]), 2).T[0].astype(np.float64)
    back = float(lights.radius[j]) / np.sqrt(1.0 - cos_half * cos_half)
    n = len(o)
    apex = np.broadcast_to(lights.position[j] - axis * back, (n, 3))
    return equiangular.cone_range(o, dvec, apex, np.broadcast_to(axis, (n, 3)), np.full(n, cos_half), end)


def _phases_of(phases, idx):
    """The phase closures (shading.volume.PhaseClosure) of the points idx only."""
    return [PhaseClosure(c.phase, np.take(c.weight, idx, axis=1), {k: np.take(v, idx) for k, v in c.params.items()})
            for c in phases]


def vertex(tables, wave, state, scattered: Scattered, first: bool, last: int):
    """The paths `state` (those of `scattered`) at their scattering points: light samples through the phase
    function, then the next direction from it. Returns (state, (origins, dirs)) of those that go on, or None."""
    n = len(state)
    if state.link_set is not None:   # the points receive (and their phase rays leave) as their media's objects
        state.link_set, state.scattered = medium_receivers(tables, state.media), np.ones(n, bool)
    p = (scattered.origins + scattered.dirs * scattered.t[:, None]).astype(F32)
    d = tuple(np.ascontiguousarray(scattered.dirs[:, k]) for k in range(3))
    shaded = p if scattered.shade_t is None else \
        (scattered.origins + scattered.dirs * scattered.shade_t[:, None]).astype(F32)
    coefficients = tables.media.stack_coefficients(state.media, shaded, scattered.dirs, emission=False)
    mixture = PhaseMixture(coefficients.phases, n)
    if state.continuation is not None:   # Russian roulette's survivors (tracking let only them scatter)
        c = state.continuation
        state.throughput = state.throughput / np.where(c > 0, c, ONE)
        state.continuation = None
    numbers = state.samples.bounce(0 if first else 1)
    if wave.nee:
        own = np.flatnonzero(~scattered.lit)   # those whose segment took no light sample of its own
        if len(own):
            (u_select, _), (u1, u2) = numbers[LIGHT], numbers[LIGHT_POINT]
            nee.medium_next_event(tables, wave, state, own, p[own], tuple(c[own] for c in d),
                                  mixture if len(own) == n else PhaseMixture(_phases_of(coefficients.phases, own),
                                                                             len(own)),
                                  (u_select[own], u1[own], u2[own]),
                                  receiver=None if state.link_set is None else state.link_set[own])
    u1, u2 = numbers[BSDF]
    u_pick = uniforms(ray_keys(state, np.arange(n)), 0, PICK_SALT)[0]
    wo, f, pdf = mixture.sample(d, u_pick, u1, u2)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(pdf > 0, f / np.where(pdf > 0, pdf, ONE), ZERO)
    if state.pass_weights is not None:   # the first scattering in a medium: the Volume passes' (Cycles)
        first_hit = np.flatnonzero(state.bounce == 0)
        state.pass_weights[:, first_hit] = 0.0
        state.pass_weights[passes.VOLUME_ROW, first_hit] = 1.0
    throughput = state.throughput * weight
    alive = (pdf > 0) & ((throughput[0] > 0) | (throughput[1] > 0) | (throughput[2] > 0))
    state.bounce = state.bounce + 1
    state.volume_bounces = state.volume_bounces + 1
    if state.see_through is not None:   # a scattering in a medium is no smooth glass
        state.see_through[:] = False
    # Where the segment took its light sample without MIS (direct_light), the phase sample's rays count no light
    # that sampling can find: a pdf that MIS weighs to 0 against any light's, to 1 where none samples it.
    state.bsdf_pdf = np.where(scattered.lit, NO_MIS_PDF, pdf).astype(F32)
    if state.mis_facing is not None:
        state.mis_facing[:] = 0.0   # a point in a medium: the light choice reads no normal there
    if state.mis_origin is not None:
        state.mis_origin[:] = np.nan   # the ray starts at the point in the medium
    state.focus = None
    state.escape_scale = None
    if state.min_ray_pdf is not None:
        state.min_ray_pdf = np.minimum(state.min_ray_pdf, pdf)
    if state.lobes is not None:   # none of the surface labels (Cycles' LABEL_VOLUME_SCATTER), no surface count
        state.lobes[0] = VOLUME_SCATTER | (state.lobes[0] & DIFFUSE_ANCESTOR)
    if state.partner is not None:
        state.partner[:] = -1
        state.handed[:] = False
    state.continuation = roulette_verdict(wave, state, throughput, numbers, np.ones(n, bool))
    state.throughput = throughput
    alive &= state.segments < last
    alive = np.flatnonzero(alive)
    if not len(alive):
        return None
    state.compact(alive)
    state.segments = state.segments + 1
    dirs = np.stack([c[alive] for c in wo], axis=1).astype(F32)
    return state, (p[alive], dirs)


def transmittance_to(tables, wave, state, rays, rows, t) -> np.ndarray:
    """(3, m) the transmittance of the paths rows' media along their rays to distances t (a light they meet)."""
    out = np.ones((3, len(rows)), F32)
    inside = np.flatnonzero((np.take(state.media, rows, axis=1) >= 0).any(axis=0))
    if len(inside):
        paths = rows[inside]
        out[:, inside] = transmittance(tables.media, state.media[:, paths], rays.origins[paths], rays.dirs[paths],
                                       t[inside].astype(F32), ray_keys(state, paths), salt=LIGHT_HIT_SALT,
                                       march=marching(wave.settings))
    return out


def clip_crossings(tables, state, origins) -> None:
    """Camera rays start at the near clip distance: the stacks of the paths take the volume boundaries between
    the eye (whose media Media.start_stack found) and their rays' origins, as Cycles' volume stack
    initialisation traces from the camera (integrator/intersect_volume_stack.h)."""
    eye = np.asarray(tables.camera_frame[0], F32)
    offset = origins - eye
    length = np.sqrt(np.einsum("ij,ij->i", offset, offset)).astype(F32)
    live = np.flatnonzero(length > 0)
    start = np.broadcast_to(eye, (len(live), 3)).copy()
    for _ in range(64):
        if not len(live):
            return
        dirs = (offset[live] / length[live, None]).astype(F32)
        left = length[live] - np.sqrt(np.einsum("ij,ij->i", start - eye, start - eye)).astype(F32)
        hits = tables.accel.intersect(start, dirs, np.maximum(left, F32(0.0)))
        found = np.flatnonzero((hits.prim >= 0) & (left > 0))
        if not len(found):
            return
        prim = hits.prim[found]
        g = tables.triangles.gather(prim)
        d = dirs[found]
        behind = g[NG] * d[:, 0] + g[NG + 1] * d[:, 1] + g[NG + 2] * d[:, 2] > 0
        rows = live[found]
        state.media[:, rows] = volume_stack.enter_exit(state.media[:, rows], tables.media.of_hits(prim), behind)
        step = hits.t[found] + F32(1e-5) * np.maximum(F32(1.0), np.abs(start[found]).max(axis=1))
        start = start[found] + d * step[:, None]
        live = rows


def enter_exit_surfaces(tables, state, hit, alive, below) -> None:
    """The stacks of the paths (state, compacted to the hits `alive`) whose next rays go through their hits'
    surfaces (below): the media behind them entered, or left where the ray met the surface from behind."""
    if not below.any():
        return
    prim = np.take(hit.prim, alive)
    medium = np.where(below, tables.media.of_hits(prim), -1).astype(np.int32)
    state.media = volume_stack.enter_exit(state.media, medium, np.take(hit.backfacing, alive))
