"""Shadow linking's dedicated light rays, as Cycles traces them (kernel/integrator/intersect_dedicated_light.h,
shade_dedicated_light.h): what BSDF rays find of shadow-linked emitters (called by the integrator's step when
the scene links lights, once the paths' rays have found their hits), and which emission BSDF rays count at the
surfaces they hit.

An emitter whose light only some objects block (its shadow mask is not every set: kernels/lights/links.py)
cannot be found by the path's own next ray, which stops at the first surface whatever blocks that light. So
BSDF rays do not count such emitters where they meet them (nor lamps and suns of that kind); instead, after
each bounce that scatters (not a transparent pass-through, nor a subsurface entry), the new ray is followed
through everything but the first opaque object that blocks in the default shadow set (0) and the surfaces
past the transparent bounce limit: the shadow-linked emitters it crosses that reach the light set of the
object it left are collected (emissive triangles, lamps with a surface, suns where nothing stopped it); one of
them is picked uniformly, weighted by their number, and a shadow ray with that emitter's shadow mask is traced
from the ray's origin to the point: the emitter's light with the MIS weight the path's own ray would have
given it (BSDF pdf against the receiver's light choice), counted as light the path's ray found. The dedicated
ray is the path's own next ray, so its first hit is the one the path found: only rays whose first surface does
not stop them are traced further (Cycles traces the dedicated ray anew; reusing the hit took shadow linking's
cost in the three-sphere scene from 23% to 16% of the CPU time).
"""
from __future__ import annotations

import numpy as np

from . import light_groups, passes, sampling, visibility
from .interaction import RayInfo, SurfaceHit, spawn_offset
from .lights import ray_visibility
from .lights.links import reaches
from .lights.nee import shadow_of
from .media.stage import VOLUME_BOUNDS_MAX
from .paths import facing_of, ray_keys
from .rng import keyed_uniforms

# rng.keyed_uniforms salt of the pick among the emitters a dedicated ray crosses.
PICK_SALT = 1699
# Surfaces a dedicated ray passes at most (Cycles' SHADOW_LINK_MAX_INTERSECTION_COUNT).
MAX_INTERSECTIONS = 1024


def counted_emission(tables, state, hit, lit: np.ndarray) -> np.ndarray:
    """(n,) bool over the emissive hits lit (rows of hit): those whose emission the paths count. Camera rays
    (bounce 0) see every emitter; later rays the emission of objects that reach the set of the object they
    left and whose light no dedicated ray counts (kernel/integrator/shade_surface.h integrate_surface_emission)."""
    links = tables.links
    rows = links.rows(tables.triangles, np.take(hit.prim, lit))
    return (np.take(state.bounce, lit) == 0) | links.lit(rows, np.take(state.link_set, lit))


