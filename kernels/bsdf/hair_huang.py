"""Cycles' Principled Hair BSDF, Huang model (`kernel/closure/bsdf_principled_hair_huang.h`: Huang, Hullin and
Hanika 2022, "A Microfacet-based Hair Scattering Model", as Cycles implements it): GGX microfacets on a tilted
elliptical fibre, R by Simpson's rule across the fibre, TT and TRT by Simpson's rule with one random half vector
per node (Cycles' combined Monte Carlo-Simpson quadrature), TRRT+ as Chiang's residual lobe.

The lobe's local frame (the closure table's: x its tangent, z its normal) is Cycles' Huang frame: z = bsdf->N (for
a circular fibre, or any hit off a curve, normalize(dPdu x viewer); for an elliptical one on a curve, the major
axis), x = Y = the unit tangent, y = Z = N x Y. Cycles' local coordinates (N, Y, Z) are (z, x, y) here; the code
below works in Cycles' and converts at the edges. `wo` points to the viewer (Cycles' sd->wi), `wi` to the light.

Per closure ((N,) arrays, colours (3, N)): roughness (the GGX alpha, clamped to [0.001, 1]), tilt (-Offset: Cycles'
setup negates it), eta, b (the aspect ratio minor / major; 1 is circular), sigma, lobes (3, N) the R, TT and TRT
scales (at least 0), h (the offset across the fibre, -1..1) and coverage (half a pixel's width over the fibre's
radius on camera rays at curves, Cycles' pixel_coverage; 1 elsewhere). Where coverage is below the fibre's
projected radius the near field applies: eval integrates only over the part of the fibre the pixel covers, and
sample starts at h; else (always on meshes) the far field: eval integrates over the whole visible width and
sample draws h uniformly.

Cycles' own contract, kept: eval and sample report pdf 1 (its "TODO: better estimation of the pdf"; used only for
MIS), sample returns the lobe's value over that pdf (its weight), and eval is itself a random estimate: its
quadrature draws half vectors from numbers hashed from the two directions (Cycles uses the path's LCG), so two
evaluations of one pair agree. Every sample is a glossy reflection for the path (Cycles' LABEL_REFLECT), whichever
side it leaves on. Cycles' fast_sincosf and fast_sinf are exact here. The fibre's geometry and the microfacet terms are
hair_fibre.py's.
"""
from __future__ import annotations

import numpy as np

from ..rng import keyed_uniforms, pcg2d
from ..vec import F32, INV_2PI, ONE, PI, TWO_PI, ZERO, normalize_xyz
from . import hair_fibre as fb
from .fresnel import dielectric
from .hair_chiang import longitudinal

TWO_OVER_PI = F32(2.0 / np.pi)
# Cycles' Simpson node spacing across the fibre, over the roughness: R's, then TT and TRT's.
NODE_SPACING = (F32(0.7), F32(0.8))


# ---------------------------------------------------------------- per-closure quantities
class HuangParams:
    """One closure per entry, as the lobe reads it (module docstring); wo_local: the viewer in Cycles' local
    coordinates, from which the projected radius (Cycles' extra->radius) follows."""

    def __init__(self, roughness, tilt, eta, b, sigma, lobes, h, coverage, wo_local):
        self.roughness = np.asarray(roughness, F32)
        self.tilt = np.asarray(tilt, F32)
        self.eta = np.asarray(eta, F32)
        self.b = np.asarray(b, F32)
        self.sigma = np.asarray(sigma, F32)
        self.lobes = np.asarray(lobes, F32)
        self.h = np.asarray(h, F32)
        self.coverage = np.asarray(coverage, F32)
        self.wi = wo_local
        self.circular = self.b == ONE
        self.e2 = (ONE - self.b * self.b).astype(F32)
        self.radius = huang_radius(self.b, wo_local)

    @property
    def nearfield(self):
        return self.radius > self.coverage

    def take(self, idx):
        p = object.__new__(HuangParams)
        for k, val in vars(self).items():
            setattr(p, k, tuple(c[idx] for c in val) if isinstance(val, tuple) else val[..., idx])
        return p


