"""The phase functions of Cycles 5.x's volume scattering closures, over n scattering points: Henyey-Greenstein,
Fournier-Forand, Draine and Rayleigh (Cycles' kernel/closure/volume_util.h, called by volume_henyey_greenstein.h,
volume_fournier_forand.h, volume_draine.h and volume_rayleigh.h), their setup from the nodes' inputs (Cycles'
svm_alloc_closure_volume_scatter in kernel/svm/closure.h, the Mie fit included). A point's closures are mixed by
kernels/media/scatter.py.

Directions, in Cycles' names and signs. At a scattering point `wi` points back toward the previous vertex (the
viewer: Cycles' sd->wi = -ray.D) and `wo` away from the point, along the scattered ray or toward a light:

    cos_theta = dot(-wi, wo) = dot(ray.D, wo)

so cos_theta = 1 is light going on undeflected and g > 0 scatters forward. (kernels/bsdf names the two the
other way round: its wo points to the viewer.) Directions are unit world vectors, (x, y, z) tuples or (3, n)
arrays, float32.

Contract (the BSDFs', without a cosine): a phase function is a density per unit solid angle of wo that
integrates to 1 over the sphere, and its value equals its pdf, as in Cycles (each sampler is exact, so a
sample's weight value / pdf is 1). A closure's weight (colour times density) is not in the value; it enters
the mixture as its sample weight. evaluate and sample return float32 (n,) values and pdfs, 0 where the
arithmetic is not finite (out-of-domain parameters), never NaN.

Parameters are three float32 rows per closure, an array params (3, n), what Cycles' setup stores:

    HENYEY_GREENSTEIN   g (clamped to |g| <= 0.999)
    FOURNIER_FORAND     n (the IOR, at least 1.001), v, c3 (Cycles' c1, c2, c3, from the IOR and Backscatter)
    DRAINE              g (clamped to |g| <= 0.999), alpha
    RAYLEIGH            (none)

henyey_greenstein_params, fournier_forand_params, draine_params and rayleigh_params compute them from the
inputs; scatter_closures gives the closures a Volume Scatter (or Volume Coefficients) node makes, Mie as two
(Henyey-Greenstein and Draine, weighted by the fit of mie_fit); Principled Volume makes one Henyey-Greenstein
closure of its Anisotropy.

Cycles' float32 arithmetic is kept, and with it two losses of precision: Fournier-Forand's density cancels
beside the band |1 - delta| < 1e-3 that its Taylor expansion covers (errors up to tens of percent where
|1 - delta| is near 1e-3, a narrow ring of angles); and Draine's closed-form sampler cancels where alpha is
large and |g| small (Mie's Draine lobe below 1.5 um has alpha = 250: at g = 0.05 the sampled distribution is
some 0.1 off the density in the Kolmogorov distance; computed in float64, the same formula is exact).

Where Ember differs from Cycles: the Mie fit uses exact sin, cos, tan, log and exp where Cycles takes its
fast_* approximations (the fitted parameters differ by up to 2e-5 relative; fast_inv_cbrtf, part of two
samplers' arithmetic, is reproduced); sampled directions are normalised (Cycles normalises the ray it makes
of them); and where Cycles' arithmetic gives NaN or infinity (Alpha below 0 with |g| < 0.01, a parameter
table filled by hand with |g| = 1) the pdf is 0 and a sampled direction wo = -wi.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..shading.cycles_math import cycles_max, cycles_min
from ..vec import F32, I32, INV_2PI, INV_4PI, INV_PI, PI, TWO_PI, U32, dot_xyz, make_orthonormals_xyz, normalize_xyz

# Phase kinds.
HENYEY_GREENSTEIN, FOURNIER_FORAND, DRAINE, RAYLEIGH = range(4)
PARAM_ROWS = 3

# Cycles' clamps at setup (volume_henyey_greenstein.h, volume_draine.h, volume_fournier_forand.h).
G_LIMIT = F32(1.0 - 1e-3)
BACKSCATTER_LIMIT = F32(0.5 - 1e-3)
IOR_MIN = F32(1.0 + 1e-3)
CBRT2 = F32(1.2599210498948732)       # Cycles' M_CBRT2_F


# ---------------------------------------------------------------- Cycles' numeric helpers
def _fast_inv_cbrtf(x):
    """Cycles' fast_inv_cbrtf (util/math_fast.h): 1 / cbrt(x) for x >= 0 from a bit-level first guess and two
    Newton steps (relative error below 2e-6, which Cycles' Rayleigh and Draine samples carry). float32."""
    x = np.asarray(x, F32)
    bits = x.view(I32).astype(np.int64)
    third = np.where(bits >= 0, bits // 3, -(-bits // 3))          # C's division truncates toward zero
    y = ((0x54a24242 - third) & 0xFFFFFFFF).astype(U32).view(F32)
    for _ in range(2):
        y = F32(2.0 / 3.0) * y + 1 / (3 * y * y * x)
    return y


def _signf(x):
    """Cycles' signf: -1 where x < 0, else 1 (0, -0 and NaN give 1)."""
    return np.where(x < 0, F32(-1.0), F32(1.0))


def _clamp_g(g):
    """Cycles' anisotropy clamp at setup, signf(g) min(|g|, 1 - 1e-3), against a delta function."""
    return _signf(g) * cycles_min(np.abs(g), G_LIMIT)


# ---------------------------------------------------------------- densities of cos_theta
# Each computes in its operands' precision: float32 in the kernels (the tests also integrate them in float64).
def _hg(g, cos_theta):
    """volume_util.h phase_henyey_greenstein: (1 - g^2) / (4 pi (1 + g^2 - 2 g cos)^(3/2)); 1 / (4 pi)
    where |g| < 1e-3."""
    fac = 1 + g * (g - 2 * cos_theta)
    pdf = (1 - g * g) / ((4 * PI) * fac * np.sqrt(cycles_max(fac, 0.0)))
    return np.where(np.abs(g) < 1e-3, INV_4PI, pdf)


def _rayleigh(cos_theta):
    """volume_util.h phase_rayleigh: 3 / (16 pi) (1 + cos^2)."""
    return (F32(0.1875) * INV_PI) * (1 + cos_theta * cos_theta)


def _draine_special_cases(g, alpha, value, hg, rayleigh):
    """value where Cycles' Draine is itself; hg() where its alpha is about 0 (Henyey-Greenstein), rayleigh() where g
    is about 0 and alpha about 1 (phase_draine and phase_draine_sample_cos, volume_util.h)."""
    as_hg = np.abs(alpha) < 1e-3
    if np.any(as_hg):
        value = np.where(as_hg, hg(), value)
    as_rayleigh = (np.abs(g) < 1e-3) & (alpha > 0.999)
    if np.any(as_rayleigh):
        value = np.where(as_rayleigh, rayleigh(), value)
    return value


def _draine(g, alpha, cos_theta):
    """volume_util.h phase_draine (Draine 2003): HG(g) (1 + alpha cos^2) / (1 + alpha (1 + 2 g^2) / 3);
    Rayleigh where |g| < 1e-3 and alpha > 0.999 (whatever alpha), HG where |alpha| < 1e-3."""
    g2 = g * g
    fac = 1 + g2 - 2 * g * cos_theta
    pdf = ((1 - g2) * (1 + alpha * (cos_theta * cos_theta))) / (
        (1 + (alpha * (1 + 2 * g2)) * (1 / 3)) * (4 * PI) * fac * np.sqrt(fac))
    return _draine_special_cases(g, alpha, pdf, lambda: _hg(g, cos_theta), lambda: _rayleigh(cos_theta))


def _ff_delta(n, sin_half_sqr):
    """volume_util.h phase_fournier_forand_delta: delta = 4 sin^2(theta / 2) / (3 (n - 1)^2)."""
    return (4 * sin_half_sqr) / (3 * ((n - 1) * (n - 1)))


def _ff_terms(cos_theta, delta, delta_v, v, sin_half_sqr, backscatter_coeff):
    """volume_util.h phase_fournier_forand_impl (Fournier and Forand 1999): the density given delta and
    delta^v, its first-order Taylor expansion where |1 - delta| < 1e-3, plus the backscatter term
    c3 / (16 pi) (3 cos^2 - 1)."""
    m_delta = 1 - delta
    m_delta_v = 1 - delta_v
    taylor = v * ((v - 1) - (v + 1) / sin_half_sqr) * (1 / (8 * PI)) + \
        v * (v + 1) * m_delta * (2 * (v - 1) - (2 * v + 1) / sin_half_sqr) * (1 / (24 * PI))
    exact = (v * m_delta - m_delta_v + (delta * m_delta_v - v * m_delta) / sin_half_sqr) / (
        (4 * PI) * (m_delta * m_delta) * delta_v)
    pf = np.where(np.abs(m_delta) < 1e-3, taylor, exact)
    return pf + backscatter_coeff * (3 * (cos_theta * cos_theta) - 1)


def _fournier_forand(n, v, c3, cos_theta):
    """volume_util.h phase_fournier_forand: 0 where |cos| >= 1 (the forward peak is integrable but
    infinite)."""
    sin_half_sqr = 0.5 * (1 - cos_theta)
    delta = _ff_delta(n, sin_half_sqr)
    pf = _ff_terms(cos_theta, delta, delta ** v, v, sin_half_sqr, c3 * (1 / (16 * PI)))
    return np.where(np.abs(cos_theta) >= 1, 0.0, pf)


# ---------------------------------------------------------------- samplers of cos_theta
def _hg_sample_cos(g, u1):
    """volume_util.h phase_henyey_greenstein_sample: the inverse CDF; uniform in cos where |g| < 1e-3."""
    cos_theta = 1 - 2 * u1
    k = (1 - g * g) / (1 - g * cos_theta)
    return np.where(np.abs(g) >= 1e-3, (1 + g * g - k * k) / (2 * g), cos_theta)


def _rayleigh_sample_cos(u1):
    """volume_util.h phase_rayleigh_sample: the root of the CDF's cubic (Frisvad 2011)."""
    a = 2 - 4 * u1
    inv_u = -_fast_inv_cbrtf(np.sqrt(1 + a * a) + a)
    return 1 / inv_u - inv_u


def _draine_general_cos(g, alpha, u1):
    """volume_util.h phase_draine_sample_cos, |g| >= 0.01: the closed-form inverse CDF of Jendersie and
    d'Eon's approximate Mie (its terms T1..T10)."""
    g2 = g * g
    g3 = g * g2
    g4 = g2 * g2
    g6 = g2 * g4
    pgp1_2 = (1 + g2) * (1 + g2)
    t1a = alpha * (g4 - 1)
    t1a3 = t1a * t1a * t1a
    t2 = -1296 * (g2 - 1) * (alpha - alpha * g2) * t1a * (4 * g2 + alpha * pgp1_2)
    t9 = 2 + g2 + g3 * (1 + 2 * g2) * (2 * u1 - 1)
    t3 = 3 * g2 * (1 + g * (2 * u1 - 1)) + alpha * t9
    t4a = 432 * t1a3 + t2 + 432 * (alpha * (1 - g2)) * (t3 * t3)
    t10 = alpha * (2 * g4 - g2 - g6)
    t4b = 144 * t10
    t4b3 = t4b * t4b * t4b
    t4 = t4a + np.sqrt(-4 * t4b3 + t4a * t4a)
    inv_t4p3 = _fast_inv_cbrtf(t4)
    t8 = 48 * CBRT2 * t10
    t6 = (2 * t1a + t8 * inv_t4p3 + 1 / (3 * CBRT2 * inv_t4p3)) / (alpha * (1 - g2))
    t5 = 6 * (1 + g2) + t6
    t7 = 6 * (1 + g2) - (8 * t3) / (alpha * (g2 - 1) * np.sqrt(t5)) - t6
    root = np.sqrt(t7) - np.sqrt(t5)
    return (1 + g2 - 0.25 * (root * root)) / (2 * g)


def _draine_sample_cos(g, alpha, u1):
    """volume_util.h phase_draine_sample and phase_draine_sample_cos: Rayleigh's sampler where |g| < 1e-3
    and alpha > 0.999, HG's where |alpha| < 1e-3; where |g| < 0.01 the sampler of g = 0 (Cycles' guard
    against dividing by g: between 1e-3 and 1e-2 it samples g = 0 and reports the pdf of g)."""
    cos_theta = _draine_general_cos(g, alpha, u1)
    small_g = np.abs(g) < 1e-2
    if np.any(small_g):
        inv_alpha = 1 / alpha
        b_2 = (3 + alpha) * inv_alpha * (0.5 - u1)
        inv_u = -_fast_inv_cbrtf(b_2 + np.sqrt(b_2 * b_2 + (inv_alpha * inv_alpha) * inv_alpha))
        cos_theta = np.where(small_g, 1 / inv_u - inv_u / alpha, cos_theta)
    return _draine_special_cases(g, alpha, cos_theta, lambda: _hg_sample_cos(g, u1), lambda: _rayleigh_sample_cos(u1))


def _ff_sample_cos(n, v, c3, u1):
    """volume_util.h phase_fournier_forand_newton: Newton's method on the CDF (the fraction scattered within
    theta), from 50 degrees; at most 20 steps, done when a step moves less than 1e-6, never past cos = 1."""
    cdf_coeff = c3 * F32(0.125)
    backscatter_coeff = c3 * (1 / (16 * PI))
    cos_theta = np.full(np.shape(u1), 0.64278760968, np.result_type(u1, F32))
    live = np.arange(cos_theta.size)
    c = cos_theta.copy()
    for _ in range(20):
        sin_half_sqr = 0.5 * (1 - c)
        delta = _ff_delta(n, sin_half_sqr)
        delta_v = delta ** v
        m_delta = 1 - delta
        taylor = 1 + v * (1 - sin_half_sqr) * (1 - 0.5 * (v + 1) * m_delta)
        exact = (1 - delta_v * delta - (1 - delta_v) * sin_half_sqr) / (m_delta * delta_v)
        cdf = np.where(np.abs(m_delta) < 1e-3, taylor, exact) + cdf_coeff * c * (1 - c * c)
        pf = _ff_terms(c, delta, delta_v, v, sin_half_sqr, backscatter_coeff)
        new = c + INV_2PI * (cdf - u1) / pf
        new = np.where(new >= 1, cycles_max(c + 0.5 * (1 - c), F32(0.99)), new)
        cos_theta[live] = new
        going = ~((np.abs(c - new) < 1e-6) | (new == 1))
        if not going.any():
            break
        live = live[going]
        c, n, v, u1 = new[going], n[going], v[going], u1[going]
        cdf_coeff, backscatter_coeff = cdf_coeff[going], backscatter_coeff[going]
    return cos_theta


# ---------------------------------------------------------------- the table
def _quiet(fn):
    """fn with NumPy's floating-point warnings off: every branch is computed for every point and the branches
    a point does not take (Cycles skips them) may divide by zero."""
    @functools.wraps(fn)
    def quiet(*args):
        with np.errstate(all="ignore"):
            return fn(*args)
    return quiet


@_quiet
def _hg_eval(params, cos_theta):
    return _hg(params[0], cos_theta)


@_quiet
def _hg_sample(params, u1):
    return _hg_sample_cos(params[0], u1)


@_quiet
def _ff_eval(params, cos_theta):
    return _fournier_forand(params[0], params[1], params[2], cos_theta)


@_quiet
def _ff_sample(params, u1):
    return _ff_sample_cos(params[0], params[1], params[2], u1)


@_quiet
def _draine_eval(params, cos_theta):
    return _draine(params[0], params[1], cos_theta)


@_quiet
def _draine_sample(params, u1):
    return _draine_sample_cos(params[0], params[1], u1)


@_quiet
def _rayleigh_eval(params, cos_theta):
    return _rayleigh(cos_theta)


@_quiet
def _rayleigh_sample(params, u1):
    return _rayleigh_sample_cos(u1)


@dataclass(frozen=True)
class Phase:
    """One phase kind's entry. Both functions take the closures' params (3, n) and work on cos_theta alone
    (every phase function is symmetric about the incoming direction; evaluate and sample add the directions):
    eval(params, cos_theta (n,)) -> pdf (n,); sample(params, u1 (n,)) -> cos_theta (n,), distributed with
    density 2 pi eval (Cycles' sampler, whose pdf is eval there). Both compute in their operands' precision:
    float32 in the kernels, as Cycles; the tests also run them in float64."""
    name: str
    eval: Callable
    sample: Callable
    rows: dict = field(default_factory=dict)    # parameter row -> meaning


PHASES = {
    HENYEY_GREENSTEIN: Phase("Henyey-Greenstein", _hg_eval, _hg_sample, {0: "g"}),
    FOURNIER_FORAND: Phase("Fournier-Forand", _ff_eval, _ff_sample, {0: "n (IOR)", 1: "v", 2: "c3"}),
    DRAINE: Phase("Draine", _draine_eval, _draine_sample, {0: "g", 1: "alpha"}),
    RAYLEIGH: Phase("Rayleigh", _rayleigh_eval, _rayleigh_sample),
}


# ---------------------------------------------------------------- setup from the nodes' inputs
def _inputs(*values):
    """Node inputs (numbers or arrays) as float32 (n,) arrays of one length (1 when all are numbers)."""
    return np.broadcast_arrays(*(np.atleast_1d(np.asarray(x, F32)) for x in values))


def _params(*rows):
    """Parameter rows as a (3, n) float32 array, unused rows 0."""
    n = len(rows[0]) if rows else 1
    out = np.zeros((PARAM_ROWS, n), F32)
    for i, row in enumerate(rows):
        out[i] = row
    return out


def henyey_greenstein_params(g) -> np.ndarray:
    """Henyey-Greenstein's params (3, n) from the Anisotropy input (Volume Scatter, Volume Coefficients,
    Principled Volume), clamped as volume_henyey_greenstein_setup does."""
    (g,) = _inputs(g)
    return _params(_clamp_g(g))


def fournier_forand_params(ior, backscatter) -> np.ndarray:
    """Fournier-Forand's params (3, n) from the IOR and Backscatter inputs (volume_fournier_forand_setup:
    B = min(|B|, 0.499), n = max(IOR, 1.001); volume_util.h phase_fournier_forand_coeffs: with
    delta90 = delta(n, 1/2) and delta180 = delta(n, 1), v = -log(2 B (delta90 - 1) + 1) / log(delta90), the
    slope the backscatter fraction B gives, and c3 = (delta180^-v - 1) / (delta180 - 1))."""
    ior, backscatter = _inputs(ior, backscatter)
    b = cycles_min(np.abs(backscatter), BACKSCATTER_LIMIT)
    n = cycles_max(ior, IOR_MIN)
    d90 = _ff_delta(n, F32(0.5))
    d180 = _ff_delta(n, F32(1.0))
    v = -np.log(2 * b * (d90 - 1) + 1) / np.log(d90)
    return _params(n, v, (d180 ** -v - 1) / (d180 - 1))


def draine_params(g, alpha) -> np.ndarray:
    """Draine's params (3, n) from the Anisotropy and Alpha inputs: g clamped as volume_draine_setup does,
    alpha as given."""
    g, alpha = _inputs(g, alpha)
    return _params(_clamp_g(g), alpha)


def rayleigh_params(n: int = 1) -> np.ndarray:
    """Rayleigh's params (3, n): none, zeros."""
    return np.zeros((PARAM_ROWS, n), F32)


def mie_fit(diameter):
    """Cycles' phase_mie_fitted_parameters (volume_util.h; Jendersie and d'Eon 2023, "An Approximate Mie
    Scattering Function for Fog and Cloud Rendering", supplemental): a water droplet's diameter in micrometres
    (negative and NaN taken as 0) -> (g_hg, g_draine, alpha, w), float32 (n,) each, of the mixture
    (1 - w) HG(g_hg) + w Draine(g_draine, alpha), unclamped. Four fits: d <= 0.1 (eq. 11-14), 0.1 < d < 1.5
    (15-18), 1.5 <= d < 5 (19-22), d >= 5 (7-10); the last holds for any larger d (g_hg tends to 1)."""
    (d,) = _inputs(diameter)
    d = np.fmax(d, F32(0.0))                                    # C's fmaxf: a NaN diameter gives 0
    g_hg, g_d, alpha, w = (np.zeros_like(d) for _ in range(4))

    tiny = d <= F32(0.1)
    x = d[tiny]
    g_hg[tiny] = F32(13.8) * (x * x)
    g_d[tiny] = F32(1.1456) * x * np.sin(F32(9.29044) * x)
    alpha[tiny] = 250
    w[tiny] = F32(0.252977) - F32(312.983) * x ** F32(4.3)

    small = ~tiny & (d < F32(1.5))
    log_d = np.log(d[small])
    g_hg[small] = F32(0.862) - F32(0.143) * (log_d * log_d)
    a = (log_d - F32(0.238604)) * (log_d + F32(1.00667))
    b = F32(0.507522) - F32(0.15677) * log_d
    c = F32(1.19692) * np.cos(a / b) + F32(1.37932) * log_d + F32(0.0625835)
    g_d[small] = F32(0.379685) * np.cos(c) + F32(0.344213)
    alpha[small] = 250
    w[small] = F32(0.146209) * np.cos(F32(3.38707) * log_d + F32(2.11193)) + F32(0.316072) + \
        F32(0.0778917) * log_d

    medium = ~tiny & ~small & (d < F32(5.0))
    log_d = np.log(d[medium])
    log_log_d = np.log(log_d)
    g_hg[medium] = F32(0.0604931) * log_log_d + F32(0.940256)
    g_d[medium] = F32(0.500411) - F32(0.081287) / (F32(-2.0) * log_d + np.tan(log_d) + F32(1.27551))
    alpha[medium] = F32(7.30354) * log_d + F32(6.31675)
    w[medium] = F32(0.026914) * (log_d - np.cos(F32(5.68947) * (log_log_d - F32(0.0292149)))) + F32(0.3764)

    large = ~tiny & ~small & ~medium
    x = d[large]
    g_hg[large] = np.exp(F32(-0.0990567) / (x - F32(1.67154)))
    g_d[large] = np.exp(F32(-2.20679) / (x + F32(3.91029)) - F32(0.428934))
    alpha[large] = np.exp(F32(3.62489) - F32(8.29288) / (x + F32(5.52825)))
    w[large] = np.exp(F32(-0.599085) / (x - F32(0.641583)) - F32(0.665888))
    return g_hg, g_d, alpha, w


SCATTER_PHASES = ("HENYEY_GREENSTEIN", "FOURNIER_FORAND", "DRAINE", "RAYLEIGH", "MIE")   # Blender's enum


def scatter_closures(phase: str = "HENYEY_GREENSTEIN", anisotropy=0.0, ior=1.33, backscatter=0.1, alpha=0.5,
                     diameter=20.0):
    """The phase closures a Volume Scatter or Volume Coefficients node makes (svm_alloc_closure_volume_scatter,
    kernel/svm/closure.h), as a list of (kind, weight (n,) float32, params (3, n) float32): one closure of
    weight 1, or for MIE two, Henyey-Greenstein of weight 1 - w and Draine of weight w (mie_fit). Inputs are
    numbers or (n,) arrays, defaults the node's (Cycles' scene/shader_nodes.cpp); each phase reads its own:
    Anisotropy (Henyey-Greenstein, Draine), IOR and Backscatter (Fournier-Forand), Alpha (Draine), Diameter
    (Mie). Cycles gives each closure the weight times the node's colour and density, whose channel average is
    the closure's sample weight in a mixture."""
    if phase == "MIE":
        g_hg, g_d, mie_alpha, w = mie_fit(diameter)
        return [(HENYEY_GREENSTEIN, 1 - w, henyey_greenstein_params(g_hg)),
                (DRAINE, w, draine_params(g_d, mie_alpha))]
    if phase == "HENYEY_GREENSTEIN":
        kind, params = HENYEY_GREENSTEIN, henyey_greenstein_params(anisotropy)
    elif phase == "FOURNIER_FORAND":
        kind, params = FOURNIER_FORAND, fournier_forand_params(ior, backscatter)
    elif phase == "DRAINE":
        kind, params = DRAINE, draine_params(anisotropy, alpha)
    elif phase == "RAYLEIGH":
        kind, params = RAYLEIGH, rayleigh_params(1)
    else:
        raise ValueError(f"unknown phase {phase!r}: one of {SCATTER_PHASES}")
    return [(kind, np.ones(params.shape[1], F32), params)]


# ---------------------------------------------------------------- evaluate and sample
def cos_theta_of(wi, wo):
    """cos of the scattering angle, dot(-wi, wo), as Cycles' phase closures take it. (n,) float32."""
    return dot_xyz((-wi[0], -wi[1], -wi[2]), wo)


def _finite(pdf):
    return np.where(np.isfinite(pdf), pdf, F32(0.0)).astype(F32, copy=False)


def _direction(d, cos_theta, u2):
    """volume_util.h phase_sample_direction: the direction at angle acos(cos_theta) from the unit d, at
    azimuth 2 pi u2 in Cycles' make_orthonormals frame about d; normalised. (x, y, z) float32."""
    t, b = make_orthonormals_xyz(d)
    sin_theta = np.sqrt(cycles_max(1 - cos_theta * cos_theta, F32(0.0)))
    phi = TWO_PI * u2
    x, y = sin_theta * np.cos(phi), sin_theta * np.sin(phi)
    return normalize_xyz(tuple(x * t[k] + y * b[k] + cos_theta * d[k] for k in range(3)))


def _as_params(params):
    return np.asarray(params, F32)


def _as_direction(w):
    return tuple(np.asarray(c, F32) for c in w)


def evaluate(kind: int, params, wi, wo):
    """One phase kind at n points: params (3, n) (or (3, 1)), wi and wo unit (x, y, z) of (n,) float32 ->
    (value (n,), pdf (n,)) float32, equal."""
    pdf = _finite(PHASES[kind].eval(_as_params(params), cos_theta_of(_as_direction(wi), _as_direction(wo))))
    return pdf.copy(), pdf


def sample(kind: int, params, wi, u1, u2):
    """One phase kind at n points: a direction wo from uniforms u1 (the angle) and u2 (the azimuth), each (n,)
    float32 in [0, 1) -> (wo (x, y, z), value (n,), pdf (n,)), value = pdf = eval at the sampled angle (as
    Cycles, which evaluates at the sampled cos_theta, not at the direction's). pdf 0 where the sampler failed
    (then wo = -wi) or where the phase is 0 (Fournier-Forand outside |cos| < 1)."""
    u1, u2 = np.asarray(u1, F32), np.asarray(u2, F32)
    params, wi = np.broadcast_to(_as_params(params), (PARAM_ROWS, len(u1))), _as_direction(wi)
    phase = PHASES[kind]
    cos_theta = phase.sample(params, u1).astype(F32, copy=False)
    pdf = phase.eval(params, cos_theta)
    ok = np.isfinite(cos_theta) & np.isfinite(pdf)
    cos_theta = np.where(ok, cos_theta, F32(1.0))
    pdf = np.where(ok, pdf, F32(0.0)).astype(F32, copy=False)
    wo = _direction((-wi[0], -wi[1], -wi[2]), cos_theta, u2)
    return wo, pdf.copy(), pdf