def dedicated_light(tables, wave, state, rays, hits) -> None:
    """The light of shadow-linked emitters that the paths' rays leaving a scattering (state.scattered) would
    find (module docstring), added to the image; hits: the rays' closest hits among the objects they see."""
    links = tables.links
    if links is None or not links.shadow_linking:
        return
    idx = np.flatnonzero(state.scattered)
    if not len(idx):
        return
    whole = len(idx) == len(state)   # (every ray but after transparent surfaces: no gathers)

    def rows(a):
        return a if whole else np.take(a, idx, axis=0)
    origins, dirs, receiver = rows(rays.origins), rows(rays.dirs), rows(state.link_set)
    first = tuple(rows(a) for a in (hits.prim, hits.t, hits.u, hits.v))
    stop, met, meshes = _march(tables, wave, state, idx, origins, dirs, rows(rays.t_max), receiver, first)
    ox, oy, oz = (np.ascontiguousarray(origins[:, k]) for k in range(3))
    dx, dy, dz = (np.ascontiguousarray(dirs[:, k]) for k in range(3))
    facing = facing_of(state.mis_facing, idx)   # the light choice at the vertices the rays left
    lamps = tables.lights.shadow_linked_hits(ox, oy, oz, dx, dy, dz, stop, receiver, facing)
    suns = _suns(tables, receiver, dx, dy, dz, stop)
    # Candidates: (ray, kind, index into its kind's list); kind 0 triangles, 1 lamps, 2 suns.
    ray = np.concatenate([meshes[0], lamps[0], suns[0]]).astype(np.int64)
    if not len(ray):
        return
    kind = np.repeat(np.arange(3), [len(meshes[0]), len(lamps[0]), len(suns[0])])
    which = np.concatenate([np.arange(len(meshes[0])), np.arange(len(lamps[0])), np.arange(len(suns[0]))])
    order = np.argsort(ray, kind="stable")
    ray, kind, which = ray[order], kind[order], which[order]
    starts = np.flatnonzero(np.r_[True, ray[1:] != ray[:-1]])
    count = np.diff(np.r_[starts, len(ray)])
    u = keyed_uniforms(ray_keys(state, idx[ray[starts]]), 0, PICK_SALT)[0]
    pick = starts + np.minimum((u * count).astype(np.int64), count - 1)
    ray, kind, which = ray[pick], kind[pick], which[pick]
    m = len(ray)
    le = np.zeros((3, m), np.float32)
    light_pdf = np.zeros(m, np.float32)
    t = np.zeros(m, np.float32)
    masks = np.empty(m, np.uint64)
    shadowed = np.ones(m, bool)
    sel = np.flatnonzero(kind == 0)
    if len(sel):
        le[:, sel], light_pdf[sel], t[sel], masks[sel] = _triangle_light(tables, state, idx, meshes, which[sel],
                                                                         origins, dirs, receiver, facing)
    sel = np.flatnonzero(kind == 1)
    if len(sel):
        w = which[sel]
        lamp = lamps[1][w]
        le[:, sel], light_pdf[sel], t[sel] = lamps[4][:, w], lamps[3][w], lamps[2][w]
        masks[sel] = tables.lights.links.shadow[lamp]
        shadowed[sel] = tables.lights.shadowed[lamp]
    sel = np.flatnonzero(kind == 2)
    if len(sel):
        w = which[sel]
        sun = suns[1][w]
        le[:, sel], light_pdf[sel], t[sel] = tables.lights.sun_radiance[sun].T, suns[2][w], np.inf
        masks[sel] = tables.lights.links.shadow[sun]
        shadowed[sel] = tables.lights.shadowed[sun]
        # As what the ray would see of the world if it left the scene at once (glass_escapes.py).
        if state.escape_scale is not None:
            free = sel[~met[ray[sel]]]
            le[:, free] *= np.take(state.escape_scale, idx[ray[free]])
    paths = idx[ray]
    if tables.lights.visibility is not None:
        # A lamp's Ray Visibility, once picked (shade_dedicated_light.h is_light_shader_visible_to_path): rays of a
        # kind it is hidden from get nothing from it; the pick still counted it among the candidates.
        lamp = np.flatnonzero(kind != 0)
        source = np.empty(len(lamp), np.int64)
        is_lamp = kind[lamp] == 1
        source[is_lamp] = lamps[1][which[lamp[is_lamp]]]
        source[~is_lamp] = suns[1][which[lamp[~is_lamp]]]
        types = np.take(visibility.ray_types(state, False), paths[lamp])
        le[:, lamp[ray_visibility.unseen(np.take(tables.lights.visibility, source), types)]] = 0.0
    if wave.nee:
        bsdf_pdf = np.take(state.bsdf_pdf, paths)
        mis = np.isfinite(bsdf_pdf) & (light_pdf > 0)
        le *= np.where(mis, sampling.power_heuristic(bsdf_pdf, light_pdf), np.float32(1.0))
    le *= count.astype(np.float32)   # one of `count`, picked uniformly (one pick per ray, in starts' order)
    useful = np.flatnonzero((le[0] > 0) | (le[1] > 0) | (le[2] > 0))
    if not len(useful):
        return
    groups = None if wave.groups is None else _picked_groups(tables, kind[useful], which[useful], meshes, lamps, suns)
    ray, paths, le, t, masks, shadowed = ray[useful], paths[useful], le[:, useful], t[useful], masks[useful], \
        shadowed[useful]
    o, d = origins[ray], dirs[ray]
    reach = np.where(np.isfinite(t), t * np.float32(1.0 - 1e-4) - spawn_offset(tables.ray_epsilon, *o.T), np.inf)
    transmittance = np.ones((3, len(ray)), np.float32)
    traced = np.flatnonzero(shadowed & (reach > 0))
    if len(traced):
        transmittance[:, traced] = shadow_of(tables, o[traced], d[traced], reach[traced].astype(np.float32), wave,
                                             state, paths[traced], masks=masks[traced])
    value = np.take(state.throughput, paths, axis=1) * le * transmittance
    value = passes.clamp(wave, value, np.take(state.bounce, paths) > 1)
    passes.accumulate(wave.radiance, state.path[paths], value)
    if groups is not None:
        light_groups.write(wave, state.path[paths], value, groups)
    if state.pass_weights is not None:
        passes.write_light(tables, wave, state, paths, value)


