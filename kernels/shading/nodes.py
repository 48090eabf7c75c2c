"""Closure nodes -> closures, as Cycles' `svm_node_closure_bsdf` builds them (`kernel/svm/closure.h`).

`build` hands a closure node to the function of its kind (BUILDERS: the Principled BSDF in principled.py,
the Principled Hair BSDF in hair_nodes.py, the other nodes in bsdf_nodes.py), which reads the node's inputs at the hits of one material
(node_context.Context) and adds closures to the wave's ClosureBuilder (with the node's Mix Shader
weight), or returns emission and holdout. Inputs a shader leaves out take Blender 5.0's defaults
(node_context.DEFAULTS). And what a closure may do, asked without hits: emit, be transparent, transmit.
"""
from __future__ import annotations

import numpy as np

from ..scene import Closure, Param
from ..vec import ONE, ZERO
from . import bsdf_nodes
from .hair_nodes import principled_hair_bsdf
from .node_context import Built, Context, DEFAULTS, param_may_differ
from .principled import principled_bsdf


# Every closure node kind (kernels.scene.CLOSURE_KINDS) and the function that builds its closures.
BUILDERS = {"DIFFUSE": bsdf_nodes.diffuse_bsdf, "PRINCIPLED": principled_bsdf, "GLOSSY": bsdf_nodes.glossy_bsdf,
            "GLASS": bsdf_nodes.glass_bsdf, "REFRACTION": bsdf_nodes.refraction_bsdf,
            "METALLIC": bsdf_nodes.metallic_bsdf, "SHEEN": bsdf_nodes.sheen_bsdf,
            "TRANSLUCENT": bsdf_nodes.translucent_bsdf, "TRANSPARENT": bsdf_nodes.transparent_bsdf,
            "TOON": bsdf_nodes.toon_bsdf, "PORTAL": bsdf_nodes.ray_portal_bsdf, "HAIR": bsdf_nodes.hair_bsdf,
            "EMISSION": bsdf_nodes.emission, "HOLDOUT": bsdf_nodes.holdout,
            "SUBSURFACE": bsdf_nodes.subsurface_scattering, "PRINCIPLED_HAIR": principled_hair_bsdf}


def build(closure: Closure, ctx: Context, weight: np.ndarray, builder) -> Built:
    """Add the closure node's closures (weight (n,) from the Mix Shaders above it) to builder; builder
    None asks for emission and holdout only."""
    return BUILDERS[closure.kind](closure, ctx.for_node(closure), weight, builder)


# ---------------------------------------------------------------- what a closure may do, without hits
def may_emit(c: Closure) -> bool:
    if c.kind == "EMISSION":
        return param_may_differ(c, "Strength", 0.0) and param_may_differ(c, "Color", 0.0)
    if c.kind == "PRINCIPLED":
        return param_may_differ(c, "Emission Strength", 0.0) and param_may_differ(c, "Emission Color", 0.0)
    return False


def emission_varies(c: Closure) -> bool:
    """Whether the emission depends on the point or the direction (textures; Principled layers)."""
    names = ("Color", "Strength") if c.kind == "EMISSION" else ("Emission Color", "Emission Strength")
    textured = any((p := c.input(k)) is not None and p.varies for k in names) or \
        any(p.varies for p, _ in c.factors)
    layered = c.kind == "PRINCIPLED" and any(
        param_may_differ(c, k, v) for k, v in (("Alpha", 1.0), ("Sheen Weight", 0.0), ("Coat Weight", 0.0)))
    return textured or layered


def may_be_transparent(c: Closure) -> bool:
    return c.kind == "TRANSPARENT" or (c.kind == "PRINCIPLED" and param_may_differ(c, "Alpha", 1.0))


def may_transmit(c: Closure) -> bool:
    """Whether rays may go through the closure's surface (refract, pass straight, or scatter to its back)."""
    if c.kind in ("GLASS", "REFRACTION", "TRANSLUCENT", "PORTAL", "HAIR", "PRINCIPLED_HAIR"):
        return True
    return may_be_transparent(c) or (c.kind == "PRINCIPLED" and param_may_differ(c, "Transmission Weight", 0.0))


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
