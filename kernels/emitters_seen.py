"""The path loop's stages where rays find light (kernels/integrator.py runs them in `step`): lamps with a surface
met before the rays' hits, emissive surfaces at the hits, and the world where rays leave the scene, each
MIS-weighted against the light sampling that could have found the same light (Cycles' shade_light.h,
shade_surface.h integrate_surface_emission, shade_background.h)."""
from __future__ import annotations

import numpy as np

from . import light_groups, passes, sampling, shadow_linking, visibility
from .interaction import RayInfo
from .lights import ray_visibility
from .lights.sampler import LightHits
from .media import stage as media_stage
from .paths import facing_of, fast_gi_replaced, kept_origins, seen_through

# ---- stage: lights with a surface, found by BSDF rays and by camera rays (those of Ray Visibility > Camera)
def lights_hit(tables, wave, state, rays, hits) -> np.ndarray:
    """Count the lights the rays meet before their hits (each a transparent bounce, as in Cycles);
    return the (N,) mask of the paths that end at one, their transparent bounces spent."""
    # Met from where Cycles' ray starts: past the transparent surfaces it passed, not from the last of them (a
    # sphere lamp around a transparent card is not met again from inside, behind the card).
    o, back = kept_origins(state, rays)
    d = rays.dirs
    seeing = state.bounce > 0   # camera rays see only the lamps of _camera_hits
    if wave.bake is not None:
        seeing &= wave.bake.sees_lights(state.bounce)
    budget = np.where(seeing, int(wave.settings.transparent_max_bounces) - state.transparent, 0)
    camera = None if tables.lights.camera is None or wave.bake is not None else np.flatnonzero(state.bounce == 0)
    if camera is not None and len(camera) == len(state):   # camera rays alone (the first step)
        met = _camera_hits(tables, wave, state, rays, hits, slice(None))
        seeing[:] = True
    else:
        met = tables.lights.intersect(o[:, 0], o[:, 1], o[:, 2], d[:, 0], d[:, 1], d[:, 2], hits.t + back, budget,
                                      state.link_set, facing=facing_of(state.mis_facing),
                                      allowed=None if wave.only_catchers is None else wave.only_catchers.lights,
                                      types=lamp_ray_types(tables, state), t_min=back if back.any() else None)
        met.t -= back
        met.crossed[~seeing] = 0
        if camera is not None and len(camera):   # camera rays beside others (past transparent surfaces)
            seen = _camera_hits(tables, wave, state, rays, hits, camera)
            for name in ("hit", "crossed", "stopped", "t", "light", "pdf"):
                getattr(met, name)[camera] = getattr(seen, name)
            met.radiance[:, camera] = seen.radiance
            seeing[camera] = True
    state.transparent = state.transparent + met.crossed
    lit, le, light_pdf = met.hit & seeing, met.radiance, met.pdf
    if lit.any():
        idx = np.flatnonzero(lit)
        le = np.take(state.throughput * le, idx, axis=1)
        if state.media is not None:   # the media before the light (their scattering is the segment's own)
            le *= media_stage.transmittance_to(tables, wave, state, rays, idx, np.take(met.t, idx))
        later = np.take(state.bounce, idx) > 0
        if wave.nee:   # a camera ray's light is not weighed (Cycles' PATH_RAY_MIS_SKIP)
            le = le * np.where(later, sampling.power_heuristic(np.take(state.bsdf_pdf, idx), np.take(light_pdf, idx)),
                               np.float32(1))
        le = passes.clamp(wave, le, np.take(state.bounce, idx) > 1)
        passes.accumulate(wave.radiance, state.path[idx], le)
        if wave.groups is not None:
            light_groups.write(wave, state.path[idx], le, light_groups.lamp_groups(tables, np.take(met.light, idx)))
        if camera is not None and not later.all():
            _seen_by_camera(wave, state, idx[~later], le[:, ~later], np.take(met.radiance, idx[~later], axis=1))
            idx, le = idx[later], le[:, later]
        if state.pass_weights is not None:
            passes.write_light(tables, wave, state, idx, le)
    return met.stopped & seeing


