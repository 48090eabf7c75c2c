"""The BSSRDF closure, as Cycles 5.x sets it up (`kernel/closure/bssrdf.h`) and enters it
(`kernel/integrator/subsurface.h`, subsurface_entry_bounce). The walk beneath the surface is
kernels/subsurface.py's.

A BSSRDF is one closure of the mixture: it has a sample weight (mean weight x the number of channels
whose radius is sampled) but no eval, so the mixture treats it as singular. Picked, its sample is the
direction the walk starts along, with weight  weight x (sum of sample weights / its own)  (Cycles'
surface_shader_bssrdf_sample_weight: the delta rule of mixture_sample). Christensen-Burley's disk probes are
kernels/subsurface_disk.py's; after a diffuse bounce (Cycles' PATH_RAY_DIFFUSE_ANCESTOR) a Burley closure is a
Lambert closure of its whole weight, as bssrdf_setup makes it.

Parameter columns (registry.LOBES[BSSRDF]): c0 the radius (per channel, method-scaled), c1 the albedo,
ax the entry's GGX alpha, eta the IOR, offset the anisotropy, dist the method.
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..vec import F32, ONE, ZERO, normalize_xyz
from . import lobes
from .microfacet import sample_visible_normal

# Methods (the dist column): Cycles' CLOSURE_BSSRDF_RANDOM_WALK_ID, _RANDOM_WALK_SKIN_ID, _BURLEY_ID and
# _RANDOM_WALK_LEGACY_ID (the Random Walk of Cycles up to Blender 5.1: radius / (4 pi), the legacy albedo fit; the
# export names it for those Blenders' Random Walk).
RANDOM_WALK, RANDOM_WALK_SKIN, BURLEY, RANDOM_WALK_LEGACY = 0, 1, 2, 3
METHODS = {"RANDOM_WALK": RANDOM_WALK, "RANDOM_WALK_SKIN": RANDOM_WALK_SKIN, "BURLEY": BURLEY,
           "RANDOM_WALK_LEGACY": RANDOM_WALK_LEGACY}
MIN_RADIUS = F32(1e-8)
CUTOFF = F32(1e-5)          # CLOSURE_WEIGHT_CUTOFF      # types.h BSSRDF_MIN_RADIUS: thinner channels become a Lambert closure


def _dipole_rd(alpha_prime, fourthird_a):
    """bssrdf.h bssrdf_dipole_compute_Rd."""
    s = np.sqrt(3.0 * (1.0 - alpha_prime))
    return 0.5 * alpha_prime * (1.0 + np.exp(-fourthird_a * s)) * np.exp(-s)


def _dipole_alpha_prime(rd, fourthird_a):
    """bssrdf.h bssrdf_dipole_compute_alpha_prime: Rd inverted by 12 bisection steps on [0, 1] (the last
    midpoint); 0 for rd < 1e-4, 0.999999 for rd >= 0.995."""
    lo = np.zeros_like(rd, dtype=np.float64)
    hi = np.ones_like(rd, dtype=np.float64)
    mid = lo
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        below = _dipole_rd(mid, fourthird_a) < rd
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    return np.where(rd < 1e-4, 0.0, np.where(rd >= 0.995, 0.999999, mid))


def setup_radius(radius, albedo, ior, method):
    """bssrdf_setup_radius: Burley's and Random Walk (Legacy)'s radius x 1/(4 pi); Random Walk (Skin)'s x sqrt(3 (1 - alpha')) with alpha'
    the dipole's single-scattering albedo for the surface albedo and IOR (Jensen's Fdr); Random Walk as given.
    radius, albedo (3, n); ior, method (n,)."""
    radius = np.array(radius, np.float64)
    inv_eta = 1.0 / np.asarray(ior, np.float64)
    f_dr = inv_eta * (-1.440 * inv_eta + 0.710) + 0.668 + 0.0636 * np.asarray(ior, np.float64)
    fourthird_a = (4.0 / 3.0) * (1.0 + f_dr) / (1.0 - f_dr)
    skin = method == RANDOM_WALK_SKIN
    if np.any(skin):
        ap = _dipole_alpha_prime(np.asarray(albedo, np.float64), fourthird_a)
        radius = np.where(skin, radius * np.sqrt(3.0 * (1.0 - ap)), radius)
    radius = np.where((method == BURLEY) | (method == RANDOM_WALK_LEGACY), radius * (0.25 / np.pi), radius)
    return radius.astype(F32)


def add_bssrdf(b, idx, weight, albedo, radius, ior, alpha, anisotropy, method, normal=None, soften=None,
               ancestor=None):
    """Cycles' bssrdf_alloc + bssrdf_setup for the hits idx: weight, albedo, radius (3, n); ior, alpha,
    anisotropy (n,); method one of METHODS' values (all hits). Channels of radius < BSSRDF_MIN_RADIUS go to
    a Lambert closure on the BSSRDF's normal, and so do all channels of a Burley closure where ancestor ((n,)
    bool or None) says the path had a diffuse bounce; the others make the BSSRDF with sample weight
    mean(weight) x the channels kept. The anisotropy is clamped to [-0.99, 0.99] (Random Walk) or
    [-0.99, 0.9], the IOR to [1.01, 3.8]."""
    weight = np.broadcast_to(np.asarray(weight, F32), (3, len(idx)))
    keep = np.flatnonzero(np.abs(sampling.channel_mean(weight)) >= CUTOFF)   # bssrdf_alloc's cutoff
    n = len(keep)
    if n == 0:
        return
    m = len(idx)   # the hits given (idx itself is narrowed to the kept ones below)
    sub = (lambda a, k=3: np.take(np.broadcast_to(np.asarray(a, F32), (k, m) if k else (m,)),  # noqa: E731
                                  keep, axis=-1))
    idx, weight, albedo, radius = np.asarray(idx)[keep], weight[:, keep], sub(albedo), sub(radius)
    ior, alpha, anisotropy = sub(ior, 0), sub(alpha, 0), sub(anisotropy, 0)
    normal = None if normal is None else tuple(np.take(c, keep) for c in normal)
    radius = np.maximum(radius, ZERO)
    thin = radius < MIN_RADIUS
    if method == BURLEY and ancestor is not None:
        thin = thin | np.asarray(ancestor)[keep][None]
    extra = {} if soften is None else soften
    if thin.any():
        b.add(lobes.LAMBERT, idx, np.where(thin, weight, ZERO), normal=normal, **extra)
        weight = np.where(thin, ZERO, weight)
        radius = np.where(thin, ZERO, radius)
    channels = (~thin).sum(axis=0).astype(F32)
    g = np.clip(np.broadcast_to(np.asarray(anisotropy, F32), (n,)), -0.99, 0.99 if method == RANDOM_WALK else 0.9)
    ior = np.clip(np.broadcast_to(np.asarray(ior, F32), (n,)), 1.01, 3.8).astype(F32)
    alpha = np.broadcast_to(np.asarray(ONE if method == RANDOM_WALK_SKIN else alpha, F32), (n,))
    methods = np.full(n, method, F32)
    radius = setup_radius(radius, albedo, ior, methods)
    b.add(lobes.BSSRDF, idx, weight, sample_weight=np.abs(sampling.channel_mean(weight)) * channels,
          normal=normal, c0=radius, c1=np.broadcast_to(np.asarray(albedo, F32), (3, n)), ax=alpha, eta=ior,
          offset=g, dist=methods)


def entry_sample(wo, alpha, ior, method, u1, u2):
    """subsurface_entry_bounce in the closure's local frame (z its normal; wo toward the viewer): Random Walk
    (Skin) goes in along a cosine about -z half of the time (u1 < 1/2, rescaled); otherwise, and always for
    Random Walk, the viewer direction refracts through a GGX microfacet of alpha (visible normals), with no
    weight (Cycles keeps only the direction). Returns wi and ok (wo above the surface)."""
    u1 = np.asarray(u1, F32)
    skin = method == RANDOM_WALK_SKIN
    cosine = skin & (u1 < F32(0.5))
    u1 = np.where(skin, np.where(cosine, u1 * F32(2.0), F32(2.0) * (u1 - F32(0.5))), u1).astype(F32)
    cx, cy, cz = sampling.sample_cosine_hemisphere(u1, u2)
    a = np.maximum(alpha, F32(1e-7))
    hx, hy, hz = sample_visible_normal(wo, a, a, u1, u2)
    neta = ONE / ior
    cos_hi = hx * wo[0] + hy * wo[1] + hz * wo[2]
    dnp = np.maximum(np.sqrt(np.maximum(ONE - neta * neta * (ONE - cos_hi * cos_hi), ZERO)), F32(1e-7))
    nk = neta * cos_hi - dnp
    rx, ry, rz = normalize_xyz((-neta * wo[0] + nk * hx, -neta * wo[1] + nk * hy, -neta * wo[2] + nk * hz))
    wi = (np.where(cosine, cx, rx), np.where(cosine, cy, ry), np.where(cosine, -cz, rz))
    ok = cosine | (wo[2] > ZERO)
    # Christensen-Burley takes no entry direction (subsurface_bounce): its disk probes start at the hit.
    # Straight through (-wo) passes the integrator's test of the side a transmission leaves on.
    burley = method == BURLEY
    if np.any(burley):
        wi = tuple(np.where(burley, -w, c) for w, c in zip(wo, wi))
        ok = ok | burley
    return tuple(c.astype(F32) for c in wi), ok
