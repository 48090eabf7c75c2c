"""The microfacet family of Cycles 5.0 (`kernel/closure/bsdf_microfacet.h`): the GGX and Beckmann
distributions, their visible normal sampling, the reflection, refraction and glass lobes, the anisotropy
mappings of the Principled and Glossy BSDFs, the multiscatter energy compensation (GGX only, as in Cycles)
and the albedo estimates Cycles uses for layering and sample weights.

Distributions. The lobe functions take `distribution=GGX` (the default) or `distribution=BECKMANN`, one
per call: D, Smith Lambda and the visible normal sampler change, the Fresnel, Jacobian, masking and
lobe-choice code is shared. Beckmann follows Cycles: D = exp(-tan^2 / alpha^2) / (pi alpha^2 cos^4)
(anisotropic form), Lambda is Walter et al.'s rational approximation, and visible normals are sampled
with Jakob's slope inversion (Heitz & d'Eon 2014) from Cycles' approximate erf and inverse erf and its
three Newton steps; its small error against the analytic pdf is Cycles' too.

Contract (see the package docstring). Local frame: z = the lobe's normal, x = its tangent (alpha_x is
along x). A direction is a tuple (x, y, z) of (N,) float32 unit arrays; `wo` points to the viewer,
`wi` to the light or the sampled direction (Cycles' source calls the viewer direction wi: translate).
    eval_*(wo, wi, ...)   -> (f_cos (3, N), pdf (N,)): f |cos theta_i| and the pdf per unit solid angle
    sample_*(wo, ..., u1, u2[, uc]) -> MicrofacetSample(wi, weight (3, N), pdf (N,), delta (N,) bool,
                                                         transmission (N,) bool)
with weight = f |cos theta_i| / pdf. Invalid samples have weight 0 and pdf 0. alpha_x, alpha_y, eta are
(N,) float32 or scalars; Fresnel models are callables from `fresnel` (see its docstring). The lobes do
not include the closure weight, nor the multiscatter factors (the caller multiplies by those).

The viewer's side. As in Cycles, the viewer must be above the lobe's normal: eval and sample return 0
where wo.z <= 0. The caller flips the frame to the viewer's side on back faces (Cycles flips N) and then
passes eta = IOR for a viewer outside an object of index IOR, eta = 1 / IOR for a viewer inside it:
eta is always the index of the far side (-z) over the index of the viewer's side (+z).

Singular lobes (either distribution). alpha_x alpha_y <= 2e-10 is a perfectly smooth surface (Cycles'
BSDF_ROUGHNESS_SQ_THRESH): eval returns 0 (f and pdf); sample returns the mirror or refracted direction
with its exact weight (Fresnel over the event's probability), pdf = +inf and delta = True. Cycles also
treats a refraction as singular when |eta - 1| < 1e-4 (the ray goes straight through), whatever the
roughness; so do we, and eval of a transmission then returns 0. A caller recognises a delta sample by
`delta` (equivalently pdf == inf); its weight is already the full throughput factor and it takes no MIS
against lights.

Checks left to the caller: Cycles rejects sampled directions on the wrong side of the geometric normal
(reflections below Ng, refractions above it); the lobe sees only the shading frame.

Where eval follows Cycles 5.0 although it is odd, and the one place it does not:
- A transmission pair that no microfacet can produce (the generalised half vector faces away from wo or
  toward wi) is NOT rejected by eval, exactly as in Cycles (its source has a TODO there). Such pairs
  are never sampled, so the eval pdf integrates to more than the sampler covers (a few percent of the
  transmitted pdf at alpha 0.5): light sampling picks up that extra energy in Cycles, and so here.
  `refraction_is_physical` gives the mask of reachable pairs; multiplying eval by it is the fix.
- eval of a transmission with |eta - 1| < 1e-4 returns 0, consistent with its delta sampling; Cycles
  evaluates a meaningless half vector there (measure-zero for lights in practice).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import fresnel as fr
from . import tables
from ..sampling import channel_mean
from ..vec import F32, HALF, INV_PI, ONE, ZERO, dot_xyz, normalize_xyz

SINGULAR_ALPHA2 = F32(2e-10)
SINGULAR_ETA = F32(1e-4)
GGX, BECKMANN = 0, 1  # the `distribution` argument of the lobe functions


class MicrofacetSample(NamedTuple):
    wi: tuple           # sampled direction, three (N,) float32
    weight: np.ndarray  # (3, N) float32, f |cos theta_i| / pdf; 0 if invalid
    pdf: np.ndarray     # (N,) float32 per unit solid angle; +inf for delta, 0 if invalid
    delta: np.ndarray   # (N,) bool: a perfectly specular event (pdf inf)
    transmission: np.ndarray  # (N,) bool: the sample went through (False for reflections and invalid)


# ---------------------------------------------------------------- small vector helpers
def _f32(x):
    return np.asarray(x, dtype=np.float32)


def _select(mask, a, b):
    """Per-lane choice between two directions."""
    return tuple(np.where(mask, p, q).astype(np.float32) for p, q in zip(a, b))


def is_singular(alpha_x, alpha_y):
    """True where the lobe is perfectly smooth (alpha_x alpha_y <= 2e-10)."""
    return _f32(alpha_x) * _f32(alpha_y) <= SINGULAR_ALPHA2


# ---------------------------------------------------------------- GGX distribution
def ggx_D(h, alpha_x, alpha_y):
    """Anisotropic GGX D(h) = 1 / (pi ax ay (hx^2/ax^2 + hy^2/ay^2 + hz^2)^2), h unit. (N,).
    Isotropic: alpha^2 / (pi (1 - c^2 + alpha^2 c^2)^2), c = hz. Symmetric in the sign of h."""
    ax, ay = _f32(alpha_x), _f32(alpha_y)
    sx, sy = h[0] / ax, h[1] / ay
    d = sx * sx + sy * sy + h[2] * h[2]
    return (INV_PI / (ax * ay * d * d)).astype(np.float32)


def ggx_lambda(w, alpha_x, alpha_y):
    """Smith Lambda(w) = (sqrt(1 + a^2 tan^2) - 1) / 2 with a^2 tan^2 = (ax^2 wx^2 + ay^2 wy^2) / wz^2,
    written as a^2 tan^2 / (2 (1 + sqrt(1 + a^2 tan^2))) to keep precision for small alpha.
    +inf at grazing (wz = 0), which makes G = 0."""
    ax, ay = _f32(alpha_x), _f32(alpha_y)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a2t2 = (np.square(ax * w[0]) + np.square(ay * w[1])) / (w[2] * w[2])
        lam = a2t2 / (F32(2.0) * (ONE + np.sqrt(ONE + a2t2)))
    return np.where(np.isinf(a2t2), np.inf, lam).astype(np.float32)


# ---------------------------------------------------------------- Beckmann distribution
def beckmann_D(h, alpha_x, alpha_y):
    """Anisotropic Beckmann D(h) = exp(-(hx^2/ax^2 + hy^2/ay^2) / hz^2) / (pi ax ay hz^4), h unit. (N,).
    Isotropic: exp(-tan^2 theta_h / alpha^2) / (pi alpha^2 cos^4 theta_h). 0 at hz = 0; symmetric in h."""
    ax, ay = _f32(alpha_x), _f32(alpha_y)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        sx, sy = h[0] / ax, h[1] / ay
        c2 = h[2] * h[2]
        d = np.exp(-(sx * sx + sy * sy) / c2) / (F32(np.pi) * ax * ay * c2 * c2)
    return np.where(c2 > 0, d, ZERO).astype(np.float32)


def beckmann_lambda(w, alpha_x, alpha_y):
    """Cycles' Smith Lambda for Beckmann (Walter et al. 2007, below their eq. 69): with a = 1 / (alpha
    tan), Lambda = (1 - 1.259 a + 0.396 a^2) / (3.535 a + 2.181 a^2) where a < 1.6 (alpha^2 tan^2 >=
    0.39), else 0. +inf at grazing (wz = 0), which makes G = 0."""
    ax, ay = _f32(alpha_x), _f32(alpha_y)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a2t2 = (np.square(ax * w[0]) + np.square(ay * w[1])) / (w[2] * w[2])
        a = ONE / np.sqrt(a2t2)
        lam = ((F32(0.396) * a - F32(1.259)) * a + ONE) / ((F32(2.181) * a + F32(3.535)) * a)
    lam = np.where(a2t2 < F32(0.39), ZERO, lam)
    return np.where(np.isinf(a2t2), np.inf, lam).astype(np.float32)


def _erf(x):
    """Cycles' fast_erff: Abramowitz & Stegun 7.1.28 (about 2e-6 absolute error), float32."""
    a = np.abs(x)
    r = np.full_like(a, F32(0.0000430638))  # Horner, from the highest power down
    for c in (F32(0.0002765672), F32(0.0001520143), F32(0.0092705272), F32(0.0422820123), F32(0.0705230784),
              ONE):
        r = r * a + c
    with np.errstate(over="ignore", divide="ignore"):
        v = np.square(np.square(np.square(np.square(r))))  # r^16
        e = ONE - ONE / v
    return (np.where(a >= F32(12.3), ONE, e) * np.where(x < 0, -ONE, ONE)).astype(np.float32)


