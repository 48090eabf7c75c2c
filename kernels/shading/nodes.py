"""Closure nodes -> closures, as Cycles' `svm_node_closure_bsdf` builds them (`kernel/svm/closure.h`).

One function per node kind: it reads the node's inputs at the hits of one material, and adds closures to
the wave's ClosureBuilder (with the node's Mix Shader weight), or returns emission and holdout. Inputs
a shader leaves out take Blender 5.0's defaults (DEFAULTS). The Principled BSDF is Cycles' layer stack:
alpha, sheen, coat, emission, metal, transmission, specular, diffuse, each layer dimming the ones below
by its estimated albedo (`closure_layering_weight`).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .. import sampling
from ..bsdf import lobes
from ..bsdf import microfacet_closures as mf
from ..bsdf.sheen import sheen_albedo
from ..bsdf.toon import toon_angles
from ..paths import DIFFUSE as DIFFUSE_LABEL
from ..scene import Closure, NormalMap, Param, Tangent
from ..vec import F32, ONE, TWO_PI, ZERO, normalize_xyz
from . import normals
from .input_ops import radial_tangent
from .program import HitInputs

CUTOFF = F32(1e-5)  # Cycles' CLOSURE_WEIGHT_CUTOFF: lighter layers are not made

WHITE, GREY = (1.0, 1.0, 1.0), (0.8, 0.8, 0.8)
UNSET = (float("nan"),) * 3  # a vector input that stands for something of the hit when it is not linked
# Blender 5.0's defaults of the inputs Ember reads (node_shader_bsdf_*.cc, node_shader_emission.cc).
DEFAULTS = {
    "PRINCIPLED": {"Base Color": GREY, "Metallic": 0.0, "Roughness": 0.5, "IOR": 1.5, "Alpha": 1.0,
                   "Diffuse Roughness": 0.0, "Subsurface Weight": 0.0, "Specular IOR Level": 0.5,
                   "Specular Tint": WHITE, "Anisotropic": 0.0, "Anisotropic Rotation": 0.0,
                   "Transmission Weight": 0.0, "Coat Weight": 0.0, "Coat Roughness": 0.03, "Coat IOR": 1.5,
                   "Coat Tint": WHITE, "Sheen Weight": 0.0, "Sheen Roughness": 0.5, "Sheen Tint": WHITE,
                   "Emission Color": WHITE, "Emission Strength": 0.0},
    "DIFFUSE": {"Color": GREY, "Roughness": 0.0},
    "GLOSSY": {"Color": GREY, "Roughness": 0.5, "Anisotropy": 0.0, "Rotation": 0.0},
    "GLASS": {"Color": WHITE, "Roughness": 0.0, "IOR": 1.5},
    "REFRACTION": {"Color": WHITE, "Roughness": 0.0, "IOR": 1.5},
    "METALLIC": {"Base Color": (0.617, 0.577, 0.540), "Edge Tint": (0.695, 0.726, 0.770),
                 "IOR": (2.757, 2.513, 2.231), "Extinction": (3.867, 3.404, 3.009), "Roughness": 0.5,
                 "Anisotropy": 0.0, "Rotation": 0.0},
    "SHEEN": {"Color": GREY, "Roughness": 0.5},
    "TRANSLUCENT": {"Color": GREY},
    "TOON": {"Color": GREY, "Size": 0.5, "Smooth": 0.0},
    # Unlinked, Position is the hit's (Cycles links it to the position) and Direction (0, 0, 0) the ray's.
    "PORTAL": {"Color": WHITE, "Position": UNSET, "Direction": (0.0, 0.0, 0.0)},
    "HAIR": {"Color": GREY, "Offset": 0.0, "RoughnessU": 0.1, "RoughnessV": 1.0},
    "TRANSPARENT": {"Color": WHITE},
    "EMISSION": {"Color": WHITE, "Strength": 1.0},
    "HOLDOUT": {},
}


@dataclass
class Built:
    """What a node gives besides closures: emission (3, n) and holdout (n,), or None."""
    emission: np.ndarray | None = None
    holdout: np.ndarray | None = None


class Context:
    """The hits of one material in a wave: idx into the wave's hits, and their inputs on demand.

    ns is the normal the closures of the node being built are made on: the hits' shading normal, or the
    node's Normal input (normal_given). Views of one context (for_node, with_normal, specular) share the
    hits and what was computed for them (the tangent frame)."""

    def __init__(self, shading, hit, idx: np.ndarray, wo, bump_map_correction: bool = True, material: int = -1):
        self.shading, self.hit, self.idx, self.material = shading, hit, idx, material
        self.wo = tuple(np.take(c, idx) for c in wo)
        self.ns = tuple(np.take(c, idx) for c in hit.ns)
        self.hit_ns = self.ns
        self.normal_given = False
        self.bump_map_correction = bump_map_correction
        self._specular = None
        self._shared = {}

    def take(self, a):
        return np.take(a, self.idx)

    def input(self, closure: Closure, name: str) -> np.ndarray:
        """(n,) for float inputs, (3, n) for colours, from the closure's Param or the default."""
        default = DEFAULTS[closure.kind][name]
        channels = 3 if isinstance(default, tuple) else 1
        p = closure.input(name)
        if p is None:
            value = np.asarray(default, F32)
            return np.broadcast_to(value[:, None] if channels == 3 else value, (3, len(self.idx)) if channels == 3
                                   else (len(self.idx),))
        return self.shading.param(p, self, channels)

    def caustics(self):
        """Cycles' caustics switches at these hits (svm_node_closure_bsdf): (reflective, refractive), (n,) bool
        each, False where the render turned that kind off and the ray comes from a diffuse bounce (glossy
        reflection, or refraction, closures are then not made); None where every closure is made."""
        ray = getattr(self.hit, "ray", None)
        if ray is None or ray.caustics is None:
            return None
        if "caustics" not in self._shared:
            direct = (np.take(ray.lobes[0], self.idx) & DIFFUSE_LABEL) == 0
            everywhere = np.ones(len(self.idx), bool)
            reflective, refractive = ray.caustics
            self._shared["caustics"] = (everywhere if reflective else direct, everywhere if refractive else direct)
        return self._shared["caustics"]

    def mu(self, normal=None) -> np.ndarray:
        """cos of the angle between the viewer and the normal (the context's normal by default)."""
        n = self.ns if normal is None else normal
        return self.wo[0] * n[0] + self.wo[1] * n[1] + self.wo[2] * n[2]

    # ---- normals and tangents
    @property
    def normal_arg(self):
        """The normal to hand ClosureBuilder.add: None when it is the hits' shading normal."""
        return self.ns if self.normal_given else None

    def for_node(self, closure: Closure) -> "Context":
        """The view a closure node builds on: its Normal input, when a normal map feeds it."""
        return self.with_normal(self.normal_input(closure, "Normal"))

    def normal_input(self, closure: Closure, name: str):
        """A Normal or Coat Normal input at the hits: a normal map's normal, or None when unlinked."""
        spec = closure.input(name)
        if isinstance(spec, Param) and spec.link is not None:  # a program's normal (a Bump, a Normal Map)
            return normalize_xyz(tuple(self.shading.param(spec, self, 3)))
        if not isinstance(spec, NormalMap):
            return None
        color = self.shading.param(spec.color, self, 3)
        strength = self.shading.param(spec.strength, self, 1)
        frame = self._frame() if spec.space == "TANGENT" else None
        return normals.normal_map(color, strength, spec.space, self.hit_ns, self.take(self.hit.backfacing), frame,
                                  spec.invert_green)

    def with_normal(self, normal) -> "Context":
        """This context on another (unit) normal; itself for None."""
        if normal is None:
            return self
        view = copy.copy(self)
        view.ns, view.normal_given, view._specular = normal, True, None
        return view

    def specular(self) -> "Context":
        """The view specular closures are made on: the normal tilted until the mirror direction clears
        the surface (Cycles' maybe_ensure_valid_specular_reflection), unless the material turns Bump Map
        Correction off."""
        if self._specular is None:
            self._specular = self
            if self.bump_map_correction:
                ng = tuple(np.take(c, self.idx) for c in self.hit.ng)
                valid = normals.valid_specular_normal(ng, self.wo, self.ns)
                if valid is not self.ns:
                    self._specular = self.with_normal(valid)
        return self._specular

    def tangent(self, closure: Closure, rotation: str | None, axis, anisotropic: bool = True):
        """The closure's Tangent input rotated about axis by 2 pi x the rotation input (None: not): a Tangent node's
        UV-map tangent, or unlinked Cycles' default, the radial tangent about the object's Z axis (only
        made when the closure is anisotropic). None: no tangent (the closure takes an arbitrary one)."""
        spec = closure.input("Tangent")
        if isinstance(spec, Param):  # a program's vector (a radial Tangent node, ...)
            t = normalize_xyz(tuple(self.shading.param(spec, self, 3)))
        elif isinstance(spec, Tangent):
            if "uv_tangent" not in self._shared:
                self._shared["uv_tangent"] = normals.uv_tangent(self._frame(), self.hit_ns)
            t = self._shared["uv_tangent"]
        elif spec is None and anisotropic:
            if "radial_tangent" not in self._shared:
                hits = HitInputs(self.shading.data, self.hit, self.idx)
                radial = radial_tangent(hits, "Z")
                self._shared["radial_tangent"] = tuple(np.ascontiguousarray(radial[:, k]) for k in range(3))
            t = self._shared["radial_tangent"]
        else:
            return None
        if t is None:
            return None
        angle = 0.0 if rotation is None else self.input(closure, rotation)
        if np.any(angle != 0):
            t = normals.rotate_about(t, axis, TWO_PI * angle)
        return t

    def _frame(self):
        if "frame" not in self._shared:
            self._shared["frame"] = self.hit.tangent_frame(self.idx)
        return self._shared["frame"]


