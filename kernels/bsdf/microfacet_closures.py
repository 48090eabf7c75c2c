"""Microfacet closures in the mixture: how Cycles sets up its GGX and Beckmann closures
(`bsdf_microfacet_setup_fresnel_*`, `microfacet_ggx_preserve_energy` in `kernel/closure/bsdf_microfacet.h`)
and its Ashikhmin-Shirley closure, and how the closure table evaluates and samples them.

A microfacet closure carries alpha_x, alpha_y, eta (far side over the viewer's side), its distribution
(`dist`: microfacet.GGX or BECKMANN), its Fresnel mode and up to three colour parameters:

    F_ONE        F = 1 (Glossy: its colour is in the weight)
    F_DIELECTRIC exact dielectric Fresnel at eta (the Principled coat)
    F_F82        c0 = F0, c1 = b of F82-tint (Principled metal, Metallic BSDF)
    F_CONDUCTOR  c0 = n, c1 = k (Metallic BSDF, physical conductor)
    F_REMAP      c0 = F0, c1 = reflection tint, c2 = transmission tint, F90 = 1 (Principled specular and
                 transmission, Glass): the exact curve remapped onto [F0, 1]
    F_F82_FILM, F_CONDUCTOR_FILM, F_REMAP_FILM  the same under a thin film (thin_film.py) of `film_t` nm
                 and IOR `film_ior`: Cycles' models when Thin Film Thickness > 0.1 nm

Setup, as Cycles: the sample weight is mean(weight) x mean(estimated albedo); with multiscatter GGX, eval
is scaled by 1/E (`eval_scale`) and the weight (and sample weight) by E + Fms (1 - E). Under a thin film
Cycles estimates the albedo by the film's Fresnel at mu (its tables know no film), while the compensation's
Fss stays the plain model's (`bsdf_microfacet_estimate_albedo`, `bsdf_microfacet_setup_fresnel_*`). Beckmann is never
compensated (Cycles has multiscatter for GGX only); its albedo estimate is the GGX one, as in Cycles.
The Ashikhmin-Shirley closure (Glossy only) is its own lobe, closures.ASHIKHMIN_SHIRLEY: F = 1, alpha
clamped to [1e-4, 1], sample weight the mean of its weight.
"""
from __future__ import annotations

import numpy as np

from . import ashikhmin_shirley as ash
from . import frames, lobes
from . import fresnel as fr
from . import microfacet as mf
from . import thin_film as tf
from ..sampling import channel_mean
from ..vec import F32, ONE, ZERO

F_ONE, F_DIELECTRIC, F_F82, F_CONDUCTOR, F_REMAP, F_F82_FILM, F_CONDUCTOR_FILM, F_REMAP_FILM = range(8)
GGX, BECKMANN = mf.GGX, mf.BECKMANN

principled_anisotropy = mf.principled_anisotropy
glossy_anisotropy = mf.glossy_anisotropy
ior_from_f0 = fr.ior_from_f0


# ---------------------------------------------------------------- setup (called by the closure nodes of kernels/shading)
def add_glossy(b, ctx, color, w, ax, ay, multiscatter: bool, sub=None, distribution=mf.GGX):
    """Glossy BSDF: GGX or Beckmann reflection with F = 1, weight colour x mix weight; its colour is the
    Fss of the compensation (Cycles' bsdf_microfacet_setup_fresnel_constant, multiscatter GGX only)."""
    hits, normal, mu = _where(ctx, sub)
    _add_reflection(b, hits, normal, color * w, np.ones_like(color), ax, ay, mu, color,
                    multiscatter and distribution == mf.GGX, F_ONE, dist=distribution)


def add_ashikhmin_shirley(b, ctx, color, w, ax, ay, sub=None):
    """Glossy BSDF, Ashikhmin-Shirley: its own lobe, weight colour x mix weight, alpha clamped to [1e-4, 1]
    (Cycles' bsdf_ashikhmin_shirley_setup)."""
    hits, normal, _ = _where(ctx, sub)
    lo, hi = F32(1e-4), ONE
    b.add(lobes.ASHIKHMIN_SHIRLEY, hits, color * w, normal=normal, ax=np.clip(ax, lo, hi), ay=np.clip(ay, lo, hi))


