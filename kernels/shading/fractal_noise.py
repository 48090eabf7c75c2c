"""Cycles' fractal noise over arrays of points (`kernel/svm/fractal_noise.h`): fBM, multifractal,
heterogeneous terrain, hybrid and ridged multifractal, octaves of snoise (kernels.shading.perlin), and
`fractal`, the Noise node's choice among them. Rounded as Cycles' compiled kernel rounds them (fma where
it fuses a multiply-add: see kernels.shading.perlin).

Detail is a loop count. A constant Detail runs the octaves with scalar bookkeeping; a per-hit Detail runs
to the largest count and evaluates each octave only at the hits that still need it. Every octave's
points go to Perlin in one call (perlin.noise_at).
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, HALF, I32, ONE, ZERO, fma
from .perlin import NOISE_SCALE, noise_at, perlin_wrapped, snoise


class _Octaves:
    """Detail as a loop: `count` octaves (Cycles: i = 0 ..= int(detail)) and the fractional remainder.

    Uniform detail: count is an int, `live(i)` is None (every hit) and rmd a scalar. Per-hit detail:
    live(i) is the mask of hits that run octave i, rmd an array."""

    def __init__(self, detail, n: int):
        d = np.asarray(detail, F32)
        if d.size == 1 or d.min() == d.max():
            d = F32(d.flat[0])
            self.counts = None
            self.count = max(int(np.trunc(d)) + 1, 0)
            self.rmd = d - np.floor(d)
        else:
            d = np.broadcast_to(d, (n,))
            self.counts = np.trunc(d).astype(I32) + I32(1)
            self.count = max(int(self.counts.max()), 0)
            self.rmd = d - np.floor(d)

    def live(self, i: int):
        return None if self.counts is None else self.counts > i

    def remainder(self):
        """Mask of hits with a fractional octave (None: all), or False when no hit has one."""
        if self.counts is None:
            return None if self.rmd != 0 else False
        has = self.rmd != 0
        return has if has.any() else False


def _on(live, p, fn=snoise):
    """fn(p) at the hits in mask `live` (None: all); 0 elsewhere."""
    if live is None:
        return fn(p)
    out = np.zeros(p[0].shape, F32)
    if live.any():
        out[live] = fn(tuple(c[live] for c in p))
    return out


def _snoise_plus(live, p, offset, raw=None):
    """snoise(p) + offset at the hits in `live`, with the scale's multiply fused into the add as
    Cycles' inlined snoise is compiled. raw: the wrapped unscaled Perlin there if already computed."""
    if raw is None:
        raw = _on(live, p, perlin_wrapped)
    return fma(NOISE_SCALE[len(p)], raw, offset)


def _keep(live, new, old):
    return new if live is None else np.where(live, new, old)


def _both(a, b):
    """Intersection of two masks where None means all hits."""
    if a is None:
        return b
    return a if b is None else a & b


def scaled(p, s):
    """The coordinates p, each times s."""
    return tuple(c * s for c in p)


def _prepare(p, detail, *params):
    """A fractal's arguments: p's components as float32 arrays of one 1-d shape, the octave plan, and
    the parameters as float32 (scalars or per-hit arrays), so that the bookkeeping rounds in float32."""
    comps = np.broadcast_arrays(*(np.atleast_1d(np.asarray(c, F32)) for c in p))
    p = tuple(np.ascontiguousarray(c) for c in comps)
    return p, _Octaves(detail, len(p[0])), tuple(np.asarray(x, F32) for x in params)


def _progression(p, lives, lacunarity):
    """The octaves' points when each octave scales the last one's by lacunarity (at its live hits):
    len(lives) + 1 coordinate tuples, the first p itself."""
    points = [p]
    for live in lives:
        points.append(tuple(_keep(live, c * lacunarity, c) for c in points[-1]))
    return points


def fbm(p, detail, roughness, lacunarity, normalize=True):
    """Fractal Brownian motion: octaves of snoise(lacunarity^i p) with amplitudes roughness^i."""
    p, octaves, (roughness, lacunarity) = _prepare(p, detail, roughness, lacunarity)
    lives = [octaves.live(i) for i in range(octaves.count)]
    has = octaves.remainder()
    fscales = [ONE]
    for live in lives:
        fscales.append(_keep(live, fscales[-1] * lacunarity, fscales[-1]))
    jobs = [(live, scaled(p, fscale)) for live, fscale in zip(lives, fscales)]
    if has is not False:
        jobs.append((has, scaled(p, fscales[-1])))
    noise = noise_at(jobs) if jobs else []
    amp, maxamp, total = ONE, ZERO, ZERO
    for live, t in zip(lives, noise):
        total = _keep(live, fma(t, amp, total), total)
        maxamp = _keep(live, maxamp + amp, maxamp)
        amp = _keep(live, amp * roughness, amp)
    total = np.broadcast_to(np.asarray(total, F32), p[0].shape)
    with np.errstate(divide="ignore", invalid="ignore"):     # detail < 0: Cycles divides 0 by 0 too
        out = HALF * total / maxamp + HALF if normalize else total
        if has is not False:
            total2 = fma(noise[-1], amp, total)
            if normalize:
                extra = HALF * total2 / (maxamp + amp) + HALF
            else:
                extra = total2
            out = _keep(has, fma(octaves.rmd, extra - out, out), out)
    return np.asarray(out, F32)