class _TangentBuilder:
    """The wave's ClosureBuilder, handing a Tangent input's tangent to the (anisotropic) reflection closures
    added through it: microfacet_closures sets its closures up without a tangent (the builder's arbitrary
    one)."""

    def __init__(self, builder, idx: np.ndarray, tangent):
        self._builder = builder
        self._tangent = np.full((3, builder.n_hits), np.nan, F32)
        self._tangent[:, idx] = np.stack(tangent)

    def add(self, lobe, hits, weight, tangent=None, **kwargs):
        if tangent is None and lobe in (lobes.REFLECTION, lobes.ASHIKHMIN_SHIRLEY):
            tangent = np.take(self._tangent, hits, axis=1)
        self._builder.add(lobe, hits, weight, tangent=tangent, **kwargs)


def _with_tangent(b, ctx: Context, tangent):
    return b if b is None or tangent is None else _TangentBuilder(b, ctx.idx, tangent)


def build(closure: Closure, ctx: Context, weight: np.ndarray, builder) -> Built:
    """Add the closure node's closures (weight (n,) from the Mix Shaders above it) to builder; builder
    None asks for emission and holdout only."""
    return _BUILDERS[closure.kind](closure, ctx.for_node(closure), weight, builder)


def _made(ctx: Context, refractive: bool = False):
    """(n,) float32: 1 where the context's glossy reflection (or, refractive, refraction) closures are made,
    0 where the caustics switch drops them (Context.caustics); None where they are made at every hit."""
    switches = ctx.caustics()
    if switches is None:
        return None
    ok = switches[1 if refractive else 0]
    return None if ok.all() else ok.astype(F32)


