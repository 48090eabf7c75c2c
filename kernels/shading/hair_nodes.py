"""The Principled Hair BSDF as Cycles sets it up (`kernel/svm/closure.h`'s CLOSURE_BSDF_HAIR_CHIANG_ID and
CLOSURE_BSDF_HAIR_HUANG_ID case, `bsdf_hair_chiang_setup`, `bsdf_hair_huang_setup`; defaults and parametrizations in
`scene/shader_nodes.cpp` PrincipledHairBsdfNode): one Chiang or Huang closure (kernels/bsdf/hair_chiang.py,
hair_huang.py) per hit, weighted by the Mix Shader weight, on the frame Cycles builds from the hit.

What a closure reads of its hit is a HairHits record. On a triangle it is Cycles' ShaderData there (mesh_hair_hits):
the tangent dPdu = p1 - p0 of the triangle's corners in Blender's order (reversed on back faces, as Cycles reverses
it), the geometric and shading normals, no ribbon and no curve. A curve geometry hands its own record through the
hit record's `hair_hits(idx)` when it has that method (the contract is HairHits' docstring). On curves met by rays
that still have camera visibility, Huang's pixel coverage (pixel_coverage) selects its near field where a strand is
wider than a pixel.

Node inputs, Cycles' order: Random is the curve's random value where the hit is on a curve and the input is not
linked (Cycles' ATTR_STD_CURVE_RANDOM), else the input. Roughness and Radial Roughness (Chiang; Huang takes
Roughness for both) are scaled by 1 + 2 (Random - 1/2) Random Roughness. The absorption comes from the
parametrization: Absorption Coefficient as given; Melanin (hair_chiang.sigma_from_melanin) plus the Tint's; or
Direct Coloring's Color (hair_chiang.sigma_from_reflectance, with the radial roughness).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..bsdf import hair_chiang as chiang
from ..bsdf import hair_huang as huang
from ..bsdf import lobes
from ..vec import F32, ONE, ZERO, cross_xyz, dot_xyz, make_orthonormals_xyz, normalize_xyz
from .node_context import Built
from .program import HitInputs

CURVE_RANDOM = "std:curve_random"   # the export's ATTR_STD_CURVE_RANDOM, made where a Principled Hair's Random is free
# The export's ATTR_STD_VERTEX_NORMAL of curves, Blender's curve normals (zero on particle hair), made for Huang
# hair whose Aspect Ratio is other than 1: an elliptical fibre's major axis.
CURVE_NORMAL = "std:curve_normal"

PARAMETRIZATIONS = ("COLOR", "MELANIN", "ABSORPTION")
MODELS = ("CHIANG", "HUANG")


@dataclass
class HairHits:
    """What the Principled Hair closures read of n hits (Cycles' ShaderData after shader_setup_from_ray), world space:

    tangent : (x, y, z) of (n,) float32, Cycles' sd->dPdu: along the curve (any length), reversed on back faces.
    ng : (x, y, z), the geometric normal toward the viewer (sd->Ng): on a thick curve the direction from the curve's
        axis to the hit, on a ribbon the viewer direction.
    ns : (x, y, z), the shading normal (sd->N).
    ribbon_v : None, or (n,) float32 the hit's v across a ribbon, -1..1 (Cycles' h = -v there), NaN elsewhere.
    curve : None, or (n,) bool, the hits on curves: they take no bump shadowing term, read Random from `random`
        (unless the input is linked), and Huang's elliptical frame and near field apply there.
    random : None, or (n,) float32, the curve's random value (Cycles' ATTR_STD_CURVE_RANDOM).
    major_axis : None, or (x, y, z), the curve's normal attribute (ATTR_STD_VERTEX_NORMAL): an elliptical fibre's
        major axis (Huang, Aspect Ratio other than 1). None on curves: Cycles' zero attribute, an arbitrary frame.
    coverage : None, or (n,) float32: half a pixel's width over the curve's radius where a camera ray hit a curve
        (Cycles' 0.5 sd->dP / radius), 1 elsewhere. Below the fibre's projected radius Huang uses its near field.
    """
    tangent: tuple
    ng: tuple
    ns: tuple
    ribbon_v: np.ndarray | None = None
    curve: np.ndarray | None = None
    random: np.ndarray | None = None
    major_axis: tuple | None = None
    coverage: np.ndarray | None = None


def mesh_hair_hits(hit, idx) -> HairHits:
    """HairHits of triangle hits idx: dPdu = p1 - p0, reversed on back faces (Cycles' triangle_dPdudv and its
    backfacing flip)."""
    edge = hit.edges(idx)[0]
    sign = np.where(np.take(hit.backfacing, idx), F32(-1.0), ONE)
    return HairHits(tuple((edge[:, k] * sign).astype(F32) for k in range(3)),
                    tuple(np.take(c, idx) for c in hit.ng), tuple(np.take(c, idx) for c in hit.ns))


def hair_hits(ctx) -> HairHits:
    """HairHits of the context's hits: on triangles mesh_hair_hits; on curves (SurfaceHit.shapes) what Cycles'
    curve_shader_setup gives: dPdu, the tube's normals, v across a ribbon, and the curve's random value."""
    g = mesh_hair_hits(ctx.hit, ctx.idx)
    shapes = getattr(ctx.hit, "shapes", None)
    if shapes is None:
        return g
    curve = np.take(shapes.curve, ctx.idx)
    if not curve.any():
        return g
    dpdu = np.take(shapes.dpdu, ctx.idx, axis=0)
    g.tangent = tuple(np.where(curve, dpdu[:, k], g.tangent[k]).astype(F32) for k in range(3))
    g.curve = curve
    g.ribbon_v = np.where(curve & np.take(shapes.ribbon, ctx.idx), np.take(shapes.v, ctx.idx), np.nan).astype(F32)
    inputs = HitInputs(ctx.shading.data, ctx.hit, ctx.idx)
    random = inputs.attribute(CURVE_RANDOM)
    g.random = None if random is None else np.ascontiguousarray(random[:, 0], F32)
    normal = inputs.attribute(CURVE_NORMAL)
    if normal is not None:   # object space, read as Cycles reads it (curve_attribute: the keys' values mixed at u)
        g.major_axis = tuple(np.where(curve, normal[:, k], ZERO).astype(F32) for k in range(3))
    g.coverage = pixel_coverage(ctx.hit.ray, ctx.idx, curve, np.take(shapes.key_radius, ctx.idx))
    return g


def pixel_coverage(ray, idx, curve, radius) -> np.ndarray | None:
    """(n,) Cycles' pixel_coverage of hits idx (svm/closure.h, the Huang setup): 0.5 sd->dP / radius where the ray
    still has camera visibility (PATH_RAY_VISIBILITY_CAMERA: no bounce yet, only transparent surfaces and portals
    passed, integrator/path_state.h path_state_next) and the hit is on a curve, radius that of the frame's keys
    mixed at u; 1 elsewhere. sd->dP is the ray's compact differential carried to the hit (RayInfo.dp,
    util/differential.h differential_transfer_compact). None where no hit has it (no path state: far field)."""
    if ray is None or ray.dp is None or ray.shadow or not ray.camera:
        return None
    seen = curve & (np.take(ray.depth, idx) == 0)
    if not seen.any():
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        coverage = F32(0.5) * np.take(ray.dp, idx) / radius
    # A radius of 0 (a closed tip) gives inf in Cycles: the far field, as 1 gives (Huang's radius is at most 1), and
    # Cycles reads the coverage nowhere else.
    return np.where(seen & np.isfinite(coverage), coverage, ONE).astype(F32)


def principled_hair_bsdf(c, ctx, w, b):
    """The Principled Hair BSDF node (module docstring)."""
    if b is None:
        return Built()
    n = len(ctx.idx)
    model = c.option("model", "CHIANG")
    g = hair_hits(ctx)
    random = _random(c, ctx, g)
    factor = ONE + F32(2.0) * (random - F32(0.5)) * ctx.input(c, "Random Roughness")
    roughness = (ctx.input(c, "Roughness") * factor).astype(F32)
    radial = (ctx.input(c, "Radial Roughness") * factor).astype(F32) if model == "CHIANG" else roughness
    sigma = _sigma(c, ctx, random, radial)
    weight = np.broadcast_to(np.asarray(w, F32), (3, n)).astype(F32)
    offset = ctx.input(c, "Offset").astype(F32)
    ior = ctx.input(c, "IOR").astype(F32)
    on_curve = ZERO if g.curve is None else g.curve.astype(F32)
    if model == "HUANG":
        _add_huang(c, ctx, b, g, weight, roughness, offset, ior, sigma, on_curve)
    else:
        _add_chiang(c, ctx, b, g, weight, roughness, radial, offset, ior, sigma, on_curve)
    return Built()


def _random(c, ctx, g: HairHits) -> np.ndarray:
    random = np.array(ctx.input(c, "Random"), F32)
    p = c.input("Random")
    linked = p is not None and p.varies
    if g.curve is not None and g.random is not None and not linked:
        random = np.where(g.curve, g.random, random).astype(F32)
    return random


def _sigma(c, ctx, random, radial) -> np.ndarray:
    kind = c.option("parametrization", "COLOR")
    if kind == "ABSORPTION":
        return np.array(ctx.input(c, "Absorption Coefficient"), F32)
    if kind == "MELANIN":
        melanin = chiang.sigma_from_melanin(ctx.input(c, "Melanin"), ctx.input(c, "Melanin Redness"),
                                            ctx.input(c, "Random Color"), random)
        return (melanin + chiang.sigma_from_reflectance(ctx.input(c, "Tint"), radial)).astype(F32)
    return chiang.sigma_from_reflectance(ctx.input(c, "Color"), radial)


def _add_chiang(c, ctx, b, g, weight, roughness, radial, offset, ior, sigma, on_curve):
    """bsdf_hair_chiang_setup: X the unit tangent, Y = X x viewer (the closure's normal), h from the normal."""
    x = normalize_xyz(g.tangent)
    y = normalize_xyz(cross_xyz(x, ctx.wo))
    h = chiang.chiang_h(x, g.ng, ctx.wo)
    if g.ribbon_v is not None:
        h = np.where(np.isnan(g.ribbon_v), h, -g.ribbon_v).astype(F32)
    v, s, m0 = chiang.chiang_roughness(roughness, radial, ctx.input(c, "Coat"))
    ok = np.flatnonzero((dot_xyz(y, y) > 0) & (dot_xyz(x, x) > 0))
    alpha = -offset
    albedo = weight * chiang.chiang_albedo(dot_xyz(ctx.wo, x), h, v, ior, sigma)
    b.add(lobes.HAIR_CHIANG, ctx.idx[ok], weight[:, ok], normal=_rows(y, ok), tangent=_rows(x, ok),
          albedo=(albedo[:, ok], np.zeros((3, len(ok)), F32)), hair_h=h[ok], hair_v=v[ok], hair_s=s[ok],
          hair_m0=m0[ok], offset=alpha[ok], eta=ior[ok], c0=sigma[:, ok], on_curve=_at(on_curve, ok))


def _add_huang(c, ctx, b, g, weight, roughness, offset, ior, sigma, on_curve):
    """bsdf_hair_huang_setup: Y the unit tangent, N = dPdu x viewer (or an elliptical fibre's major axis on a
    curve), the closure's normal; a hit beyond the fibre's projected radius is a Transparent closure."""
    n = len(ctx.idx)
    scales = np.stack([np.maximum(ctx.input(c, k), ZERO) for k in ("R lobe", "TT lobe", "TRT lobe")]).astype(F32)
    made = np.any(scales > 0, axis=0)
    tangent = g.tangent
    y = normalize_xyz(tangent)
    x = normalize_xyz(cross_xyz(tangent, ctx.wo))
    h = (-dot_xyz(x, g.ns)).astype(F32)
    if g.ribbon_v is not None:
        h = np.where(np.isnan(g.ribbon_v), h, -g.ribbon_v).astype(F32)
    aspect = np.array(ctx.input(c, "Aspect Ratio"), F32)
    normal = x
    if g.curve is not None:
        elliptic = g.curve & (aspect != ONE)
        if elliptic.any():
            normal, aspect = _major_axis(g, tangent, x, aspect, elliptic)
    degenerate = ~((dot_xyz(normal, normal) > 0) & np.all(np.isfinite(np.stack(normal)), axis=0))
    if degenerate.any():
        z_any, n_any = make_orthonormals_xyz(y)
        normal = tuple(np.where(degenerate, a, m).astype(F32) for a, m in zip(n_any, normal))
    z = normalize_xyz(cross_xyz(normal, tangent))
    if degenerate.any():
        z = tuple(np.where(degenerate, a, m).astype(F32) for a, m in zip(z_any, z))
    wo_local = (dot_xyz(ctx.wo, normal), dot_xyz(ctx.wo, y), dot_xyz(ctx.wo, z))
    through = made & (np.abs(h) >= huang.huang_radius(aspect, wo_local))
    if through.any():
        t = np.flatnonzero(through)
        b.add(lobes.TRANSPARENT, ctx.idx[t], weight[:, t])
    ok = np.flatnonzero(made & ~through)
    if not len(ok):
        return
    coverage = np.ones(n, F32) if g.coverage is None else np.asarray(g.coverage, F32)
    rough = np.clip(roughness, F32(0.001), ONE)
    params = huang.HuangParams(rough[ok], -offset[ok], ior[ok], aspect[ok], sigma[:, ok], scales[:, ok], h[ok],
                               coverage[ok], tuple(c[ok] for c in wo_local))
    albedo = weight[:, ok] * huang.huang_albedo(params)
    b.add(lobes.HAIR_HUANG, ctx.idx[ok], weight[:, ok], normal=_rows(normal, ok), tangent=_rows(y, ok),
          albedo=(albedo, np.zeros((3, len(ok)), F32)), hair_h=h[ok], rough=rough[ok], offset=-offset[ok],
          eta=ior[ok], aspect=aspect[ok], c0=sigma[:, ok], c1=scales[:, ok], coverage=coverage[ok],
          on_curve=_at(on_curve, ok))


def _major_axis(g, tangent, x, aspect, elliptic):
    """An elliptical fibre on a curve: its normal made the major axis, orthogonal to dPdu; an aspect ratio above 1
    inverted, the axes swapped (bsdf_hair_huang_setup)."""
    zero = tuple(np.zeros_like(c) for c in tangent)
    axis = g.major_axis if g.major_axis is not None else zero
    m = normalize_xyz(cross_xyz(tangent, normalize_xyz(cross_xyz(axis, tangent))))
    wide = elliptic & (aspect > ONE)
    minor = normalize_xyz(cross_xyz(tangent, m))
    swapped = normalize_xyz(cross_xyz(minor, tangent))
    m = tuple(np.where(wide, s, a) for s, a in zip(swapped, m))
    normal = tuple(np.where(elliptic, a, b).astype(F32) for a, b in zip(m, x))
    with np.errstate(divide="ignore"):
        aspect = np.where(wide, ONE / aspect, aspect).astype(F32)
    return normal, aspect


def _rows(v, ok):
    return tuple(np.asarray(c)[ok] for c in v)


def _at(value, ok):
    return value if np.ndim(value) == 0 else value[ok]