def add_f82(b, ctx, weight, ax, ay, f0, tint, multiscatter: bool, sub=None, distribution=mf.GGX, film=None):
    """F82-tint conductor (Principled metal with F0 = base colour and tint = specular tint; Metallic BSDF,
    GGX or Beckmann). film: (thickness nm, film IOR) (n,) each, or None (every add_* takes it: _film)."""
    hits, normal, mu = _where(ctx, sub)
    multiscatter = multiscatter and distribution == mf.GGX
    b_term = np.where(np.all(tint == ONE, axis=0), ZERO, fr.f82_tint_b(f0, tint))
    albedo = mf.albedo_f82(ax, ay, mu, f0, b_term)
    fss = fr.f82_fss(f0, b_term) if multiscatter else None
    mode, albedo, film_cols = _film(film, F_F82, F_F82_FILM, albedo,
                                    lambda on, t, i: tf.iridescence(mu[on], t, i, *_f82_film(f0, b_term, on)))
    _add_reflection(b, hits, normal, weight, albedo, ax, ay, mu, fss, multiscatter, mode, c0=f0, c1=b_term,
                    dist=distribution, **film_cols)


def add_conductor(b, ctx, weight, ax, ay, n, k, multiscatter: bool, sub=None, distribution=mf.GGX, film=None):
    """Metallic BSDF, physical conductor: exact Fresnel of complex IOR n + ik (GGX or Beckmann)."""
    hits, normal, mu = _where(ctx, sub)
    multiscatter = multiscatter and distribution == mf.GGX
    albedo = mf.albedo_conductor(mu, n, k)
    fss = fr.conductor_fss(n, k) if multiscatter else None
    mode, albedo, film_cols = _film(film, F_CONDUCTOR, F_CONDUCTOR_FILM, albedo, lambda on, t, i: tf.iridescence(
        mu[on], t, i, n=_columns(n, on, len(mu)), k=_columns(k, on, len(mu))))
    _add_reflection(b, hits, normal, weight, albedo, ax, ay, mu, fss, multiscatter, mode, c0=n, c1=k,
                    dist=distribution, **film_cols)


def add_specular(b, ctx, weight, ax, ay, eta, f0, multiscatter: bool, sub=None, film=None) -> np.ndarray:
    """Principled specular: GGX reflection with the remapped Fresnel. Returns the layering albedo (3, n):
    the closure weight times its estimated reflection albedo."""
    hits, normal, mu = _where(ctx, sub)
    f0 = np.clip(f0, 0.0, 1.0)
    albedo = mf.albedo_remapped(ax, ay, mu, eta, f0)
    fss = fr.generalized_schlick_fss(f0, ONE, eta, F32(-1.0), ONE) if multiscatter else None
    mode, albedo, film_cols = _film(film, F_REMAP, F_REMAP_FILM, albedo, lambda on, t, i: tf.remapped(
        mu[on], _rows(eta, on), _columns(f0, on, len(mu)), t, i))
    weight = _add_reflection(b, hits, normal, weight, albedo, ax, ay, mu, fss, multiscatter, mode, eta=eta,
                             c0=f0, c1=ONE, c2=ZERO, **film_cols)
    return weight * albedo


def _film(film, plain_mode, film_mode, albedo, film_fresnel):
    """A closure's Fresnel mode, albedo estimate and film columns: where the film counts (thicker than
    0.1 nm), the film mode and the film's Fresnel at mu, film_fresnel(rows, thickness, film IOR) (3, r),
    for albedo, as Cycles' estimate does; elsewhere, and without a film, the plain ones."""
    if film is None:
        return plain_mode, albedo, {}
    thickness, film_ior = film
    on = np.flatnonzero(tf.film_on(thickness))
    if not len(on):
        return plain_mode, albedo, {}
    albedo = np.array(np.broadcast_to(albedo, (3, len(thickness))), F32)
    albedo[:, on] = film_fresnel(on, thickness[on], film_ior[on])
    mode = np.where(tf.film_on(thickness), F32(film_mode), F32(plain_mode))
    return mode, albedo, {"film_t": thickness, "film_ior": film_ior}