def _times(a, made):
    return a if made is None else a * made


# ---------------------------------------------------------------- simple nodes
def _diffuse(c, ctx, w, b):
    if b is not None:
        color = ctx.input(c, "Color")
        _diffuse_lobe(b, ctx, color * w, ctx.input(c, "Roughness"), np.clip(color, 0.0, 1.0))
    return Built()


def _diffuse_lobe(b, ctx, weight, roughness, rho):
    """Lambert where roughness < 1e-5, else Cycles' Oren-Nayar with sigma = roughness."""
    rough = roughness >= CUTOFF
    normal = ctx.normal_arg
    flat = np.flatnonzero(~rough)
    b.add(lobes.LAMBERT, ctx.idx[flat], np.take(weight, flat, axis=1), normal=_rows(normal, flat), **_soften(ctx))
    on = np.flatnonzero(rough)
    if len(on):
        b.add(lobes.OREN_NAYAR, ctx.idx[on], np.take(weight, on, axis=1), normal=_rows(normal, on),
              rough=np.clip(roughness[on], 0.0, 1.0), c0=np.take(rho, on, axis=1), **_soften(ctx))


def _soften(ctx) -> dict:
    """Diffuse closures on a normal map are softened by the bump shadowing term, unless the material
    turns Bump Map Correction off (kernels.bsdf.closures)."""
    return {} if ctx.bump_map_correction or not ctx.normal_given else {"soften": ZERO}