def _camera_hits(tables, wave, state, rays, hits, rows) -> LightHits:
    """The lamps of Ray Visibility > Camera that the camera rays of state rows (bounce 0, transparent surfaces
    passed; an index array or a slice) meet before their hits. As Cycles' lights_intersect (kernel/light/light.h)
    for a ray of PATH_RAY_VISIBILITY_CAMERA: the other lamps are skipped, not met (no transparent bounce), and
    the lamps that are seen are met whatever the light and shadow linking (a camera ray is no receiver, and
    shadow-linked lamps are met by the main path's camera rays); a shadow catcher's own paths still skip the
    lamps that are no shadow catchers. An area light's Spread dims what they see as it dims what BSDF rays see
    (kernels/lights/area.py intersect)."""
    allowed = tables.lights.camera
    if wave.only_catchers is not None:
        allowed = allowed & wave.only_catchers.lights
    o, back = kept_origins(state, rays, rows)
    d = rays.dirs[rows]
    budget = int(wave.settings.transparent_max_bounces) - state.transparent[rows]
    seen = tables.lights.intersect(o[:, 0], o[:, 1], o[:, 2], d[:, 0], d[:, 1], d[:, 2], hits.t[rows] + back, budget,
                                   allowed=allowed, camera=True, t_min=back if back.any() else None)
    seen.t -= back
    return seen


def _seen_by_camera(wave, state, rows, le, radiance) -> None:
    """What Cycles' film_write_surface_emission writes besides Combined and the light groups for a lamp (or
    sun) a camera ray sees (kernel/film/light_passes.h film_write_emission_or_background_pass): the clamped
    (3, n) le of state rows to the Emission pass (directly visible), and to the denoising albedo of the paths
    still looking for it their feature throughput times the lamp's (3, n) radiance. No other light pass."""
    if wave.aux is None:
        return
    if "emission" in wave.aux:
        passes.accumulate(wave.aux["emission"], state.path[rows], le)
    if state.features is not None and "denoising_albedo" in wave.aux:
        open_ = np.flatnonzero(~np.isnan(np.take(state.features[0], rows)))
        if len(open_):
            passes.add_albedo(wave.aux, state.path[rows[open_]],
                              np.take(state.features, rows[open_], axis=1) * radiance[:, open_])


