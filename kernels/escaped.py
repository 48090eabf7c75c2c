"""The integrator's stage for rays that leave the scene: the world they see, MIS-weighted against the world's
light samples, and the sun discs they look into (Cycles' integrator/shade_background.h); with a transparent
film, the world seen straight from the camera is a hole in alpha instead.
"""
from __future__ import annotations

import numpy as np

from . import light_groups, passes, sampling
from .interaction import RayInfo


def escaped(tables, wave, state, rays, hits, ended=None):
    """The world seen by the rays that hit nothing (ended: (N,) mask of paths that ended before)."""
    miss = np.flatnonzero((hits.prim < 0) if ended is None else (hits.prim < 0) & ~ended)
    if not len(miss):
        return
    keep = np.ones(len(miss), bool)
    if wave.settings.transparent_background:
        # Seen straight from the camera (through transparent surfaces only): a hole in alpha.
        direct = state.bounce[miss] == 0
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
    env = np.take(state.throughput, miss, axis=1) * light
    if state.escape_scale is not None:
        env *= np.take(state.escape_scale, miss)
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
            sampling.scale_columns(env, mis, heuristic(state.bsdf_pdf[miss[mis]], tables.lights.pdf_world(
                mx[mis], my[mis], mz[mis], focus, None if state.link_set is None else state.link_set[miss[mis]])))
    later = np.flatnonzero(state.bounce[miss] > 0)   # camera rays do not see lamps
    world, suns = env, []   # the light groups' parts: the world's, and each sun's
    if len(later) and len(tables.lights.sun_discs):
        if wave.groups is not None:
            world = env.copy()
        sun = tables.lights.suns_seen(mx[later], my[later], mz[later],
                                      state.bsdf_pdf[miss[later]] if wave.nee else None,
                                      None if state.link_set is None else state.link_set[miss[later]],
                                      parts=None if wave.groups is None else suns)
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