def _rows(normal, sub):
    """A per-hit normal at hits sub (None stays None: the shading normal)."""
    return None if normal is None else tuple(np.take(c, sub) for c in normal)


def _translucent(c, ctx, w, b):
    if b is not None:
        b.add(lobes.TRANSLUCENT, ctx.idx, ctx.input(c, "Color") * w, normal=ctx.specular().normal_arg,
              **_soften(ctx))
    return Built()


def _transparent(c, ctx, w, b):
    if b is not None:
        b.add(lobes.TRANSPARENT, ctx.idx, np.maximum(ctx.input(c, "Color"), ZERO) * w)
    return Built()


def _sheen(c, ctx, w, b):
    if b is not None:
        rough = np.clip(ctx.input(c, "Roughness"), 0.0, 1.0)
        weight = ctx.input(c, "Color") * w
        albedo = sheen_albedo(ctx.mu(), rough)
        b.add(lobes.SHEEN, ctx.idx, weight, sample_weight=_sheen_sample_weight(weight, albedo),
              normal=ctx.normal_arg, rough=rough, **_soften(ctx))
    return Built()


def _sheen_sample_weight(weight, albedo):
    """Cycles' bsdf_sheen_setup scales a sheen closure's sample weight by the lobe's albedo toward the
    viewer (its colour weight too; Ember's lobe carries that factor in its evaluation instead): the lobe is
    picked in proportion to the light it reflects, and its albedo (Denoising Albedo, Diffuse Color) is
    weight x albedo. A closure whose albedo Cycles would drop gets 0 and is not made."""
    return (np.abs(sampling.channel_mean(np.asarray(weight, F32))) * albedo).astype(F32)


def _toon(c, ctx, w, b):
    """Toon BSDF: one diffuse or glossy toon closure on the node's normal (not tilted for specular
    reflection), weight colour x mix weight; the caustics switch drops the glossy one as a glossy closure."""
    if b is not None:
        glossy = c.option("component", "DIFFUSE") == "GLOSSY"
        color = ctx.input(c, "Color")
        if glossy:
            color = _times(color, _made(ctx))
        size, smooth = toon_angles(ctx.input(c, "Size"), ctx.input(c, "Smooth"))
        b.add(lobes.TOON_GLOSSY if glossy else lobes.TOON_DIFFUSE, ctx.idx, color * w, normal=ctx.normal_arg,
              size=size, smooth=smooth, **({} if glossy else _soften(ctx)))
    return Built()


def portal_weight(c: Closure, ctx: Context, w: np.ndarray) -> np.ndarray:
    """(3, n) a Ray Portal's closure weight, 0 where Cycles would not make it (below its cutoff)."""
    weight = ctx.input(c, "Color") * w
    return np.where(np.abs(weight.mean(axis=0)) >= CUTOFF, weight, ZERO).astype(F32)


def _portal(c, ctx, w, b):
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


def _hair(c, ctx, w, b):
    """Hair BSDF (Cycles' bsdf_hair_*_setup on a triangle): weight colour x mix weight, on the normal tilted
    for specular reflection; roughnesses clamped to [0.001, 1]. Its tangent is the Tangent input (normalised,
    the highlight shifted by -Offset), or unlinked the triangle's p2 - p0 (Cycles' dPdv, reversed on back
    faces) with no shift: one direction per triangle, in the order Blender lists its corners."""
    if b is not None:
        given = ctx.tangent(c, None, ctx.ns, anisotropic=False)
        if given is None:
            edge = ctx.hit.edges(ctx.idx)[1]
            sign = np.where(ctx.take(ctx.hit.backfacing), F32(-1.0), ONE)
            tangent = normalize_xyz(tuple(edge[:, k] * sign for k in range(3)))
            offset = ZERO
        else:
            tangent, offset = normalize_xyz(given), -ctx.input(c, "Offset")
        transmission = c.option("component", "Reflection") == "Transmission"
        b.add(lobes.HAIR_TRANSMISSION if transmission else lobes.HAIR_REFLECTION, ctx.idx, ctx.input(c, "Color") * w,
              normal=ctx.specular().normal_arg, hair_t=tangent, offset=offset,
              r1=np.clip(ctx.input(c, "RoughnessU"), F32(0.001), ONE),
              r2=np.clip(ctx.input(c, "RoughnessV"), F32(0.001), ONE))
    return Built()