_IERF_CENTRE = (2.81022636e-08, 3.43273939e-07, -3.5233877e-06, -4.39150654e-06, 0.00021858087,
                -0.00125372503, -0.00417768164, 0.246640727, 1.50140941)
_IERF_TAIL = (-0.000200214257, 0.000100950558, 0.00134934322, -0.00367342844, 0.00573950773,
              -0.0076224613, 0.00943887047, 1.00167406, 2.83297682)


def _erfinv(x):
    """Cycles' fast_ierff: Giles' single-precision inverse error function, |x| clamped below 1."""
    a = np.minimum(np.abs(x), F32(0.99999994))
    w = -np.log((ONE - a) * (ONE + a))
    centre = w < F32(5.0)
    t = np.where(centre, w - F32(2.5), np.sqrt(w) - F32(3.0))
    p = np.where(centre, F32(_IERF_CENTRE[0]), F32(_IERF_TAIL[0]))
    for c0, c1 in zip(_IERF_CENTRE[1:], _IERF_TAIL[1:]):
        p = p * t + np.where(centre, F32(c0), F32(c1))
    return (p * x).astype(np.float32)


def _sign(x):
    """Cycles' signf: -1 below 0, else 1."""
    return np.where(x < 0, -ONE, ONE)


def sample_visible_normal_beckmann(wo, alpha_x, alpha_y, u1, u2):
    """A Beckmann microfacet normal h with density D_wo(h) (wo.z > 0), as Cycles samples it: stretch wo,
    sample the slope of a visible normal of the unit-roughness distribution (x: Jakob's inversion of
    the slope CDF, a closed-form first guess then at most three Newton steps safeguarded by bisection,
    stopping at a residual of 1e-6; y: an inverse erf), rotate to wo's azimuth, unstretch.
    Returns h, three (N,) float32 with h.z > 0."""
    ax, ay = _f32(alpha_x), _f32(alpha_y)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        vx, vy, vz = normalize_xyz((ax * wo[0], ay * wo[1], wo[2]))
        # Normal incidence: a 2D Gaussian of slopes.
        r = np.sqrt(-np.log(np.maximum(u1, np.finfo(np.float32).tiny)))
        phi = F32(2.0 * np.pi) * u2
        normal_x, normal_y = r * np.cos(phi), r * np.sin(phi)
        # General case.
        sin_t = np.sqrt(np.maximum(ONE - vz * vz, ZERO))
        tan_t = sin_t / vz
        cot_t = ONE / tan_t
        erf_a = _erf(cot_t)
        exp_a2 = np.exp(-cot_t * cot_t)
        k = tan_t * F32(0.56418958354)  # tan / sqrt(pi)
        y_approx = u1 * (ONE + erf_a + k * (ONE - erf_a * erf_a))
        y_exact = u1 * (ONE + erf_a + k * exp_a2)
        b = np.where(k > 0, (HALF - np.sqrt(k * (k - y_approx + ONE) + F32(0.25))) / k, y_approx - ONE)
        inv_erf = _erfinv(b)
        begin_x, begin_y = np.full_like(b, -ONE), -y_exact
        end_x = erf_a
        cur_x = b
        cur_y = ONE + b + k * np.exp(-inv_erf * inv_erf) - y_exact
        for _ in range(3):
            active = np.abs(cur_y) > F32(1e-6)
            if not active.any():
                break
            same = _sign(begin_y) == _sign(cur_y)
            begin_x = np.where(active & same, cur_x, begin_x)
            begin_y = np.where(active & same, cur_y, begin_y)
            end_x = np.where(active & ~same, cur_x, end_x)
            newton = cur_x - cur_y / (ONE - inv_erf * tan_t)
            step = np.where((newton >= begin_x) & (newton <= end_x), newton, HALF * (begin_x + end_x))
            cur_x = np.where(active, step, cur_x)
            inv_erf = np.where(active, _erfinv(cur_x), inv_erf)
            cur_y = np.where(active, ONE + cur_x + k * np.exp(-inv_erf * inv_erf) - y_exact, cur_y)
        slope_y = _erfinv(F32(2.0) * u2 - ONE)
        cos_phi, sin_phi = vx / sin_t, vy / sin_t
        general_x = cos_phi * inv_erf - sin_phi * slope_y
        general_y = sin_phi * inv_erf + cos_phi * slope_y
        at_normal = vz >= F32(0.99999)
        sx = np.where(at_normal, normal_x, general_x) * ax
        sy = np.where(at_normal, normal_y, general_y) * ay
        h = normalize_xyz((-sx, -sy, np.ones_like(sx)))
    ok = np.isfinite(h[0]) & np.isfinite(h[1]) & np.isfinite(h[2])
    return tuple(np.where(ok, c, d).astype(np.float32) for c, d in zip(h, (ZERO, ZERO, ONE)))


