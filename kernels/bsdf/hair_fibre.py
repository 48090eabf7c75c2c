"""The geometry of the Huang hair model's fibre and of its microfacets, in Cycles' local frame (x toward the
closure's normal N, y along the tangent, z = N x Y): small vector helpers, Cycles' GGX terms and its elliptical
cross-section (Figure 5 of Huang et al. 2022), as `kernel/closure/bsdf_principled_hair_huang.h` and
`bsdf_microfacet.h` write them. b is the aspect ratio (minor over major axis), circular where it is 1; gamma is a
point's angle on the ellipse, phi the azimuth of a direction, h the offset across the fibre.
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, ONE, PI, ZERO, make_orthonormals_xyz
from ..vec import dot_xyz as dot
from . import tables
from .fresnel import dielectric
from .microfacet import sample_visible_normal


# ---------------------------------------------------------------- vectors (tuples of (N,) float32)
def neg(a):
    return (-a[0], -a[1], -a[2])


def scale(a, s):
    return tuple((c * s).astype(F32) for c in a)


def reflect(incident, n):
    d = F32(2.0) * dot(incident, n)
    return tuple((i - d * c).astype(F32) for i, c in zip(incident, n))


def refract_angle(incident, n, cos_t, inv_eta):
    """Cycles' refract_angle; cos_t the refracted cosine relative to n, negative."""
    k = inv_eta * dot(n, incident) + cos_t
    return tuple((k * c - inv_eta * i).astype(F32) for c, i in zip(n, incident))


def fresnel(cos_i, eta):
    """Cycles' fresnel_dielectric: (F, the refracted cosine, negative; 0 under total internal reflection)."""
    f, cos_t = dielectric(cos_i, eta)
    return f, -cos_t


def cos_theta(w):
    return np.sqrt(np.maximum(w[0] * w[0] + w[2] * w[2], ZERO)).astype(F32)


def dir_phi(w):
    return np.arctan2(w[0], w[2]).astype(F32)


def visible(v, m, h):
    return (dot(v, h) > 0) & (dot(v, m) > 0)


def visible2(wi, wo, m, h):
    return visible(wi, m, h) & visible(wo, m, h)


def ggx_lambda(alpha2, cos_n):
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = alpha2 * np.maximum(ONE / (cos_n * cos_n) - ONE, ZERO)
        return (F32(0.5) * (np.sqrt(ONE + t) - ONE)).astype(F32)


def ggx_g(alpha2, cos_i, cos_o):
    return (ONE / (ONE + ggx_lambda(alpha2, cos_i) + ggx_lambda(alpha2, cos_o))).astype(F32)


def ggx_go(alpha2, cos_i, cos_o):
    """bsdf_Go: the shadowing-masking term over the masking toward the incoming direction."""
    li, lo = ggx_lambda(alpha2, cos_i), ggx_lambda(alpha2, cos_o)
    return ((ONE + li) / (ONE + li + lo)).astype(F32)


def ggx_d(alpha2, cos_nh):
    c2 = np.minimum(cos_nh * cos_nh, ONE)
    return (alpha2 / (PI * np.square(ONE - c2 + alpha2 * c2))).astype(F32)


# ---------------------------------------------------------------- the fibre's ellipse (Figure 5 of the paper)
def to_phi(gamma, b, circular):
    return np.where(circular, gamma, np.arctan2(b * np.sin(gamma), np.cos(gamma))).astype(F32)


def to_gamma(phi, b, circular):
    return np.where(circular, phi, np.arctan2(np.sin(phi), b * np.cos(phi))).astype(F32)


def sincos_phi(w):
    c = cos_theta(w)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (w[0] / c).astype(F32), (w[2] / c).astype(F32)


def phi_to_h(phi, b, wi, circular):
    g = to_gamma(phi, b, circular)
    sin_phi_i, cos_phi_i = sincos_phi(wi)
    ellipse = -cos_phi_i * np.sin(g) + b * sin_phi_i * np.cos(g)
    return np.where(circular, -np.sin(phi), ellipse).astype(F32)


def h_to_gamma(h, b, wi, circular):
    with np.errstate(invalid="ignore"):
        ellipse = np.arctan2(wi[2], -b * wi[0]) - np.arccos(np.clip(-h, -ONE, ONE))
        return np.where(circular, -np.arcsin(np.clip(h, -ONE, ONE)), ellipse).astype(F32)


def d_gamma_d_h(sin_phi_i, cos_phi_i, gamma, b, circular):
    d = np.where(circular, np.cos(gamma), cos_phi_i * np.cos(gamma) + b * sin_phi_i * np.sin(gamma))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(d != 0, ONE / np.where(d != 0, d, ONE), ZERO).astype(F32)


def to_point(gamma, b):
    return np.sin(gamma).astype(F32), (b * np.cos(gamma)).astype(F32)


def point_distance(g1, g2, b):
    x1, y1 = to_point(g1, b)
    x2, y2 = to_point(g2, b)
    return np.sqrt(np.square(x1 - x2) + np.square(y1 - y2)).astype(F32)


def sphg_dir(theta, gamma, b, circular):
    """The direction of latitude theta whose azimuth is the ellipse's normal at gamma."""
    st, ct = np.sin(theta).astype(F32), np.cos(theta).astype(F32)
    sg, cg = np.sin(gamma).astype(F32), np.cos(gamma).astype(F32)
    plain = circular | (np.abs(cg) < F32(1e-6))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tan_phi = b * sg / cg
        cos_phi = np.sign(cg) / np.sqrt(tan_phi * tan_phi + ONE)
        sin_phi = cos_phi * tan_phi
    sin_phi, cos_phi = np.where(plain, sg, sin_phi), np.where(plain, cg, cos_phi)
    return (sin_phi * ct).astype(F32), np.broadcast_to(st, sg.shape).astype(F32), (cos_phi * ct).astype(F32)


def arc_length(e2, gamma):
    return np.where(e2 == 0, ONE, np.sqrt(np.maximum(ONE - e2 * np.square(np.sin(gamma)), ZERO))).astype(F32)


def energy_scale(mu, rough_sqrt, eta):
    """bsdf_hair_huang_energy_scale: 1 / the GGX glass albedo table at (sqrt(alpha), mu, eta)."""
    return (ONE / tables.glass_E(rough_sqrt, mu, eta)).astype(F32)


def sample_wh(alpha, wi, wm, u1, u2):
    """A visible GGX normal seen from wi about the mesonormal wm (sample_wh)."""
    s, t = make_orthonormals_xyz(wm)
    local = (dot(wi, s), dot(wi, t), dot(wi, wm))
    h = sample_visible_normal(local, alpha, alpha, u1, u2)
    return tuple((h[0] * a + h[1] * c + h[2] * m).astype(F32) for a, c, m in zip(s, t, wm))


def trrt(t, r, a):
    """bsdf_hair_huang_eval_trrt: the geometric series beyond TRT, from the earlier interactions."""
    t_avg = np.maximum(ONE - r, F32(1e-5))
    return (t * r * r * t_avg * a * a * a / (ONE - a * (ONE - t_avg))).astype(F32)
