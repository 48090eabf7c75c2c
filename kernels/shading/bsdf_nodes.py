"""The closure nodes but the Principled BSDF, as Cycles' `svm_node_closure_bsdf` sets them up
(`kernel/svm/closure.h`): Diffuse, Translucent, Transparent, Sheen, Toon, Ray Portal and Hair BSDFs,
Emission and Holdout, and the microfacet ones (Glossy, Glass, Refraction, Metallic).

Each is `node(closure, ctx, w, b) -> Built`: it reads the node's inputs at the hits of one material
(node_context.Context), and adds closures to the wave's ClosureBuilder b (with the node's Mix Shader
weight w), or returns emission and holdout; b None asks for those only.
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..bsdf import bssrdf, lobes
from ..bsdf import microfacet_closures as mf
from ..bsdf.sheen import sheen_albedo
from ..bsdf.toon import toon_angles
from ..scene import Closure
from ..vec import F32, ONE, ZERO, normalize_xyz
from .node_context import (Built, CUTOFF, Context, caustics_made, normal_rows, soften, thin_film, times_made,
                           with_tangent)


# ---------------------------------------------------------------- simple nodes
def diffuse_bsdf(c, ctx, w, b):
    if b is not None:
        color = ctx.input(c, "Color")
        diffuse_lobe(b, ctx, color * w, ctx.input(c, "Roughness"), np.clip(color, 0.0, 1.0))
    return Built()


def subsurface_scattering(c, ctx, w, b):
    """The Subsurface Scattering node (svm_node_closure_bsdf's BSSRDF case): weight Color x the Mix weight, albedo
    Color, Radius x Scale, the node's IOR, alpha = Roughness (clamped, not squared), Anisotropy, on its Normal."""
    if b is not None:
        color = ctx.input(c, "Color")
        radius = np.maximum(ctx.input(c, "Radius") * ctx.input(c, "Scale"), ZERO)
        method = bssrdf.METHODS[c.option("subsurface_method", "RANDOM_WALK")]
        bssrdf.add_bssrdf(b, ctx.idx, color * w, color, radius, ctx.input(c, "IOR"),
                          np.clip(ctx.input(c, "Roughness"), 0.0, 1.0), ctx.input(c, "Anisotropy"), method,
                          normal=ctx.normal_arg, soften=soften(ctx), ancestor=ctx.diffuse_ancestor())
    return Built()


def diffuse_lobe(b, ctx, weight, roughness, rho):
    """Lambert where roughness < 1e-5, else Cycles' Oren-Nayar with sigma = roughness."""
    rough = roughness >= CUTOFF
    normal = ctx.normal_arg
    flat = np.flatnonzero(~rough)
    b.add(lobes.LAMBERT, ctx.idx[flat], np.take(weight, flat, axis=1), normal=normal_rows(normal, flat), **soften(ctx))
    on = np.flatnonzero(rough)
    if len(on):
        b.add(lobes.OREN_NAYAR, ctx.idx[on], np.take(weight, on, axis=1), normal=normal_rows(normal, on),
              rough=np.clip(roughness[on], 0.0, 1.0), c0=np.take(rho, on, axis=1), **soften(ctx))


def translucent_bsdf(c, ctx, w, b):
    if b is not None:
        b.add(lobes.TRANSLUCENT, ctx.idx, ctx.input(c, "Color") * w, normal=ctx.specular().normal_arg,
              **soften(ctx))
    return Built()


def transparent_bsdf(c, ctx, w, b):
    if b is not None:
        b.add(lobes.TRANSPARENT, ctx.idx, np.maximum(ctx.input(c, "Color"), ZERO) * w)
    return Built()


def sheen_bsdf(c, ctx, w, b):
    if b is not None and c.option("distribution", "MICROFIBER") == "ASHIKHMIN":
        # Cycles' Ashikhmin velvet: sigma the Roughness clamped to [0, 1], no bump softening (a glossy closure).
        b.add(lobes.VELVET, ctx.idx, ctx.input(c, "Color") * w, normal=ctx.normal_arg,
              rough=np.clip(ctx.input(c, "Roughness"), 0.0, 1.0))
        return Built()
    if b is not None:
        rough = np.clip(ctx.input(c, "Roughness"), 0.0, 1.0)
        weight = ctx.input(c, "Color") * w
        albedo = sheen_albedo(ctx.mu(), rough)
        b.add(lobes.SHEEN, ctx.idx, weight, sample_weight=sheen_sample_weight(weight, albedo),
              normal=ctx.normal_arg, rough=rough, **soften(ctx))
    return Built()


def sheen_sample_weight(weight, albedo):
    """Cycles' bsdf_sheen_setup scales a sheen closure's sample weight by the lobe's albedo toward the
    viewer (its colour weight too; Ember's lobe carries that factor in its evaluation instead): the lobe is
    picked in proportion to the light it reflects, and its albedo (Denoising Albedo, Diffuse Color) is
    weight x albedo. A closure whose albedo Cycles would drop gets 0 and is not made."""
    return (np.abs(sampling.channel_mean(np.asarray(weight, F32))) * albedo).astype(F32)


def toon_bsdf(c, ctx, w, b):
    """Toon BSDF: one diffuse or glossy toon closure on the node's normal (not tilted for specular
    reflection), weight colour x mix weight; the caustics switch drops the glossy one as a glossy closure."""
    if b is not None:
        glossy = c.option("component", "DIFFUSE") == "GLOSSY"
        color = ctx.input(c, "Color")
        if glossy:
            color = times_made(color, caustics_made(ctx))
        size, smooth = toon_angles(ctx.input(c, "Size"), ctx.input(c, "Smooth"))
        b.add(lobes.TOON_GLOSSY if glossy else lobes.TOON_DIFFUSE, ctx.idx, color * w, normal=ctx.normal_arg,
              size=size, smooth=smooth, **({} if glossy else soften(ctx)))
    return Built()


def portal_weight(c: Closure, ctx: Context, w: np.ndarray) -> np.ndarray:
    """(3, n) a Ray Portal's closure weight, 0 where Cycles would not make it (below its cutoff)."""
    weight = ctx.input(c, "Color") * w
    return np.where(np.abs(weight.mean(axis=0)) >= CUTOFF, weight, ZERO).astype(F32)


def ray_portal_bsdf(c, ctx, w, b):
    """Ray Portal BSDF (Cycles' bsdf_ray_portal_setup): weight colour x mix weight; the ray goes on from
    Position along Direction, or straight on where Direction is zero; a Position within 3.2e-5 of the hit
    (Cycles' squared 1e-9) is the hit itself, which the ray leaves as from any surface. Direction is
    normalised: Cycles traces it as given, and a direction that is not of unit length gives the next hit a
    viewer direction that is not either."""
    if b is not None:
        origin = ctx.input(c, "Position")
        hit_p = np.stack([ctx.take(a) for a in ctx.hit.p])
        origin = np.where(np.isnan(origin), hit_p, origin)
        moved = np.sum(np.square(origin - hit_p), axis=0) > F32(1e-9)
        direction = ctx.input(c, "Direction")
        length = np.sqrt(np.sum(np.square(direction), axis=0))
        ahead = np.stack([-a for a in ctx.wo])
        usable = (length > 0) & np.isfinite(length)
        direction = np.where(usable, direction / np.where(usable, length, ONE), ahead).astype(F32)
        b.add(lobes.PORTAL, ctx.idx, portal_weight(c, ctx, w), origin=np.where(moved, origin, np.nan),
              direction=direction)
    return Built()


def hair_bsdf(c, ctx, w, b):
    """Hair BSDF (Cycles' bsdf_hair_*_setup, svm/closure.h): weight colour x mix weight, on the normal tilted
    for specular reflection; roughnesses clamped to [0.001, 1]. Its tangent is the Tangent input (normalised,
    the highlight shifted by -Offset); unlinked, on a curve the curve's dPdu with the shift, on a triangle its
    p2 - p0 (Cycles' dPdv, reversed on back faces) with no shift: one direction per triangle, in the order
    Blender lists its corners."""
    if b is not None:
        given = ctx.tangent(c, None, ctx.ns, anisotropic=False)
        if given is None:
            edge = ctx.hit.edges(ctx.idx)[1]
            sign = np.where(ctx.take(ctx.hit.backfacing), F32(-1.0), ONE)
            tangent = normalize_xyz(tuple(edge[:, k] * sign for k in range(3)))
            offset = ZERO
            curve = ctx.on_curves()
            if curve is not None:
                dpdu = np.take(ctx.hit.shapes.dpdu, ctx.idx, axis=0)
                along = normalize_xyz(tuple(dpdu[:, k] for k in range(3)))
                tangent = tuple(np.where(curve, a, e) for a, e in zip(along, tangent))
                offset = np.where(curve, -ctx.input(c, "Offset"), ZERO).astype(F32)
        else:
            tangent, offset = normalize_xyz(given), -ctx.input(c, "Offset")
        transmission = c.option("component", "Reflection") == "Transmission"
        b.add(lobes.HAIR_TRANSMISSION if transmission else lobes.HAIR_REFLECTION, ctx.idx, ctx.input(c, "Color") * w,
              normal=ctx.specular().normal_arg, hair_t=tangent, offset=offset,
              r1=np.clip(ctx.input(c, "RoughnessU"), F32(0.001), ONE),
              r2=np.clip(ctx.input(c, "RoughnessV"), F32(0.001), ONE))
    return Built()


def emission(c, ctx, w, b):
    # Not clamped: Cycles emits what the nodes compute, negative values too (a node program's output).
    return Built(emission=ctx.input(c, "Color") * (ctx.input(c, "Strength") * w))


def holdout(c, ctx, w, b):
    return Built(holdout=w.astype(F32))


# ---------------------------------------------------------------- microfacet nodes
def glossy_bsdf(c, ctx, w, b):
    if b is not None:
        color = times_made(np.maximum(ctx.input(c, "Color"), ZERO), caustics_made(ctx))
        alpha = np.square(np.clip(ctx.input(c, "Roughness"), 0.0, 1.0))
        aniso = np.clip(ctx.input(c, "Anisotropy"), -0.99, 0.99)
        ax, ay = mf.glossy_anisotropy(alpha, aniso)
        distribution = c.option("distribution", "MULTI_GGX")
        spec = ctx.specular()
        # Cycles rotates it about the closure's own normal.
        tangent = ctx.tangent(c, "Rotation", spec.ns, bool(np.any(ax != ay)))
        if distribution == "ASHIKHMIN_SHIRLEY":
            mf.add_ashikhmin_shirley(with_tangent(b, ctx, tangent), spec, color, w, ax, ay)
        else:
            mf.add_glossy(with_tangent(b, ctx, tangent), spec, color, w, ax, ay,
                          multiscatter=distribution == "MULTI_GGX", distribution=_distribution(c))
    return Built()


def _distribution(c):
    """The microfacet distribution of a node's `distribution` option: Beckmann, else GGX."""
    return mf.BECKMANN if c.option("distribution", "MULTI_GGX") == "BECKMANN" else mf.GGX


def glass_bsdf(c, ctx, w, b):
    if b is not None:
        color = np.maximum(ctx.input(c, "Color"), ZERO)
        alpha = np.square(np.clip(ctx.input(c, "Roughness"), 0.0, 1.0))
        ior = np.maximum(ctx.input(c, "IOR"), F32(1e-5))
        # Cycles zeroes the tint of a branch whose caustics are off (neither: no closure).
        mf.add_glass(b, ctx.specular(), w, alpha, ior, reflection_tint=times_made(color, caustics_made(ctx)),
                     transmission_tint=times_made(color, caustics_made(ctx, refractive=True)),
                     specular_tint=None, multiscatter=c.option("distribution", "MULTI_GGX") == "MULTI_GGX",
                     distribution=_distribution(c), film=thin_film(c, ctx, "Thin Film Thickness", "Thin Film IOR"))
    return Built()


def refraction_bsdf(c, ctx, w, b):
    if b is not None:
        color = times_made(ctx.input(c, "Color"), caustics_made(ctx, refractive=True))
        alpha = np.square(ctx.input(c, "Roughness"))
        ior = np.maximum(ctx.input(c, "IOR"), F32(1e-5))
        mf.add_refraction(b, ctx.specular(), color * w, alpha, ior, distribution=_distribution(c))
    return Built()


def metallic_bsdf(c, ctx, w, b):
    if b is not None:
        alpha = np.square(np.clip(ctx.input(c, "Roughness"), 0.0, 1.0))
        ax, ay = mf.principled_anisotropy(alpha, np.clip(ctx.input(c, "Anisotropy"), 0.0, 1.0))
        multiscatter = c.option("distribution", "MULTI_GGX") == "MULTI_GGX"
        weight = np.broadcast_to(times_made(w, caustics_made(ctx)), (3, len(w)))
        spec = ctx.specular()
        b = with_tangent(b, ctx, ctx.tangent(c, "Rotation", ctx.ns, bool(np.any(ax != ay))))
        film = thin_film(c, ctx, "Thin Film Thickness", "Thin Film IOR")
        if c.option("fresnel", "F82") == "PHYSICAL_CONDUCTOR":
            mf.add_conductor(b, spec, weight, ax, ay, np.maximum(ctx.input(c, "IOR"), ZERO),
                             np.maximum(ctx.input(c, "Extinction"), ZERO), multiscatter,
                             distribution=_distribution(c), film=film)
        else:
            mf.add_f82(b, spec, weight, ax, ay, np.clip(ctx.input(c, "Base Color"), 0.0, 1.0),
                       np.clip(ctx.input(c, "Edge Tint"), 0.0, 1.0), multiscatter, distribution=_distribution(c),
                       film=film)
    return Built()