def _lambda(distribution):
    return beckmann_lambda if distribution == BECKMANN else ggx_lambda


def _D(distribution):
    return beckmann_D if distribution == BECKMANN else ggx_D


def smith_G1(w, alpha_x, alpha_y, distribution=GGX):
    """Masking 1 / (1 + Lambda(w))."""
    return (ONE / (ONE + _lambda(distribution)(w, alpha_x, alpha_y))).astype(np.float32)


def sample_visible_normal(wo, alpha_x, alpha_y, u1, u2, distribution=GGX):
    """A microfacet normal h with density D_wo(h) = G1(wo) max(wo.h, 0) D(h) / wo.z (wo.z > 0).
    distribution=BECKMANN: sample_visible_normal_beckmann. GGX:

    Dupuy & Benyoub 2023 ("Sampling Visible GGX Normals with Spherical Caps"): in the stretched
    configuration where the surface is a hemisphere, visible normals are wo_std plus a uniform point of
    the spherical cap z >= -wo_std.z; then unstretch. The same distribution as Heitz 2018, which Cycles
    uses, without its tangent basis. Returns h, three (N,) float32 with h.z >= 0.
    """
    if distribution == BECKMANN:
        return sample_visible_normal_beckmann(wo, alpha_x, alpha_y, u1, u2)
    ax, ay = _f32(alpha_x), _f32(alpha_y)
    vx, vy, vz = normalize_xyz((ax * wo[0], ay * wo[1], wo[2]))
    phi = F32(2.0 * np.pi) * u1
    z = (ONE - u2) * (ONE + vz) - vz
    sin_theta = np.sqrt(np.clip(ONE - z * z, ZERO, ONE))
    hx = sin_theta * np.cos(phi) + vx
    hy = sin_theta * np.sin(phi) + vy
    hz = z + vz
    return normalize_xyz((ax * hx, ay * hy, np.maximum(hz, ZERO)))


