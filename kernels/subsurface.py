"""Subsurface scattering beneath a surface: Cycles 5.x's random walk (`kernel/integrator/subsurface.h`,
`subsurface_random_walk.h`), batched over a wave's walking paths (one ray query per step for all of them);
enter() hands Christensen-Burley's paths to kernels/subsurface_disk.py instead.

A path whose closure pick chose a BSSRDF (kernels/bsdf/bssrdf.py: its entry direction and sample weight) walks
inside the mesh of the object it entered: free flights in a homogeneous medium whose coefficients come from the
closure's albedo and radius (the van de Hulst inversion of d'Eon's Hitchhiker's guide for Random Walk and for
negative anisotropy, the Chiang-Kutz-Burley polynomial fit otherwise), Henyey-Greenstein scattering, with
Cycles' MIS of classic and Dwivedi-guided sampling (forward and, where the first ray found the far side,
backward) and of the three colour channels, the similarity relation past step 9, and at most 256 steps. Rays
meet only the object walked in (Cycles' scene_intersect_local). Where a step leaves the surface the path exits:
the integrator shades that point with a white Lambert closure on its normal facing out
(subsurface_shader_data_setup), without emission, holdout, data passes or roulette, and the entry counted no
bounce (the exit's diffuse bounce counts).

Each walk step draws its numbers from rng.keyed_uniforms keyed by the path's ray (paths.ray_keys) and the step.
"""
from __future__ import annotations

import numpy as np

from . import sampling, subsurface_disk
from .bsdf import bssrdf, lobes
from .bsdf.closures import ClosureBuilder
from .interaction import spawn_offset
from .local_hits import LocalRays
from .paths import ray_keys
from .rng import keyed_uniforms
from .vec import F32, INV_2PI

SALT = 307                  # rng.keyed_uniforms salt of the walk's numbers (3 draws of two per step)
MAX_BOUNCES = 256           # types.h BSSRDF_MAX_BOUNCES
SIMILARITY_LEVEL = 9        # subsurface_random_walk.h SUBSURFACE_RANDOM_WALK_SIMILARITY_LEVEL
THROUGHPUT_EPSILON = 1e-6   # volume.h VOLUME_THROUGHPUT_EPSILON
MIN_ALPHA = 0.2             # subsurface_random_walk_coefficients' floor on the single-scattering albedo


# ---------------------------------------------------------------- coefficients
def _legacy_alpha(albedo, g):
    """The single-scattering albedo for a multiple-scattering albedo (per channel, Chiang et al. 2016's fit
    extended to anisotropy, subsurface_random_walk_remap's float version)."""
    g2, g3, g4, g5, g6, g7 = g ** 2, g ** 3, g ** 4, g ** 5, g ** 6, g ** 7
    A = 1.8260523782 - 1.28451056436 * g - 1.79904629312 * g2 + 9.19393289202 * g3 - 22.8215585862 * g4 + \
        32.0234874259 * g5 - 23.6264803333 * g6 + 7.21067002658 * g7
    B = 4.98511194385 + 0.127355959438 * np.exp(31.1491581433 * g - 201.847017512 * g2 + 841.576016723 * g3 -
                                                 2018.09288505 * g4 + 2731.71560286 * g5 - 1935.41424244 * g6 +
                                                 559.009054474 * g7)
    C = 1.09686102424 - 0.394704063468 * g + 1.05258115941 * g2 - 8.83963712726 * g3 + 28.8643230661 * g4 - \
        46.8802913581 * g5 + 38.5402837518 * g6 - 12.7181042538 * g7
    D = 0.496310210422 + 0.360146581622 * g - 2.15139309747 * g2 + 17.8896899217 * g3 - 55.2984010333 * g4 + \
        82.065982243 * g5 - 58.5106008578 * g6 + 15.8478295021 * g7
    E = 4.23190299701 + 0.00310603949088 * np.exp(76.7316253952 * g - 594.356773233 * g2 + 2448.8834203 * g3 -
                                                   5576.68528998 * g4 + 7116.60171912 * g5 - 4763.54467887 * g6 +
                                                   1303.5318055 * g7)
    F = 2.40602999408 - 2.51814844609 * g + 9.18494908356 * g2 - 79.2191708682 * g3 + 259.082868209 * g4 - \
        403.613804597 * g5 + 302.85712436 * g6 - 87.4370473567 * g7
    blend = albedo ** 0.25
    alpha = (1 - blend) * A * np.arctan(B * albedo) ** C + blend * D * np.arctan(E * albedo) ** F
    return np.clip(alpha, 0.0, 0.999999)


