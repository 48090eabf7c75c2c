"""Smooth glass's other branch: what the branch a path did not take sees of the world along its first segment
(called by the integrator's surface vertex when Renderer.glass_escapes_on)."""
from __future__ import annotations

import numpy as np

from . import light_groups, passes, visibility
from .bsdf.light_passes import pass_classes
from .lights import ray_visibility
from .paths import may_scatter
from .rays import leaves_its_side, rays_from


def glass_escapes(tables, wave, state, hit, closures, bs, receiver=None) -> None:
    """Smooth glass chooses reflection or refraction at random (with probability P and 1 - P) and weighs
    the branch taken by 1 / its probability: the sun reflected by a window once in twenty samples is a
    firefly. Where the chosen closure is singular glass, the branch not taken is traced one segment too:
    if it leaves the scene, what it sees of the world is added at once, weighted by that branch's own
    Fresnel factor; and what the taken branch sees of the world if it leaves at once is scaled by its
    probability (state.escape_scale, read by the integrator's escape stage). Each branch's light from the
    world along its first segment then counts in full whichever branch was taken, and what it finds on
    surfaces (and lamps) as before, so the estimate is unbiased and the world's part of it no longer a
    lottery. Cycles follows one branch (it has nothing of this). receiver: the hits' light sets (Light
    Linking), or None: the branch not taken sees the suns that reach them, shadow-linked ones too (it met
    nothing that could block them, and no dedicated ray goes its way: kernels/shadow_linking.py)."""
    state.escape_scale = None
    if not closures.branches:
        return
    row = bs.row
    chosen = np.flatnonzero((row >= 0) & bs.delta & ~bs.transparent & (bs.pdf > 0) &
                            may_scatter(wave, state))
    if not len(chosen):
        return
    r = row[chosen]
    smooth = closures.two_branched(r)
    chosen, r = chosen[smooth], r[smooth]
    if not len(chosen):
        return
    wi, weight, transmit, p_taken, ok = closures.other_branch(chosen, r, bs.transmit[chosen])
    scale = np.ones(len(state), np.float32)
    scale[chosen] = p_taken
    state.escape_scale = scale
    # The other branch must leave on its side of the true surface, as the integrator asks of a sample.
    ok &= leaves_its_side(wi, tuple(np.take(c, chosen) for c in hit.side_ng), transmit)
    live = np.flatnonzero(ok)
    if not len(live):
        return
    idx = chosen[live]
    wx, wy, wz = (c[live] for c in wi)
    rays = rays_from(tables, hit, idx, (wx, wy, wz), transmit[live])
    times = None if state.time is None else state.time.take(idx)
    hits = tables.accel.intersect(rays.origins, rays.dirs, rays.t_max, wave.split, times)
    if wave.only_catchers is not None or tables.shapes is not None:
        # A shadow catcher's own paths see shadow catchers only; the branch leaving a curve or a point passes it,
        # as the path's ray would.
        visibility.skip_hidden(tables, rays.origins, rays.dirs, rays.t_max, hits,
                               visibility.ALL_RAYS if wave.only_catchers is not None else None, wave.split, times,
                               None if tables.shapes is None else tables.triangles.self_keys(np.take(hit.prim, idx)),
                               catchers_only=wave.only_catchers is not None)
    out = np.flatnonzero(hits.prim < 0)
    if not len(out):
        return
    idx, live = idx[out], live[out]
    wx, wy, wz = wx[out], wy[out], wz[out]
    world = light = tables.environment.radiance(wx, wy, wz)
    suns = []   # each sun's share, for the light groups' passes
    types = None   # the branch's ray type, where a lamp or the world has a bounce kind off (lights/ray_visibility.py)
    if tables.lights.visibility is not None or tables.lights.world_restricted:
        types = np.where(transmit[live], visibility.TRANSMIT_RAY, visibility.GLOSSY_RAY).astype(np.uint8)
    if tables.lights.world_restricted:
        unseen = ray_visibility.world_unseen(tables.lights, types, np.zeros(len(types), bool))
        world = light = np.where(unseen, np.float32(0.0), light)
    sun = tables.lights.suns_seen(wx, wy, wz, None, None if receiver is None else receiver[idx],
                                  shadow_linked=True,   # after a singular bounce: no MIS
                                  parts=None if wave.groups is None else suns, types=types)
    if sun is not None:
        light = light + sun
    carried = np.take(state.throughput, idx, axis=1) * weight[:, live]   # what reaches the camera of the light
    groups = None if wave.groups is None else light_groups.sky_parts(
        tables, carried * world, [(k, cols, carried[:, cols] * share) for k, cols, share in suns])

    def branch_class(first):  # at the first hit, the class of the branch not taken (glossy, transmission)
        diffuse, glossy = pass_classes(closures, r[live[first]], (wx[first], wy[first], wz[first]))
        return np.concatenate([np.repeat(diffuse[None, :], 3, axis=0),
                               np.repeat(glossy[None, :], 3, axis=0)]).astype(np.float32)
    passes.add_light(tables, wave, state, idx, carried * light, branch_class, groups)