def _f82_film(f0, b_term, on=None):
    """The conductor arguments (eta, n, k, f82) of thin_film.iridescence for F82-tint rows `on` (None: all)."""
    if on is not None:
        num = np.shape(b_term)[-1]
        f0, b_term = _columns(f0, on, num), _columns(b_term, on, num)
    n, k, g = tf.f82_conductor(f0, b_term)
    return None, n, k, g


def _columns(c, on, num):
    return np.take(fr.color(c, num), on, axis=1)


def _rows(x, on):
    x = np.asarray(x, F32)
    return x if x.ndim == 0 else x[on]


def add_coat(b, ctx, sub, weight, alpha, ior) -> np.ndarray:
    """Principled coat: GGX reflection, exact dielectric Fresnel, energy compensation always on. Returns
    the layering albedo (3, n): the closure's weight, compensated, times its estimated reflection albedo;
    b None gives the albedo alone (the emission under the coat needs it)."""
    hits, normal, mu = _where(ctx, sub)
    albedo = mf.albedo_dielectric(alpha, alpha, mu, ior)
    fss = np.broadcast_to(fr.dielectric_fss(ior), (3, len(hits)))
    if b is None:
        _, factor = mf.multiscatter_reflection(alpha, alpha, mu, fss=fss)
        return np.broadcast_to(weight, (3, len(hits))) * factor * albedo
    return _add_reflection(b, hits, normal, weight, albedo, alpha, alpha, mu, fss, True, F_DIELECTRIC, eta=ior) * albedo


def add_glass(b, ctx, weight, alpha, ior, reflection_tint, transmission_tint, specular_tint, multiscatter: bool,
              sub=None, distribution=mf.GGX, film=None):
    """GGX or Beckmann glass (Glass BSDF, Principled transmission): remapped Fresnel with F0 = F0(IOR) x
    specular tint, reflection and transmission tints; eta = IOR from outside, 1/IOR from inside (back
    faces). A film's IOR is divided by the IOR on back faces: outside-film-glass seen from the glass is
    1-(film/IOR)-(1/IOR) (Cycles' adjust_thin_film_ior_at_backface)."""
    multiscatter = multiscatter and distribution == mf.GGX
    hits, normal, mu = _where(ctx, sub)
    back = ctx.take(ctx.hit.backfacing) if sub is None else ctx.take(ctx.hit.backfacing)[sub]
    eta = np.where(back, ONE / ior, ior).astype(F32)
    n = len(hits)
    f0 = fr.f0_from_ior(ior)[None, :] * (np.ones((3, n), F32) if specular_tint is None else specular_tint)
    f0 = np.clip(f0, 0.0, 1.0)
    weight = np.broadcast_to(weight, (3, n))
    reflect, transmit = mf.albedo_remapped_parts(alpha, alpha, mu, eta, f0, ONE, reflection_tint, transmission_tint)
    mode, film_cols = F_REMAP, {}
    if film is not None and np.any(tf.film_on(film[0])):
        thickness, film_ior = film[0], np.where(back, film[1] * (ONE / ior), film[1]).astype(F32)
        on = np.flatnonzero(tf.film_on(thickness))
        f = tf.remapped(mu[on], eta[on], f0[:, on], thickness[on], film_ior[on])
        reflect, transmit = np.array(reflect), np.array(transmit)
        reflect[:, on] = f * _columns(reflection_tint, on, n)
        transmit[:, on] = (ONE - f) * _columns(transmission_tint, on, n)
        mode = np.where(tf.film_on(thickness), F32(F_REMAP_FILM), F32(F_REMAP))
        film_cols = {"film_t": thickness, "film_ior": film_ior}
    albedo = reflect + transmit
    sw = np.abs(channel_mean(weight)) * channel_mean(albedo)
    eval_scale = ONE
    if multiscatter:
        eval_scale, factor = mf.multiscatter_glass(alpha, alpha, mu, eta, fss=transmission_tint)
        weight = weight * factor
        sw = sw * channel_mean(factor)
    b.add(lobes.GLASS, hits, weight, sample_weight=sw, normal=normal, ax=alpha, ay=alpha, eta=eta,
          albedo=(weight * reflect, weight * transmit),
          eval_scale=eval_scale, fresnel=mode, c0=f0, c1=reflection_tint, c2=transmission_tint,
          **_dist(distribution), **film_cols)