def huang_radius(b, wo_local):
    """(N,) the fibre's projected radius toward the viewer (extra->radius): where |h| reaches it Cycles shades the
    hit as transparent."""
    e2 = ONE - np.asarray(b, F32) ** 2
    ix2, iz2 = np.square(wo_local[0]), np.square(wo_local[2])
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.sqrt(np.maximum(ONE - e2 * ix2 / (ix2 + iz2), ZERO))
    return np.where(e2 == 0, ONE, np.nan_to_num(r, nan=1.0)).astype(F32)


def to_cycles(w):
    """Directions from the closure frame (x tangent, y, z normal) to Cycles' local (N, Y, Z) coordinates."""
    return (w[2], w[0], w[1])


def from_cycles(c):
    return (c[1], c[2], c[0])


# ---------------------------------------------------------------- eval
def _ragged(count):
    """(lane, node) of every node 0..count[lane] of every lane, concatenated."""
    lane = np.repeat(np.arange(len(count)), count + 1)
    start = np.repeat(np.cumsum(count + 1) - (count + 1), count + 1)
    return lane, (np.arange(len(lane)) - start).astype(np.int64)


def _simpson(h_min, h_len, resolution):
    """Cycles' node layout: an even number of intervals of at most `resolution`, and their width."""
    with np.errstate(divide="ignore", invalid="ignore"):
        intervals = (F32(2.0) * np.ceil(h_len / resolution * F32(0.5))).astype(np.int64)
    intervals = np.maximum(intervals, 2)
    res = (h_len / intervals).astype(F32)
    lane, node = _ragged(intervals)
    weight = np.where((node == 0) | (node == intervals[lane]), F32(0.5), (node % 2 + 1).astype(F32))
    return lane, node, (h_min[lane] + node * res[lane]).astype(F32), weight.astype(F32), res


def _seeds(wi, wo):
    """Per-evaluation keys for the quadrature's numbers: the two directions' bits hashed."""
    bits = [np.ascontiguousarray(c, F32).view(np.uint32) for c in (*wi, *wo)]
    x, y = pcg2d(bits[0] ^ (bits[1] * np.uint32(0x9E3779B9)), bits[2] ^ (bits[3] * np.uint32(0x85EBCA6B)))
    return pcg2d(x ^ bits[4], y ^ bits[5])


def _eval_r(p, wi, wo, h_min, h_len):
    """bsdf_hair_huang_eval_r (N,): Simpson's rule over h of D G across the fibre."""
    n = len(h_min)
    out = np.zeros(n, F32)
    live = np.flatnonzero(p.lobes[0] > 0)
    if not len(live):
        return out
    q = p.take(live)
    wi_l, wo_l = tuple(c[live] for c in wi), tuple(c[live] for c in wo)
    wh = normalize_xyz(tuple(a + b for a, b in zip(wi_l, wo_l)))
    lane, node, h, weight, res = _simpson(h_min[live], h_len[live], q.roughness * NODE_SPACING[0])
    b, circ = q.b[lane], q.circular[lane]
    wi_n = tuple(c[lane] for c in wi_l)
    wo_n = tuple(c[lane] for c in wo_l)
    wh_n = tuple(c[lane] for c in wh)
    sin_phi_i, cos_phi_i = fb.sincos_phi(wi_n)
    gamma = fb.h_to_gamma(h, b, wi_n, circ)
    wm = fb.sphg_dir(q.tilt[lane], gamma, b, circ)
    macro = (wm[0], np.zeros_like(wm[0]), wm[2])
    ok = fb.visible2(wi_n, wo_n, macro, wh_n)
    alpha2 = np.square(q.roughness[lane])
    cos_mi = fb.dot(wm, wi_n)
    term = weight * fb.d_gamma_d_h(sin_phi_i, cos_phi_i, gamma, b, circ) * fb.ggx_d(alpha2, fb.dot(wm, wh_n)) * \
        fb.ggx_g(alpha2, cos_mi, fb.dot(wm, wo_n)) * fb.arc_length(q.e2[lane], gamma) * \
        fb.energy_scale(cos_mi, np.sqrt(q.roughness[lane]), q.eta[lane])
    integral = np.bincount(lane, np.where(ok, term, ZERO), minlength=len(live)).astype(F32)
    f = dielectric(fb.dot(wi_l, wh), q.eta)[0]
    out[live] = q.lobes[0] * F32(0.25) * f * integral * (F32(2.0 / 3.0) * res)
    return out