def multi_fractal(p, detail, roughness, lacunarity):
    """Multifractal: the product of (1 + roughness^i snoise(lacunarity^i p))."""
    p, octaves, (roughness, lacunarity) = _prepare(p, detail, roughness, lacunarity)
    lives = [octaves.live(i) for i in range(octaves.count)]
    has = octaves.remainder()
    points = _progression(p, lives, lacunarity)
    jobs = list(zip(lives, points)) + ([(has, points[-1])] if has is not False else [])
    noise = noise_at(jobs) if jobs else []
    value, pwr = ONE, ONE
    for live, t in zip(lives, noise):
        value = _keep(live, value * fma(pwr, t, ONE), value)
        pwr = _keep(live, pwr * roughness, pwr)
    if has is not False:
        value = _keep(has, value * fma(octaves.rmd * pwr, noise[-1], ONE), value)
    return np.broadcast_to(np.asarray(value, F32), p[0].shape).copy()


def hetero_terrain(p, detail, roughness, lacunarity, offset):
    """Heterogeneous terrain: octaves scaled by the value so far."""
    p, octaves, (roughness, lacunarity, offset) = _prepare(p, detail, roughness, lacunarity, offset)
    lives = [octaves.live(i) for i in range(1, octaves.count)]
    has = octaves.remainder()
    points = [p] + _progression(scaled(p, lacunarity), lives, lacunarity)
    jobs = [(None, p)] + list(zip(lives, points[1:])) + ([(has, points[-1])] if has is not False else [])
    raw = noise_at(jobs, scaled=False)
    pwr = roughness
    value = _snoise_plus(None, p, offset, raw[0])
    for live, q, r in zip(lives, points[1:], raw[1:]):
        value = _keep(live, fma(_snoise_plus(live, q, offset, r) * pwr, value, value), value)
        pwr = _keep(live, pwr * roughness, pwr)
    if has is not False:
        increment = _snoise_plus(has, points[-1], offset, raw[-1]) * pwr * value
        value = _keep(has, fma(octaves.rmd, increment, value), value)
    return np.asarray(value, F32)


def hybrid_multi_fractal(p, detail, roughness, lacunarity, offset, gain):
    """Hybrid additive/multiplicative multifractal: octaves weighted by gain times the last signal,
    stopping where the weight falls to 0.001."""
    p, octaves, (roughness, lacunarity, offset, gain) = _prepare(p, detail, roughness, lacunarity, offset, gain)
    n = len(p[0])
    pwr = np.full(n, ONE)
    value = np.zeros(n, F32)
    weight = np.full(n, ONE)
    threshold = F32(0.001)
    for i in range(octaves.count):
        live = _both(octaves.live(i), weight > threshold)
        if not live.any():
            break
        weight = _keep(live, np.minimum(weight, ONE), weight)
        signal = _snoise_plus(live, p, offset) * pwr
        pwr = _keep(live, pwr * roughness, pwr)
        value = _keep(live, fma(weight, signal, value), value)
        weight = _keep(live, weight * (gain * signal), weight)
        p = tuple(_keep(live, c * lacunarity, c) for c in p)
    has = octaves.remainder()
    if has is not False:
        has = _both(has, weight > threshold)
        w = np.minimum(weight, ONE)
        signal = _snoise_plus(has, p, offset) * pwr
        value = _keep(has, fma(octaves.rmd * w, signal, value), value)
    return value


def ridged_multi_fractal(p, detail, roughness, lacunarity, offset, gain):
    """Ridged multifractal: squared (offset - |snoise|) ridges, each octave weighted by the last.
    No fractional octave: Cycles ignores the fraction of Detail here."""
    p, octaves, (roughness, lacunarity, offset, gain) = _prepare(p, detail, roughness, lacunarity, offset, gain)
    lives = [octaves.live(i) for i in range(1, octaves.count)]
    points = _progression(p, lives, lacunarity)
    noise = noise_at([(None, p)] + list(zip(lives, points[1:])))
    pwr = roughness
    signal = offset - np.abs(noise[0])
    signal = signal * signal
    value = signal
    for live, t in zip(lives, noise[1:]):
        weight = np.clip(signal * gain, ZERO, ONE)
        s = offset - np.abs(t)
        s = s * s * weight
        signal = _keep(live, s, signal)
        value = _keep(live, fma(s, pwr, value), value)
        pwr = _keep(live, pwr * roughness, pwr)
    return np.asarray(value, F32)


def fractal(p, detail, roughness, lacunarity, offset, gain, noise_type="FBM", normalize=True):
    """Cycles' noise_select: the Noise node's fractal by Blender's noise_type identifier."""
    if noise_type == "FBM":
        return fbm(p, detail, roughness, lacunarity, normalize)
    if noise_type == "MULTIFRACTAL":
        return multi_fractal(p, detail, roughness, lacunarity)
    if noise_type == "HYBRID_MULTIFRACTAL":
        return hybrid_multi_fractal(p, detail, roughness, lacunarity, offset, gain)
    if noise_type == "RIDGED_MULTIFRACTAL":
        return ridged_multi_fractal(p, detail, roughness, lacunarity, offset, gain)
    if noise_type == "HETERO_TERRAIN":
        return hetero_terrain(p, detail, roughness, lacunarity, offset)
    raise ValueError(f"unknown noise_type {noise_type!r}")