def add_refraction(b, ctx, weight, alpha, ior, sub=None, distribution=mf.GGX):
    """Refraction BSDF: GGX or Beckmann refraction alone, no Fresnel, no compensation."""
    hits, normal, _ = _where(ctx, sub)
    back = ctx.take(ctx.hit.backfacing) if sub is None else ctx.take(ctx.hit.backfacing)[sub]
    alpha = np.clip(alpha, 0.0, 1.0)
    b.add(lobes.REFRACTION, hits, weight, normal=normal, ax=alpha, ay=alpha,
          eta=np.where(back, ONE / ior, ior).astype(F32), **_dist(distribution))


def _add_reflection(b, hits, normal, weight, albedo, ax, ay, mu, fss, multiscatter, mode, **params):
    weight = np.broadcast_to(weight, (3, len(hits)))
    sw = np.abs(channel_mean(weight)) * channel_mean(albedo)
    eval_scale = ONE
    if multiscatter:
        eval_scale, factor = mf.multiscatter_reflection(ax, ay, mu, fss=fss)
        weight = weight * factor
        sw = sw * channel_mean(factor)
    dist = params.pop("dist", mf.GGX)
    b.add(lobes.REFLECTION, hits, weight, sample_weight=sw, normal=normal, ax=ax, ay=ay, eval_scale=eval_scale,
          fresnel=mode, albedo=(weight * albedo, ZERO), **params, **_dist(dist))
    return weight


def _dist(distribution):
    """The `dist` column, left out for GGX (its default) so GGX-only tables stay as they were."""
    return {} if distribution == mf.GGX else {"dist": F32(distribution)}


def _where(ctx, sub):
    """(wave hit indices, normal, mu) of the context's hits, or of its subset sub."""
    if sub is None:
        hits, normal, wo = ctx.idx, ctx.ns, ctx.wo
    else:
        hits = ctx.idx[sub]
        normal = tuple(c[sub] for c in ctx.ns)
        wo = tuple(c[sub] for c in ctx.wo)
    mu = (wo[0] * normal[0] + wo[1] * normal[1] + wo[2] * normal[2]).astype(F32)
    return hits, normal, mu


# ---------------------------------------------------------------- the lobes in the closure table
def _reflection_fresnel(cs, rows):
    mode, eta = np.take(cs.fresnel, rows).astype(np.int8), np.take(cs.eta, rows)
    c0, c1 = np.take(cs.c0, rows, axis=1), np.take(cs.c1, rows, axis=1)

    def fresnel(cos_h):
        out = np.ones((3, len(rows)), F32)
        for m in np.unique(mode):
            s = np.flatnonzero(mode == m)
            if m == F_DIELECTRIC:
                out[:, s] = fr.dielectric(cos_h[s], eta[s])[0][None, :]
            elif m == F_F82:
                out[:, s] = fr.f82(cos_h[s], c0[:, s], c1[:, s])
            elif m == F_CONDUCTOR:
                out[:, s] = fr.conductor(cos_h[s], c0[:, s], c1[:, s])
            elif m == F_REMAP:
                out[:, s] = fr.remapped(cos_h[s], eta[s], c0[:, s], ONE)[0] * c1[:, s]
            elif m == F_REMAP_FILM:
                out[:, s] = tf.remapped(cos_h[s], eta[s], c0[:, s], *film(s)) * c1[:, s]
            elif m == F_F82_FILM:
                out[:, s] = tf.iridescence(cos_h[s], *film(s), *_f82_film(c0[:, s], c1[:, s]))
            elif m == F_CONDUCTOR_FILM:
                out[:, s] = tf.iridescence(cos_h[s], *film(s), n=c0[:, s], k=c1[:, s])
        return out

    def film(s):
        return np.take(cs.film_t, rows[s]), np.take(cs.film_ior, rows[s])
    return fresnel