def visible_normal_pdf(wo, h, alpha_x, alpha_y, distribution=GGX):
    """D_wo(h) = G1(wo) max(wo.h, 0) D(h) / wo.z, the density of sample_visible_normal. (N,)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        pdf = (smith_G1(wo, alpha_x, alpha_y, distribution) * np.maximum(dot_xyz(wo, h), ZERO)
               * _D(distribution)(h, alpha_x, alpha_y)
               / wo[2])
    return np.where((wo[2] > 0) & np.isfinite(pdf), pdf, ZERO).astype(np.float32)


# ---------------------------------------------------------------- lobe terms shared by eval and sample
def _reflection_common(wo, h, alpha_x, alpha_y, distribution):
    """D / (4 wo.z): f_cos = F common / (1 + Lo + Li), pdf = common / (1 + Lo)."""
    return _D(distribution)(h, alpha_x, alpha_y) / (F32(4.0) * wo[2])


def _refraction_common(wo, wi, h, alpha_x, alpha_y, eta, distribution):
    """D / wo.z |wo.h| |wi.h| / (wi.h + wo.h / eta)^2: the refraction analogue of _reflection_common,
    the Jacobian of Walter et al. 2007 written as Cycles does (eta^2 kept, see the module docstring)."""
    cos_ho, cos_hi = dot_xyz(wo, h), dot_xyz(wi, h)
    denom = cos_hi + cos_ho / eta
    return _D(distribution)(h, alpha_x, alpha_y) / wo[2] * np.abs(cos_ho * cos_hi) / (denom * denom)


def _finish(valid, f_cos, pdf, delta=False):
    """Zero everything outside `valid` and anything non-finite (grazing limits); delta pdfs stay inf."""
    ok = valid & (np.isfinite(pdf) | delta) & np.all(np.isfinite(f_cos), axis=0)
    return (np.where(ok[None, :], f_cos, ZERO).astype(np.float32),
            np.where(ok, pdf, ZERO).astype(np.float32))


def _nonzero(c):
    """Cycles' !is_zero(colour): some channel differs from 0."""
    return np.any(c != 0, axis=0)