def _eval_residual(p, wi, wo, h_min, h_len, seeds):
    """bsdf_hair_huang_eval_residual: (TT + TRT (3, N) by Monte Carlo-Simpson quadrature, TRRT+ (3, N) by Simpson's
    rule times Chiang's residual lobe)."""
    n = len(h_min)
    out, beyond = np.zeros((3, n), F32), np.zeros((3, n), F32)
    live = np.flatnonzero((p.lobes[1] > 0) | (p.lobes[2] > 0))
    if not len(live):
        return out, beyond
    q = p.take(live)
    wi_l, wo_l = tuple(c[live] for c in wi), tuple(c[live] for c in wo)
    lane, node, h, weight_s, res = _simpson(h_min[live], h_len[live], q.roughness * NODE_SPACING[1])
    m = len(lane)
    b, circ, tilt, eta = q.b[lane], q.circular[lane], q.tilt[lane], q.eta[lane]
    rough = q.roughness[lane]
    alpha2, rough_sqrt = np.square(rough), np.sqrt(rough)
    inv_eta = (ONE / eta).astype(F32)
    mu_a = q.sigma[:, lane]
    tt_on, trt_on = q.lobes[1][lane] > 0, q.lobes[2][lane] > 0
    e2 = q.e2[lane]
    wi_n = tuple(c[lane] for c in wi_l)
    wo_n = tuple(c[lane] for c in wo_l)
    keys = (seeds[0][live][lane] ^ node.astype(np.uint32), seeds[1][live][lane])
    u1, u2 = keyed_uniforms(keys, 0, salt=0x4855)
    u3, u4 = keyed_uniforms(keys, 1, salt=0x4855)
    sin_phi_i, cos_phi_i = fb.sincos_phi(wi_n)

    gamma_mi = fb.h_to_gamma(h, b, wi_n, circ)
    wmi = fb.sphg_dir(tilt, gamma_mi, b, circ)
    wmi_ = fb.sphg_dir(ZERO, gamma_mi, b, circ)
    wh1 = fb.sample_wh(rough, wi_n, wmi, u1, u2)
    cos_hi1 = fb.dot(wi_n, wh1)
    cos_mi1 = fb.dot(wi_n, wmi)
    r1, cos_t1 = fb.fresnel(cos_hi1, eta)
    t1 = ONE - r1
    scale1 = fb.energy_scale(cos_mi1, rough_sqrt, eta)
    wt = fb.refract_angle(wi_n, wh1, cos_t1, inv_eta)
    phi_t = fb.dir_phi(wt)
    gamma_mt = (F32(2.0) * fb.to_phi(phi_t, b, circ) - gamma_mi).astype(F32)
    wmt = fb.sphg_dir(-tilt, gamma_mt, b, circ)
    wmt_ = fb.sphg_dir(ZERO, gamma_mt, b, circ)
    mwt = fb.neg(wt)
    cos_mo1 = fb.dot(mwt, wmi)
    cos_mi2 = fb.dot(mwt, wmt)
    g1o = fb.ggx_go(alpha2, cos_mi1, cos_mo1)
    ok = (cos_hi1 > 0) & fb.visible2(wi_n, mwt, wmi, wh1) & fb.visible2(wi_n, mwt, wmi_, wh1)
    weight = weight_s * fb.d_gamma_d_h(sin_phi_i, cos_phi_i, gamma_mi, b, circ)
    cos_wt = fb.cos_theta(wt)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        path_t = np.where(circ, F32(2.0) * np.cos(gamma_mi - phi_t),
                          -fb.point_distance(gamma_mi, gamma_mt + PI, b)) / cos_wt
        a_t = np.exp(mu_a * path_t).astype(F32)
    scale2 = fb.energy_scale(cos_mi2, rough_sqrt, inv_eta)

    s_tt = np.zeros((3, m), F32)
    s_trt = np.zeros((3, m), F32)
    s_trrt = np.zeros((3, m), F32)
    # TT: the half vector that refracts wt into wo.
    tt = ok & tt_on & (fb.dot(wo_n, wt) >= inv_eta - F32(1e-5))
    if tt.any():
        wh2 = tuple(a + inv_eta * c for a, c in zip(mwt, wo_n))
        with np.errstate(divide="ignore"):
            rcp2 = (ONE / np.sqrt(fb.dot(wh2, wh2))).astype(F32)
        wh2 = fb.scale(wh2, rcp2)
        cos_mh2 = fb.dot(wmt, wh2)
        tt &= cos_mh2 >= 0
        cos_hi2, cos_ho2, cos_mo2 = fb.dot(mwt, wh2), fb.dot(fb.neg(wo_n), wh2), fb.dot(fb.neg(wo_n), wmt)
        t2 = (ONE - dielectric(cos_hi2, inv_eta)[0]) * scale2
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            result = weight * t1 * scale1 * t2 * fb.ggx_d(alpha2, cos_mh2) * g1o * fb.ggx_g(alpha2, cos_mi2, cos_mo2) * \
                a_t / cos_mo1 * cos_mi1 * cos_hi2 * cos_ho2 * rcp2 * rcp2
        good = tt & np.all(np.isfinite(result), axis=0)
        s_tt = np.where(good, q.lobes[1][lane] * result * fb.arc_length(e2, gamma_mt), ZERO).astype(F32)
    # TRT: a sampled reflection inside, then the half vector that refracts it into wo.
    trt = ok & trt_on
    if trt.any():
        wh2 = fb.sample_wh(rough, mwt, wmt, u3, u4)
        cos_hi2 = fb.dot(mwt, wh2)
        trt &= cos_hi2 > 0
        r2 = dielectric(cos_hi2, inv_eta)[0]
        wtr = fb.neg(fb.reflect(wt, wh2))
        residual = fb.trrt(t1, r2, a_t)
        tir = trt & (fb.dot(fb.neg(wtr), wo_n) < inv_eta - F32(1e-5))
        seen = trt & ~tir & fb.visible2(mwt, fb.neg(wtr), wmt, wh2) & fb.visible2(mwt, fb.neg(wtr), wmt_, wh2)
        phi_tr = fb.dir_phi(wtr)
        gamma_mtr = (gamma_mi - F32(2.0) * (fb.to_phi(phi_t, b, circ) - fb.to_phi(phi_tr, b, circ)) + PI).astype(F32)
        wmtr = fb.sphg_dir(-tilt, gamma_mtr, b, circ)
        wmtr_ = fb.sphg_dir(ZERO, gamma_mtr, b, circ)
        wh3 = tuple(a + inv_eta * c for a, c in zip(wtr, wo_n))
        with np.errstate(divide="ignore"):
            rcp3 = (ONE / np.sqrt(fb.dot(wh3, wh3))).astype(F32)
        wh3 = fb.scale(wh3, rcp3)
        cos_mh3 = fb.dot(wmtr, wh3)
        mwo = fb.neg(wo_n)
        out_ok = (cos_mh3 >= 0) & fb.visible2(wtr, mwo, wmtr, wh3) & fb.visible2(wtr, mwo, wmtr_, wh3)
        cos_hi3, cos_ho3, cos_mi3 = fb.dot(wh3, wtr), fb.dot(wh3, mwo), fb.dot(wmtr, wtr)
        t3 = (ONE - dielectric(cos_hi3, inv_eta)[0]) * fb.energy_scale(cos_mi3, rough_sqrt, inv_eta)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            path_tr = -np.where(circ, F32(2.0) * np.abs(np.cos(phi_tr - gamma_mt)),
                                fb.point_distance(gamma_mtr, gamma_mt, b)) / fb.cos_theta(wtr)
            a_tr = np.exp(mu_a * path_tr).astype(F32)
            cos_mo2 = fb.dot(wmt, fb.neg(wtr))
            result = weight * t1 * scale1 * r2 * scale2 * t3 * fb.ggx_d(alpha2, cos_mh3) * g1o * \
                fb.ggx_go(alpha2, cos_mi2, cos_mo2) * fb.ggx_g(alpha2, cos_mi3, fb.dot(wmtr, mwo)) * a_t * a_tr / \
                (cos_mo1 * cos_mo2) * cos_mi1 * cos_mi2 * cos_hi3 * cos_ho3 * rcp3 * rcp3
        good = seen & out_ok & np.all(np.isfinite(result), axis=0)
        s_trt = np.where(good, q.lobes[2][lane] * result * fb.arc_length(e2, gamma_mtr), ZERO).astype(F32)
        counted = tir | seen
        s_trrt = np.where(counted & np.all(np.isfinite(residual), axis=0), weight * residual, ZERO).astype(F32)

    def per_lane(a):
        return np.stack([np.bincount(lane, a[k], minlength=len(live)) for k in range(3)]).astype(F32)
    mm = longitudinal(wi_l[1], fb.cos_theta(wi_l), wo_l[1], fb.cos_theta(wo_l), F32(4.0) * q.roughness)
    coefficient = F32(2.0 / 3.0) * res
    out[:, live] = (per_lane(s_tt) + per_lane(s_trt)) * np.square(ONE / q.eta) * coefficient
    beyond[:, live] = per_lane(s_trrt) * mm * INV_2PI * TWO_OVER_PI * coefficient
    return out, beyond


