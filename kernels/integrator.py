"""The wavefront path tracer: the lecture's path_trace as arrays of live paths per bounce.

A wave is a batch of paths (a band of image rows, one or more samples per pixel). Each bounce runs
named stages over the live paths: intersect, handle escaped rays, shade hits (shading data and
emission), sample the next direction, compact. Paths never recurse; a path leaves the live set when
it escapes, is absorbed, or reaches the path length.

Bounces follow Cycles: max_bounces = 0 is direct light only, so a path scatters at most
max_bounces + 1 times (the lecture's "max path length").
"""
from __future__ import annotations

import time

import numpy as np

from . import emitters_seen, motion, passes, sampling, shadow_catcher, shadow_linking, subsurface, visibility
from .accel import Hits, RayTimes
from .ao_pass import DIFFUSE_CLOSURES, ambient_occlusion
from .camera import generate_rays
from .environment import WorldFocus
from .geometry.deform import deformed_corners
from .glass_escapes import glass_escapes
from .bsdf.mixture_sample import BsdfSample
from .interaction import RayInfo, SurfaceHit
from .lights import nee
from .media import stage as media_stage
from .paths import (PathState, fast_gi_replaced, may_scatter, ray_keys, roulette_stops, roulette_verdict,
                    roulette_weights, seen_through, transparent_limit, type_limits)
from .rays import Rays, below, concat_rays, leaves_its_side, spawn
from .samples import BSDF, LENS, LOBE, TIME, Samples
from .settings import RenderSettings
from .vec import F32