# ---------------------------------------------------------------- reflection
def eval_reflection(wo, wi, alpha_x, alpha_y, fresnel, distribution=GGX):
    """GGX (or Beckmann) reflection. fresnel(cos_h) -> (3, N) with cos_h = wo.h. Returns (f_cos (3, N), pdf (N,)):
        f_cos = F D / (4 wo.z (1 + L(wo) + L(wi))),   pdf = D / (4 wo.z (1 + L(wo)))   (VNDF sampling).
    Zero below either horizon, for singular lobes, and where F = 0 in all channels (as Cycles)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        valid = (wo[2] > 0) & (wi[2] > 0) & ~is_singular(alpha_x, alpha_y)
        h = normalize_xyz((wo[0] + wi[0], wo[1] + wi[1], wo[2] + wi[2]))
        cos_h = np.where(valid, np.clip(dot_xyz(wo, h), ZERO, ONE), ONE)
        f = fresnel(cos_h)
        common = _reflection_common(wo, h, alpha_x, alpha_y, distribution)
        lam = _lambda(distribution)
        lo, li = lam(wo, alpha_x, alpha_y), lam(wi, alpha_x, alpha_y)
        pdf = common / (ONE + lo)
        f_cos = f * (common / (ONE + lo + li))[None, :]
        return _finish(valid & _nonzero(f), f_cos, pdf)


def sample_reflection(wo, alpha_x, alpha_y, fresnel, u1, u2, distribution=GGX):
    """Sample GGX (or Beckmann) reflection by visible normals. u1, u2 (N,) float32 in [0, 1). Returns
    MicrofacetSample; weight = F (1 + L(wo)) / (1 + L(wo) + L(wi)), or F for singular lobes."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        singular = is_singular(alpha_x, alpha_y) & np.ones(np.shape(u1), bool)
        h = _select(singular, (ZERO, ZERO, ONE), sample_visible_normal(wo, alpha_x, alpha_y, u1, u2, distribution))
        cos_h = np.clip(dot_xyz(wo, h), ZERO, ONE)
        wi = normalize_xyz(tuple(F32(2.0) * cos_h * hc - oc for hc, oc in zip(h, wo)))
        f = fresnel(np.where(wo[2] > 0, cos_h, ONE))
        valid = (wo[2] > 0) & (wi[2] > 0) & _nonzero(f)
        lam = _lambda(distribution)
        lo, li = lam(wo, alpha_x, alpha_y), lam(wi, alpha_x, alpha_y)
        pdf = np.where(singular, np.inf, _reflection_common(wo, h, alpha_x, alpha_y, distribution) / (ONE + lo))
        weight = f * np.where(singular, ONE, (ONE + lo) / (ONE + lo + li))[None, :]
        weight, pdf = _finish(valid, weight, pdf, singular)
    return MicrofacetSample(wi, weight, pdf, singular & (pdf > 0), np.zeros(np.shape(u1), bool))


# ---------------------------------------------------------------- refraction and glass
def _transmission_half_vector(wo, wi, eta):
    """h = normalize(-(eta wi + wo)), Cycles' generalised half vector (it may face either way)."""
    return normalize_xyz((-(eta * wi[0] + wo[0]), -(eta * wi[1] + wo[1]), -(eta * wi[2] + wo[2])))


def refraction_is_physical(wo, wi, eta):
    """True where a transmission pair (wo above, wi below) can come from a microfacet: with the
    generalised half vector h oriented to +z, wo.h > 0 and wi.h < 0. Sampling only produces such pairs;
    Cycles' eval (and ours) does not check it. (N,) bool."""
    eta = _f32(eta)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = _transmission_half_vector(wo, wi, eta)
        flip = np.where(h[2] < 0, -ONE, ONE)
        return (wo[2] > 0) & (wi[2] < 0) & (flip * dot_xyz(wo, h) > 0) & (flip * dot_xyz(wi, h) < 0)


def reflect_probability(r, t):
    """Cycles' choice of reflection: mean(R) / mean(R + T); NaN where both vanish (caller masks)."""
    return channel_mean(r) / channel_mean(r + t)


def _eval_dielectric(wo, wi, alpha_x, alpha_y, eta, fresnel, distribution):
    """Glass-type eval: reflection above, transmission below, each weighted by Cycles' lobe choice.
    fresnel(cos_h, eta) -> (R, T), called with |wo.h| (Cycles' dielectric curves ignore its sign)."""
    eta = np.broadcast_to(_f32(eta), np.shape(wo[2]))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        transmit = wi[2] < 0
        valid = (wo[2] > 0) & (wi[2] != 0) & ~is_singular(alpha_x, alpha_y)
        valid &= ~(transmit & (np.abs(eta - ONE) < SINGULAR_ETA))
        h = _select(transmit, _transmission_half_vector(wo, wi, eta),
                    normalize_xyz((wo[0] + wi[0], wo[1] + wi[1], wo[2] + wi[2])))
        cos_h = np.where(valid, np.clip(np.abs(dot_xyz(wo, h)), ZERO, ONE), ONE)
        r, t = fresnel(cos_h, eta)
        # No refracted ray at the microfacet: T = 0 whatever the model says (refraction-only lobe).
        t = np.where((fr.refracted_cos_sq(cos_h, eta) <= 0)[None, :], ZERO, t)
        p_reflect = reflect_probability(r, t)
        common = np.where(transmit, _refraction_common(wo, wi, h, alpha_x, alpha_y, eta, distribution),
                          _reflection_common(wo, h, alpha_x, alpha_y, distribution))
        lam = _lambda(distribution)
        lo, li = lam(wo, alpha_x, alpha_y), lam(wi, alpha_x, alpha_y)
        lobe_p = np.where(transmit, ONE - p_reflect, p_reflect)
        pdf = common * lobe_p / (ONE + lo)
        f_cos = np.where(transmit[None, :], t, r) * (common / (ONE + lo + li))[None, :]
        return _finish(valid & (_nonzero(r) | _nonzero(t)), f_cos, pdf)