def huang_eval(p: HuangParams, wo, wi):
    """(f |cos| (3, N), pdf (N,) = 1): bsdf_hair_huang_eval toward wi (closure frame; p.wi is wo in Cycles'
    coordinates)."""
    parts = huang_eval_parts(p, wo, wi)
    return (parts[0] + parts[1] + parts[2]).astype(F32), np.ones(len(p.h), F32)


def huang_eval_parts(p: HuangParams, wo, wi):
    """huang_eval's value in its three parts, (R, TT + TRT, TRRT+), each (3, N)."""
    n = len(p.h)
    local_i, local_o = p.wi, to_cycles(wi)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tan_tilt = np.tan(p.tilt).astype(F32)
        tan_o = local_o[1] / fb.cos_theta(local_o)
        tan_i = local_i[1] / fb.cos_theta(local_i)
        ok = ~(tan_tilt * tan_o < -ONE)
        arg = np.maximum(-tan_tilt * tan_i, ZERO)
        ok &= arg <= ONE
        half_span = np.arccos(np.minimum(arg, ONE)).astype(F32)
    phi_i = np.where(p.circular, ZERO, fb.dir_phi(local_i)).astype(F32)
    lo = fb.phi_to_h(phi_i + half_span, p.b, local_i, p.circular)
    hi = fb.phi_to_h(phi_i - half_span, p.b, local_i, p.circular)
    r = p.radius
    dh = np.full(n, F32(2.0))
    near = p.nearfield
    if near.any():
        n_lo = np.maximum(-r, p.h - p.coverage)
        n_hi = np.minimum(r, p.h + p.coverage)
        dh = np.where(near, (n_hi - n_lo) / r, dh).astype(F32)
        lo, hi = np.where(near, np.maximum(lo, n_lo), lo), np.where(near, np.minimum(hi, n_hi), hi)
    lo, hi = np.maximum(lo / r, F32(-0.999)), np.minimum(hi / r, F32(0.999))
    ok &= lo < hi
    parts = [np.zeros((3, n), F32) for _ in range(3)]
    live = np.flatnonzero(ok)
    if len(live):
        q = p.take(live)
        wi_l, wo_l = tuple(c[live] for c in local_i), tuple(c[live] for c in local_o)
        length = (hi[live] - lo[live]).astype(F32)
        with np.errstate(under="ignore"):   # dark hair's attenuation and far lobes' tails
            values = (np.broadcast_to(_eval_r(q, wi_l, wo_l, lo[live], length), (3, len(live))),
                      *_eval_residual(q, wi_l, wo_l, lo[live], length, _seeds(wi_l, wo_l)))
        with np.errstate(divide="ignore", invalid="ignore", under="ignore"):
            area = fb.cos_theta(wi_l) * dh[live]
            for part, value in zip(parts, values):
                value = value / area
                part[:, live] = np.where(np.isfinite(value), value, ZERO)
    return tuple(parts)


