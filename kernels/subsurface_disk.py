"""Christensen-Burley subsurface scattering as Cycles 5.x renders it: the Burley profile
(`kernel/closure/bssrdf.h`: bssrdf_burley_eval / _pdf / _sample, bssrdf_sample's channel choice) and disk
projection sampling (`kernel/integrator/subsurface_disk.h`, King et al. 2013), batched over a wave's paths.

A path whose closure pick chose a Burley BSSRDF (kernels/bsdf/bssrdf.py) takes no entry direction: about the
entry point's true normal (facing the viewer) one axis of its frame is drawn (the normal half of the time, either
tangent a quarter), a channel among those with a radius and a radius r on the profile of that channel's d (the
closure's radius x 1/(4 pi), truncated at 16 d), and a probe ray goes along the axis through the disk point at r,
2 h long (h^2 + r^2 = (16 d)^2). Of its hits on the object entered (local_hits: a random 4 where there are more,
weighted up) each gets the weight  profile(distance to the entry) / pdf(r)  times the power-heuristic MIS of the
three axes (by the hit's true normal); one is kept in proportion to its mean weight, and the throughput takes the
resampled weight. As in Cycles the profile is the radial density 2 pi r R(r) evaluated at the true distance
over the same density at the disk radius (no r_disk / r factor). The exit is shaded from outside along the hit's
true normal (flipped where the entry was a back face), as the random walk's exits are.

The probe's numbers are the two the BSSRDF's lobe sample was given (BsdfSample.subsurface_u: stratified at a
path's first vertex, as Cycles' Sobol dimensions are); the choice among hits draws from rng.keyed_uniforms keyed
by the path's ray (paths.ray_keys).
"""
from __future__ import annotations

import numpy as np

from .geometry import NG
from .local_hits import own_hits, pick_hits
from .rng import keyed_uniforms
from .shading.program import make_orthonormals
from .vec import F32, ONE, TWO_PI, ZERO, columns, dot_rows

TRUNCATE = F32(16.0)                        # bssrdf.h BURLEY_TRUNCATE: the profile's support, in units of d
TRUNCATE_CDF = F32(0.9963790093708328)      # BURLEY_TRUNCATE_CDF: the profile's mass within it
SALT, PICK_SALT = 331, 337                  # rng.keyed_uniforms salts of the disk's numbers and of the hits kept


# ---------------------------------------------------------------- the Burley profile (bssrdf.h)
def profile_eval(d, r):
    """bssrdf_burley_eval: the radial density 2 pi r R(r) = (exp(-r/d) + exp(-r/3d)) / 4d, zero from 16 d on
    (and where d is 0). d, r broadcast together."""
    d = np.asarray(d, F32)
    r = np.asarray(r, F32)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        e3 = np.exp(-r / (F32(3.0) * d))
        out = (e3 * e3 * e3 + e3) / (F32(4.0) * d)
    return np.where(r < TRUNCATE * d, out, ZERO).astype(F32)


def profile_pdf(d, r):
    """bssrdf_burley_pdf: the truncated profile normalised over [0, 16 d); 0 at r = 0."""
    return np.where(np.asarray(r) == 0, ZERO, profile_eval(d, r) * (ONE / TRUNCATE_CDF)).astype(F32)


def root_find(xi):
    """bssrdf_burley_root_find: x with 1 - exp(-x)/4 - 3 exp(-x/3)/4 = xi (the profile's CDF at r = x d), by
    Newton's method from Cycles' fitted start, at most 10 steps, until |f| < 1e-6, x kept >= 0."""
    xi = np.asarray(xi, F32)
    x = np.where(xi <= F32(0.9), np.exp(xi * xi * F32(2.4)) - ONE, F32(15.0)).astype(F32)
    going = np.ones(x.shape, bool)
    for _ in range(10):
        e3 = np.exp(-x / F32(3.0))
        e = e3 * e3 * e3
        f = ONE - F32(0.25) * e - F32(0.75) * e3 - xi
        f_ = F32(0.25) * e + F32(0.25) * e3
        going &= ~((np.abs(f) < F32(1e-6)) | (f_ == ZERO))
        if not going.any():
            break
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(going, np.maximum(x - f / f_, ZERO), x).astype(F32)
    return x


def sample_radius(radius, xi):
    """bssrdf_sample: one channel among those of radius > 0 (radius (3, n)), uniformly, by xi (n,) rescaled
    and reused for the radius on that channel's profile. Returns (r, h): the disk radius and the half-length
    of the probe, h^2 + r^2 = (16 d)^2."""
    radius = np.asarray(radius, F32)
    xi = np.asarray(xi, F32)
    has = radius > ZERO
    count = has.sum(axis=0)
    scaled = xi * count.astype(F32)
    k = np.minimum(np.floor(scaled), np.maximum(count - 1, 0).astype(F32))
    # The k-th channel that has a radius.
    rank = np.cumsum(has, axis=0) - 1
    pick = has & (rank == k.astype(np.int64)[None])
    d = np.where(pick, radius, ZERO).sum(axis=0).astype(F32)
    u = (scaled - k).astype(F32)
    r = (root_find(u * TRUNCATE_CDF) * d).astype(F32)
    rm = TRUNCATE * d
    return r, np.sqrt(np.maximum(rm * rm - r * r, ZERO)).astype(F32)


def radius_pdf(radius, r):
    """bssrdf_pdf: the density of sample_radius's r, the channels' profile pdfs averaged over those with a
    radius. radius (3, n), r (n,)."""
    radius = np.asarray(radius, F32)
    count = (radius > ZERO).sum(axis=0).astype(F32)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(count > 0, profile_pdf(radius, r).sum(axis=0) / count, ZERO).astype(F32)


