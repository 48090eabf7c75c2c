"""Cycles 5.0's Ashikhmin-Shirley glossy lobe (`kernel/closure/bsdf_ashikhmin_shirley.h`, the Glossy BSDF's
"Ashikhmin-Shirley" distribution): the anisotropic Phong reflection of Ashikhmin & Shirley 2000 without
its Fresnel factor (the colour is in the closure weight) and without any masking term.

Contract (see the package docstring): local frame z = normal, x = tangent (alpha_x along x); `wo` toward
the viewer (Cycles' wi), `wi` toward the light or the sampled direction. alpha_x, alpha_y are (N,)
float32 or scalars, already clamped to [1e-4, 1] by the caller (Cycles' setup). Exponents
n = 2 / alpha^2 - 2 per axis. With h = normalize(wo + wi):

    pdf   = sqrt((n_x + 1)(n_y + 1)) / (8 pi) h.z^e / |h.wo|,   e = (n_x h.x^2 + n_y h.y^2) / (1 - h.z^2)
    f_cos = sqrt((n_x + 1)(n_y + 1)) / (8 pi) h.z^e wi.z / (|h.wo| max(wo.z, wi.z))

(isotropic n_x = n_y: e = n), with Cycles' 1e-6 floors on the cosines. eval returns (f_cos (N,), pdf
(N,)), 0 where either direction is below the horizon. sample returns (wi, weight (N,), pdf (N,), delta
(N,) bool): h.z = u2^(1 / (n(phi) + 1)) with phi uniform (isotropic) or by Ashikhmin & Shirley's
quadrant inversion (anisotropic), then wi is wo reflected about h and pdf, weight come from eval.

Where this differs from Cycles 5.0:
- A sampled h facing away from wo: Cycles flips h but reflects with the unflipped sign, which yields a
  non-unit direction that is not a reflection; here such samples are invalid (weight 0, pdf 0). They
  need the viewer within about the lobe's width of grazing (a few degrees at roughness 0.3).
- max(alpha_x, alpha_y) <= 1e-4 (Roughness <= 0.01): Cycles returns the sampled direction with eval =
  pdf = 1e6 and a singular label; here it is a delta mirror (pdf inf, weight 1), and eval is 0 as in
  Cycles.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, ONE, ZERO

EPS = F32(1e-6)
SINGULAR_ALPHA = F32(1e-4)
INV_8PI = F32(1.0 / (8.0 * np.pi))


def is_singular(alpha_x, alpha_y):
    """True where Cycles treats the lobe as a mirror: max(alpha_x, alpha_y) <= 1e-4."""
    return np.maximum(np.asarray(alpha_x, F32), np.asarray(alpha_y, F32)) <= SINGULAR_ALPHA


def _exponent(alpha):
    alpha = np.asarray(alpha, F32)
    return (F32(2.0) / (alpha * alpha) - F32(2.0)).astype(F32)


def eval_ashikhmin_shirley(wo, wi, alpha_x, alpha_y):
    """(f_cos (N,), pdf (N,)) of the lobe; see the module docstring."""
    shape = np.shape(wo[2])
    ax = np.broadcast_to(np.asarray(alpha_x, F32), shape)
    ay = np.broadcast_to(np.asarray(alpha_y, F32), shape)
    valid = ~is_singular(ax, ay) & (wo[2] >= 0) & (wi[2] >= 0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        cos_o = np.maximum(wo[2], EPS)
        cos_i = np.maximum(wi[2], EPS)
        hx, hy, hz = wo[0] + wi[0], wo[1] + wi[1], wo[2] + wi[2]
        length = np.sqrt(hx * hx + hy * hy + hz * hz)
        inv = np.where(length > 0, ONE / np.where(length > 0, length, ONE), ZERO)
        hx, hy, hz = hx * inv, hy * inv, hz * inv
        cos_ho = np.maximum(np.abs(hx * wo[0] + hy * wo[1] + hz * wo[2]), EPS)
        cos_hn = np.maximum(hz, EPS)
        pump = ONE / np.maximum(EPS, cos_ho * np.maximum(cos_o, cos_i))
        nx, ny = _exponent(ax), _exponent(ay)
        iso = nx == ny
        e_aniso = (nx * hx * hx + ny * hy * hy) / (ONE - cos_hn * cos_hn)
        e = np.where(iso, nx, e_aniso)
        lobe = np.where(iso | (cos_hn < ONE), np.power(cos_hn, e), ONE)
        norm = np.where(iso, (nx + ONE), np.sqrt((nx + ONE) * (ny + ONE))) * INV_8PI
        f_cos = cos_i * norm * lobe * pump
        pdf = norm * lobe / cos_ho
    ok = valid & np.isfinite(f_cos) & np.isfinite(pdf)
    return np.where(ok, f_cos, ZERO).astype(F32), np.where(ok, pdf, ZERO).astype(F32)


def _first_quadrant(nx, ny, u, v):
    """phi in [0, pi/2] and cos theta of h for the anisotropic lobe (Ashikhmin & Shirley eq. 9)."""
    phi = np.arctan(np.sqrt((nx + ONE) / (ny + ONE)) * np.tan(F32(np.pi / 2) * u))
    c, s = np.cos(phi), np.sin(phi)
    return phi, np.power(v, ONE / (nx * c * c + ny * s * s + ONE))


def sample_ashikhmin_shirley(wo, alpha_x, alpha_y, u1, u2):
    """(wi, weight (N,), pdf (N,), delta (N,) bool); see the module docstring."""
    shape = np.shape(u1)
    ax = np.broadcast_to(np.asarray(alpha_x, F32), shape)
    ay = np.broadcast_to(np.asarray(alpha_y, F32), shape)
    singular = is_singular(ax, ay)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        nx, ny = _exponent(ax), _exponent(ay)
        iso = nx == ny
        # Anisotropic: u1 picks a quadrant and is stretched back to [0, 1) within it.
        quadrant = np.minimum((u1 * F32(4.0)).astype(np.int8), 3)
        u = np.select([quadrant == 0, quadrant == 1, quadrant == 2],
                      [F32(4.0) * u1, F32(4.0) * (F32(0.5) - u1), F32(4.0) * (u1 - F32(0.5))],
                      F32(4.0) * (ONE - u1)).astype(F32)
        phi_q, cos_aniso = _first_quadrant(nx, ny, u, u2)
        pi = F32(np.pi)
        phi_aniso = np.select([quadrant == 0, quadrant == 1, quadrant == 2],
                              [phi_q, pi - phi_q, pi + phi_q], F32(2.0) * pi - phi_q)
        phi = np.where(iso, F32(2.0) * pi * u1, phi_aniso)
        cos_t = np.where(iso, np.power(u2, ONE / (nx + ONE)), cos_aniso)
        cos_t = np.where(singular, ONE, cos_t)
        sin_t = np.sqrt(np.maximum(ONE - cos_t * cos_t, ZERO))
        h = (sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t)
        cos_ho = h[0] * wo[0] + h[1] * wo[1] + h[2] * wo[2]
        wi = tuple((F32(2.0) * cos_ho * hc - oc).astype(F32) for hc, oc in zip(h, wo))
    f_cos, pdf = eval_ashikhmin_shirley(wo, wi, ax, ay)
    valid = (wo[2] > 0) & (cos_ho >= 0) & (wi[2] > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(valid & (pdf > 0), f_cos / np.where(pdf > 0, pdf, ONE), ZERO)
    pdf = np.where(valid, pdf, ZERO)
    delta = singular & valid
    weight = np.where(delta, ONE, weight).astype(F32)
    pdf = np.where(delta, np.inf, pdf).astype(F32)
    return wi, weight, pdf, delta