def _picked_groups(tables, kind, which, meshes, lamps, suns) -> np.ndarray:
    """(n,) int32 light groups of the picked emitters (kind 0: the triangles meshes[1][which], 1: the lamps
    lamps[1][which], 2: the suns suns[1][which]), as Cycles' dedicated light writes its emitter's group
    (kernel/integrator/shade_dedicated_light.h)."""
    out = np.full(len(kind), light_groups.NO_GROUP, np.int32)
    for k, emitters in ((0, meshes[1]), (1, lamps[1]), (2, suns[1])):
        sel = np.flatnonzero(kind == k)
        if len(sel):
            chosen = np.take(emitters, np.take(which, sel))
            out[sel] = light_groups.of_triangles(tables, chosen) if k == 0 else \
                light_groups.lamp_groups(tables, chosen)
    return out


def _march(tables, wave, state, idx, origins, dirs, t_max, receiver, first):
    """Follow the rays through the scene from their first hits (first: (prim, t, u, v) (m,) each) on (Cycles'
    shadow_linking_pick_mesh_intersection): returns (stop (m,) float32, the distance past which no emitter
    counts: the first opaque surface of an object in shadow set 0, or the surface past the transparent bounce or
    volume boundary limits, inf if none; met (m,) bool, the ray met a surface; the shadow-linked emissive
    triangles reaching the rays' sets that they cross before it: (ray, prim, t, u, v))."""
    links = tables.links
    m = len(idx)
    stop = t_max.astype(np.float32).copy()
    met = np.zeros(m, bool)
    found = ([], [], [], [], [])
    types = visibility.ray_types(state, False)[idx] if tables.visibility is not None else None
    times = None if state.time is None else state.time.take(idx)
    bounds = tables.media.boundary if tables.media is not None else None
    transparent = np.take(state.transparent, idx).copy()
    volume = np.take(state.volume_bounds, idx).copy() if state.volume_bounds is not None else np.zeros(m, np.int32)
    limit = int(wave.settings.transparent_max_bounces)
    live = np.arange(m)
    start = np.zeros(m, np.float32)   # distance along the ray of the current origin
    for step in range(MAX_INTERSECTIONS):
        if not len(live):
            break
        if step == 0:
            prim, t, u, v = first
        else:
            o = np.ascontiguousarray(origins[live] + dirs[live] * start[live, None], np.float32)
            d = np.ascontiguousarray(dirs[live])
            left = (stop[live] - start[live]).astype(np.float32)
            hits = tables.accel.intersect(o, d, left, wave.split, None if times is None else times.take(live))
            if types is not None:
                visibility.skip_hidden(tables, o, d, left, hits, types[live], wave.split,
                                       None if times is None else times.take(live))
            prim, t, u, v = hits.prim, start[live] + hits.t, hits.u, hits.v
        on = np.flatnonzero(prim >= 0)
        live, prim, t, u, v = live[on], prim[on], t[on], u[on], v[on]
        if not len(live):
            break
        met[live] = True
        mat = tables.triangles.materials(prim)
        rows = links.rows(tables.triangles, prim)
        emits = np.take(tables.shading.emissive, mat) & np.take(links.shadow_linked_rows, rows) & \
            reaches(np.take(links.light_sets, rows), receiver[live])
        k = np.flatnonzero(emits)
        for part, values in zip(found, (live[k], prim[k], t[k], u[k], v[k])):
            part.append(values)
        clear = np.take(tables.shading.shadow_transparent, mat)
        boundary = np.zeros(len(mat), bool) if bounds is None else np.take(bounds, mat)
        volume[live] += boundary
        transparent[live] += clear & ~boundary
        ends = (~clear & ~boundary & (np.take(links.blocker, rows) == 0)) | \
            (boundary & (volume[live] >= VOLUME_BOUNDS_MAX)) | (clear & ~boundary & (transparent[live] >= limit))
        stop[live[ends]] = t[ends]
        live, t = live[~ends], t[~ends]
        p = origins[live] + dirs[live] * t[:, None]
        start[live] = t + spawn_offset(tables.ray_epsilon, p[:, 0], p[:, 1], p[:, 2])
        live = live[start[live] < stop[live]]
    meshes = tuple(np.concatenate(p) if p else np.zeros(0, dtype) for p, dtype in
                   zip(found, (np.int64, np.int32, np.float32, np.float32, np.float32)))
    return stop, met, meshes