def _emission(c, ctx, w, b):
    # Not clamped: Cycles emits what the nodes compute, negative values too (a node program's output).
    return Built(emission=ctx.input(c, "Color") * (ctx.input(c, "Strength") * w))


def _holdout(c, ctx, w, b):
    return Built(holdout=w.astype(F32))


# ---------------------------------------------------------------- microfacet nodes
def _glossy(c, ctx, w, b):
    if b is not None:
        color = _times(np.maximum(ctx.input(c, "Color"), ZERO), _made(ctx))
        alpha = np.square(np.clip(ctx.input(c, "Roughness"), 0.0, 1.0))
        aniso = np.clip(ctx.input(c, "Anisotropy"), -0.99, 0.99)
        ax, ay = mf.glossy_anisotropy(alpha, aniso)
        distribution = c.option("distribution", "MULTI_GGX")
        spec = ctx.specular()
        # Cycles rotates it about the closure's own normal.
        tangent = ctx.tangent(c, "Rotation", spec.ns, bool(np.any(ax != ay)))
        if distribution == "ASHIKHMIN_SHIRLEY":
            mf.add_ashikhmin_shirley(_with_tangent(b, ctx, tangent), spec, color, w, ax, ay)
        else:
            mf.add_glossy(_with_tangent(b, ctx, tangent), spec, color, w, ax, ay,
                          multiscatter=distribution == "MULTI_GGX", distribution=_distribution(c))
    return Built()


def _distribution(c):
    """The microfacet distribution of a node's `distribution` option: Beckmann, else GGX."""
    return mf.BECKMANN if c.option("distribution", "MULTI_GGX") == "BECKMANN" else mf.GGX


def _glass(c, ctx, w, b):
    if b is not None:
        color = np.maximum(ctx.input(c, "Color"), ZERO)
        alpha = np.square(np.clip(ctx.input(c, "Roughness"), 0.0, 1.0))
        ior = np.maximum(ctx.input(c, "IOR"), F32(1e-5))
        # Cycles zeroes the tint of a branch whose caustics are off (neither: no closure).
        mf.add_glass(b, ctx.specular(), w, alpha, ior, reflection_tint=_times(color, _made(ctx)),
                     transmission_tint=_times(color, _made(ctx, refractive=True)),
                     specular_tint=None, multiscatter=c.option("distribution", "MULTI_GGX") == "MULTI_GGX",
                     distribution=_distribution(c))
    return Built()


def _refraction(c, ctx, w, b):
    if b is not None:
        color = _times(ctx.input(c, "Color"), _made(ctx, refractive=True))
        alpha = np.square(ctx.input(c, "Roughness"))
        ior = np.maximum(ctx.input(c, "IOR"), F32(1e-5))
        mf.add_refraction(b, ctx.specular(), color * w, alpha, ior, distribution=_distribution(c))
    return Built()


def _metallic(c, ctx, w, b):
    if b is not None:
        alpha = np.square(np.clip(ctx.input(c, "Roughness"), 0.0, 1.0))
        ax, ay = mf.principled_anisotropy(alpha, np.clip(ctx.input(c, "Anisotropy"), 0.0, 1.0))
        multiscatter = c.option("distribution", "MULTI_GGX") == "MULTI_GGX"
        weight = np.broadcast_to(_times(w, _made(ctx)), (3, len(w)))
        spec = ctx.specular()
        b = _with_tangent(b, ctx, ctx.tangent(c, "Rotation", ctx.ns, bool(np.any(ax != ay))))
        if c.option("fresnel", "F82") == "PHYSICAL_CONDUCTOR":
            mf.add_conductor(b, spec, weight, ax, ay, np.maximum(ctx.input(c, "IOR"), ZERO),
                             np.maximum(ctx.input(c, "Extinction"), ZERO), multiscatter,
                             distribution=_distribution(c))
        else:
            mf.add_f82(b, spec, weight, ax, ay, np.clip(ctx.input(c, "Base Color"), 0.0, 1.0),
                       np.clip(ctx.input(c, "Edge Tint"), 0.0, 1.0), multiscatter, distribution=_distribution(c))
    return Built()


