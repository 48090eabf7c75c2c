"""The Principled BSDF as Cycles builds it (`kernel/svm/closure.h`): a layer stack of alpha, sheen, coat,
emission, metal, transmission, specular and diffuse, each layer dimming the ones below by its estimated
albedo (`closure_layering_weight`). A node builder as bsdf_nodes describes them.
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..bsdf import bssrdf, lobes
from ..bsdf import microfacet_closures as mf
from ..bsdf.sheen import sheen_albedo
from ..vec import F32, ONE, ZERO, normalize_xyz
from .bsdf_nodes import diffuse_lobe, sheen_sample_weight
from ..bsdf.thin_film import film_on
from .node_context import (Built, CUTOFF, caustics_made, film_rows, normal_rows, param_may_differ, soften, thin_film,
                           with_tangent)


def principled_bsdf(c, ctx, w, b):
    """Cycles' Principled BSDF layer stack (module docstring); emission dimmed by the layers above it.
    Layers whose weight input is a constant 0 (param_may_differ) are skipped: every hit's weight would be cut
    off anyway."""
    n = len(ctx.idx)
    get = lambda name: ctx.input(c, name)  # noqa: E731
    weight = np.broadcast_to(w, (3, n)).astype(F32)
    multiscatter = c.option("distribution", "MULTI_GGX") == "MULTI_GGX"
    # 0. Alpha: a transparent closure for what the surface lets through.
    if param_may_differ(c, "Alpha", 1.0):
        alpha = np.clip(get("Alpha"), 0.0, 1.0)
        if b is not None:
            b.add(lobes.TRANSPARENT, ctx.idx, weight * (ONE - alpha))
        weight = weight * alpha
    # Glossy closures dropped by the caustics switch take no light from the layers below either (Cycles
    # skips their setup, layering included); refraction keeps its share (Context.caustics).
    made = caustics_made(ctx)

    def glossy(mask):  # the hits of mask whose glossy closures the caustics switch keeps
        return np.flatnonzero(mask if made is None else mask & (made > 0))
    no_coat = not param_may_differ(c, "Coat Weight", 0.0)
    coat_w = None if no_coat else np.maximum(get("Coat Weight"), ZERO)
    # The coat's normal: its Coat Normal input, else the node's Normal.
    coat = ctx if no_coat else ctx.with_normal(ctx.normal_input(c, "Coat Normal"))
    # 1. Sheen, on the normal partway to the coat's normal, by the coat's weight.
    sheen_w = np.maximum(get("Sheen Weight"), ZERO) if param_may_differ(c, "Sheen Weight", 0.0) else None
    has = () if sheen_w is None else np.flatnonzero(sheen_w > CUTOFF)
    if len(has):
        sheen = ctx
        if coat is not ctx:
            t = np.clip(coat_w, 0.0, 1.0)
            sheen = ctx.with_normal(normalize_xyz(tuple(n + (m - n) * t for n, m in zip(ctx.ns, coat.ns))))
        rough = np.clip(get("Sheen Roughness")[has], 0.0, 1.0)
        sheen_weight = sheen_w[has] * np.maximum(np.take(get("Sheen Tint"), has, axis=1), ZERO) * \
            np.take(weight, has, axis=1)
        albedo = sheen_albedo(sheen.mu()[has], rough)
        if b is not None:
            b.add(lobes.SHEEN, ctx.idx[has], sheen_weight,
                  sample_weight=sheen_sample_weight(sheen_weight, albedo),
                  normal=normal_rows(sheen.normal_arg, has), rough=rough, **soften(sheen))
        sampling.put_columns(weight, has, layering_weight(sheen_weight * albedo, np.take(weight, has, axis=1)))
    # 2. Coat: GGX with exact dielectric Fresnel at the coat IOR, then its tint along the refracted path.
    has = () if no_coat else np.flatnonzero(coat_w > CUTOFF)
    if len(has):
        cw = coat_w[has]
        ior_c = np.maximum(get("Coat IOR")[has], ONE)
        coat = coat.specular()
        layered = glossy(coat_w > CUTOFF)
        if len(layered):
            albedo = mf.add_coat(b, coat, layered, coat_w[layered] * np.take(weight, layered, axis=1),
                                 np.square(np.clip(get("Coat Roughness")[layered], 0.0, 1.0)),
                                 np.maximum(get("Coat IOR")[layered], ONE))
            sampling.put_columns(weight, layered, layering_weight(albedo, np.take(weight, layered, axis=1)))
        tint = np.maximum(np.take(get("Coat Tint"), has, axis=1), ZERO)
        tinted = np.flatnonzero(np.any(tint != ONE, axis=0))
        if len(tinted):
            mu = coat.mu()[has][tinted]
            ior_t = ior_c[tinted]
            cos_t = np.sqrt(np.maximum(ONE - (ONE - mu * mu) / (ior_t * ior_t), ZERO))
            depth = ONE / np.maximum(cos_t, F32(1e-7))
            factor = ONE + (np.power(np.take(tint, tinted, axis=1), depth) - ONE) * cw[tinted]
            sampling.scale_columns(weight, has[tinted], factor)
    # 3. Emission, under sheen and coat.
    emission = None
    if param_may_differ(c, "Emission Strength", 0.0):
        strength = get("Emission Strength")
        emission = np.maximum(get("Emission Color"), ZERO) * strength * weight if np.any(strength != 0) else None
    if b is None:
        return Built(emission=emission)
    base = np.maximum(get("Base Color"), ZERO)
    clamped = np.minimum(base, ONE)
    roughness = np.clip(get("Roughness"), 0.0, 1.0)
    alpha_r = roughness * roughness
    ax, ay = mf.principled_anisotropy(alpha_r, np.clip(get("Anisotropic"), 0.0, 1.0))
    spec = ctx.specular()
    anisotropic = with_tangent(b, ctx, ctx.tangent(c, "Anisotropic Rotation", ctx.ns, bool(np.any(ax != ay))))
    ior = np.maximum(get("IOR"), F32(1e-5))
    specular_tint = np.maximum(get("Specular Tint"), ZERO)
    # Thin film over metal, transmission and specular (Cycles' svm_node_closure_principled).
    film = thin_film(c, ctx, "Thin Film Thickness", "Thin Film IOR")
    # 4. Metal: F82-tint conductor.
    if param_may_differ(c, "Metallic", 0.0):
        metallic = np.clip(get("Metallic"), 0.0, 1.0)
        has = glossy(metallic > CUTOFF)
        if len(has):
            mf.add_f82(anisotropic, spec, metallic[has] * np.take(weight, has, axis=1), ax[has], ay[has],
                       np.take(clamped, has, axis=1),
                       np.minimum(np.take(specular_tint, has, axis=1), ONE), multiscatter, sub=has,
                       film=film_rows(film, has))
        weight = weight * (ONE - metallic)
    # 5. Transmission: GGX glass, tinted by sqrt(base) through refraction.
    if param_may_differ(c, "Transmission Weight", 0.0):
        transmission = np.clip(get("Transmission Weight"), 0.0, 1.0)
        has = np.flatnonzero(transmission > CUTOFF)
        if len(has):
            refracted = caustics_made(ctx, refractive=True)
            mf.add_glass(b, spec, transmission[has] * np.take(weight, has, axis=1), alpha_r[has], ior[has],
                         reflection_tint=np.ones((3, len(has)), F32) * (ONE if made is None else made[has]),
                         transmission_tint=np.sqrt(np.take(clamped, has, axis=1)) *
                         (ONE if refracted is None else refracted[has]),
                         specular_tint=np.take(specular_tint, has, axis=1), multiscatter=multiscatter, sub=has,
                         film=film_rows(film, has))
        weight = weight * (ONE - transmission)
    # 6. Specular: dielectric GGX reflection; Specular IOR Level scales F0 (and the IOR with it).
    f0 = np.square((ior - ONE) / (ior + ONE))
    eta = ior
    level = np.maximum(get("Specular IOR Level"), ZERO)
    adjusted = level != F32(0.5)
    if np.any(adjusted):
        f0 = np.where(adjusted, f0 * F32(2.0) * level, f0)
        eta_adj = mf.ior_from_f0(f0)
        eta = np.where(adjusted, np.where(ior < ONE, ONE / eta_adj, eta_adj), eta)
    # Made where eta != 1 or a film counts. Hits whose layers above left no weight (metal, glass) make no
    # specular closure: skip their tables.
    makes = eta != ONE if film is None else (eta != ONE) | film_on(film[0])
    has = glossy(makes & np.any(weight != ZERO, axis=0))
    if len(has):
        albedo = mf.add_specular(anisotropic, spec, np.take(weight, has, axis=1), ax[has], ay[has], eta[has],
                                 f0[has] * np.take(specular_tint, has, axis=1), multiscatter, sub=has,
                                 film=film_rows(film, has))
        sampling.put_columns(weight, has, layering_weight(albedo, np.take(weight, has, axis=1)))
    # 7. Subsurface (a BSSRDF of the clamped base colour, Radius x Scale, the specular layer's eta, or Subsurface
    # IOR for Skin; bssrdf.add_bssrdf) and diffuse.
    if not param_may_differ(c, "Subsurface Weight", 0.0):
        diffuse_lobe(b, ctx, base * weight, np.clip(get("Diffuse Roughness"), 0.0, 1.0), clamped)
    else:
        sss = np.clip(get("Subsurface Weight"), 0.0, 1.0)
        has = np.flatnonzero(sss > CUTOFF)
        if len(has):
            method = bssrdf.METHODS[c.option("subsurface_method", "RANDOM_WALK")]
            ior_s = get("Subsurface IOR") if method == bssrdf.RANDOM_WALK_SKIN else eta
            radius = np.maximum(get("Subsurface Radius") * get("Subsurface Scale"), ZERO)
            bssrdf.add_bssrdf(b, ctx.idx[has], sss[has] * np.take(clamped * weight, has, axis=1),
                              np.take(clamped, has, axis=1), np.take(radius, has, axis=1), ior_s[has], alpha_r[has],
                              get("Subsurface Anisotropy")[has], method, normal=normal_rows(spec.normal_arg, has),
                              soften=soften(spec), ancestor=_taken(ctx.diffuse_ancestor(), has))
        diffuse_lobe(b, ctx, base * (ONE - sss) * weight, np.clip(get("Diffuse Roughness"), 0.0, 1.0), clamped)
    return Built(emission=emission)


def _taken(a, sub):
    return None if a is None else a[sub]


def layering_weight(layer_albedo: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Cycles' closure_layering_weight: what the layers below keep, weight * clamp01(1 - max(albedo / weight))."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(weight != 0, layer_albedo / np.where(weight != 0, weight, ONE), ZERO)
    return (weight * np.clip(ONE - ratio.max(axis=0), 0.0, 1.0)).astype(F32)