def coefficients(albedo, radius, g, van_de_hulst):
    """(sigma_t, single-scattering albedo alpha), (3, n) float64 each, as subsurface_random_walk_remap gives
    them: van de Hulst (d'Eon, Hitchhiker's guide eq. 53.7) with sigma_t = 1 / radius, or the legacy fit with
    sigma_t = 1 / (radius (1 - g)). albedo, radius (3, n); g, van_de_hulst (n,)."""
    albedo = np.asarray(albedo, np.float64)
    radius = np.asarray(radius, np.float64)
    g = np.asarray(g, np.float64)
    s = 4.20863 * albedo - np.sqrt(9.59217 + 41.6808 * albedo + 17.7126 * albedo * albedo) + 4.09712
    s_sq = s * s
    den = 1.0 - g * s_sq
    with np.errstate(divide="ignore", invalid="ignore"):
        vdh = np.clip(np.where(den != 0, (1.0 - s_sq) / den, 0.0), 0.0, 0.999999)
    legacy = _legacy_alpha(albedo, g)
    alpha = np.where(van_de_hulst, vdh, legacy)
    sigma_t = 1.0 / np.maximum(radius, 1e-16)
    sigma_t = np.where(van_de_hulst, sigma_t, sigma_t / (1.0 - g))
    return sigma_t, alpha


def diffusion_length(alpha):
    """Dwivedi's diffusion length for a single-scattering albedo (d'Eon and Krivanek 2020, eq. 67)."""
    return 1.0 / np.sqrt(1.0 - alpha ** (2.44294 - 0.0215813 * alpha + 0.578637 / alpha))