def _glass_fresnel(cs, rows):
    c0, c1, c2 = (np.take(c, rows, axis=1) for c in (cs.c0, cs.c1, cs.c2))
    plain = fr.remapped_glass(c0, ONE, c1, c2)
    on = np.flatnonzero(np.take(cs.fresnel, rows) == F_REMAP_FILM)
    if not len(on):
        return plain
    thickness, film_ior = np.take(cs.film_t, rows[on]), np.take(cs.film_ior, rows[on])

    def fresnel(cos_h, eta):
        r, t = plain(cos_h, eta)
        f = tf.remapped(cos_h[on], np.broadcast_to(eta, cos_h.shape)[on], c0[:, on], thickness, film_ior)
        r[:, on], t[:, on] = f * c1[:, on], (ONE - f) * c2[:, on]
        return r, t
    return fresnel


def _params(cs, rows, *names):
    """The closures' scalar columns `names` at rows."""
    return tuple(np.take(getattr(cs, name), rows) for name in names)


def _reflection_eval(cs, rows, wo, wi, dist=mf.GGX):
    ax, ay, scale = _params(cs, rows, "ax", "ay", "eval_scale")
    f, pdf = mf.eval_reflection(wo, wi, ax, ay, _reflection_fresnel(cs, rows), dist)
    return f * scale, pdf


def _reflection_sample(cs, rows, wo, u1, u2, uc, dist=mf.GGX):
    ax, ay, scale = _params(cs, rows, "ax", "ay", "eval_scale")
    s = mf.sample_reflection(wo, ax, ay, _reflection_fresnel(cs, rows), u1, u2, dist)
    return s.wi, s.weight * scale, s.pdf, s.transmission


def _glass_eval(cs, rows, wo, wi, dist=mf.GGX):
    ax, ay, eta, scale = _params(cs, rows, "ax", "ay", "eta", "eval_scale")
    f, pdf = mf.eval_glass(wo, wi, ax, ay, eta, _glass_fresnel(cs, rows), dist)
    return f * scale, pdf


def _glass_sample(cs, rows, wo, u1, u2, uc, dist=mf.GGX):
    ax, ay, eta, scale = _params(cs, rows, "ax", "ay", "eta", "eval_scale")
    s = mf.sample_glass(wo, ax, ay, eta, _glass_fresnel(cs, rows), u1, u2, uc, dist)
    return s.wi, s.weight * scale, s.pdf, s.transmission


def _refraction_eval(cs, rows, wo, wi, dist=mf.GGX):
    return mf.eval_refraction(wo, wi, *_params(cs, rows, "ax", "ay", "eta"), dist)


def _refraction_sample(cs, rows, wo, u1, u2, uc, dist=mf.GGX):
    s = mf.sample_refraction(wo, *_params(cs, rows, "ax", "ay", "eta"), u1, u2, dist)
    return s.wi, s.weight, s.pdf, s.transmission


def _by_distribution_eval(fn):
    """Eval of rows that may mix distributions: one call per distribution present (GGX alone: one call,
    exactly as before the column existed)."""
    def run(cs, rows, wo, wi):
        dist = np.take(cs.dist, rows)
        if not np.any(dist != mf.GGX):
            return fn(cs, rows, wo, wi)
        f, pdf = np.zeros((3, len(rows)), F32), np.zeros(len(rows), F32)
        for d in np.unique(dist):
            s = np.flatnonzero(dist == d)
            f[:, s], pdf[s] = fn(cs, rows[s], _take(wo, s), _take(wi, s), int(d))
        return f, pdf
    return run