def trace(tables, paths, settings: RenderSettings, split: bool = True, aux: dict | None = None,
           live: int | None = None, bake=None, timing: dict | None = None):
    """trace_paths for the paths of `paths` (GivenPaths, WavePaths: what each starts from, made a
    batch at a time; a bake's texels with `bake`, kernels/bake.BakeRun, whose start makes their first vertex).

    live: the most paths traced at once (None: all N). The paths start in their order, a batch at a
    time: when fewer than half of `live` are left, the next ones start beside them (their camera rays
    and first bounce a batch of their own, then one batch with the others), so that a wave's long paths
    (glass, many bounces) go on beside new ones rather than alone, bounce after bounce, each bounce
    paying the stages' fixed cost for a few paths. Subsurface walks are parked between steps beside
    them (subsurface.WalkPool; their paths count as in flight). Each path's numbers are its own: the
    radiance is the same whichever batches the paths shared.

    timing: a dict that gets "tail_s", the seconds of the wave's tail: its steps once every path has
    started and fewer than an eighth of a batch go on (what a wave costs whatever its size: schedule.WaveCost)."""
    n = len(paths)
    radiance = np.zeros((3, n), np.float32)
    alpha = np.ones(n, np.float32)
    nee = settings.mode == "NEE_MIS" and tables.lights.has_lights
    max_scatters = int(settings.max_bounces) + 1
    wave = _Wave(settings, nee, split, max_scatters, radiance, alpha,
                 0.0 if tables.scene.camera.kind == "ORTHO" else tables.pixel_size)
    wave.aux, wave.bake = aux, bake
    wave.walks = subsurface.WalkPool.of(tables)
    wave.groups = passes.wave_groups(aux)
    wave.catcher = shadow_catcher.start(tables, wave, n, _Wave)
    # The last step a path may take: a bounce or a transparent pass-through per ray, and the camera ray.
    last = max_scatters + transparent_limit(settings)
    live = n if live is None else max(1, int(live))
    started = 0
    going = None   # the paths past their first bounce: (PathState, Rays), or None
    thin, tail_began = max(1, min(live, n) // 8), None
    while True:
        # The paths in flight: those going on and those whose walks are parked (subsurface.WalkPool).
        flying = (0 if going is None else len(going[0])) + _parked(wave)
        if tail_began is None and started >= n and flying < thin:
            tail_began = time.perf_counter()
        if started < n and 2 * flying < live:
            size = live - flying
            if size > paths.spp:
                size -= size % paths.spp   # whole pixels: their places in the sequence are found once
            end = min(n, started + size)
            if bake is None:
                fresh = start_paths(tables, wave, paths, started, end)
                if fresh is not None:
                    fresh = step(tables, wave, *fresh, first=True, last=last)
            else:
                fresh = bake.start(tables, wave, paths, started, end, last)
            started = end
            if fresh is not None:
                going = _joined(going, fresh)
            going = _walks_on(tables, wave, going, started >= n, last)
            _catch_up(tables, wave, last)
            continue
        if going is None:
            if _parked(wave):   # only walks are left in flight: they go to their ends
                going = _walks_on(tables, wave, None, True, last)
            elif not _catch_up(tables, wave, last):
                break
            continue
        going = step(tables, wave, *going, first=False, last=last)
        going = _walks_on(tables, wave, going, started >= n, last)
        _catch_up(tables, wave, last)
    if wave.catcher is not None:
        shadow_catcher.finish(wave, radiance, alpha)
    if timing is not None:
        timing["tail_s"] = 0.0 if tail_began is None else time.perf_counter() - tail_began
    return radiance, alpha


def _joined(a, b):
    """Two batches of going paths (PathState, Rays) as one; either may be None."""
    if a is None or b is None:
        return b if a is None else a
    return PathState.concat(a[0], b[0]), concat_rays(a[1], b[1])


def _walks_on(tables, wave, going, all_started: bool, last: int):
    """The subsurface walks parked in the wave (subsurface.WalkPool) take their next steps, all of them once no
    path goes on and none is left to start; the paths whose walks came out go on from their exits beside
    `going`. Returns the going paths (PathState, Rays), or None."""
    if not _parked(wave):
        return going
    found = wave.walks.advance(drain=going is None and all_started)
    tables.crew.check_stop()
    return going if found is None else _joined(going, _exits_go_on(tables, wave, *found, last))


def _parked(wave) -> int:
    return 0 if wave.walks is None else len(wave.walks)


def _catch_up(tables, wave, last: int) -> bool:
    """One step of the shadow catchers' copies (kernels.shadow_catcher) beside the wave's own; whether some go on."""
    going = None if wave.catcher is None else wave.catcher.take()
    if going is not None:
        wave.catcher.add(step(tables, wave.catcher.paths, *going, first=False, last=last))
    return going is not None and wave.catcher.going is not None


def start_paths(tables, wave, paths, start: int, end: int):
    """The camera rays of the paths [start, end): (PathState, Rays), None when none is traced."""
    settings = wave.settings
    n = end - start
    rng, row, col, strata = paths.batch(start, end)
    # A lobe to choose, or light samples to leave untraced (the Light Threshold): the LOBE numbers are drawn.
    samples = Samples(rng, strata if settings.mode == "NEE_MIS" else None, settings.seed, wave.nee,
                      lobes=tables.shading.mixes_lobes or nee.termination_scale(tables, settings) > 0)
    jx, jy = samples.camera()
    camera = tables.scene.camera
    lens = samples.camera_extra(LENS) if camera.aperture_radius > 0 else None
    times = None
    if tables.scene.has_motion:
        times = motion.sample_time(samples.camera_extra(TIME)[0], tables.scene.shutter_table, row,
                                  camera.height, tables.scene.rolling_shutter).astype(np.float32)
    # Each camera ray's own differentials, as Cycles', not the frame centre's, where something reads them: a Bump's
    # steps, the Wireframe's Pixel Size, Huang hair's pixel coverage on curves.
    footprint = camera.kind != "ORTHO" and (tables.shading.reads_footprint or tables.shapes is not None)
    origins, dirs, t_max, *spread = generate_rays(camera, row, col, jx, jy, lens, times, spread=footprint)
    rays = Rays(origins, dirs, t_max)
    state = new_paths(tables, wave, n, samples, start, times, tables.camera_media)
    if footprint:
        state.dp, state.dd = spread[0]
    if tables.media is not None and camera.kind != "ORTHO":
        media_stage.clip_crossings(tables, state, rays.origins)
    if camera.kind == "ORTHO":
        state.dp[:] = tables.pixel_size
    if camera.kind == "PANO":
        traced = np.flatnonzero(rays.t_max > 0)  # outside a fisheye's circle: black, alpha 1 (Cycles)
        if not len(traced):
            return None
        if len(traced) < n:
            state.compact(traced)
            rays = Rays(rays.origins[traced], rays.dirs[traced], rays.t_max[traced])
    return state, rays


def new_paths(tables, wave, n: int, samples, start: int, times=None, media=None) -> PathState:
    """The state of n new paths (wave indices start.., numbers `samples`, shutter times or None) with the records
    the scene and the wave's passes ask for; in scenes with media, inside the media `media` (a (K,) volume stack:
    the eye's), or None: the world's medium alone (a bake's paths, as Cycles starts them)."""
    settings, aux = wave.settings, wave.aux
    state = PathState.start(n, samples)
    if start:
        state.path = state.path + start
    state.time = None if times is None else RayTimes(times)
    if tables.coincident is not None:
        state.partner, state.partner_uv = np.full(n, -1, np.int64), np.zeros((2, n), np.float32)
        state.handed = np.zeros(n, bool)
    if tables.shading.has_portal:
        state.portal = np.zeros(n, np.int32)
    if aux is not None and ("denoising_albedo" in aux or "denoising_normal" in aux or "denoising_depth" in aux):
        state.features = np.ones((3, n), np.float32)
    if aux is not None and any(passes.kind(name) == "LIGHT" for name in aux if passes.known(name)):
        state.pass_weights = np.zeros((6 if tables.media is None else 7, n), np.float32)
    if tables.shading.reads_lobes or _caustics(settings) is not None or type_limits(settings) is not None \
            or tables.visibility is not None or tables.shading.burley \
            or tables.lights.visibility is not None or tables.lights.world_restricted \
            or (settings.ao_bounces and settings.ao_factor):   # (visibility.py ray_types reads the last label)
        state.lobes = np.zeros((4, n), np.int32)
    if settings.filter_glossy > 0 or tables.shading.bevels:  # Cycles' Bevel skips blurry bounces too
        state.min_ray_pdf = np.full(n, np.inf, np.float32)
    if wave.nee and tables.lights.reads_facing:
        state.mis_facing = np.zeros((4, n), np.float32)
    if (tables.lights.has_surface_lights or tables.emissive or tables.lights.portals is not None) \
            and (tables.shading.transparent.any() or tables.media is not None):
        state.mis_origin = np.full((3, n), np.nan, np.float32)
    if tables.links is not None:   # camera rays leave the world's object (light set 0), no scattering
        state.link_set, state.scattered = np.zeros(n, np.uint8), np.zeros(n, bool)
    if tables.shapes is not None:
        state.self_key = np.full(n, -1, np.int64)
    if settings.widen_differentials and tables.shading.reads_footprint:
        state.dd = np.full(n, wave.spread_dd, np.float32)
    if settings.transparent_background and settings.transparent_glass is not None:
        state.see_through = np.ones(n, bool)
    if passes.has_single_passes(aux):
        state.data_pending = np.ones(n, bool)
    if tables.media is not None:
        state.media = tables.media.start_stack(n) if media is None else np.repeat(media[:, None], n, axis=1)
        state.volume_bounces = np.zeros(n, np.int32)
        state.volume_bounds = np.zeros(n, np.int32)
    return state


def first_vertex(tables, wave, state, rays, hits, last: int):
    """The first vertex of paths whose first hits are given (a bake's texels, kernels/bake.py), as step() goes on
    once it has traced the camera's rays: (the paths that go on, their rays) or None."""
    return _surface_vertex(tables, wave, state, rays, hits, np.arange(len(state)), first=True, last=last)


def step(tables, wave, state, rays, first: bool, last: int):
    """One step of the paths: trace their rays, take what they find, shade, sample lights and the next
    direction. first: the paths' camera rays (they all are; otherwise none is). Returns the paths that
    go on and their next rays, or None."""
    tables.crew.check_stop()
    replaced = None if first else fast_gi_replaced(wave.settings, state)
    if replaced is not None and replaced.any():   # Fast GI: these rays reach as far as the world's AO distance
        reach = np.float32(tables.scene.world.ao_distance)
        rays = Rays(rays.origins, rays.dirs, np.where(replaced, np.minimum(rays.t_max, reach), rays.t_max))
    hits = tables.accel.intersect(rays.origins, rays.dirs, rays.t_max, wave.split, state.time)
    if replaced is not None and replaced.any():   # nor do their lamps and media
        hits.t = np.where((hits.prim < 0) & replaced, np.minimum(hits.t, rays.t_max), hits.t)
    if state.partner is not None:
        _hand_over(state, hits)
    if tables.visibility is not None or state.self_key is not None:
        # Past objects the ray's type does not see, and the curve or point the ray leaves (Cycles' rays skip it).
        visibility.skip_hidden(tables, rays.origins, rays.dirs, rays.t_max, hits,
                               visibility.ray_types(state, first) if tables.visibility is not None else None,
                               wave.split, state.time, state.self_key, wave.only_catchers is not None)
    if tables.links is not None and not first:
        shadow_linking.dedicated_light(tables, wave, state, rays, hits)
    ended = None
    if tables.lights.has_surface_lights and (not first or tables.lights.camera is not None):
        ended = emitters_seen.lights_hit(tables, wave, state, rays, hits)
    scattered = None
    if state.media is not None:
        scattered = media_stage.segments(tables, wave, state, rays, hits, ended, first)
        if scattered is not None:
            ended = scattered.mask if ended is None else ended | scattered.mask
    emitters_seen.escaped(tables, wave, state, rays, hits, ended)
    tables.crew.check_stop()   # also between the bounce's long stages: tracing, shading, light samples
    found = np.flatnonzero((hits.prim >= 0) if ended is None else (hits.prim >= 0) & ~ended)
    if state.continuation is not None:
        found = roulette_stops(tables, state, hits, found)
    medium = None
    if scattered is not None:
        medium = media_stage.vertex(tables, wave, state.rows(scattered.rows), scattered, first, last)
        if medium is not None:
            medium = (medium[0], Rays(*medium[1], np.full(len(medium[0]), np.inf, np.float32)))
            if medium[0].self_key is not None:   # a ray leaving a point in a medium skips no curve
                medium[0].self_key = np.full(len(medium[0]), -1, np.int64)
    through = None
    if tables.visibility is not None:
        found, through = _held_out(tables, wave, state, hits, found)
    copies = None if wave.catcher is None else shadow_catcher.split(tables, wave, state, rays, hits, found)
    if not len(found):
        return medium
    state.compact(found)
    surface = _surface_vertex(tables, wave, state, rays, hits, found, first, last,
                              held=None if through is None else np.searchsorted(found, through))
    if copies is not None:   # the shadow catchers' copies of the paths shade the same hits, for their own pass
        wave.catcher.add(_surface_vertex(tables, wave.catcher.paths, copies[0], rays, hits, copies[1], first, last))
    if medium is None or surface is None:
        return surface if medium is None else medium
    return PathState.concat(surface[0], medium[0]), concat_rays(surface[1], medium[1])


def _surface_vertex(tables, wave, state, rays, hits, found, first: bool, last: int, subsurface_exit: bool = False,
                    held=None):
    """The paths `state` (compacted to the rays' hits `found`) at the surfaces they met: shading, data
    passes, emission, holdout, next-event estimation, the next direction, roulette. Returns the paths that go
    on and their next rays, or None. (A participating medium adds a vertex stage of its own beside this one:
    docs/architecture.md, Where new content goes.) subsurface_exit: the points where subsurface walks left
    the surface, shaded as Cycles shades them (kernels.subsurface.exit_closures; no emission, holdout, data
    passes or roulette). held: the rows met on a holdout object whose material may be transparent (_held_out)."""
    settings, aux = wave.settings, wave.aux
    hit = _surface_hit(tables, hits, rays, found, state.time)
    t_hit = np.take(hits.t, found)
    if not subsurface_exit:
        # Cycles' compact ray differentials: the spread grows by the camera's pixel angle per unit
        # of distance, bounce after bounce (kernel/util/differential.h).
        state.dp = state.dp + t_hit * (wave.spread_dd if state.dd is None else state.dd)
    hit.ray = RayInfo(state.bounce, state.transparent, t_hit, dp=state.dp, lobes=state.lobes,
                      caustics=_caustics(settings), portal=state.portal)
    if subsurface_exit:
        closures = subsurface.exit_closures(hit)
    else:
        if tables.shading.traces:  # Ambient Occlusion and Bevel nodes trace here (Cycles' shade_surface_raytrace)
            hit.ray.keys = ray_keys(state, np.arange(len(state)))
            hit.ray.time, hit.ray.min_ray_pdf, hit.ray.split = state.time, state.min_ray_pdf, wave.split
        shading = tables.shading.surface(hit)
        if first and wave.bake is not None:
            wave.bake.first_hit(wave, state, hit, shading)
        if held is not None:
            _held_transparent(tables, wave, state, hit, shading, held)
        closures = shading.closures
        tables.crew.check_stop()
        if aux is not None and (first or state.data_pending is not None or passes.behind_transparent(aux)):
            passes.write_data(tables, aux, state, hit, closures, settings, first)
        if state.features is not None:
            passes.write_denoising_features(tables, aux, state, hit, shading, t_hit, settings)
        if state.min_ray_pdf is not None and settings.filter_glossy > 0:
            _filter_glossy(closures, state.min_ray_pdf, settings.filter_glossy)
        if tables.emissive:
            emitters_seen.emission_on_hit(tables, wave, state, hit, shading, hits, rays, found)
        if tables.shading.has_holdout:
            _holdout(wave, state, shading)
        if state.continuation is not None:
            roulette_weights(state)
    numbers = state.samples.bounce(0 if first else 1)
    if aux is not None and "ao" in aux and not subsurface_exit:
        _ao_pass(tables, wave, state, hit, closures, shading, numbers)
    if settings.ao_additive and wave.only_catchers is None:
        _fast_gi_add(tables, wave, state, hit, closures, numbers)
    receiver = None if tables.links is None else tables.links.receivers(tables.triangles, hit.prim)
    focus = None
    lit = wave.nee and not (first and wave.bake is not None and not wave.bake.direct)
    if lit:
        focus = nee.world_focus(tables, hit, closures)
        nee.next_event(tables, wave, state, hit, closures, numbers, focus, receiver)
        tables.crew.check_stop()
    bs = _sample_bsdf(tables, wave, hit, closures, numbers)
    tables.crew.check_stop()
    if state.pass_weights is not None:
        passes.first_bounce_shares(tables, state, closures, bs)
    # (Not with Transparent Glass: the world a smooth glass branch escapes to may be alpha instead.)
    if lit and tables.glass_escapes_on and state.see_through is None:
        glass_escapes(tables, wave, state, hit, closures, bs, receiver)
    alive = _continues(tables, wave, hit, state, bs, numbers, focus, closures)
    if state.mis_origin is not None:
        _keep_origins(state, rays, found, bs)
    if receiver is not None:   # the next ray leaves this object (transparent pass-throughs keep the last one's)
        state.link_set, state.scattered = np.where(bs.transparent, state.link_set, receiver), ~bs.transparent
    if state.lobes is not None:
        state.track_lobes(bs, closures, bs.transparent if bs.subsurface is None else bs.transparent | bs.subsurface)
    # A path takes at most `last` + 1 steps (its rays: the camera's, one per bounce or pass-through); a
    # volume's invisible boundary is not one, up to Cycles' VOLUME_BOUNDS_MAX crossings.
    bounds = None if tables.media is None else bs.transparent & np.take(tables.media.boundary, hit.mat)
    if bounds is None:
        alive = alive[np.take(state.segments, alive) < last]
    else:
        alive = alive[np.where(bounds[alive], np.take(state.volume_bounds, alive) < media_stage.VOLUME_BOUNDS_MAX,
                               np.take(state.segments, alive) < last)]
    exits = None
    if bs.subsurface is not None:   # the paths that picked a subsurface closure walk beneath the surface and come out
        walking = np.take(bs.subsurface, alive)
        if walking.any():
            exits = _subsurface_exits(tables, wave, state.rows(alive[walking]), hit, closures, bs, alive[walking],
                                      last)
            alive = alive[~walking]
    if not len(alive):
        return exits
    state.compact(alive)
    if state.self_key is not None:
        state.self_key = tables.triangles.self_keys(np.take(hit.prim, alive))
    if bounds is None:
        state.segments = state.segments + 1
    else:
        crossed = bounds[alive]
        state.segments = state.segments + ~crossed
        state.volume_bounds = state.volume_bounds + crossed
    through = np.take(below(bs), alive)
    if state.partner is not None:
        _crossings(tables, state, hit, alive, bs)
        if bounds is not None and state.media is not None:
            # A ray leaving a volume's boundary where an opaque surface lies on it (a fog box standing on a floor)
            # is handed that surface at once and reflects back to the side it came from: it does not cross the
            # boundary. Otherwise the floor under a fog box would shade (and light) as if outside the fog.
            met = state.partner >= 0
            if met.any():
                stays = met & bounds[alive]
                stays[met] &= tables.coincident.opaque_of(state.partner[met])
                through = through & ~stays
    if state.media is not None:
        media_stage.enter_exit_surfaces(tables, state, hit, alive, through)
    going = state, _clipped(spawn(tables, hit, alive, bs), rays, found, t_hit, alive, bs)
    if exits is None:
        return going
    return PathState.concat(going[0], exits[0]), concat_rays(going[1], exits[1])


# ---- the surface vertex's helpers: the next rays' reach, the AO pass, Fast GI's Add
def _keep_origins(state, rays, found, bs) -> None:
    """PathState.mis_origin after a surface vertex (state rows: the rays' hits found): a ray that passes the surface
    straight through keeps the start of the ray that met it (Cycles moves only its tmin); any other starts here."""
    kept = bs.transparent & ~bs.portal
    state.mis_origin[:, ~kept] = np.nan
    first = np.flatnonzero(kept & np.isnan(state.mis_origin[0]))
    if len(first):
        state.mis_origin[:, first] = rays.origins[found[first]].T


def _clipped(next_rays, rays, found, t_hit, alive, bs):
    """next_rays with the rays that pass straight through (transparent surfaces, volume boundaries) keeping what
    was left of their ray's reach: Cycles continues such a ray with its tmax (only its tmin moves on), so a
    camera ray still ends at the far clip plane behind them."""
    reach = np.take(rays.t_max, found)[alive]
    if not np.isfinite(reach).any():
        return next_rays
    through = np.take(bs.transparent, alive) & np.isfinite(reach)
    if not through.any():
        return next_rays
    left = np.maximum(reach - t_hit[alive], np.float32(0.0)).astype(np.float32)
    return Rays(next_rays.origins, next_rays.dirs, np.where(through, left, next_rays.t_max).astype(np.float32))


def _ao_pass(tables, wave, state, hit, closures, shading, numbers) -> None:
    """The Ambient Occlusion pass (kernels/ao_pass.py) at the surfaces the camera sees: the paths that have not
    scattered yet (their first hit, or one behind transparent surfaces), but not those a holdout ends there."""
    rows = np.flatnonzero((state.bounce == 0) & (state.transparent < transparent_limit(wave.settings)))
    if tables.shading.has_holdout and len(rows):
        rows = rows[np.take(shading.holdout, rows) < 1]
    if len(rows):
        ao = ambient_occlusion(tables, wave, hit, closures, numbers[BSDF], rows)
        passes.accumulate(wave.aux["ao"], state.path[rows], ao * np.take(state.throughput, rows, axis=1))


def _fast_gi_add(tables, wave, state, hit, closures, numbers) -> None:
    """Fast GI's Add (Cycles' KERNEL_FEATURE_AO_ADDITIVE, integrate_surface_ao): at every surface a path may
    scatter from, its diffuse closures' weight times the AO factor times the AO of one ray (kernels/ao_pass.py),
    added to the image alone (no light pass), as light from a white sky the surroundings shade."""
    rows = np.flatnonzero(may_scatter(wave, state))
    if not len(rows) or not len(closures):
        return
    diffuse = np.flatnonzero(np.isin(closures.lobe, DIFFUSE_CLOSURES))
    if not len(diffuse):
        return
    n = len(hit)
    weight = np.stack([np.bincount(closures.hit[diffuse], closures.weight[k, diffuse], minlength=n)
                       for k in range(3)]).astype(F32) * F32(wave.settings.ao_additive)
    rows = rows[np.any(np.take(weight, rows, axis=1) != 0, axis=0)]
    if len(rows):
        ao = ambient_occlusion(tables, wave, hit, closures, numbers[BSDF], rows)
        passes.accumulate(wave.radiance, state.path[rows],
                          ao * np.take(weight, rows, axis=1) * np.take(state.throughput, rows, axis=1))


# ---- stage: subsurface scattering (kernels.subsurface), between a subsurface closure's pick and its exit point
def _subsurface_exits(tables, wave, state, hit, closures, bs, rows, last):
    """The paths `state` (of the hits rows, which picked a subsurface closure) walk beneath their surfaces; where a walk
    comes out, the exit point is a surface vertex of its own (Cycles' INTERSECT_SUBSURFACE, then SHADE_SURFACE
    with PATH_RAY_SUBSURFACE). Returns the paths that go on from there and their rays, or None."""
    out, prim, u, v, t, direction, throughput = subsurface.enter(tables, state, hit, closures, bs, rows, wave.split,
                                                                wave.walks)
    tables.crew.check_stop()
    if not len(out):
        return None
    state.compact(out)
    state.throughput = throughput
    return _exits_go_on(tables, wave, state, prim, u, v, t, direction, last)


def _exits_go_on(tables, wave, state, prim, u, v, t, direction, last):
    """The paths `state` (their throughput the walks' at the exits) at the points where their walks came out: the
    triangles prim at barycentrics u, v, after a last flight of length t along direction (3, n)."""
    n = len(state)
    # As Cycles, the exit is seen from outside: the ray arrives against the last flight's direction.
    rays = Rays(np.zeros((n, 3), np.float32), np.ascontiguousarray(-direction.T), np.full(n, np.inf, np.float32))
    return _surface_vertex(tables, wave, state, rays, Hits(prim, t, u, v), np.arange(n), first=False, last=last,
                           subsurface_exit=True)


# ---- stage: the surface-interaction record of the rays that hit
def _surface_hit(tables, hits, rays, found, times=None) -> SurfaceHit:
    d = rays.dirs
    direction = (np.take(d[:, 0], found), np.take(d[:, 1], found), np.take(d[:, 2], found))
    prim = np.take(hits.prim, found)
    return SurfaceHit(tables.triangles, prim, np.take(hits.u, found),
                      np.take(hits.v, found), direction, tables.shading.needs_uv,
                      _hit_motion(tables, prim, times) if tables.accel.moves else None,
                      None if tables.shapes is None else (np.take(rays.origins, found, axis=0), np.take(hits.t, found),
                                                          None if times is None else times.times),
                      deformed_corners(tables.scene, prim, None if times is None else times.times)
                      if tables.accel.moves else None)


def _hit_motion(tables, prim, times):
    """(hits on moving triangles, (m, 3, 4) matrices taking the triangles' stored positions to where
    they are at each hit's time, (m, 3, 3) the same for normals), or None when no hit moves; every object's at
    once (a particle system's hundreds of moving instances cost what one does)."""
    ids = tables.scene.motion_ids
    if ids is None or not len(tables.motion):   # only deformation moves (deformed_corners)
        return None
    # Curves and points (numbered after the triangles) move by their own motion keys, not here.
    ids = np.where(prim < len(ids), np.take(ids, np.minimum(prim, len(ids) - 1)), -1)
    rows = np.flatnonzero(ids >= 0)
    if not len(rows):
        return None
    obj = ids[rows]
    t = np.take(times.times, rows) if times is not None else np.full(len(rows), 0.5, np.float32)
    m = np.empty((len(rows), 3, 4), np.float64)
    stack = tables.motion_stack_of[obj]
    for k, (_, stacked) in enumerate(tables.motion_stacks):
        sel = np.flatnonzero(stack == k)
        if len(sel):
            m[sel] = motion.interpolate_many(stacked, tables.motion_place[obj[sel]], t[sel])
    delta, normal = _moved_by(m, tables.motion_inverse[obj])
    return rows, delta, normal


def _moved_by(m: np.ndarray, ref: np.ndarray):
    """(n, 3, 4) M(t) M_ref^-1 and (n, 3, 3) its normal matrix (inverse transpose), from (n, 3, 4) M(t) and (n, 4, 4)
    M_ref^-1."""
    delta = np.empty((len(m), 3, 4), np.float64)
    delta[:, :, :3] = m[:, :, :3] @ ref[:, :3, :3]
    delta[:, :, 3] = np.einsum("nij,nj->ni", m[:, :, :3], ref[:, :3, 3]) + m[:, :, 3]
    rows3 = delta[:, :, :3]  # inverse transpose = rows' cross products / determinant (cofactors)
    cof = np.stack([np.cross(rows3[:, 1], rows3[:, 2]), np.cross(rows3[:, 2], rows3[:, 0]),
                    np.cross(rows3[:, 0], rows3[:, 1])], axis=1)
    det = np.einsum("ni,ni->n", rows3[:, 0], cof[:, 0])
    normal = cof / np.where(np.abs(det) > 1e-30, det, 1.0)[:, None, None]
    return delta.astype(np.float32), normal.astype(np.float32)


# ---- stage: Holdout closures cut a hole in alpha where the camera sees them
def _holdout(wave, state, shading):
    held = np.flatnonzero((shading.holdout > 0) & seen_through(state))
    if len(held):
        share = np.take(shading.holdout, held) * np.take(state.throughput, held, axis=1).mean(axis=0)
        wave.alpha[state.path[held]] -= share


# ---- stage: holdout objects cut a hole in alpha where the camera sees them, and end the path there
def _held_out(tables, wave, state, hits, found):
    """(found, through): found without the camera paths (bounce 0: only transparent surfaces passed, Cycles'
    PATH_RAY_TRANSPARENT_BACKGROUND) that met a holdout object of an opaque material: each takes its
    throughput's mean off the pixel's alpha and ends, as Cycles' integrate_surface_holdout with a holdout weight
    of one. through (or None): those on a material that may be transparent, kept in found: they are shaded,
    and _held_transparent keeps only their transparency. Later rays see the object as a plain one (Cycles
    tests the holdout for camera paths only)."""
    camera = found[seen_through(state, found)]
    if not len(camera):
        return found, None
    held = camera[visibility.holdouts(tables, np.take(hits.prim, camera))]
    if not len(held):
        return found, None
    clear = np.take(tables.shading.transparent, tables.triangles.materials(np.take(hits.prim, held)))
    through = held[clear] if clear.any() else None
    held = held[~clear]
    wave.alpha[state.path[held]] -= np.take(state.throughput, held, axis=1).mean(axis=0)
    return np.setdiff1d(found, held, assume_unique=True), through


def _held_transparent(tables, wave, state, hit, shading, held) -> None:
    """Holdout objects with transparency, as Cycles' surface_shader_apply_holdout: at the rows held, the
    material's transparent closures stay (the path goes on through them, a transparent bounce), every other
    closure and the emission go, and the held share, one less the transparency, comes off the pixel's alpha.
    Where no transparent closure was made the share is whole, and with no closure left the path ends."""
    rows = np.zeros(len(hit), bool)
    rows[held] = True
    shading.closures, passed = shading.closures.transparent_only(rows, hit.ns)
    share = (F32(1.0) - np.take(passed, held, axis=1)) * np.take(state.throughput, held, axis=1)
    wave.alpha[state.path[held]] -= share.mean(axis=0)
    # Holdout closures of the material count no more: the object's holdout took their place.
    shading.emission = np.where(rows, F32(0.0), shading.emission)
    if shading.holdout is not None:
        shading.holdout = np.where(rows, F32(0.0), shading.holdout)


# ---- stage: sample the next direction from the closure mixture
def _sample_bsdf(tables, wave, hit, closures, numbers) -> BsdfSample:
    u_lobe, uc = numbers[LOBE] if LOBE in numbers else (np.zeros(len(hit), np.float32),) * 2
    u1, u2 = numbers[BSDF]
    if wave.settings.mode == "NEE_MIS":   # the closure by the direction's own first number, as Cycles
        return closures.sample(None, u1, u2, uc)
    lecture = wave.settings.mode == "LECTURE"

    def warp(idx, ux, uy):
        nx, ny, nz = (np.take(c, idx) for c in hit.ns)
        if lecture:
            lx, ly, lz, sin_t = sampling.sample_lecture_hemisphere(ux, uy)
            pdf = sampling.lecture_hemisphere_pdf(sin_t)
        else:
            lx, ly, lz = sampling.sample_cosine_hemisphere(ux, uy)
            pdf = sampling.cosine_hemisphere_pdf(lz)
        return sampling.local_to_world(lx, ly, lz, nx, ny, nz), pdf
    return closures.sample(u_lobe, u1, u2, uc, warp=warp)


def _widen(state, closures, rows, wi) -> None:
    """Cycles 5.2's bsdf_widen_dD after the bounces of paths rows (not singular) toward wi: the direction spread
    becomes at least the square root of the closures' average roughness squared there (a diffuse bounce: 1)."""
    if not len(rows):
        return
    rough = closures.average_roughness_squared(rows, tuple(np.take(c, rows) for c in wi))
    state.dd[rows] = np.where(rough > 0, np.maximum(state.dd[rows], np.sqrt(rough)), state.dd[rows])


# ---- stage: absorb what cannot continue, count bounces, then Russian roulette
def _continues(tables, wave, hit, state, bs, numbers, focus=None, closures=None) -> np.ndarray:
    """Update the path state with the sampled BSDF (focus: the world's at these hits, _world_focus; closures:
    theirs); return the indices of the paths that go on."""
    portal, free = bs.portal, bs.any_side
    if free.any():  # hair and Ray Portal samples leave on the side they point to, untested (as in Cycles)
        bs.through = np.where(free, leaves_its_side(bs.wi, hit.ng, True), bs.transmit)
    ok = (leaves_its_side(bs.wi, hit.side_ng, bs.transmit) | free) & (bs.pdf > 0)
    throughput = state.throughput * bs.weight
    alive = ok & ((throughput[0] > 0) | (throughput[1] > 0) | (throughput[2] > 0))
    passing = bs.transparent
    # A subsurface closure's pick counts no bounce and keeps the MIS pdf: the exit's diffuse bounce counts (Cycles'
    # subsurface_bounce leaves path_state_next to the exit).
    entering = np.zeros(len(passing), bool) if bs.subsurface is None else bs.subsurface
    # Past the last bounce a path still passes through transparent surfaces (as in Cycles), not portals.
    alive &= (passing & ~portal) | may_scatter(wave, state)
    replaced = fast_gi_replaced(wave.settings, state)
    if replaced is not None and not tables.shading.shadow_transparent.all():
        # Fast GI ends a replaced path at a surface that neither emits nor passes shadow rays, transparent or not
        # (Cycles' integrator_intersect_terminate: only SD_HAS_TRANSPARENT_SHADOW or SD_HAS_EMISSION go on).
        kept = tables.shading.shadow_transparent | tables.shading.emissive
        alive &= ~replaced | np.take(kept, hit.mat)
    # A volume's boundary (a material with only a Volume output) is passed without counting (Cycles'
    # volume_bounds_bounce).
    state.transparent = state.transparent + (passing if tables.media is None else
                                             passing & ~np.take(tables.media.boundary, hit.mat))
    # A path at the limit goes on to the world or to the emission of its next surface (may_scatter), no further.
    alive &= state.transparent <= transparent_limit(wave.settings)
    state.bounce = state.bounce + (~passing & ~entering)
    if state.dd is not None and closures is not None and wave.settings.widen_differentials \
            and tables.shading.reads_footprint:
        _widen(state, closures, np.flatnonzero(alive & ~passing & ~entering & ~bs.delta & (bs.pdf > 0)), bs.wi)
    if state.see_through is not None:
        state.see_through &= passing | _through_clear_glass(wave, bs, closures)
    if state.portal is not None:
        state.portal = state.portal + portal
    # What a portal's ray finds counts in full (Cycles' PATH_RAY_MIS_SKIP): its pdf is inf.
    state.bsdf_pdf = np.where((passing & ~portal) | entering, state.bsdf_pdf, bs.pdf)
    if state.mis_facing is not None:   # kept, like bsdf_pdf, through what the path passes
        now = np.flatnonzero(~((passing & ~portal) | entering))
        facing = nee.shading_facing(tables, hit, closures)
        for k in range(4):
            state.mis_facing[k, now] = np.take(facing[k], now)
    if focus is not None or state.focus is not None:
        # Like bsdf_pdf, a transparent pass-through keeps the focus of the vertex before.
        now = focus if focus is not None else WorldFocus.none(len(state))
        if state.focus is not None and passing.any():
            kept = np.flatnonzero(passing)
            now.put(kept, state.focus.take(kept))
        state.focus = now
    if state.min_ray_pdf is not None:
        state.min_ray_pdf = np.where(passing | entering, state.min_ray_pdf, np.minimum(state.min_ray_pdf, bs.pdf))
    # After a few bounces, Russian roulette judges the surface the new ray will hit, as Cycles does
    # (path_state_continuation_probability, decided in intersect_closest): the ray is traced whatever
    # the verdict, and what it finds emitting counts in full; only the surface's shading (its light
    # sample and the next bounce) goes on with probability q = min(sqrt(max throughput), 1), weighted
    # by 1/q. The square root keeps paths longer than q = max throughput would.
    state.continuation = roulette_verdict(wave, state, throughput, numbers, ~passing & ~entering)
    state.throughput = throughput
    return np.flatnonzero(alive)


def _through_clear_glass(wave, bs, closures) -> np.ndarray:
    """(N,) bool: samples that went through a closure smooth enough for Transparent Glass (Cycles' bsdf_sample
    labels them LABEL_TRANSMIT_TRANSPARENT: a transmission, not diffuse, whose alpha_x alpha_y is at most the
    threshold to the fourth, scene/background.cpp: the threshold is a roughness, its square an alpha), which keep
    the path's see-through state."""
    out = np.zeros(len(bs.pdf), bool)
    rows = np.flatnonzero(bs.transmit & (bs.row >= 0))
    if closures is None or not len(rows):
        return out
    r = bs.row[rows]
    threshold = F32(wave.settings.transparent_glass) ** 4
    out[rows] = ~closures.is_diffuse(r) & (closures.specular_roughness_squared(r) <= threshold)
    return out


# ---- stage: spawn the next rays, origins offset off the surface (Embree's tnear is always 0)
def _crossings(tables, state, hit, alive, bs) -> None:
    """The coincident triangle each ray meets at once where it leaves its surface (kernels.coincident), for the
    next intersection: a ray going through its surface meets the other object's surface lying there (not a ray
    whose hit was itself handed over); a ray leaving on its side meets an opaque one lying there or a hair
    ahead (a duplicated face, as Cycles' rays do, which skip only the triangle they leave)."""
    down = np.take(below(bs), alive)
    leaving = np.ones(len(alive), bool)
    if bs.origin is not None:  # a portal's ray that starts elsewhere crosses nothing here
        leaving &= ~np.isfinite(np.take(bs.origin[0], alive))
    state.partner[:] = -1
    for rows, rule in ((np.flatnonzero(leaving & down & ~state.handed), "through"),
                       (np.flatnonzero(leaving & ~down), "side")):
        if not len(rows):
            continue
        at = alive[rows]
        prim, p = np.take(hit.prim, at), tuple(np.take(c, at) for c in hit.p)
        if rule == "through":
            partner, b1, b2 = tables.coincident.crossing(prim, *p, other_object=True)
        else:
            partner, b1, b2 = tables.coincident.crossing(prim, *p, among=tables.coincident.opaque,
                                                         side=tuple(np.take(c, at) for c in hit.ng))
        state.partner[rows] = partner
        state.partner_uv[0, rows], state.partner_uv[1, rows] = b1, b2


class _Wave:
    """Per-wave constants and outputs shared by the stages."""
    __slots__ = ("settings", "nee", "split", "max_scatters", "radiance", "alpha", "spread_dd", "aux", "bake", "catcher",
                 "only_catchers", "groups", "walks")

    def __init__(self, settings, nee, split, max_scatters, radiance, alpha, spread_dd=0.0):
        self.settings, self.nee, self.split, self.max_scatters = settings, nee, split, max_scatters
        self.radiance, self.alpha = radiance, alpha
        self.spread_dd = np.float32(spread_dd)  # the camera rays' direction spread per pixel (radians)
        self.aux = None  # the data passes being recorded ({name: (C, N)}), or None
        self.bake = None  # kernels/bake.BakeRun: what a bake leaves out of its paths (Cycles' filter_closures)
        self.catcher = None  # kernels.shadow_catcher.CatcherWave where paths split at shadow catchers, or None
        self.only_catchers = None  # the shadow_catcher.Catchers a wave of the catchers' copies sees, else None
        self.groups = None  # the light groups' passes among them ({group: (3, N)}), or None
        self.walks = None  # kernels.subsurface.WalkPool of the walks parked between steps; None: walks end at once


def _caustics(settings):
    """The Caustics switches (reflective, refractive) when one is off, None when both are on (the last
    bounce's label is then read)."""
    if settings.caustics_reflective and settings.caustics_refractive:
        return None
    return bool(settings.caustics_reflective), bool(settings.caustics_refractive)


def _filter_glossy(closures, min_ray_pdf: np.ndarray, filter_glossy: float) -> None:
    """Cycles' Filter Glossy (surface_shader_prepare): where (1 / filter_glossy) x the path's smallest
    BSDF pdf so far is below 1, glossy closures get at least sqrt(1 - that) / 2 roughness."""
    blur_pdf = min_ray_pdf * np.float32(1.0 / filter_glossy)
    need = blur_pdf < 1
    if need.any():
        closures.blur(np.where(need, np.sqrt(np.maximum(np.float32(1.0) - blur_pdf, 0)) * np.float32(0.5),
                               np.float32(0.0)).astype(np.float32))


def _hand_over(state, hits) -> None:
    """Rays that leave a surface where a coincident one lies meet that one first, at distance zero (as Cycles'
    rays do, which skip only the primitive they leave); the others keep what Embree found."""
    handed = state.partner >= 0
    state.handed = handed
    rows = np.flatnonzero(handed)
    if len(rows):
        hits.prim[rows] = state.partner[rows]
        hits.u[rows], hits.v[rows] = state.partner_uv[0, rows], state.partner_uv[1, rows]
        hits.t[rows] = 0.0