# ---------------------------------------------------------------- Principled BSDF
def _principled(c, ctx, w, b):
    """Cycles' Principled BSDF layer stack (module docstring); emission dimmed by the layers above it.
    Layers whose weight input is a constant 0 (_param_may_differ) are skipped: every hit's weight would be cut
    off anyway."""
    n = len(ctx.idx)
    get = lambda name: ctx.input(c, name)  # noqa: E731
    weight = np.broadcast_to(w, (3, n)).astype(F32)
    multiscatter = c.option("distribution", "MULTI_GGX") == "MULTI_GGX"
    # 0. Alpha: a transparent closure for what the surface lets through.
    if _param_may_differ(c, "Alpha", 1.0):
        alpha = np.clip(get("Alpha"), 0.0, 1.0)
        if b is not None:
            b.add(lobes.TRANSPARENT, ctx.idx, weight * (ONE - alpha))
        weight = weight * alpha
    # Glossy closures dropped by the caustics switch take no light from the layers below either (Cycles
    # skips their setup, layering included); refraction keeps its share (Context.caustics).
    made = _made(ctx)

    def glossy(mask):  # the hits of mask whose glossy closures the caustics switch keeps
        return np.flatnonzero(mask if made is None else mask & (made > 0))
    no_coat = not _param_may_differ(c, "Coat Weight", 0.0)
    coat_w = None if no_coat else np.maximum(get("Coat Weight"), ZERO)
    # The coat's normal: its Coat Normal input, else the node's Normal.
    coat = ctx if no_coat else ctx.with_normal(ctx.normal_input(c, "Coat Normal"))
    # 1. Sheen, on the normal partway to the coat's normal, by the coat's weight.
    sheen_w = np.maximum(get("Sheen Weight"), ZERO) if _param_may_differ(c, "Sheen Weight", 0.0) else None
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
                  sample_weight=_sheen_sample_weight(sheen_weight, albedo),
                  normal=_rows(sheen.normal_arg, has), rough=rough, **_soften(sheen))
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
    if _param_may_differ(c, "Emission Strength", 0.0):
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
    anisotropic = _with_tangent(b, ctx, ctx.tangent(c, "Anisotropic Rotation", ctx.ns, bool(np.any(ax != ay))))
    ior = np.maximum(get("IOR"), F32(1e-5))
    specular_tint = np.maximum(get("Specular Tint"), ZERO)
    # 4. Metal: F82-tint conductor.
    if _param_may_differ(c, "Metallic", 0.0):
        metallic = np.clip(get("Metallic"), 0.0, 1.0)
        has = glossy(metallic > CUTOFF)
        if len(has):
            mf.add_f82(anisotropic, spec, metallic[has] * np.take(weight, has, axis=1), ax[has], ay[has],
                       np.take(clamped, has, axis=1),
                       np.minimum(np.take(specular_tint, has, axis=1), ONE), multiscatter, sub=has)
        weight = weight * (ONE - metallic)
    # 5. Transmission: GGX glass, tinted by sqrt(base) through refraction.
    if _param_may_differ(c, "Transmission Weight", 0.0):
        transmission = np.clip(get("Transmission Weight"), 0.0, 1.0)
        has = np.flatnonzero(transmission > CUTOFF)
        if len(has):
            refracted = _made(ctx, refractive=True)
            mf.add_glass(b, spec, transmission[has] * np.take(weight, has, axis=1), alpha_r[has], ior[has],
                         reflection_tint=np.ones((3, len(has)), F32) * (ONE if made is None else made[has]),
                         transmission_tint=np.sqrt(np.take(clamped, has, axis=1)) *
                         (ONE if refracted is None else refracted[has]),
                         specular_tint=np.take(specular_tint, has, axis=1), multiscatter=multiscatter, sub=has)
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
    # Hits whose layers above left no weight (metal, glass) make no specular closure: skip their tables.
    has = glossy((eta != ONE) & np.any(weight != ZERO, axis=0))
    if len(has):
        albedo = mf.add_specular(anisotropic, spec, np.take(weight, has, axis=1), ax[has], ay[has], eta[has],
                                 f0[has] * np.take(specular_tint, has, axis=1), multiscatter, sub=has)
        sampling.put_columns(weight, has, layering_weight(albedo, np.take(weight, has, axis=1)))
    # 7. Diffuse (subsurface scattering is rendered as the diffuse it would be without its radius).
    if not _param_may_differ(c, "Subsurface Weight", 0.0):
        _diffuse_lobe(b, ctx, base * weight, np.clip(get("Diffuse Roughness"), 0.0, 1.0), clamped)
    else:
        sss = np.clip(get("Subsurface Weight"), 0.0, 1.0)
        b.add(lobes.LAMBERT, ctx.idx, clamped * sss * weight, normal=spec.normal_arg, **_soften(spec))
        _diffuse_lobe(b, ctx, base * (ONE - sss) * weight, np.clip(get("Diffuse Roughness"), 0.0, 1.0), clamped)
    return Built(emission=emission)