def _suns(tables, receiver, dx, dy, dz, stop):
    """Shadow-linked suns reaching the rays' sets whose discs the rays that nothing stopped look into: (ray,
    sun, pdf per solid angle with selection)."""
    lights = tables.lights
    out = ([], [], [])
    free = np.isinf(stop)
    for k in (lights.sun_discs if lights.links is not None else ()):
        if not lights.links.shadow_linked[k]:
            continue
        zx, zy, zz = lights.axes[k, :, 2]
        rays = np.flatnonzero(free & (dx * zx + dy * zy + dz * zz >= lights.sun_cos[k]) &
                              reaches(lights.links.light[k], receiver))
        out[0].append(rays)
        out[1].append(np.full(len(rays), k, np.int64))
        out[2].append(lights.links.pmf(k, receiver[rays]) * sampling.uniform_cone_pdf(lights.sun_cos[k]))
    return tuple(np.concatenate(p) if p else np.zeros(0, dtype) for p, dtype in
                 zip(out, (np.int64, np.int64, np.float32)))


def _triangle_light(tables, state, idx, meshes, which, origins, dirs, receiver, facing=None):
    """The picked emissive triangles (which: rows of meshes): (radiance (3, n) toward the rays' origins, light
    pdf (solid angle, with the receivers' selection), distance, shadow mask)."""
    ray, prim, t, u, v = (part[which] for part in meshes)
    d = dirs[ray]
    hit = SurfaceHit(tables.triangles, prim, u, v, (d[:, 0], d[:, 1], d[:, 2]), tables.shading.needs_uv)
    paths = idx[ray]
    hit.ray = RayInfo(np.take(state.bounce, paths), np.take(state.transparent, paths), t,
                      lobes=None if state.lobes is None else np.take(state.lobes, paths, axis=1),
                      portal=None if state.portal is None else np.take(state.portal, paths))
    le = tables.shading.surface(hit, closures=False).emission
    gx, gy, gz = hit.ng
    cos_l = gx * d[:, 0] + gy * d[:, 1] + gz * d[:, 2]
    o = origins[ray]
    pdf = tables.lights.pdf_triangle_hit(prim, t, cos_l, o[:, 0], o[:, 1], o[:, 2], receiver[ray],
                                         None if facing is None else tuple(np.take(c, ray) for c in facing),
                                         hit.backfacing)
    rows = tables.links.rows(tables.triangles, prim)
    return le, pdf, t, np.take(tables.links.shadow_sets, rows)