def _sample_dielectric(wo, alpha_x, alpha_y, eta, fresnel, u1, u2, uc, distribution):
    eta = np.broadcast_to(_f32(eta), np.shape(u1))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        singular = is_singular(alpha_x, alpha_y) & np.ones(np.shape(u1), bool)
        h = _select(singular, (ZERO, ZERO, ONE), sample_visible_normal(wo, alpha_x, alpha_y, u1, u2, distribution))
        cos_h = np.clip(dot_xyz(wo, h), ZERO, ONE)
        cos_h = np.where(wo[2] > 0, cos_h, ONE)
        r, t = fresnel(cos_h, eta)
        cos_t_sq = fr.refracted_cos_sq(cos_h, eta)
        t = np.where((cos_t_sq <= 0)[None, :], ZERO, t)
        p_reflect = reflect_probability(r, t)
        refract = uc >= p_reflect
        # Refraction through h (Cycles' refract_angle): wi = (cos_h / eta - cos_t) h - wo / eta.
        cos_t = np.sqrt(np.maximum(cos_t_sq, ZERO))
        k = cos_h / eta - cos_t
        wi_t = normalize_xyz(tuple(k * hc - oc / eta for hc, oc in zip(h, wo)))
        wi_r = normalize_xyz(tuple(F32(2.0) * cos_h * hc - oc for hc, oc in zip(h, wo)))
        wi = _select(refract, wi_t, wi_r)
        valid = ((wo[2] > 0) & np.isfinite(p_reflect) & np.where(refract, wi[2] < 0, wi[2] > 0))
        delta = singular | (refract & (np.abs(eta - ONE) < SINGULAR_ETA))
        lobe_p = np.where(refract, ONE - p_reflect, p_reflect)
        common = np.where(refract, _refraction_common(wo, wi, h, alpha_x, alpha_y, eta, distribution),
                          _reflection_common(wo, h, alpha_x, alpha_y, distribution))
        lam = _lambda(distribution)
        lo, li = lam(wo, alpha_x, alpha_y), lam(wi, alpha_x, alpha_y)
        pdf = np.where(delta, np.inf, lobe_p * common / (ONE + lo))
        shadowing = np.where(delta, ONE, (ONE + lo) / (ONE + lo + li))
        weight = np.where(refract[None, :], t, r) / lobe_p[None, :] * shadowing[None, :]
        weight, pdf = _finish(valid & (lobe_p > 0), weight, pdf, delta)
    ok = pdf > 0
    return MicrofacetSample(wi, weight, pdf, delta & ok, refract & ok)


def eval_glass(wo, wi, alpha_x, alpha_y, eta, fresnel, distribution=GGX):
    """GGX glass (Cycles' glass closure: reflect + refract). eta: see the module docstring; fresnel
    (cos_h, eta) -> (R (3, N), T (3, N)), e.g. fresnel.dielectric_glass() or fresnel.remapped_glass(..).
    With P = mean(R) / mean(R + T) at the half vector:
      reflection (wi.z > 0):   f_cos = R D / (4 wo.z (1 + Lo + Li)),   pdf = P D / (4 wo.z (1 + Lo))
      transmission (wi.z < 0), h = normalize(-(eta wi + wo)), J = |wo.h||wi.h| / (wi.h + wo.h / eta)^2:
                               f_cos = T D J / (wo.z (1 + Lo + Li)),   pdf = (1 - P) D J / (wo.z (1 + Lo))
    Cycles' glass is isotropic (its setup sets alpha_y = alpha_x); pass equal alphas to match it."""
    return _eval_dielectric(wo, wi, alpha_x, alpha_y, eta, fresnel, distribution)


def sample_glass(wo, alpha_x, alpha_y, eta, fresnel, u1, u2, uc, distribution=GGX):
    """Sample GGX glass: a visible normal h from (u1, u2), then reflection if uc < P, P = mean(R) /
    mean(R + T) at h (T = 0 under total internal reflection), else refraction. Returns MicrofacetSample;
    `transmission` says which event happened. Weight = R / P (1 + Lo) / (1 + Lo + Li) for reflection,
    T / (1 - P) (...) for transmission; delta samples drop the shadowing ratio."""
    return _sample_dielectric(wo, alpha_x, alpha_y, eta, fresnel, u1, u2, uc, distribution)


def _refraction_only(cos_h, eta):
    """Cycles' Refraction closure (GGX or Beckmann): no Fresnel, R = 0, T = 1 (TIR is zeroed by the lobe)."""
    n = np.shape(cos_h)[0]
    return np.zeros((3, n), np.float32), np.ones((3, n), np.float32)


def eval_refraction(wo, wi, alpha_x, alpha_y, eta, distribution=GGX):
    """Cycles' Refraction BSDF: the transmission half of eval_glass with T = 1, R = 0 (so P = 0), and 0
    where the microfacet totally reflects. No compensation in Cycles."""
    return _eval_dielectric(wo, wi, alpha_x, alpha_y, eta, _refraction_only, distribution)


