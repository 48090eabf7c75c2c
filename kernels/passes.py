"""Data passes: what the film records about each pixel's first visible surface besides its colour, as
Cycles' data passes do (kernel/film/data_passes.h, scene/pass.cpp).

Two kinds, as in Cycles:
- FIRST: written by the pixel's sample 0 only and never averaged (Cycles' "overwrite" passes, unfiltered):
  Depth (distance along the camera's view axis; 1e10 where sample 0 saw no surface), Position,
  Object Index and Material Index (the pass indices; 0 for the background).
- MEAN: accumulated over every sample and divided by the sample count (misses count as 0): Normal (the
  closures' average normal, weighted by their sample weights), UV (u, v, 0 of the render UV map),
  Denoising Albedo and Denoising Normal, as Cycles' denoising features (kernel/film/denoising_passes.h):
  read at the first hit whose closures are not mostly specular (75% or more of the sample weight in
  closures of roughness^2 below 0.075^2: the path waits for the next bounce, its feature throughput
  multiplied by their albedo), the albedo summed over the diffuse-like closures (each closure's weight
  times its albedo estimate), the normal in camera space (x right, y up, z forward); where the path leaves
  to the world, the world's colour times that throughput. Albedo is clipped to [0, 1] for the denoiser.
- MIST: Cycles' mist, 1 minus the mean over samples of (1 - mist) x the camera ray's throughput at its first
  hit, mist = clamp((distance - start) / depth, 0, 1) ^ falloff (the world's Mist Pass settings); 1 where
  the camera sees the world.
- Emission and Environment (MEAN): what the camera sees of emitting surfaces and of the world directly
  (Environment even where a transparent film leaves it out of Combined), as Cycles' passes of those names.
- LIGHT: Cycles' Diffuse, Glossy and Transmission Direct and Indirect (kernel/film/light_passes.h): every
  contribution after the camera's first hit, split by the shares of the path's first bounce among the
  closure classes (diffuse-like; reflecting microfacets and glass seen from outside; the rest), direct when
  it lit the first hit. Read, as Cycles reads them, divided by the class's Color pass (the first hit's
  closure colours of that class): Combined = Emission + Environment + sum over classes of
  (Direct + Indirect) x Color.
- Vector (WEIGHTED): Cycles' motion vectors, in pixels: (previous - current) and (current - next) raster
  positions of the camera rays' first surface point (x right, y up), the object's and the camera's
  transforms one frame before and after; averaged over the samples that hit a surface.
- Shader AOVs ("aov:<name>:color" or ":value", MEAN): the AOV Output node of that name at the camera rays'
  first hit (0 where the material has none), averaged over samples.
- NOISE: an unbiased estimate of the variance of each pixel's mean: the squared difference between the
  mean of its odd-numbered samples and the mean of all (Cycles' adaptive sampling compares the same two);
  one estimate per pixel, so itself noisy (blur it to read it); 0 with fewer than two samples.
"""
from __future__ import annotations

import numpy as np

from .bsdf.closures import MICROFACET_LOBES, SINGULAR_LOBES, closure_albedos

# name -> (channels, kind)
PASSES = {
    "depth": (1, "FIRST"),
    "position": (3, "FIRST"),
    "object_index": (1, "FIRST"),
    "material_index": (1, "FIRST"),
    "normal": (3, "MEAN"),
    "uv": (3, "MEAN"),
    "denoising_albedo": (3, "MEAN"),
    "denoising_normal": (3, "MEAN"),
    "denoising_depth": (1, "MEAN"),
    "mist": (1, "MIST"),
    "emission": (3, "MEAN"),
    "environment": (3, "MEAN"),
    "noise": (3, "NOISE"),
    "vector": (4, "WEIGHTED"), "vector_weight": (1, "MEAN"),
    "diffuse_direct": (3, "LIGHT"), "diffuse_indirect": (3, "LIGHT"), "diffuse_color": (3, "MEAN"),
    "glossy_direct": (3, "LIGHT"), "glossy_indirect": (3, "LIGHT"), "glossy_color": (3, "MEAN"),
    "transmission_direct": (3, "LIGHT"), "transmission_indirect": (3, "LIGHT"), "transmission_color": (3, "MEAN"),
}
BACKGROUND_DEPTH = 1e10


CRYPTO_KINDS = ("object", "material", "asset")


def channels(name: str) -> int:
    if name.startswith("aov:"):  # Shader AOVs: "aov:<name>:color" (3) or "aov:<name>:value" (1)
        return 3 if name.endswith(":color") else 1
    return PASSES[name][0]


def is_first(name: str) -> bool:
    return kind(name) == "FIRST"


def kind(name: str) -> str:
    return "MEAN" if name.startswith("aov:") else PASSES[name][1]


def known(name: str) -> bool:
    return name in PASSES or (name.startswith("aov:") and name.endswith((":color", ":value")))


def denoising_features(closures, n_hits: int, fallback):
    """Per hit: (normal (3, n) sample-weighted, diffuse albedo (3, n), specular albedo (3, n), done (n,)):
    done where the diffuse-like closures hold more than a quarter of the sample weight (or there is no
    closure), as Cycles' film_write_denoising_features_surface decides."""
    normal = closure_normal(closures, n_hits, fallback)
    diffuse = np.zeros((3, n_hits), np.float32)
    specular = np.zeros((3, n_hits), np.float32)
    if not len(closures):
        return normal, diffuse, specular, np.ones(n_hits, bool)
    albedo = closure_albedos(closures)
    sw = np.asarray(closures.sw, np.float32)
    # Cycles' bsdf_get_specular_roughness_squared: alpha_x alpha_y for microfacet lobes, 0 for singular ones,
    # 1 for the rest (diffuse, sheen, toon).
    rough2 = np.broadcast_to(closures.ax, sw.shape) * np.broadcast_to(closures.ay, sw.shape)
    diffuse_like = ~(np.isin(closures.lobe, SINGULAR_LOBES) | (
        np.isin(closures.lobe, MICROFACET_LOBES) & ~(rough2 > np.float32(0.075 ** 2))))
    for k in range(3):
        diffuse[k] = np.bincount(closures.hit, np.where(diffuse_like, albedo[k], 0), minlength=n_hits)
        specular[k] = np.bincount(closures.hit, np.where(diffuse_like, 0, albedo[k]), minlength=n_hits)
    total = np.bincount(closures.hit, sw, minlength=n_hits)
    nonspecular = np.bincount(closures.hit, np.where(diffuse_like, sw, 0), minlength=n_hits)
    done = (total == 0) | (nonspecular * 4 > total)
    return normal, diffuse, specular, done


def closure_normal(closures, n_hits: int, fallback) -> np.ndarray:
    """(3, n) the closures' average normal per hit, weighted by sample weight; the shading normal where a
    hit has no closure."""
    out = np.stack([np.asarray(c, np.float32) for c in fallback]).copy()
    if not len(closures):
        return out
    sw = np.asarray(closures.sw, np.float32)
    summed = np.stack([np.bincount(closures.hit, closures.normal[k] * sw, minlength=n_hits) for k in range(3)])
    length = np.sqrt((summed * summed).sum(axis=0))
    ok = length > 0
    out[:, ok] = (summed[:, ok] / length[ok]).astype(np.float32)
    return out
