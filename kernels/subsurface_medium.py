"""What Cycles' subsurface random walk (`kernel/integrator/subsurface_random_walk.h`) knows of a walk before it
steps, shared by the two ways Ember steps walks (kernels/subsurface.py: many at once in NumPy;
kernels/subsurface_tail.py: the last few one by one in Python floats):

- the medium a closure's albedo and radius give (subsurface_random_walk_remap, _coefficients);
- the table of each walk's constants and state, float64 rows (`WalkTable`), so that one gather or one
  compaction moves all of a walk's numbers;
- a chunk of steps' random numbers and what follows from them alone (`step_numbers`): numbers are keyed by
  the path's ray and the step (rng.keyed_uniforms), not drawn from a stream, so any number of steps can be
  drawn at once, and the directions' sines and cosines with them;
- the ray query that sees only the walk's own object (Cycles' scene_intersect_local).
"""
from __future__ import annotations

import numpy as np

from . import sampling
from .rng import keyed_uniforms
from .vec import F32

SALT = 307                  # rng.keyed_uniforms salt of the walk's numbers (3 draws of two per step)
MAX_BOUNCES = 256           # types.h BSSRDF_MAX_BOUNCES
SIMILARITY_LEVEL = 9        # subsurface_random_walk.h SUBSURFACE_RANDOM_WALK_SIMILARITY_LEVEL
THROUGHPUT_EPSILON = 1e-6   # volume.h VOLUME_THROUGHPUT_EPSILON
MIN_ALPHA = 0.2             # subsurface_random_walk_coefficients' floor on the single-scattering albedo
SIMILAR_GUIDED_FRACTION = 0.75   # the guided fraction past SIMILARITY_LEVEL ("back to isotropic heuristic")
ISOTROPIC_PDF = 1.0 / (4 * np.pi)   # phase_henyey_greenstein for |g| < 1e-3


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


# ---------------------------------------------------------------- the table of walks
# Rows of WalkTable.constants, (CONSTANT_ROWS, n) float64: the entry point, the entry's normal N and -N, the
# tangent frame about N (sampling.orthonormal_basis), the coefficients before and past the similarity level
# (sigma_t, sigma_s, sigma_t*, sigma_s*), alpha, the anisotropy g and 1 - g^2, the guided fraction, the diffusion
# length and log((d + 1) / (d - 1)), and what the first flight found of the far side (1.0 where it met a
# surface, its depth below the entry's tangent plane).
P0, NORMAL, NEG_N, TANGENT, BITANGENT = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)
SIGMA_T, SIGMA_S, SIGMA_T_STAR, SIGMA_S_STAR, ALPHA = (slice(15, 18), slice(18, 21), slice(21, 24),
                                                       slice(24, 27), slice(27, 30))
G, ONE_MINUS_G2, GUIDED_FRACTION, DIFFUSION_LENGTH, PHASE_LOG, HAVE_OPPOSITE, OPPOSITE = range(30, 37)
CONSTANT_ROWS = 37
# Rows of WalkTable.state, (9, n) float64: position, direction, throughput.
POSITION, DIRECTION, THROUGHPUT = slice(0, 3), slice(3, 6), slice(6, 9)