def sample_refraction(wo, alpha_x, alpha_y, eta, u1, u2, distribution=GGX):
    """Sample the Refraction BSDF. Microfacets that totally reflect give invalid samples (weight 0)."""
    return _sample_dielectric(wo, alpha_x, alpha_y, eta, _refraction_only, u1, u2, np.zeros_like(u1),
                              distribution)


# ---------------------------------------------------------------- anisotropy mappings (svm/closure.h)
def principled_anisotropy(alpha, anisotropy):
    """Principled BSDF: k = sqrt(1 - 0.9 a), a clamped to [0, 1]; alpha_x = alpha / k, alpha_y = alpha k,
    then clamped to [0, 1] as the GGX setup does. Returns (alpha_x, alpha_y)."""
    aspect = np.sqrt(ONE - F32(0.9) * np.clip(_f32(anisotropy), ZERO, ONE))
    alpha = _f32(alpha)
    return np.clip(alpha / aspect, ZERO, ONE).astype(np.float32), np.clip(alpha * aspect, ZERO, ONE).astype(np.float32)


def glossy_anisotropy(alpha, anisotropy):
    """Glossy BSDF: a clamped to [-0.99, 0.99]; a >= 0: (alpha (1 - a), alpha / (1 - a)); a < 0:
    (alpha / (1 + a), alpha (1 + a)); |a| <= 1e-4 is isotropic. Clamped to [0, 1] as the GGX setup does.
    (Cycles takes the isotropic branch too when no tangent is linked; that is the caller's test.)"""
    a = np.clip(_f32(anisotropy), F32(-0.99), F32(0.99))
    alpha = _f32(alpha)
    a = np.where(np.abs(a) <= F32(1e-4), ZERO, a)
    ax = np.where(a < 0, alpha / (ONE + a), alpha * (ONE - a))
    ay = np.where(a < 0, alpha * (ONE + a), alpha / (ONE - a))
    return np.clip(ax, ZERO, ONE).astype(np.float32), np.clip(ay, ZERO, ONE).astype(np.float32)