# ---- stage: smooth glass sees the world along the branch it did not take
# ---- stage: escaped rays see the world (MIS-weighted against the world's light sampling)
def escaped(tables, wave, state, rays, hits, ended=None):
    """The world seen by the rays that hit nothing (ended: (N,) mask of paths that ended before)."""
    miss = np.flatnonzero((hits.prim < 0) if ended is None else (hits.prim < 0) & ~ended)
    if wave.bake is not None:
        miss = miss[wave.bake.sees_lights(state.bounce[miss])]
    if not len(miss):
        return
    if tables.lights.camera is not None:
        _suns_seen_by_camera(tables, wave, state, rays, miss)
    keep = np.ones(len(miss), bool)
    if wave.settings.transparent_background:
        # Seen straight from the camera (through transparent surfaces only, and smooth glass with Transparent
        # Glass): a hole in alpha.
        direct = seen_through(state, miss)
        seen = miss[direct]
        if len(seen):
            wave.alpha[state.path[seen]] -= np.take(state.throughput, seen, axis=1).mean(axis=0)
            keep = ~direct
    # The world's radiance, evaluated once: for the Environment pass (what the camera sees of the world,
    # transparent film or not), the image and the denoising albedo.
    environment_pass = wave.aux is not None and "environment" in wave.aux
    looked = miss if environment_pass else miss[keep]
    if not len(looked):
        return
    d = rays.dirs
    ray = None
    if tables.environment.shader:
        ray = RayInfo(state.bounce[looked], state.transparent[looked], emission=True,
                      lobes=None if state.lobes is None else state.lobes[:, looked],
                      portal=None if state.portal is None else state.portal[looked])
    light = tables.environment.radiance(d[looked, 0], d[looked, 1], d[looked, 2], ray)
    if tables.lights.world_restricted or not tables.lights.world_camera:   # World > Ray Visibility
        unseen = ray_visibility.world_unseen(tables.lights, visibility.ray_types(state, False)[looked],
                                             state.bounce[looked] == 0)
        light = np.where(unseen, np.float32(0.0), light)
    if environment_pass:
        camera = np.flatnonzero(state.bounce[miss] == 0)
        wave.aux["environment"][:, state.path[miss[camera]]] += \
            np.take(state.throughput, miss[camera], axis=1) * light[:, camera]
        if wave.groups is not None and not keep.all():
            _hidden_world(tables, wave, state, miss[~keep], light[:, ~keep])
        light = light[:, keep]
    miss = miss[keep]
    if not len(miss):
        return
    mx, my, mz = d[miss, 0], d[miss, 1], d[miss, 2]
    # The vertices the rays left, where the choice of a distant emitter depends on them (sun discs, the world's MIS).
    points = _left_points(state, rays, miss) if tables.lights.weighs_distant else None
    env = np.take(state.throughput, miss, axis=1) * light
    if state.escape_scale is not None:
        env *= np.take(state.escape_scale, miss)
    replaced = fast_gi_replaced(wave.settings, state, miss)
    if replaced is not None:   # Fast GI's Replace: the world past the AO bounces, times the AO factor (not the suns)
        env *= np.where(replaced, np.float32(wave.settings.ao_factor), np.float32(1.0))
    if state.features is not None and wave.aux is not None and "denoising_albedo" in wave.aux:
        # A path still looking for its denoising features sees the world: the world's colour times the
        # feature throughput is its albedo, as in Cycles.
        seen = np.flatnonzero(~np.isnan(state.features[0, miss]))
        if len(seen):
            passes.add_albedo(wave.aux, state.path[miss[seen]], state.features[:, miss[seen]] * light[:, seen])
    if wave.nee:
        mis = np.flatnonzero(np.isfinite(state.bsdf_pdf[miss]))
        if len(mis):
            heuristic = sampling.balance_heuristic if tables.environment.mis_balance else sampling.power_heuristic
            focus = None if state.focus is None else state.focus.take(miss[mis])
            left = points if points is not None else \
                _left_points(state, rays, miss) if tables.lights.portals is not None else None
            o = (None,) * 4 if left is None else tuple(None if c is None else _rows_of(c, mis) for c in left)
            sampling.scale_columns(env, mis, heuristic(state.bsdf_pdf[miss[mis]], tables.lights.pdf_world(
                mx[mis], my[mis], mz[mis], focus, None if state.link_set is None else state.link_set[miss[mis]],
                *o)))
    later = np.flatnonzero(state.bounce[miss] > 0)   # camera rays do not see lamps
    world, suns = env, []   # the light groups' parts: the world's, and each sun's
    if len(later) and len(tables.lights.sun_discs):
        if wave.groups is not None:
            world = env.copy()
        types = lamp_ray_types(tables, state)
        sun = tables.lights.suns_seen(mx[later], my[later], mz[later],
                                      state.bsdf_pdf[miss[later]] if wave.nee else None,
                                      None if state.link_set is None else state.link_set[miss[later]],
                                      parts=None if wave.groups is None else suns,
                                      types=None if types is None else types[miss[later]],
                                      points=None if points is None else
                                      tuple(None if c is None else _rows_of(c, later) for c in points))
        sun *= np.take(state.throughput, miss[later], axis=1)
        if state.escape_scale is not None:
            sun *= np.take(state.escape_scale, miss[later])
        env[:, later] += sun
    scale = passes.clamp_scale(wave, env, state.bounce[miss] > 1)
    if wave.groups is not None:
        passes.write_parts(wave, state.path[miss], light_groups.sky_parts(
            tables, world, [(k, cols, share * _weights(state, miss[later[cols]])) for k, cols, share in suns],
            later), env, scale)
    env = env if scale is None else env * scale
    passes.accumulate(wave.radiance, state.path[miss], env)
    if state.pass_weights is not None:
        passes.write_light(tables, wave, state, miss[later], env[:, later])


# ---- stage: emission on hit (MIS-weighted when NEE could have found the same point)
def emission_on_hit(tables, wave, state, hit, shading, hits, rays, found):
    lit = np.flatnonzero(np.take(tables.shading.emissive, hit.mat))
    if tables.links is not None:   # Light Linking: what the ray's object receives (kernels/lights/links.py)
        lit = lit[shadow_linking.counted_emission(tables, state, hit, lit)]
    if not len(lit):
        return
    le = np.take(state.throughput, lit, axis=1) * np.take(shading.emission, lit, axis=1)
    if wave.aux is not None and "emission" in wave.aux:
        seen = np.flatnonzero(np.take(state.bounce, lit) == 0)  # emitters the camera sees
        wave.aux["emission"][:, state.path[lit[seen]]] += le[:, seen]
    if wave.nee:
        mis = np.flatnonzero(np.isfinite(np.take(state.bsdf_pdf, lit)))
        if tables.shapes is not None:   # light samples reach emissive triangles only (Cycles: MIS on triangles)
            mis = mis[np.take(hit.prim, lit[mis]) < tables.shapes.triangle_count]
        if len(mis):
            sel = lit[mis]
            gx, gy, gz = (np.take(c, sel) for c in hit.ng)
            dx, dy, dz = (np.take(c, sel) for c in hit.d)
            cos_l = gx * dx + gy * dy + gz * dz
            ray = found[sel]  # index of these rays before compaction
            # Weighed from where Cycles' ray starts, past the transparent surfaces it passed (kept_origins).
            o, back = kept_origins(state, rays, sel, ray)
            light_pdf = tables.lights.pdf_triangle_hit(
                np.take(hit.prim, sel), np.take(hits.t, ray) + back, cos_l,
                np.ascontiguousarray(o[:, 0]), np.ascontiguousarray(o[:, 1]), np.ascontiguousarray(o[:, 2]),
                None if state.link_set is None else np.take(state.link_set, sel), facing_of(state.mis_facing, sel),
                np.take(hit.backfacing, sel))
            le[:, mis] *= sampling.power_heuristic(np.take(state.bsdf_pdf, sel), light_pdf)
    le = passes.clamp(wave, le, np.take(state.bounce, lit) > 1)
    passes.accumulate(wave.radiance, state.path[lit], le)
    if wave.groups is not None:
        light_groups.write(wave, state.path[lit], le, light_groups.of_triangles(tables, np.take(hit.prim, lit)))
    if state.pass_weights is not None:
        later = np.flatnonzero(np.take(state.bounce, lit) > 0)
        passes.write_light(tables, wave, state, lit[later], le[:, later])


