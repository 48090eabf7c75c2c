"""Data passes: what the film records about each pixel's first visible surface besides its colour, as
Cycles' data passes do (kernel/film/data_passes.h, scene/pass.cpp).

Two kinds, as in Cycles:
- FIRST: written by the pixel's sample 0 only and never averaged (Cycles' "overwrite" passes, unfiltered):
  Depth (distance along the camera's view axis; 1e10 where sample 0 saw no surface), Position,
  Object Index and Material Index (the pass indices; 0 for the background).
- MEAN: accumulated over every sample and divided by the sample count (misses count as 0): Normal (the
  closures' average normal, weighted by their sample weights), UV (u, v, 0 of the render UV map),
  Denoising Albedo (each closure's weight times its albedo estimate, summed; at most 1) and Denoising
  Normal (as Normal), read at the first surface hit.
"""
from __future__ import annotations

import numpy as np

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
}
BACKGROUND_DEPTH = 1e10


def channels(name: str) -> int:
    return PASSES[name][0]


def is_first(name: str) -> bool:
    return PASSES[name][1] == "FIRST"


def closure_albedo(closures, n_hits: int) -> np.ndarray:
    """(3, n) the hits' albedo: every closure's RGB weight scaled by its albedo estimate (its sample weight
    over its mean weight), summed per hit and clipped to [0, 1]."""
    out = np.zeros((3, n_hits), np.float32)
    if not len(closures):
        return out
    weight = np.asarray(closures.weight, np.float32)
    mean = weight.mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(mean > 0, np.asarray(closures.sw, np.float32) / mean, 0.0)
    for k in range(3):
        out[k] = np.bincount(closures.hit, weight[k] * scale, minlength=n_hits)
    return np.clip(out, 0.0, 1.0)


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
