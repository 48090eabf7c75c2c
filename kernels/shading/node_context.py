"""What a closure node reads at the hits of one material in a wave: the Context (its inputs, the normal
its closures are made on, normal maps, tangents, the caustics switches), Blender 5.0's defaults of the
inputs a shader leaves out (DEFAULTS), and the helpers the node builders (bsdf_nodes, principled) share.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ..bsdf import lobes
from ..bsdf.thin_film import film_on
from ..paths import DIFFUSE as DIFFUSE_LABEL, DIFFUSE_ANCESTOR
from ..scene import Closure, NormalMap, Param, Tangent
from ..vec import F32, TWO_PI, ZERO, normalize_xyz
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
                   "Emission Color": WHITE, "Emission Strength": 0.0, "Thin Film Thickness": 0.0,
                   "Thin Film IOR": 1.33, "Subsurface Radius": (1.0, 0.2, 0.1), "Subsurface Scale": 0.05,
                   "Subsurface IOR": 1.4, "Subsurface Anisotropy": 0.0},
    "DIFFUSE": {"Color": GREY, "Roughness": 0.0},
    "GLOSSY": {"Color": GREY, "Roughness": 0.5, "Anisotropy": 0.0, "Rotation": 0.0},
    "GLASS": {"Color": WHITE, "Roughness": 0.0, "IOR": 1.5, "Thin Film Thickness": 0.0, "Thin Film IOR": 1.33},
    "REFRACTION": {"Color": WHITE, "Roughness": 0.0, "IOR": 1.5},
    "METALLIC": {"Base Color": (0.617, 0.577, 0.540), "Edge Tint": (0.695, 0.726, 0.770),
                 "IOR": (2.757, 2.513, 2.231), "Extinction": (3.867, 3.404, 3.009), "Roughness": 0.5,
                 "Anisotropy": 0.0, "Rotation": 0.0, "Thin Film Thickness": 0.0, "Thin Film IOR": 1.33},
    "SHEEN": {"Color": GREY, "Roughness": 0.5},
    "TRANSLUCENT": {"Color": GREY},
    "TOON": {"Color": GREY, "Size": 0.5, "Smooth": 0.0},
    # Unlinked, Position is the hit's (Cycles links it to the position) and Direction (0, 0, 0) the ray's.
    "PORTAL": {"Color": WHITE, "Position": UNSET, "Direction": (0.0, 0.0, 0.0)},
    "HAIR": {"Color": GREY, "Offset": 0.0, "RoughnessU": 0.1, "RoughnessV": 1.0},
    # Inputs by identifier (the lobe scales are "R lobe", "TT lobe", "TRT lobe"; Blender shows Reflection,
    # Transmission, Secondary Reflection).
    "PRINCIPLED_HAIR": {"Color": (0.017513, 0.005763, 0.002059), "Melanin": 0.8, "Melanin Redness": 1.0,
                        "Tint": WHITE, "Absorption Coefficient": (0.245531, 0.52, 1.365), "Aspect Ratio": 0.85,
                        "Roughness": 0.3, "Radial Roughness": 0.3, "Coat": 0.0, "IOR": 1.55,
                        "Offset": 0.034906585, "Random Color": 0.0, "Random Roughness": 0.0, "Random": 0.0,
                        "R lobe": 1.0, "TT lobe": 1.0, "TRT lobe": 1.0},
    "TRANSPARENT": {"Color": WHITE},
    "EMISSION": {"Color": WHITE, "Strength": 1.0},
    "HOLDOUT": {},
    "SUBSURFACE": {"Color": GREY, "Scale": 0.05, "Radius": (1.0, 0.2, 0.1), "IOR": 1.4, "Roughness": 1.0,
                   "Anisotropy": 0.0},
}


class BatchParam:
    """One input of closures batched across materials (shader._BatchClosure): a Param (or a normal map) per
    piece (lo, hi) of the batch's hits, with the piece's material (whose program its link names)."""
    __slots__ = ("pieces",)

    def __init__(self, pieces):
        self.pieces = pieces                     # (spec, lo, hi, material)


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

    def diffuse_ancestor(self):
        """(n,) bool: the paths at these hits had a diffuse bounce (Cycles' PATH_RAY_DIFFUSE_ANCESTOR); None where
        no path state is tracked (the integrator tracks it where a material has a Christensen-Burley closure)."""
        ray = getattr(self.hit, "ray", None)
        if ray is None or ray.lobes is None:
            return None
        return (np.take(ray.lobes[0], self.idx) & DIFFUSE_ANCESTOR) != 0

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
        if isinstance(spec, BatchParam):
            return self._batch_normal(spec)
        return self._normal(spec)

    def _batch_normal(self, spec: "BatchParam"):
        """A batch's normal input, material by material; the hits' own normal where a piece has none."""
        made = [(lo, hi, self._piece(lo, hi, m)._normal(p)) for p, lo, hi, m in spec.pieces]
        if all(n is None for _, _, n in made):
            return None
        out = tuple(np.array(c, F32) for c in self.hit_ns)
        for lo, hi, n in made:
            if n is not None:
                for k in range(3):
                    out[k][lo:hi] = n[k]
        return out

    def _piece(self, lo: int, hi: int, material: int) -> "Context":
        """This context's hits lo:hi, of one material."""
        view = copy.copy(self)
        view.idx, view.material, view._specular, view._shared = self.idx[lo:hi], material, None, {}
        view.wo, view.ns, view.hit_ns = (tuple(c[lo:hi] for c in x) for x in (self.wo, self.ns, self.hit_ns))
        return view

    def _normal(self, spec):
        if isinstance(spec, Param):  # a program's normal (a Bump, a Normal Map), or a constant one
            return normalize_xyz(tuple(self.shading.param(spec, self, 3)))
        if not isinstance(spec, NormalMap):
            return None
        color = self.shading.param(spec.color, self, 3)
        strength = self.shading.param(spec.strength, self, 1)
        frame = self._frame() if spec.space == "TANGENT" else None
        uneven = None if frame is None else self.shading.data.uneven_linear(self.take(self.hit.prim))
        return normals.normal_map(color, strength, spec.space, self.hit_ns, self.take(self.hit.backfacing), frame,
                                  spec.invert_green, uneven=uneven, object_frame=spec.object_frame)

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
                curve = self.on_curves()
                if curve is not None and valid is not self.ns:   # Cycles leaves a curve's normal as it is
                    valid = tuple(np.where(curve, a, b) for a, b in zip(self.ns, valid))
                if valid is not self.ns:
                    self._specular = self.with_normal(valid)
        return self._specular

    def on_curves(self):
        """(n,) bool: the hits on curves (interaction.SurfaceHit.shapes), or None where none is."""
        shapes = getattr(self.hit, "shapes", None)
        if shapes is None:
            return None
        curve = np.take(shapes.kind, self.idx) == 1
        return curve if curve.any() else None

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


# ---------------------------------------------------------------- what the node builders share
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


def with_tangent(b, ctx: Context, tangent):
    """b, handing `tangent` to the reflection closures added through it; b itself without a tangent."""
    return b if b is None or tangent is None else _TangentBuilder(b, ctx.idx, tangent)


def caustics_made(ctx: Context, refractive: bool = False):
    """(n,) float32: 1 where the context's glossy reflection (or, refractive, refraction) closures are made,
    0 where the caustics switch drops them (Context.caustics); None where they are made at every hit."""
    switches = ctx.caustics()
    if switches is None:
        return None
    ok = switches[1 if refractive else 0]
    return None if ok.all() else ok.astype(F32)


def times_made(a, made):
    """a times the caustics mask `made` of caustics_made (a itself where every closure is made)."""
    return a if made is None else a * made


def soften(ctx) -> dict:
    """Diffuse closures on a normal map are softened by the bump shadowing term, unless the material
    turns Bump Map Correction off (kernels.bsdf.bump)."""
    return {} if ctx.bump_map_correction or not ctx.normal_given else {"soften": ZERO}


def normal_rows(normal, sub):
    """A per-hit normal at hits sub (None stays None: the shading normal)."""
    return None if normal is None else tuple(np.take(c, sub) for c in normal)


def thin_film(c: Closure, ctx: Context, thickness: str, ior: str):
    """A closure's thin film at the context's hits: (thickness nm (n,), film IOR (n,), at least 1e-5 as
    Cycles clamps it), or None where no hit's film is thicker than Cycles' 0.1 nm cutoff."""
    if not param_may_differ(c, thickness, 0.0):
        return None
    t = ctx.input(c, thickness)
    if not np.any(film_on(t)):
        return None
    return t.astype(F32), np.maximum(ctx.input(c, ior), F32(1e-5)).astype(F32)


def film_rows(film, sub):
    """A thin film (thin_film) at the hits sub of its context."""
    return None if film is None else (film[0][sub], film[1][sub])


def param_may_differ(c: Closure, name: str, neutral) -> bool:
    """Whether an input may be other than `neutral` at some hit (a batch's input, varying by piece, may)."""
    p = c.input(name)
    if p is None:
        return DEFAULTS[c.kind][name] != neutral
    if not isinstance(p, Param):
        return True
    return p.varies or tuple(p.value) not in ((neutral,), (neutral,) * 3)