# ---------------------------------------------------------------- multiscatter compensation
def _kulla_conty(e, e_avg, fss):
    """eval_scale = 1 / E (the lost single-scattering energy put back), and the colour factor
    E + Fms (1 - E), Fms = Fss Eavg / (1 - Fss (1 - Eavg)) (Kulla & Conty, one Fss cancelled because
    the lobe already carries one bounce of Fresnel). Fss = 1 (or None) gives factor 1."""
    n = e.shape[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        eval_scale = np.where(e > 0, ONE / e, ONE).astype(np.float32)
        if fss is None:
            return eval_scale, np.ones((3, n), np.float32)
        fss = fr.color(fss, n)
        fms = fss * e_avg / (ONE - fss * (ONE - e_avg))
        factor = e + fms * (ONE - e)
    # Cycles skips the darkening only when Fss is exactly 1 in every channel.
    white = np.all(fss == 1, axis=0)
    factor = np.where(white[None, :] | ~np.isfinite(factor), ONE, factor)
    return eval_scale, factor.astype(np.float32)


def multiscatter_reflection(alpha_x, alpha_y, mu, fss=None):
    """Multiscatter GGX for a reflection lobe (Cycles' `microfacet_ggx_preserve_energy`, ggx_E tables).
    mu = wo.z. fss: the lobe's mean Fresnel (3, N), None for F = 1 (Glossy: its colour goes in the closure
    weight and Cycles passes that colour as Fss; pass it here). Returns (eval_scale (N,), weight_factor
    (3, N)): multiply eval and sample weights by eval_scale, the closure weight by weight_factor and its
    sample weight by weight_factor's mean. Fss by Fresnel mode: dielectric (coat) -> fresnel.dielectric_fss;
    F82 -> fresnel.f82_fss; conductor -> fresnel.conductor_fss; remap/generalized Schlick ->
    fresnel.generalized_schlick_fss; Glossy -> its colour."""
    rough, mu = np.broadcast_arrays(tables.rough_coordinate(alpha_x, alpha_y), _f32(mu))
    return _kulla_conty(tables.ggx_E(rough, mu), tables.ggx_Eavg(rough), fss)


def multiscatter_glass(alpha_x, alpha_y, mu, eta, fss=None):
    """Multiscatter GGX for a glass lobe (glass tables; the inverse ones when eta < 1). Cycles passes
    Fss = the transmission tint (Glass: its colour; Principled: sqrt(base colour)); None for white.
    Returns (eval_scale (N,), weight_factor (3, N)) as multiscatter_reflection."""
    rough, mu, eta = np.broadcast_arrays(tables.rough_coordinate(alpha_x, alpha_y), _f32(mu), _f32(eta))
    return _kulla_conty(tables.glass_E(rough, mu, eta), tables.glass_Eavg(rough, eta), fss)


# ---------------------------------------------------------------- albedo estimates
# Cycles' `bsdf_microfacet_estimate_albedo`: the albedo of the lobe caused by its Fresnel, for a base
# microfacet model of albedo 1 (the compensation's job). It scales the closure's sample weight and is
# the `albedo` of `closure_layering_weight` (times the closure weight). Reflection: the smooth Fresnel
# at mu = wo.z, replaced by a table estimate for the generalized Schlick, F82 and dielectric (eta > 1)
# modes; transmission (glass only): the smooth value at mu. Each returns (3, N).
def _table_or_smooth(smooth, estimate):
    """Cycles keeps 0 where the smooth reflectance is 0 in every channel and uses the estimate elsewhere."""
    return np.where(_nonzero(smooth)[None, :], estimate, ZERO).astype(np.float32)


def albedo_remapped(alpha_x, alpha_y, mu, eta, f0, f90=1.0, reflection_tint=1.0, transmission_tint=None):
    """Generalized Schlick in remap mode (Principled specular, transmission; Glass BSDF). A reflection
    lobe passes transmission_tint=None (its reflection albedo); a glass lobe its transmission tint (the sum
    of both parts)."""
    r, t = albedo_remapped_parts(alpha_x, alpha_y, mu, eta, f0, f90, reflection_tint,
                                 ONE if transmission_tint is None else transmission_tint)
    return r if transmission_tint is None else (r + t).astype(np.float32)


def albedo_remapped_parts(alpha_x, alpha_y, mu, eta, f0, f90=1.0, reflection_tint=1.0, transmission_tint=1.0):
    """(reflection, transmission) (3, n) albedos of a remapped-Fresnel lobe, apart (Cycles' bsdf_albedo with
    one part's flag off), from one Fresnel evaluation and one table read."""
    mu = _f32(mu)
    n = mu.shape[0]
    smooth, _ = fr.remapped(mu, eta, f0, f90)
    s = tables.gen_schlick_ior_s(tables.rough_coordinate(alpha_x, alpha_y), mu, eta)
    estimate = fr.lerp(fr.clamp01(fr.color(f0, n)), fr.color(f90, n), s[None, :]) * fr.color(reflection_tint, n)
    r = _table_or_smooth(smooth * fr.color(reflection_tint, n), estimate)
    return r, ((ONE - smooth) * fr.color(transmission_tint, n)).astype(np.float32)


def albedo_generalized_schlick(alpha_x, alpha_y, mu, eta, f0, f90, exponent, reflection_tint=1.0):
    """Generalized Schlick with exponent >= 0, reflection lobe (OSL). Table ggx_gen_schlick_s."""
    mu = _f32(mu)
    n = mu.shape[0]
    smooth, _ = fr.generalized_schlick(mu, eta, f0, f90, exponent)
    r = smooth * fr.color(reflection_tint, n)
    s = tables.gen_schlick_s(tables.rough_coordinate(alpha_x, alpha_y), mu, exponent)
    estimate = fr.lerp(fr.clamp01(fr.color(f0, n)), fr.color(f90, n), s[None, :]) * fr.color(reflection_tint, n)
    return _table_or_smooth(r, estimate)


def albedo_f82(alpha_x, alpha_y, mu, f0, b):
    """F82-tint (Principled metal): lerp(F0, 1, s) with s from ggx_gen_schlick_s at z = 0.5 (exponent 5);
    Cycles ignores b here (a TODO in its source)."""
    mu = _f32(mu)
    n = mu.shape[0]
    s = tables.gen_schlick_s_at(tables.rough_coordinate(alpha_x, alpha_y), mu, HALF)
    estimate = fr.lerp(fr.color(f0, n), ONE, s[None, :])
    return _table_or_smooth(fr.f82(mu, f0, b), estimate)


def albedo_dielectric(alpha_x, alpha_y, mu, eta, reflection_tint=1.0, transmission_tint=None):
    """Exact dielectric Fresnel (the Principled coat: a reflection lobe, transmission_tint=None).
    For eta > 1: lerp(F0(eta), 1, s) with s from ggx_gen_schlick_ior_s; for eta <= 1 the smooth F(mu)."""
    mu = _f32(mu)
    n = mu.shape[0]
    eta = np.broadcast_to(_f32(eta), mu.shape)
    f, _ = fr.dielectric(mu, eta)
    smooth = fr.color(reflection_tint, n) * f[None, :]
    s = tables.gen_schlick_ior_s(tables.rough_coordinate(alpha_x, alpha_y), mu, eta)
    estimate = fr.lerp(fr.f0_from_ior(eta), ONE, s)[None, :] * fr.color(reflection_tint, n)
    r = np.where((eta > 1)[None, :], _table_or_smooth(smooth, estimate), smooth)
    if transmission_tint is None:
        return r.astype(np.float32)
    return (r + (ONE - f)[None, :] * fr.color(transmission_tint, n)).astype(np.float32)


def albedo_conductor(mu, n, k):
    """Physical conductor: Cycles has no table and uses the smooth Fresnel at mu."""
    return fr.conductor(_f32(mu), n, k)