class WalkTable:
    """The constants and state of n walks, as subsurface_random_walk sets them up: p0, d0, n0 (3, n) the entry
    point, direction and shading normal; albedo, radius (3, n) the closure's; g (n,), van_de_hulst (n,) bool;
    throughput (3, n) the path's. `walking` (m,) are the walks that step at all (Cycles returns at once where
    the diffusion length is 1)."""

    def __init__(self, p0, d0, n0, albedo, radius, g, van_de_hulst, throughput):
        n = p0.shape[1]
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
        with np.errstate(divide="ignore", invalid="ignore"):
            phase_log = np.log((dl + 1.0) / (dl - 1.0))
        sigma_s_star = sigma_s * (1.0 - g)
        c = np.zeros((CONSTANT_ROWS, n))
        c[P0] = p0
        c[NORMAL] = n0
        c[NEG_N] = -c[NORMAL]
        tx, ty, tz, bx, by, bz = sampling.orthonormal_basis(c[NORMAL][0], c[NORMAL][1], c[NORMAL][2])
        c[TANGENT] = tx, ty, tz
        c[BITANGENT] = bx, by, bz
        c[SIGMA_T], c[SIGMA_S], c[ALPHA] = sigma_t, sigma_s, alpha
        c[SIGMA_S_STAR] = sigma_s_star
        c[SIGMA_T_STAR] = sigma_t - sigma_s + sigma_s_star
        c[G], c[ONE_MINUS_G2] = g, 1 - g * g
        c[GUIDED_FRACTION] = 1.0 - np.maximum(0.5, np.abs(g) ** 0.125)
        c[DIFFUSION_LENGTH], c[PHASE_LOG] = dl, phase_log
        self.constants = c
        self.state = np.concatenate([np.asarray(p0, np.float64), np.asarray(d0, np.float64), thr])
        self.walking = np.flatnonzero(dl != 1.0)


# ---------------------------------------------------------------- numbers
# Rows of step_numbers' (K, NUMBER_ROWS, m) array: the channel's and the guide's numbers, -log(1 - u) of the
# distance's, and the two candidate directions in their local frames: guided (about N, before the backward
# sign) and classic (Henyey-Greenstein about the flight), each as sin(theta) cos(phi), sin(theta) sin(phi),
# cos(theta).
U_CHANNEL, FLIGHT, U_GUIDED, U_BACKWARD, GUIDED_X, GUIDED_Y, GUIDED_COS, CLASSIC_X, CLASSIC_Y, CLASSIC_COS = \
    range(10)
NUMBER_ROWS = 10


def first_numbers(keys):
    """The first step's channel number and -log(1 - u) of its distance's (its direction is the entry's)."""
    u_ch, u_t = keyed_uniforms(keys, 0, SALT)
    return u_ch.astype(np.float64), -np.log(1.0 - u_t.astype(np.float64))


def step_numbers(keys, first, count, g, dl, phase_log):
    """The numbers of steps first .. first + count - 1 (first > 0: an int, or (m,) each walk's own) of m walks:
    (count, NUMBER_ROWS, m) float64. keys the walks' ray keys; g, dl, phase_log (m,) their anisotropy, diffusion
    length and its log term. Each number is the one the step would draw alone, bit for bit."""
    steps = np.arange(count)[:, None] + np.asarray(first, np.int64)
    u_ch, u_t = keyed_uniforms(keys, 3 * steps, SALT)
    u_gs, u_gd = keyed_uniforms(keys, 3 * steps + 1, SALT)
    r1, r2 = keyed_uniforms(keys, 3 * steps + 2, SALT)
    out = np.empty((count, NUMBER_ROWS, len(dl)))
    out[:, U_CHANNEL], out[:, U_GUIDED], out[:, U_BACKWARD] = u_ch, u_gs, u_gd
    r1, r2 = r1.astype(np.float64), r2.astype(np.float64)
    out[:, FLIGHT] = -np.log(1.0 - u_t.astype(np.float64))
    phi = 2 * np.pi * r2
    cos_phi, sin_phi = np.cos(phi), np.sin(phi)
    # Dwivedi's guided cosine (sample_phase_dwivedi); the backward guide only flips its sign.
    cos_g = dl - (dl + 1.0) * np.exp(-r1 * phase_log)
    sin_g = np.sqrt(np.maximum(1.0 - cos_g * cos_g, 0.0))
    out[:, GUIDED_X], out[:, GUIDED_Y], out[:, GUIDED_COS] = sin_g * cos_phi, sin_g * sin_phi, cos_g
    # Henyey-Greenstein's cosine (phase_henyey_greenstein_sample), isotropic past the similarity level.
    gl = np.where(steps > SIMILARITY_LEVEL, 0.0, g)
    cos_c = 1 - 2 * r1
    with np.errstate(divide="ignore", invalid="ignore"):
        k = (1 - gl * gl) / (1 - gl * cos_c)
        cos_c = np.where(np.abs(gl) >= 1e-3, (1 + gl * gl - k * k) / (2 * np.where(gl != 0, gl, 1.0)), cos_c)
    sin_c = np.sqrt(np.maximum(1.0 - cos_c * cos_c, 0.0))
    out[:, CLASSIC_X], out[:, CLASSIC_Y], out[:, CLASSIC_COS] = sin_c * cos_phi, sin_c * sin_phi, cos_c
    return out