def _hg(cos_theta, g):
    """volume_util.h phase_henyey_greenstein."""
    fac = 1 + g * (g - 2 * cos_theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        pdf = (1 - g * g) / (4 * np.pi * fac * np.sqrt(np.maximum(fac, 0.0)))
    return np.where(np.abs(g) < 1e-3, 1.0 / (4 * np.pi), pdf)


def _around(axis, cos_theta, u):
    """The direction at cos_theta to axis (3, n), azimuth 2 pi u (phase_sample_direction)."""
    sin_theta = np.sqrt(np.maximum(1.0 - cos_theta * cos_theta, 0.0))
    phi = 2 * np.pi * u
    w = sampling.local_to_world(sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta, axis[0], axis[1], axis[2])
    return np.stack(w)


def _transmittance_pdf(sigma_t, t, hit):
    """subsurface_random_walk_pdf: (pdf, transmittance) of a flight of length t ending at the surface (hit) or
    in a collision."""
    tr = np.exp(-sigma_t * t)
    return np.where(hit, tr, sigma_t * tr), tr


# ---------------------------------------------------------------- the walk
def walk(accel, object_rows, p0, d0, n0, ng0, obj, albedo, radius, g, van_de_hulst, throughput, keys,
         ray_epsilon=0.0, times=None):
    """Random walks from the entry points p0 (3, n) along d0 (3, n) into the surface of normal n0 (shading, facing
    the viewer) and geometric normal ng0. obj: (n,) object rows of the walks (None: the scene is one object);
    object_rows(prim) gives a hit's. albedo, radius (3, n) (the closure's, method-scaled), g (n,), van_de_hulst
    (n,) bool; throughput (3, n) the path's, closure weight included; keys the paths' ray keys.

    Returns (rows, prim, u, v, t, direction, throughput): the walks that left the surface, the triangle and
    barycentrics of their exit, the last flight's length and direction (3, m), the throughput there (3, m)."""
    n = p0.shape[1]
    p0 = p0.astype(np.float64)
    n0 = n0.astype(np.float64)
    sigma_t, alpha = coefficients(albedo, radius, g, van_de_hulst)
    thr = np.asarray(throughput, np.float64)
    albedo = np.asarray(albedo, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        thr = np.where(albedo != 0, thr / albedo, 0.0)
    low = alpha < MIN_ALPHA
    thr = np.where(low, thr * alpha / MIN_ALPHA, thr)
    alpha = np.where(low, MIN_ALPHA, alpha)
    sigma_s = sigma_t * alpha
    g = np.asarray(g, np.float64)
    dl = diffusion_length(alpha.max(axis=0))
    ok = dl != 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        phase_log = np.log((dl + 1.0) / (dl - 1.0))
    guided_fraction0 = 1.0 - np.maximum(0.5, np.abs(g) ** 0.125)
    sigma_s_star = sigma_s * (1.0 - g)
    sigma_t_star = sigma_t - sigma_s + sigma_s_star

    pos = p0.copy()
    d = np.asarray(d0, np.float64).copy()
    have_opp = np.zeros(n, bool)
    opp = np.zeros(n, np.float64)
    live = np.flatnonzero(ok)
    out_rows, out = [], []
    # The first flight leaves the entry point below its surface (Embree has no self-hit exclusion).
    start = pos.copy()
    eps = spawn_offset(ray_epsilon, *(c.astype(F32) for c in p0)).astype(np.float64)
    start -= ng0 * eps
    for bounce in range(MAX_BOUNCES):
        if not len(live):
            break
        kx, ky = keys[0][live], keys[1][live]
        u_ch, u_t = keyed_uniforms((kx, ky), 3 * bounce, SALT)
        u_gs, u_gd = keyed_uniforms((kx, ky), 3 * bounce + 1, SALT)
        r1, r2 = keyed_uniforms((kx, ky), 3 * bounce + 2, SALT)
        u_ch, u_t, u_gs, u_gd, r1, r2 = (np.asarray(x, np.float64) for x in (u_ch, u_t, u_gs, u_gd, r1, r2))
        similar = bounce > SIMILARITY_LEVEL
        gl = np.zeros(len(live)) if similar else g[live]
        gf = np.full(len(live), 0.75) if similar else guided_fraction0[live]
        st = (sigma_t_star if similar else sigma_t)[:, live]
        ss = (sigma_s_star if similar else sigma_s)[:, live]
        a_l = alpha[:, live]
        t_l = thr[:, live]
        dl_l, pl_l = dl[live], phase_log[live]
        nl = n0[:, live]
        # One channel by the throughput-weighted albedo, MIS over the three (volume_sample_channel).
        w = np.abs(t_l * a_l)
        total = w.sum(axis=0)
        ch_pdf = np.where(total > 0, w / np.where(total > 0, total, 1.0), 1.0 / 3.0)
        channel = np.where(u_ch < ch_pdf[0], 0, np.where(u_ch < ch_pdf[0] + ch_pdf[1], 1, 2))
        sample_st = np.take_along_axis(st, channel[None], axis=0)[0]
        dl_cur = d[:, live]
        fwd_f = bwd_f = back_frac = None
        fwd_s = bwd_s = 1.0
        if bounce > 0:
            guided = u_gs < gf
            x = np.clip(np.einsum("ij,ij->j", pos[:, live] - p0[:, live], -nl), 0.0, opp[live])
            with np.errstate(over="ignore"):
                back_frac = np.where(have_opp[live], 1.0 / (1.0 + np.exp((opp[live] - 2 * x) / dl_l)), 0.0)
            backward = have_opp[live] & (u_gd < back_frac)
            cos_g = dl_l - (dl_l + 1.0) * np.exp(-r1 * pl_l)
            cos_g = np.where(backward, -cos_g, cos_g)
            d_g = _around(nl, cos_g, r2)
            # Classic: Henyey-Greenstein about the flight direction.
            cos_c = 1 - 2 * r1
            with np.errstate(divide="ignore", invalid="ignore"):
                k = (1 - gl * gl) / (1 - gl * cos_c)
                cos_c = np.where(np.abs(gl) >= 1e-3, (1 + gl * gl - k * k) / (2 * np.where(gl != 0, gl, 1.0)), cos_c)
            d_c = _around(dl_cur, cos_c, r2)
            new_d = np.where(guided, d_g, d_c)
            new_d /= np.linalg.norm(new_d, axis=0)
            hg_pdf = _hg(np.einsum("ij,ij->j", dl_cur, new_d), gl)
            cos_theta = np.where(guided, cos_g, np.einsum("ij,ij->j", new_d, nl))
            fwd_f = INV_2PI / ((dl_l - cos_theta) * pl_l) / hg_pdf
            bwd_f = INV_2PI / ((dl_l + cos_theta) * pl_l) / hg_pdf
            fwd_s = 1.0 - cos_theta / dl_l
            bwd_s = 1.0 + cos_theta / dl_l
            sample_st = sample_st * np.where(guided, np.where(backward, bwd_s, fwd_s), 1.0)
            d[:, live] = new_d
            dl_cur = new_d
        t = -np.log(1.0 - u_t) / sample_st
        if bounce == 0:
            t_max = np.maximum(t, 10.0 / st.min(axis=0))
            origin = start[:, live]
        else:
            t_max = t
            origin = pos[:, live]
        prim, th, hu, hv = _local_hits(accel, object_rows, origin, dl_cur, t_max, None if obj is None else obj[live],
                                       times, live)
        hit = prim >= 0
        if bounce == 0:
            opp_new = np.einsum("ij,ij->j", origin + th * dl_cur - p0[:, live], -nl)
            have_opp[live] = hit
            opp[live] = np.where(hit, opp_new, 0.0)
            hit = hit & (th < t)
        t = np.where(hit, th, t)
        pos[:, live] = pos[:, live] + t * dl_cur
        pdf, tr = _transmittance_pdf(st, t, hit)
        if bounce > 0:
            guided_pdf = _transmittance_pdf(fwd_s * st, t, hit)[0]
            back_pdf = _transmittance_pdf(bwd_s * st, t, hit)[0]
            guided_pdf = np.where(have_opp[live], guided_pdf * fwd_f * (1 - back_frac) + back_pdf * bwd_f * back_frac,
                                  guided_pdf * fwd_f)
            pdf = pdf * (1 - gf) + guided_pdf * gf
        denom = (ch_pdf * pdf).sum(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_l = np.where(denom > 0, np.where(hit, tr, ss * tr) * t_l / np.where(denom > 0, denom, 1.0), 0.0)
        thr[:, live] = t_l
        if hit.any():
            e = np.flatnonzero(hit)
            out_rows.append(live[e])
            out.append((prim[e], hu[e], hv[e], th[e], dl_cur[:, e]))
        going = ~hit & (t_l.max(axis=0) >= THROUGHPUT_EPSILON) & np.all(np.isfinite(t_l), axis=0)
        live = live[going]
    if not out_rows:
        z = np.zeros(0, np.int64)
        return z, z, np.zeros(0, F32), np.zeros(0, F32), np.zeros(0, F32), np.zeros((3, 0), F32), np.zeros((3, 0), F32)
    rows = np.concatenate(out_rows)
    prim = np.concatenate([o[0] for o in out])
    u = np.concatenate([o[1] for o in out]).astype(F32)
    v = np.concatenate([o[2] for o in out]).astype(F32)
    t = np.concatenate([o[3] for o in out]).astype(F32)
    direction = np.concatenate([o[4] for o in out], axis=1).astype(F32)
    return rows, prim, u, v, t, direction, thr[:, rows].astype(F32)


def _triangles_only(object_rows, triangle_count: int):
    """object_rows with no object for curves and points: a walk steps over them. Cycles' local intersection
    ignores curves (kernel_embree_filter_occluded_local_func), and a walk inside a sphere never meets its inside
    (culled)."""
    def rows(prim):
        out = object_rows(prim)
        shape = prim >= triangle_count
        return np.where(shape, np.int32(-1), out) if out is not None and shape.any() else out
    return rows


def _local_hits(accel, object_rows, origin, d, t_max, obj, times, live):
    """The first hit of each ray on its own object (obj, None: any), within t_max: (prim, t, u, v), t float64.
    Hits on other objects are stepped over (at most 8 times)."""
    o = origin.T.astype(F32)
    dirs = d.T.astype(F32)
    tm = np.asarray(t_max, F32)
    tt = None if times is None else times.take(live)
    h = accel.intersect(np.ascontiguousarray(o), np.ascontiguousarray(dirs), tm, False, tt)
    prim, t, u, v = h.prim.copy(), h.t.astype(np.float64), h.u.copy(), h.v.copy()
    if obj is None or object_rows is None:
        return prim, t, u, v
    base = np.zeros(len(prim))
    for _ in range(8):
        found = np.flatnonzero(prim >= 0)
        if not len(found):
            break
        other = found[object_rows(prim[found]) != obj[found]]
        if not len(other):
            break
        step = t[other] * (1 + 1e-5) + 1e-6
        base[other] += step
        o2 = o[other] + dirs[other] * step[:, None].astype(F32)
        h2 = accel.intersect(np.ascontiguousarray(o2), np.ascontiguousarray(dirs[other]),
                             np.maximum(tm[other] - step.astype(F32), F32(0)), False,
                             None if tt is None else tt.take(other))
        prim[other], t[other], u[other], v[other] = h2.prim, h2.t, h2.u, h2.v
    t = np.where(prim >= 0, t + base, np.inf)
    return prim, t, u, v


# ---------------------------------------------------------------- what the integrator calls
def enter(tables, state, hit, closures, bs, rows, split=True):
    """The paths `state` (those of the hits rows that picked a BSSRDF, already weighted by its sample) go beneath
    their surfaces: a random walk, or Christensen-Burley's disk probes (kernels/subsurface_disk.py). Returns
    (rows of `state` that came out, prim, u, v, t, direction the exit is seen against (3, m), throughput (3, m));
    the caller makes the exit hits."""
    burley = closures.dist[bs.row[rows]] == bssrdf.BURLEY
    if not burley.any():
        return _walks(tables, state, hit, closures, bs, rows)
    disks = np.flatnonzero(burley)
    found = _disks(tables, state.rows(disks), hit, closures, bs, rows[disks], split)
    walks = np.flatnonzero(~burley)
    if not len(walks):
        return found
    walked = _walks(tables, state.rows(walks), hit, closures, bs, rows[walks])
    return tuple(np.concatenate([a, b], axis=-1) for a, b in zip((disks[found[0]],) + found[1:],
                                                                  (walks[walked[0]],) + walked[1:]))


def _disks(tables, state, hit, closures, bs, rows, split):
    """Christensen-Burley's disk probes of the paths `state` (of the hits rows)."""
    local = LocalRays(tables.accel, tables.triangles, tables.ray_epsilon)
    p = np.stack([np.take(c, rows) for c in hit.p], axis=1)
    ng = np.stack([np.take(c, rows) for c in hit.ng], axis=1)
    return subsurface_disk.disk(local, p, ng, np.take(hit.backfacing, rows), local.object_rows(np.take(hit.prim, rows)),
                                np.take(closures.c0, bs.row[rows], axis=1), state.throughput,
                                np.take(bs.subsurface_u, rows, axis=1), ray_keys(state, np.arange(len(state))), split,
                                state.time)


def _walks(tables, state, hit, closures, bs, rows):
    """The random walks of the paths `state` (of the hits rows)."""
    picked = bs.row[rows]
    g = closures.offset[picked].astype(np.float64)
    method = closures.dist[picked]
    # Cycles' state keeps anisotropy + 2 for the legacy models (Skin): van de Hulst only for Random Walk, or g < 0.
    van = (method == bssrdf.RANDOM_WALK) | (g < 0)
    p0 = np.stack([np.take(c, rows) for c in hit.p]).astype(np.float64)
    d0 = np.stack([np.take(c, rows) for c in bs.wi])
    n0 = np.stack([np.take(c, rows) for c in hit.ns])
    ng0 = np.stack([np.take(c, rows) for c in hit.ng]).astype(np.float64)
    obj = None
    object_rows = tables.triangles.object_rows
    prim_rows = object_rows(np.take(hit.prim, rows))
    if tables.shapes is not None:
        object_rows = _triangles_only(object_rows, tables.shapes.triangle_count)
    if prim_rows is not None:
        obj = prim_rows
    return walk(tables.accel, object_rows, p0, d0, n0, ng0, obj, np.take(closures.c1, picked, axis=1),
                np.take(closures.c0, picked, axis=1), g, van, state.throughput, ray_keys(state, np.arange(len(state))),
                tables.ray_epsilon, state.time)


def exit_closures(hit):
    """subsurface_shader_data_setup: a Lambert closure of weight 1 on the exit's shading normal (facing out)."""
    n = len(hit)
    wo = tuple(-c for c in hit.d)
    b = ClosureBuilder(n, hit.ns, wo)
    b.add(lobes.LAMBERT, np.arange(n), np.ones((3, n), F32))
    return b.finish()