def disk_weight(radius, disk_r, r):
    """subsurface_disk_eval: (3, n) the channels' profile pdfs at the true distance r over radius_pdf at the
    disk radius disk_r (0 where that is 0)."""
    pdf = radius_pdf(radius, disk_r)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(pdf > 0, profile_pdf(radius, r) / np.where(pdf > 0, pdf, ONE), ZERO).astype(F32)


# ---------------------------------------------------------------- the disk (subsurface_disk.h)
def disk(rays, p, ng, backfacing, objects, radius, throughput, u, keys, split=True, time=None):
    """Disk probes from the entry points p (n, 3) about their true normals ng (n, 3, facing the viewer) into the
    objects (n,) entered (backfacing (n,): entered through a back face); radius (3, n) the closures' (method-
    scaled), throughput (3, n) the paths'; rays a local_hits.LocalRays; u (2, n) the numbers of the radius and
    of the axis and angle (Cycles' PRNG_SUBSURFACE_DISK); keys the paths' ray keys (the other numbers).

    Returns (rows, prim, u, v, t, direction, throughput) of the paths that found an exit: the triangle and
    barycentrics there, the probe's length to it, the exit's true normal (3, m) (the direction the exit is seen
    along, reversed) and the throughput (3, m) with the resampled weight. The others end (Cycles: no hit, or all
    weights zero)."""
    n = len(p)
    u_r, u_axis = (np.asarray(c, F32) for c in u)
    u_pick = keyed_uniforms(keys, 0, SALT)[0]
    frame_t, frame_b = make_orthonormals(np.ascontiguousarray(ng, F32))
    along_n, along_t = u_axis < F32(0.5), (u_axis >= F32(0.5)) & (u_axis < F32(0.75))
    along_b = ~(along_n | along_t)
    # The axis drawn becomes disk_n; the one it replaced takes its place in the disk's plane.
    disk_n = np.where(columns(along_n), ng, np.where(columns(along_t), frame_t, frame_b))
    disk_t = np.where(columns(along_t), ng, frame_t)
    disk_b = np.where(columns(along_b), ng, frame_b)
    quarter, half = F32(0.25), F32(0.5)
    picks = [np.where(c, half, quarter) for c in (along_n, along_t, along_b)]
    u_phi = np.where(along_n, u_axis * F32(2.0), np.where(along_t, (u_axis - half) * F32(4.0),
                                                           (u_axis - F32(0.75)) * F32(4.0)))
    phi = TWO_PI * u_phi
    disk_r, height = sample_radius(radius, u_r)
    origins = (p + disk_n * columns(height) + disk_t * columns(disk_r * np.cos(phi))
               + disk_b * columns(disk_r * np.sin(phi))).astype(F32)
    d = np.ascontiguousarray(-disk_n, F32)
    found = list(own_hits(rays, objects, origins, d, F32(2.0) * height, split, time))
    if not found:
        return _none()
    rows, prim, t, u, v = (np.concatenate(c) for c in zip(*found))
    keep, scale = pick_hits(rows, np.bincount(rows, minlength=n), keys, 0, PICK_SALT)
    rows, prim, t, u, v = rows[keep], prim[keep], t[keep], u[keep], v[keep]
    hit_ng = rays.triangles.rows_of(prim)[:, NG:NG + 3]
    hit_ng = np.where(columns(backfacing[rows]), -hit_ng, hit_ng).astype(F32)
    pdf_n, pdf_t, pdf_b = (c[rows] * np.abs(dot_rows(a[rows], hit_ng)) for c, a in zip(picks, (disk_n, disk_t, disk_b)))
    with np.errstate(divide="ignore", invalid="ignore"):
        # The power heuristic over the three axes, pdf_n cancelled in the weight and its denominator.
        mis = pdf_n / (pdf_n * pdf_n + pdf_t * pdf_t + pdf_b * pdf_b) * scale[rows]
    mis = np.where(np.isfinite(mis), mis, ZERO).astype(F32)
    offset = origins[rows] + d[rows] * columns(t) - p[rows]
    distance = np.sqrt(dot_rows(offset, offset)).astype(F32)
    weight = disk_weight(radius[:, rows], disk_r[rows], distance) * mis
    return _resample(n, rows, prim, u, v, t, hit_ng, weight, u_pick, throughput)


def _resample(n, rows, prim, u, v, t, hit_ng, weight, u_pick, throughput):
    """Each path keeps one of its hits in proportion to its mean |weight| (Cycles' importance resampling, hits in
    order of distance) and multiplies its throughput by that weight x the sum over its hits / its own."""
    sw = np.abs(weight).astype(np.float64).mean(axis=0)
    order = np.lexsort((t, rows))
    rs, sw_o = rows[order], sw[order]
    incl = np.cumsum(sw_o)
    excl = incl - sw_o
    first = np.r_[True, rs[1:] != rs[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(len(rs)), 0))
    excl, incl = excl - excl[start], incl - excl[start]
    total = np.zeros(n)
    total[rs] = incl        # the last hit of each path writes its sum
    target = np.take(u_pick, rs).astype(np.float64) * total[rs]
    chosen = order[(excl <= target) & (target < incl) & (total[rs] > 0)]
    if not len(chosen):
        return _none()
    out = rows[chosen]
    factor = (total[out] / sw[chosen]).astype(F32)
    thr = (np.take(throughput, out, axis=1) * weight[:, chosen] * factor).astype(F32)
    return (out, prim[chosen], u[chosen].astype(F32), v[chosen].astype(F32), t[chosen].astype(F32),
            np.ascontiguousarray(hit_ng[chosen].T), thr)


def _none():
    z = np.zeros(0, np.int64)
    return z, z, np.zeros(0, F32), np.zeros(0, F32), np.zeros(0, F32), np.zeros((3, 0), F32), np.zeros((3, 0), F32)