def _left_points(state, rays, rows):
    """(px, py, pz, facing) of the vertices the rays of state rows left (as Cycles keeps a ray's origin)."""
    o = kept_origins(state, rays, rows)[0]
    return np.ascontiguousarray(o[:, 0]), np.ascontiguousarray(o[:, 1]), np.ascontiguousarray(o[:, 2]), \
        facing_of(state.mis_facing, rows)


def _rows_of(column, idx):
    """Rows idx of one of _left_points' parts (an array, or the facing tuple)."""
    return tuple(np.take(c, idx) for c in column) if isinstance(column, tuple) else np.take(column, idx)


def _suns_seen_by_camera(tables, wave, state, rays, miss) -> None:
    """The discs of the suns with Ray Visibility > Camera on that the camera rays among the escaped rays (state
    rows miss) look into: written as Cycles' integrate_sun_lights writes them (film_write_surface_emission), to
    Combined, whatever the film's transparency (alpha is the world's), to the Emission pass and the suns' light
    groups, unweighed (kernels/lights/sun.py seen_by_camera)."""
    rows = miss[state.bounce[miss] == 0]
    if not len(rows):
        return
    d = rays.dirs
    parts = [] if wave.groups is not None else None
    sun = tables.lights.camera_suns(d[rows, 0], d[rows, 1], d[rows, 2], parts)
    if sun is None:
        return
    lit = np.flatnonzero(sun.max(axis=0) > 0)
    if not len(lit):
        return
    value = sun[:, lit] * _weights(state, rows[lit])
    scale = passes.clamp_scale(wave, value, np.zeros(len(lit), bool))
    if wave.groups is not None:
        columns = np.full(len(rows), -1, np.int64)
        columns[lit] = np.arange(len(lit))
        passes.write_parts(wave, state.path[rows[lit]], light_groups.sky_parts(
            tables, None, [(k, cols, share * _weights(state, rows[cols])) for k, cols, share in parts], columns),
            value, scale)
    value = value if scale is None else value * scale
    passes.accumulate(wave.radiance, state.path[rows[lit]], value)
    _seen_by_camera(wave, state, rows[lit], value, sun[:, lit])


def lamp_ray_types(tables, state):
    """(N,) uint8 the types of the paths' rays (visibility.ray_types) where a lamp has a bounce kind off
    (kernels/lights/ray_visibility.py), else None."""
    if tables.lights.visibility is None and not tables.lights.world_restricted:
        return None
    return visibility.ray_types(state, False)


def _weights(state, rows) -> np.ndarray:
    """(3, n) what reaches the camera of light arriving along the rays of state rows: their throughput, and
    glass_escapes' share of the branch taken."""
    out = np.take(state.throughput, rows, axis=1)
    return out if state.escape_scale is None else out * np.take(state.escape_scale, rows)


def _hidden_world(tables, wave, state, rows, light) -> None:
    """A transparent film leaves the world the camera sees out of Combined, but Cycles still writes it to the
    world's light group when the Environment pass asks for the world there (integrate_background evaluates it
    for that pass, and film_write_background hands it to film_write_emission_or_background_pass with the
    world's group): the world's (3, n) light along the camera rays of state rows."""
    value = np.take(state.throughput, rows, axis=1) * light
    value = passes.clamp(wave, value, np.zeros(len(rows), bool))
    light_groups.write(wave, state.path[rows], value, light_groups.world_group(tables))
