"""Thin-film iridescence as Cycles 5.x computes it (`fresnel_iridescence_channel` and its helpers in
`kernel/closure/bsdf_util.h`; the RGB table of `ShaderManager::compute_thin_film_table`, `scene/shader.cpp`).

Belcour & Barla, "A Practical Extension to Microfacet Theory for the Modeling of Varying Iridescence"
(2017): a film of thickness d (nm) and IOR n2 between the outer medium (IOR 1) and the substrate (a
dielectric of relative IOR eta, or a conductor n + ik). Per polarisation, with R12, R23 the interfaces'
reflectances and phi the phase of one round trip, the Airy sum
    R = R12 + Rs + 2 sum_{m>=1} C_m Re(e^{i m phi} S(m OPD)),  Rs = T121^2 R23 / (1 - R12 R23),
    C_0 = Rs - T121, C_m = C_{m-1} sqrt(R12 R23),  T121 = 1 - R12,  OPD = 2 n2 d cos(theta_2)
is integrated against each RGB colour matching function in Fourier space: S is the CMF's Fourier transform
(normalised to 1 at 0), read from a 512-entry table over OPDs of 0..60 um, and the sum is cut after m = 3.
The two polarisations are averaged and clamped to [0, 1].

Cycles' choices kept here: films under 1 nm blend the film IOR toward the outer medium's by smoothstep(d)
(the wave-optics sum stops applying there); total internal reflection at either dielectric interface gives
1; the phase shift on reflection from a dielectric is its sign (0 or pi), from a conductor the exact complex
phase; for the F82 metal the film divides n and k, F0 is recomputed from them and the F82 curve taken at
the film's angle (both polarisations alike), with n, k estimated from F0 and F82 by Gulbrandsen's mapping.

Shapes: cos_i (N,) (its sign is ignored), thickness_nm and film_ior (N,); colours (3, N); returns (3, N).
"""
from __future__ import annotations

import os

import numpy as np

from ..colorspace import XYZ_TO_RGB
from ..vec import F32, ONE, TWO_PI, ZERO
from . import fresnel as fr
from .tables import lookup_1d

DATA_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "thin_film_cmf.npz")
# Cycles' THINFILM_THICKNESS_CUTOFF (`kernel/svm/types.h`): thinner films are no film at all.
THICKNESS_CUTOFF = F32(0.1)
# The table covers optical path differences of 0..60 um, in nm.
TABLE_RANGE_NM = F32(60000.0)
AIRY_ORDERS = 3

_table: list[np.ndarray] = []


def rgb_table() -> np.ndarray:
    """(6, 512) float32: Re R, G, B and Im R, G, B of the CMFs' Fourier transforms in scene-linear RGB, each
    channel divided by its value at frequency 0 (Cycles' compute_thin_film_table: the XYZ table, made by
    tools/precompute_thin_film_table.py, times XYZ -> RGB)."""
    if not _table:
        with np.load(DATA_PATH) as data:
            xyz = data["xyz_fft"].astype(F32)
        re, im = xyz[:, :3] @ XYZ_TO_RGB.T, xyz[:, 3:] @ XYZ_TO_RGB.T
        norm = ONE / re[0]
        _table.append(np.concatenate([(re * norm).T, (im * norm).T]).astype(F32))
    return _table[0]


def film_on(thickness_nm) -> np.ndarray:
    """Where a film is thick enough to count (Cycles' test thickness > 0.1 nm)."""
    return np.asarray(thickness_nm, F32) > THICKNESS_CUTOFF


# ---------------------------------------------------------------- interfaces
def _dielectric_polarized(cos_i, eta):
    """Reflectances (R_s, R_p) of a dielectric interface, the signs of their amplitudes (the phase shift
    on reflection: +1 or -1), the refracted cosine (negative: on the far side) and where light is totally
    reflected (R = 1, sign +1). cos_i >= 0."""
    eta_cos_t_sq = eta * eta - (ONE - cos_i * cos_i)
    tir = eta_cos_t_sq <= 0
    cos_t = -np.sqrt(np.maximum(eta_cos_t_sq, ZERO)) / eta
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (cos_i + eta * cos_t) / (cos_i - eta * cos_t)
        r_p = (cos_t + eta * cos_i) / (eta * cos_i - cos_t)
    reflect = [np.where(tir, ONE, r * r).astype(F32) for r in (r_s, r_p)]
    sign = [np.where(tir | (r >= 0), ONE, F32(-1.0)) for r in (r_s, r_p)]
    return reflect, sign, cos_t.astype(F32), tir