def layering_weight(layer_albedo: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Cycles' closure_layering_weight: what the layers below keep, weight * clamp01(1 - max(albedo / weight))."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(weight != 0, layer_albedo / np.where(weight != 0, weight, ONE), ZERO)
    return (weight * np.clip(ONE - ratio.max(axis=0), 0.0, 1.0)).astype(F32)


_BUILDERS = {"DIFFUSE": _diffuse, "PRINCIPLED": _principled, "GLOSSY": _glossy, "GLASS": _glass,
             "REFRACTION": _refraction, "METALLIC": _metallic, "SHEEN": _sheen, "TRANSLUCENT": _translucent,
             "TRANSPARENT": _transparent, "TOON": _toon, "PORTAL": _portal, "HAIR": _hair, "EMISSION": _emission,
             "HOLDOUT": _holdout}


# ---------------------------------------------------------------- what a closure may do, without hits
def _param_may_differ(c: Closure, name: str, neutral) -> bool:
    """Whether an input may be other than `neutral` at some hit (a batch's input, varying by piece, may)."""
    p = c.input(name)
    if p is None:
        return DEFAULTS[c.kind][name] != neutral
    if not isinstance(p, Param):
        return True
    return p.varies or tuple(p.value) not in ((neutral,), (neutral,) * 3)


def may_emit(c: Closure) -> bool:
    if c.kind == "EMISSION":
        return _param_may_differ(c, "Strength", 0.0) and _param_may_differ(c, "Color", 0.0)
    if c.kind == "PRINCIPLED":
        return _param_may_differ(c, "Emission Strength", 0.0) and _param_may_differ(c, "Emission Color", 0.0)
    return False


def emission_varies(c: Closure) -> bool:
    """Whether the emission depends on the point or the direction (textures; Principled layers)."""
    names = ("Color", "Strength") if c.kind == "EMISSION" else ("Emission Color", "Emission Strength")
    textured = any((p := c.input(k)) is not None and p.varies for k in names) or \
        any(p.varies for p, _ in c.factors)
    layered = c.kind == "PRINCIPLED" and any(
        _param_may_differ(c, k, v) for k, v in (("Alpha", 1.0), ("Sheen Weight", 0.0), ("Coat Weight", 0.0)))
    return textured or layered


def may_be_transparent(c: Closure) -> bool:
    return c.kind == "TRANSPARENT" or (c.kind == "PRINCIPLED" and _param_may_differ(c, "Alpha", 1.0))


def may_transmit(c: Closure) -> bool:
    """Whether rays may go through the closure's surface (refract, pass straight, or scatter to its back)."""
    if c.kind in ("GLASS", "REFRACTION", "TRANSLUCENT", "PORTAL", "HAIR"):
        return True
    return may_be_transparent(c) or (c.kind == "PRINCIPLED" and _param_may_differ(c, "Transmission Weight", 0.0))


def transparency(c: Closure, ctx: Context, w: np.ndarray) -> np.ndarray:
    """(3, n) straight-through transmittance of a Transparent node or a Principled BSDF's alpha."""
    if c.kind == "TRANSPARENT":
        return np.maximum(ctx.input(c, "Color"), ZERO) * w
    return np.broadcast_to((ONE - np.clip(ctx.input(c, "Alpha"), 0.0, 1.0)) * w, (3, len(w)))


def mean_emission(c: Closure, mean_param):
    """(3,) emission of a closure averaged over its textures (layers ignored), or None."""
    if not may_emit(c):
        return None
    if c.kind == "EMISSION":
        return np.maximum(mean_param(c.input("Color") or _const(c, "Color"), 3), 0) * \
            mean_param(c.input("Strength") or _const(c, "Strength"), 1)[0]
    return np.maximum(mean_param(c.input("Emission Color") or _const(c, "Emission Color"), 3), 0) * \
        mean_param(c.input("Emission Strength") or _const(c, "Emission Strength"), 1)[0]


def _const(c: Closure, name: str):
    return Param.of(DEFAULTS[c.kind][name])
