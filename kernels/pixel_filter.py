"""The film's pixel filter, importance-sampled as Cycles does (scene/film.cpp, util/math_cdf.*).

A filter is separable: the x and y offsets of a sample from its pixel's corner each come from one
inverse-CDF table of the filter's 1D profile, read with linear interpolation. Every sample then weighs 1
and counts in its own pixel only (no splatting into neighbours), so the image stays unbiased and
progressive while its pixels see the filter's footprint.

Profiles (x in pixels from the pixel centre, w the filter width):
    BOX              1 on |x| <= 1/2 (always one pixel wide, whatever w says)
    GAUSSIAN         exp(-8 x^2 / w^2) on |x| <= 1.5 w
    BLACKMAN_HARRIS  .35875 - .48829 cos v + .14128 cos 2v - .01168 cos 3v, v = 2 pi (x / 2w + 1/2),
                     on |x| <= w (Cycles' default, w = 1.5)
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

TABLE_SIZE = 1024  # Cycles' FILTER_TABLE_SIZE
# Cycles fills entries 0..1022 of its 1024-entry table symmetrically and leaves the last one at 0 (the TODO in
# scene/film.cpp), so its last 1/1023 of u lerps from the support's end back to 0. Ember keeps the 1023
# symmetric entries and reads them as a 1023-entry table: Cycles' distribution without the stray entry.
ENTRIES = TABLE_SIZE - 1


def profile(kind: str, x, width: float):
    """The unnormalised 1D filter value at offsets x (pixels from the pixel's centre); 0 outside."""
    x = np.abs(np.asarray(x, np.float64))
    if kind == "BOX":
        return np.where(x <= 0.5, 1.0, 0.0)
    if kind == "GAUSSIAN":
        return np.where(x <= 1.5 * width, np.exp(-8.0 * x * x / (width * width)), 0.0)
    if kind == "BLACKMAN_HARRIS":
        v = 2.0 * np.pi * (x / (2.0 * width) + 0.5)
        value = 0.35875 - 0.48829 * np.cos(v) + 0.14128 * np.cos(2 * v) - 0.01168 * np.cos(3 * v)
        return np.where(x <= width, value, 0.0)
    raise ValueError(f"unknown pixel filter {kind!r}")


def support(kind: str, width: float) -> float:
    """Half-width of the filter in pixels: samples land within this distance of the pixel's centre."""
    return {"BOX": 0.5, "GAUSSIAN": 1.5 * width, "BLACKMAN_HARRIS": width}[kind]


@lru_cache(maxsize=8)
def table(kind: str, width: float) -> np.ndarray:
    """(ENTRIES,) float32 offsets from the pixel's corner, increasing: entry i is the inverse CDF of the
    filter's profile at i / (ENTRIES - 1). Built as Cycles builds it: the CDF of the half profile over
    [0, support] at TABLE_SIZE - 1 points, inverted at (TABLE_SIZE - 1) / 2 + 1 levels and mirrored."""
    half = np.float32(support(kind, width))
    n = TABLE_SIZE - 1                               # points of the half profile's CDF
    x = half * np.arange(n, dtype=np.float32) / np.float32(n - 1)
    cdf = np.zeros(n + 1, np.float32)
    cdf[1:] = np.cumsum(np.abs(profile(kind, x, width)).astype(np.float32), dtype=np.float32)
    cdf = cdf / cdf[-1]
    cdf[-1] = 1.0
    half_size = (TABLE_SIZE - 1) // 2
    levels = np.arange(half_size + 1, dtype=np.float32) / np.float32(half_size)
    index = np.searchsorted(cdf, levels, side="right")          # first entry above the level
    inside = index < n
    index = np.minimum(index, n)
    lo = cdf[np.minimum(index, n - 1)]
    hi = cdf[np.minimum(index + 1, n)]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(inside, (levels - lo) / (hi - lo), 0.0).astype(np.float32)
    y = (index + t) / np.float32(TABLE_SIZE - 1) * (np.float32(2.0) * half)
    out = np.empty(ENTRIES, np.float32)
    out[half_size:half_size + len(y)] = np.float32(0.5) * (1 + y)
    out[half_size - np.arange(len(y))] = np.float32(0.5) * (1 - y)
    return out


def offsets(kind: str, width: float, u: np.ndarray) -> np.ndarray:
    """Offsets from the pixel's corner (0.5 is its centre) for uniform numbers u, float32: the table read
    with linear interpolation. BOX returns u itself: the same distribution, bit for bit the old jitter."""
    if kind == "BOX":
        return u
    values = table(kind, float(width))
    x = np.clip(u, 0, 1).astype(np.float32) * np.float32(ENTRIES - 1)
    index = np.minimum(x.astype(np.int32), ENTRIES - 1)
    t = x - index
    return (np.float32(1) - t) * values[index] + t * values[np.minimum(index + 1, ENTRIES - 1)]