def _conductor_polarized(cos_i, film_ior, n, k, f82):
    """(R_s, R_p) of the film-conductor interface and their phasors exp(i phi) as (re, im) pairs, for one
    channel: cos_i (N,) >= 0 in the film, film_ior, n, k, f82 (N,). f82 < 0: the exact Fresnel of n + ik
    (Born & Wolf 14.4.1); else the F82 curve with F0 of (n + ik) / film_ior and this F82 value."""
    eta1_sq, n_sq, k_sq = film_ior * film_ior, n * n, k * k
    two_nk = F32(2.0) * n * k
    t1 = n_sq - k_sq - eta1_sq * (ONE - cos_i * cos_i)
    t2 = np.sqrt(t1 * t1 + two_nk * two_nk)
    u_sq = np.maximum(F32(0.5) * (t2 + t1), ZERO)
    v_sq = np.maximum(F32(0.5) * (t2 - t1), ZERO)
    u, v = np.sqrt(u_sq), np.sqrt(v_sq)
    a = film_ior * cos_i
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = _safe_ratio(np.square(a - u) + v_sq, np.square(a + u) + v_sq)
        t3, t4 = (n_sq - k_sq) * cos_i, two_nk * cos_i
        r_p = _safe_ratio(np.square(t3 - film_ior * u) + np.square(t4 - film_ior * v),
                          np.square(t3 + film_ior * u) + np.square(t4 + film_ior * v))
        rel_n, rel_k_sq = n / film_ior, np.square(k / film_ior)
        f0 = (np.square(rel_n - ONE) + rel_k_sq) / (np.square(rel_n + ONE) + rel_k_sq)
    use_f82 = f82 >= 0
    if np.any(use_f82):
        curve = fr.f82(cos_i, f0[None, :], fr.f82_b(f0, f82)[None, :])[0]
        r_s, r_p = np.where(use_f82, curve, r_s), np.where(use_f82, curve, r_p)
    re_s = -u_sq - v_sq + a * a
    im_s = F32(-2.0) * a * v
    re_p = np.square((n_sq + k_sq) * cos_i) - eta1_sq * (u_sq + v_sq)
    im_p = F32(2.0) * a * (two_nk * u - (n_sq - k_sq) * v)
    return (r_s, r_p), (_unit_phasor(re_s, im_s), _unit_phasor(re_p, im_p))


def _safe_ratio(num, den):
    """Cycles' safe_divide: 0 where the denominator is 0."""
    return np.where(den != 0, num / np.where(den != 0, den, ONE), ZERO).astype(F32)


def _unit_phasor(re, im):
    mag = np.sqrt(re * re + im * im)
    zero = mag == 0
    safe = np.where(zero, ONE, mag)
    return np.where(zero, ONE, re / safe).astype(F32), np.where(zero, ZERO, im / safe).astype(F32)


# ---------------------------------------------------------------- the Airy sum
def _sensitivity(channel: int, opd):
    """(re, im) of channel's CMF transform at optical path difference opd (nm): Cycles' linear lookup at
    x = 2 pi opd / 60 um, clamped to the table."""
    table = rgb_table()
    x = TWO_PI * opd / TABLE_RANGE_NM
    return lookup_1d(table[channel], x), lookup_1d(table[channel + 3], x)


def _airy(channel: int, r12, r23, opd, phasor):
    """One polarisation's Airy sum for one channel (module docstring). phasor (re, im): exp(i phi)."""
    t121 = ONE - r12
    r123 = r12 * r23
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = t121 * t121 * r23 / (ONE - r123)
    root = np.sqrt(r123)
    total = rs + r12
    cm = rs - t121
    acc_re, acc_im = phasor
    for m in range(1, AIRY_ORDERS + 1):
        cm = cm * root
        s_re, s_im = _sensitivity(channel, F32(m) * opd)
        total = total + cm * F32(2.0) * (acc_re * s_re + acc_im * s_im)
        acc_re, acc_im = acc_re * phasor[0] - acc_im * phasor[1], acc_re * phasor[1] + acc_im * phasor[0]
    return total


def _film_ior(thickness_nm, film_ior):
    """Films under 1 nm: the film IOR blended toward the outer medium's (1) by smoothstep(thickness)."""
    t = np.clip(thickness_nm, ZERO, ONE)
    blend = t * t * (F32(3.0) - F32(2.0) * t)
    return np.where(thickness_nm < ONE, ONE + (film_ior - ONE) * blend, film_ior).astype(F32)