# ---------------------------------------------------------------- sample
def _extra_numbers(u1, u2, uc):
    """Cycles draws eight more numbers from the path's LCG; these are hashed from the three given."""
    bits = [np.ascontiguousarray(u, F32).view(np.uint32) for u in (u1, u2, uc)]
    keys = pcg2d(bits[0] ^ (bits[2] * np.uint32(0x9E3779B9)), bits[1] + np.uint32(0x68E31DA4))
    out = []
    for k in range(4):
        out += list(keyed_uniforms(keys, k, salt=0x4856))
    return out


def huang_sample(p: HuangParams, u1, u2, uc):
    """(wi (closure frame), weight (3, N), pdf (N,) 1 or 0, transmit (N,) False): bsdf_hair_huang_sample. u1 picks
    the lobe, u2 the offset h across the fibre (far field), uc with eight hashed numbers the three half vectors
    and the residual lobe's direction."""
    return huang_sample_lobes(p, u1, u2, uc)[:4]


def huang_sample_lobes(p: HuangParams, u1, u2, uc):
    """huang_sample, and the lobe each sample took (N,): 0 R, 1 TT, 2 TRT, 3 TRRT+ (-1: none)."""
    with np.errstate(under="ignore"):   # dark hair's attenuation and far lobes' tails
        return _sample(p, u1, u2, uc)