def _by_distribution_sample(fn):
    """Sample of rows that may mix distributions, as _by_distribution_eval."""
    def run(cs, rows, wo, u1, u2, uc):
        dist = np.take(cs.dist, rows)
        if not np.any(dist != mf.GGX):
            return fn(cs, rows, wo, u1, u2, uc)
        n = len(rows)
        wi = tuple(np.zeros(n, F32) for _ in range(3))
        weight, pdf, transmit = np.zeros((3, n), F32), np.zeros(n, F32), np.zeros(n, bool)
        for d in np.unique(dist):
            s = np.flatnonzero(dist == d)
            w_s, weight[:, s], pdf[s], transmit[s] = fn(cs, rows[s], _take(wo, s), u1[s], u2[s], uc[s], int(d))
            for axis in range(3):
                wi[axis][s] = w_s[axis]
        return wi, weight, pdf, transmit
    return run


def _take(w, s):
    return tuple(np.take(c, s) for c in w)


def ashikhmin_shirley_eval(cs, rows, wo, wi):
    return ash.eval_ashikhmin_shirley(wo, wi, *_params(cs, rows, "ax", "ay"))


def ashikhmin_shirley_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf, _ = ash.sample_ashikhmin_shirley(wo, *_params(cs, rows, "ax", "ay"), u1, u2)
    return wi, weight, pdf, False


# The lobes' functions in the closure table (registry.LOBES), each distribution's own.
reflection_eval = _by_distribution_eval(_reflection_eval)
reflection_sample = _by_distribution_sample(_reflection_sample)
refraction_eval = _by_distribution_eval(_refraction_eval)
refraction_sample = _by_distribution_sample(_refraction_sample)
glass_eval = _by_distribution_eval(_glass_eval)
glass_sample = _by_distribution_sample(_glass_sample)


def singular_glass_other_branch(cs, hits, rows, transmitted):
    """The branch a smooth glass closure did not take. hits (n,): wave hits whose chosen closure rows (n,)
    are singular GLASS rows of the ClosureSet cs, which sampled refraction where transmitted (n,) is True,
    reflection elsewhere (by Cycles' choice, probability P = mean(R) / mean(R + T) for reflection).

    Returns (wi world directions (3 tuple of (n,)), weight (3, n), transmit (n,) bool, p_taken (n,), ok (n,)):
    the other branch's direction, what it brings per unit of radiance arriving along it (the closure's
    weight over its choice probability, times that branch's Fresnel factor R or T: its sample weight times
    its probability), whether it is the refraction, the probability the taken branch had, and where the
    other branch exists (both Fresnel factors non-zero)."""
    wo = tuple(np.take(c, rows) for c in cs.wo)
    eta = np.take(cs.eta, rows)
    # As _sample_dielectric at the singular half vector h = n.
    cos_h = np.where(wo[2] > 0, np.clip(wo[2], ZERO, ONE), ONE)
    r, t = _glass_fresnel(cs, rows)(cos_h, eta)
    t = np.where((fr.refracted_cos_sq(cos_h, eta) <= 0)[None, :], ZERO, t)
    with np.errstate(divide="ignore", invalid="ignore"):
        p_reflect = mf.reflect_probability(r, t)
    other_reflects = transmitted
    zero = np.zeros(len(rows), F32)
    wi, weight, pdf, transmit = glass_sample(cs, rows, wo, zero, zero,
                                             np.where(other_reflects, ZERO, ONE).astype(F32))
    p_other = np.where(other_reflects, p_reflect, ONE - p_reflect)
    chance = np.isfinite(p_other) & (p_other > 0) & (p_other < 1)
    ok = chance & (pdf > 0) & (transmit != transmitted)
    scale = np.take(cs.weight, rows, axis=1) * (cs.total_sw[hits] / np.take(cs.sw, rows)) * np.where(ok, p_other, ZERO)
    world = frames.to_world(tuple(np.take(c, rows, axis=1) for c in cs.frame), wi)
    # The taken branch's probability whether or not the other one could be followed (an invalid direction).
    return world, np.where(ok, weight * scale, ZERO).astype(F32), transmit, \
        np.where(chance, ONE - p_other, ONE).astype(F32), ok