def iridescence(cos_i, thickness_nm, film_ior, eta=None, n=None, k=None, f82=None) -> np.ndarray:
    """(3, N) reflectance of a thin film over a dielectric substrate (eta (N,): substrate over outer IOR)
    or a conductor (n, k (3, N); f82 (3, N), or None for the exact conductor Fresnel). The outer medium has
    IOR 1 (Cycles calls it with ambient IOR 1 everywhere; a glass back face divides film and substrate
    IORs by the bulk IOR instead)."""
    c1 = np.abs(np.asarray(cos_i, F32))
    num = c1.shape[0]
    thickness = np.broadcast_to(np.asarray(thickness_nm, F32), (num,))
    ior2 = _film_ior(thickness, np.broadcast_to(np.asarray(film_ior, F32), (num,)))
    (r12_s, r12_p), (sign12_s, sign12_p), cos2, top_tir = _dielectric_polarized(c1, ior2)
    opd = (F32(-2.0) * ior2 * thickness * cos2).astype(F32)
    out = np.empty((3, num), F32)
    if eta is not None:
        eta = np.broadcast_to(np.asarray(eta, F32), (num,))
        (r23_s, r23_p), (sign23_s, sign23_p), _, bottom_tir = _dielectric_polarized(-cos2, eta / ior2)
        tir = top_tir | bottom_tir
        zero = np.zeros(num, F32)
        for ch in range(3):
            r_s = _airy(ch, r12_s, r23_s, opd, (-sign12_s * sign23_s, zero))
            r_p = _airy(ch, r12_p, r23_p, opd, (-sign12_p * sign23_p, zero))
            out[ch] = np.where(tir, ONE, np.clip(F32(0.5) * (r_s + r_p), ZERO, ONE))
        return out
    n, k = fr.color(n, num), fr.color(k, num)
    f82 = np.full((3, num), F32(-1.0)) if f82 is None else fr.color(f82, num)
    for ch in range(3):
        (r23_s, r23_p), (ph_s, ph_p) = _conductor_polarized(-cos2, ior2, n[ch], k[ch], f82[ch])
        r_s = _airy(ch, r12_s, r23_s, opd, (ph_s[0] * -sign12_s, ph_s[1] * -sign12_s))
        r_p = _airy(ch, r12_p, r23_p, opd, (ph_p[0] * -sign12_p, ph_p[1] * -sign12_p))
        out[ch] = np.where(top_tir, ONE, np.clip(F32(0.5) * (r_s + r_p), ZERO, ONE))
    return out


# ---------------------------------------------------------------- the Fresnel models with a film
def remapped(cos_i, eta, f0, thickness_nm, film_ior) -> np.ndarray:
    """Cycles' generalized Schlick (remap mode) with a film (Principled specular and transmission, Glass
    BSDF): the film over the dielectric eta, then each channel scaled toward f0 / F0(eta) by how close it is
    to F0(eta), s = clamp01((F - 1) / (F0(eta) - 1)), F *= lerp(1, f0 / F0(eta), s); left as it is where
    F0(eta) <= 1e-5 or F = 1 in every channel. f0 is clamped to [0, 1] as in the plain model. (3, N)."""
    f = iridescence(cos_i, thickness_nm, film_ior, eta=eta)
    num = f.shape[1]
    f0_real = np.broadcast_to(fr.f0_from_ior(eta), (num,))
    scale = (f0_real > F32(1e-5)) & ~np.all(f == ONE, axis=0)
    if not np.any(scale):
        return f
    s = fr.clamp01((f - ONE) / np.where(scale, f0_real - ONE, F32(-1.0)))
    factor = fr.clamp01(fr.color(f0, num)) / np.where(scale, f0_real, ONE)
    return np.where(scale[None, :], f * (ONE + (factor - ONE) * s), f).astype(F32)


def f82_conductor(f0, b):
    """(n, k, F82) (3, N) of Cycles' F82-tint metal under a film: F82 = the curve at cos = 1/7, n and k
    from r = min(F0, 0.999) and g = F82 by Gulbrandsen's "Artist Friendly Metallic Fresnel"."""
    f0 = np.asarray(f0, F32)
    r = np.minimum(f0, F32(0.999))
    g = fr.f82(np.full(f0.shape[1], fr.F82_COS, F32), f0, b)
    sqrt_r = np.sqrt(r)
    n = (ONE + sqrt_r) / (ONE - sqrt_r)
    n = n + ((ONE - r) / (ONE + r) - n) * g
    k = np.sqrt(np.maximum((r * np.square(n + ONE) - np.square(n - ONE)) / (ONE - r), ZERO))
    return n.astype(F32), k.astype(F32), g