def hg_pdf(cos_theta, g):
    """volume_util.h phase_henyey_greenstein."""
    fac = 1 + g * (g - 2 * cos_theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        pdf = (1 - g * g) / (4 * np.pi * fac * np.sqrt(np.maximum(fac, 0.0)))
    return np.where(np.abs(g) < 1e-3, ISOTROPIC_PDF, pdf)


# ---------------------------------------------------------------- the query
def local_hits(accel, object_rows, origin, d, t_max, obj, times, rows):
    """The first hit of each ray (origin, d (3, n) float64, t_max (n,)) on its own object (obj (n,), None: any),
    within t_max: (prim, t, u, v), t float64. rows (n,) the walks the rays belong to (for their times). Hits on
    other objects are stepped over (at most 8 times)."""
    o = np.ascontiguousarray(origin.T, F32)
    dirs = np.ascontiguousarray(d.T, F32)
    tm = np.asarray(t_max, F32)
    tt = None if times is None else times.take(rows)
    h = accel.intersect(o, dirs, tm, False, tt)
    prim, t, u, v = h.prim, h.t.astype(np.float64), h.u, h.v     # fresh arrays of this query
    if obj is None or object_rows is None:
        return prim, t, u, v
    base = None
    for _ in range(8):
        found = np.flatnonzero(prim >= 0)
        if not len(found):
            break
        other = found[object_rows(prim[found]) != obj[found]]
        if not len(other):
            break
        step = t[other] * (1 + 1e-5) + 1e-6
        if base is None:
            base = np.zeros(len(prim))
        base[other] += step
        o2 = o[other] + dirs[other] * step[:, None].astype(F32)
        h2 = accel.intersect(np.ascontiguousarray(o2), np.ascontiguousarray(dirs[other]),
                             np.maximum(tm[other] - step.astype(F32), F32(0)), False,
                             None if tt is None else tt.take(other))
        prim[other], t[other], u[other], v[other] = h2.prim, h2.t, h2.u, h2.v
    t = np.where(prim >= 0, t if base is None else t + base, np.inf)
    return prim, t, u, v


class Exits:
    """The walks that left the surface, in the order Cycles' loop would meet them were it run over all walks at
    once: by step, then by walk."""

    def __init__(self):
        self._parts = []

    def add(self, rows, step, prim, u, v, t, direction, throughput):
        """rows (k,) the walks that left at step (an int, or (k,) steps), through prim at barycentrics u, v after a
        flight of length t (k,) along direction (3, k) float64, with throughput (3, k) float64."""
        steps = np.full(len(rows), step, np.int64) if np.ndim(step) == 0 else step
        self._parts.append((rows, steps, prim, u, v, t, direction, throughput))

    def gather(self):
        """(rows, prim, u, v, t, direction (3, k), throughput (3, k)), float32 but rows and prim."""
        if not self._parts:
            z = np.zeros(0, np.int64)
            return z, z, np.zeros(0, F32), np.zeros(0, F32), np.zeros(0, F32), np.zeros((3, 0), F32), \
                np.zeros((3, 0), F32)
        rows, steps, prim, u, v, t = (np.concatenate([p[i] for p in self._parts]) for i in range(6))
        direction, throughput = (np.concatenate([p[i] for p in self._parts], axis=1) for i in (6, 7))
        order = np.lexsort((rows, steps))
        return (rows[order], prim[order], u[order].astype(F32), v[order].astype(F32), t[order].astype(F32),
                direction[:, order].astype(F32), throughput[:, order].astype(F32))