def _sample(p: HuangParams, u1, u2, uc):
    n = len(p.h)
    e1, e2_, e3, e4, e5, e6, e7, e8 = _extra_numbers(u1, u2, uc)
    wi = p.wi
    b, circ = p.b, p.circular
    rough = p.roughness
    alpha2, rough_sqrt = np.square(rough), np.sqrt(rough)
    h_div_r = np.where(p.nearfield, p.h / p.radius, np.asarray(u2, F32) * F32(2.0) - ONE).astype(F32)
    gamma_mi = fb.h_to_gamma(h_div_r, b, wi, circ)
    wmi_ = fb.sphg_dir(ZERO, gamma_mi, b, circ)
    st, ct = np.sin(p.tilt).astype(F32), np.cos(p.tilt).astype(F32)
    wmi = (wmi_[0] * ct, np.broadcast_to(st, ct.shape).astype(F32), wmi_[2] * ct)
    cos_mi1 = fb.dot(wmi, wi)
    ok = (cos_mi1 >= 0) & (fb.dot(wmi_, wi) >= 0)
    wh1 = fb.sample_wh(rough, wi, wmi, np.asarray(uc, F32), e1)
    wr = fb.neg(fb.reflect(wi, wh1))
    ok &= fb.visible(wi, wmi_, wh1)
    r1, cos_t1 = fb.fresnel(fb.dot(wi, wh1), p.eta)
    scale1 = fb.energy_scale(cos_mi1, rough_sqrt, p.eta)
    r_energy = p.lobes[0] * r1 * scale1 * fb.visible(wr, wmi_, wh1) * fb.ggx_go(alpha2, cos_mi1, fb.dot(wmi, wr))

    inv_eta = (ONE / p.eta).astype(F32)
    wt = fb.refract_angle(wi, wh1, cos_t1, inv_eta)
    mwt = fb.neg(wt)
    phi_t = fb.dir_phi(wt)
    gamma_mt = (F32(2.0) * fb.to_phi(phi_t, b, circ) - gamma_mi).astype(F32)
    wmt = fb.sphg_dir(-p.tilt, gamma_mt, b, circ)
    wmt_ = fb.sphg_dir(ZERO, gamma_mt, b, circ)
    wh2 = fb.sample_wh(rough, mwt, wmt, e2_, e3)
    wtr = fb.neg(fb.reflect(wt, wh2))
    cos_mi2 = fb.dot(mwt, wmt)
    inside = ok & (cos_mi2 > 0) & fb.visible(mwt, wmi_, wh1) & fb.visible(mwt, wmt_, wh2)
    mu_a = p.sigma
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        path_t = np.where(circ, F32(2.0) * np.cos(phi_t - gamma_mi),
                          -fb.point_distance(gamma_mi, gamma_mt + PI, b)) / fb.cos_theta(wt)
        a_t = np.exp(mu_a * path_t).astype(F32)
    r2, cos_t2 = fb.fresnel(fb.dot(mwt, wh2), inv_eta)
    t1 = (ONE - r1) * scale1 * fb.ggx_go(alpha2, cos_mi1, fb.dot(wmi, mwt))
    t2 = ONE - r2
    scale2 = fb.energy_scale(cos_mi2, rough_sqrt, inv_eta)
    wtt = fb.refract_angle(mwt, wh2, cos_t2, p.eta)
    tt_ok = inside & (fb.dot(wmt, fb.neg(wtt)) > 0) & (t2 > 0) & fb.visible(fb.neg(wtt), wmt_, wh2)
    tt = np.where(tt_ok, p.lobes[1] * t1 * a_t * t2 * scale2 * fb.ggx_go(alpha2, cos_mi2, fb.dot(wmt, fb.neg(wtt))),
                  ZERO).astype(F32)

    phi_tr = fb.dir_phi(wtr)
    gamma_mtr = (gamma_mi - F32(2.0) * (fb.to_phi(phi_t, b, circ) - fb.to_phi(phi_tr, b, circ)) + PI).astype(F32)
    wmtr = fb.sphg_dir(-p.tilt, gamma_mtr, b, circ)
    wh3 = fb.sample_wh(rough, wtr, wmtr, e4, e5)
    r3, cos_t3 = fb.fresnel(fb.dot(wtr, wh3), inv_eta)
    wtrt = fb.refract_angle(wtr, wh3, cos_t3, p.eta)
    cos_mi3 = fb.dot(wmtr, wtr)
    third = inside & (cos_mi3 > 0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        path_tr = -np.where(circ, F32(2.0) * np.abs(np.cos(phi_tr - gamma_mt)),
                            fb.point_distance(gamma_mt, gamma_mtr, b)) / fb.cos_theta(wtr)
        a_tr = np.exp(mu_a * path_tr).astype(F32)
    tr = t1 * r2 * scale2 * a_t * a_tr * fb.energy_scale(cos_mi3, rough_sqrt, inv_eta) * \
        fb.ggx_go(alpha2, cos_mi2, fb.dot(wmt, fb.neg(wtr)))
    t3 = ONE - r3
    macro3 = (wmtr[0], np.zeros_like(wmtr[0]), wmtr[2])
    trt_ok = third & (t3 > 0) & fb.visible2(wtr, fb.neg(wtrt), macro3, wh3)
    trt = np.where(trt_ok, p.lobes[2] * tr * t3 * fb.ggx_go(alpha2, cos_mi3, fb.dot(wmtr, fb.neg(wtrt))), ZERO).astype(F32)
    # TRRT+: Chiang's residual lobe, its latitude about the viewer's drawn with variance 4 roughness.
    rand_theta = np.maximum(e6, F32(1e-5))
    with np.errstate(under="ignore"):
        fac = ONE + F32(4.0) * rough * np.log(rand_theta + (ONE - rand_theta) * np.exp(-F32(0.5) / rough))
    sin_ti = wi[1]
    cos_ti = fb.cos_theta(wi)
    sin_o = np.clip(-fac * sin_ti + np.sqrt(np.maximum(ONE - fac * fac, ZERO)) * np.cos(TWO_PI * e7) * cos_ti,
                    -ONE, ONE).astype(F32)
    cos_o = np.sqrt(np.maximum(ONE - sin_o * sin_o, ZERO)).astype(F32)
    phi_o = TWO_PI * e8
    wtrrt = ((np.sin(phi_o) * cos_o).astype(F32), sin_o, (np.cos(phi_o) * cos_o).astype(F32))
    a_avg = np.sqrt(a_t * a_tr)
    t_avg = np.maximum(F32(0.5) * (t2 + t3), F32(1e-5))
    with np.errstate(divide="ignore", invalid="ignore"):
        a_res = a_avg * t_avg / (ONE - a_avg * (ONE - t_avg))
    trrt = np.where(third, tr * r3 * a_res * fb.ggx_go(alpha2, cos_mi3, fb.dot(wmtr, fb.neg(fb.reflect(wtr, wh3)))),
                    ZERO).astype(F32)

    r_energy = np.where(ok, r_energy, ZERO).astype(F32)
    tt, trt, trrt = (np.where(ok & np.all(np.isfinite(a), axis=0), a, ZERO).astype(F32) for a in (tt, trt, trrt))
    e_tt, e_trt, e_trrt = tt.mean(axis=0), trt.mean(axis=0), trrt.mean(axis=0)
    total = (r_energy + e_tt + e_trt + e_trrt).astype(F32)
    good = ok & (total > 0) & np.isfinite(total)
    pick = np.asarray(u1, F32) * total
    lobe = np.where(pick < r_energy, 0, np.where(pick < r_energy + e_tt, 1,
                                                 np.where(pick < r_energy + e_tt + e_trt, 2, 3)))

    def ratio(a, e):
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(e > 0, a / np.where(e > 0, e, ONE), ZERO) * total
    weight = np.choose(lobe, (np.broadcast_to(total, (3, n)), ratio(tt, e_tt), ratio(trt, e_trt),
                              ratio(trrt, e_trrt))).astype(F32)
    local = tuple(np.choose(lobe, (wr[k], wtt[k], wtrt[k], wtrrt[k])).astype(F32) for k in range(3))
    weight = np.where(good & np.all(np.isfinite(weight), axis=0), weight, ZERO).astype(F32)
    pdf = np.where(good, ONE, ZERO).astype(F32)
    return from_cycles(local), weight, pdf, np.zeros(n, bool), np.where(good, lobe, -1)


def huang_albedo(p: HuangParams):
    """(3, N) bsdf_hair_huang_albedo: the series of a specular circular fibre hit at h, for the passes."""
    wmi = (p.h, np.zeros_like(p.h), np.sqrt(np.maximum(ONE - p.h * p.h, ZERO)).astype(F32))
    f, cos_t = fb.fresnel(fb.dot(wmi, p.wi), p.eta)
    wt = fb.refract_angle(p.wi, wmi, cos_t, ONE / p.eta)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a = np.exp(F32(2.0) * p.sigma * cos_t / (ONE - wt[1] * wt[1]))
        albedo = (a - F32(2.0) * f * a + f) / (ONE - f * a)
    return np.where(np.isfinite(albedo), albedo, ZERO).astype(F32)
