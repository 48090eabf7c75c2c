"""The texture nodes built on Cycles' Perlin noise, over arrays of hits: Noise, White Noise, Wave
(`kernel/svm/noisetex.h`, `white_noise.h`, `wave.h`).

The results are bit-exact with Cycles' x86-64 AVX2 CPU kernel as Blender 5.0 ships it (probed: see
tests/test_nodes_noise.py), their noise also as Blender 5.3's kernel rounds it (`cycles_version`: see
kernels.shading.perlin). The one exception is the Wave's sine, within an ulp of glibc's sinf.

The node functions take sockets as the program runner passes them: a float socket (N,) or a constant
(Python float, 0-d or length-1 array), a vector (N, 3) or a constant (3,); node options are keywords with
Blender's enum identifiers (`dimensions="3D"`, `noise_type="FBM"`, `wave_type="BANDS"`, ...). They return
{output identifier: (N,) or (N, 3) float32}. The Noise node's distortion and its Color's channels go to
Perlin (or the fractal) in one call each, as every octave's points do.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..vec import F32, HALF, HALF_PI, INV_2PI, ONE, ZERO, fma
from . import hash as H
from .fractal_noise import fbm, fractal, scaled
from .perlin import cycles_rounding, noise_at

DIMENSIONS = {"1D": 1, "2D": 2, "3D": 3, "4D": 4}


# ---- Noise Texture node (noisetex.h) --------------------------------------------------------------

@lru_cache(maxsize=None)
def random_offset(seed: float, d: int) -> tuple:
    """Cycles' random_float{,2,3,4}_offset(seed): a constant per-axis shift in [100, 200]."""
    if d == 1:
        h = (H.hash_float_to_float(F32(seed))[0],)
    else:
        h = tuple(H.hash_float2_to_float((F32(seed), F32(axis)))[0] for axis in range(d))
    return tuple(F32(100.0) + x * F32(100.0) for x in h)


def _shift(p, seed: float):
    return tuple(c + o for c, o in zip(p, random_offset(seed, len(p))))


def _vector(v):
    """A vector socket as (x, y, z) component arrays."""
    v = np.asarray(v, F32).reshape(-1, 3)
    return v[:, 0], v[:, 1], v[:, 2]


def _hit_count(vector, *floats) -> int:
    """N: the hits the node runs at, from whichever input is per hit (1 when all are constants)."""
    sizes = {len(np.asarray(vector).reshape(-1, 3))} | {np.size(f) for f in floats}
    per_hit = sizes - {1}
    return per_hit.pop() if per_hit else 1


def _coords(vector, w, d: int, n: int):
    """The node's coordinates for its dimension count, each component a float32 (n,) array."""
    x, y, z = _vector(vector)
    w = np.asarray(w, F32)
    comps = {1: (w,), 2: (x, y), 3: (x, y, z), 4: (x, y, z, w)}[d]
    return tuple(np.ascontiguousarray(np.broadcast_to(c, (n,))) for c in comps)


# Which axes' p + snoise * distortion Cycles' compiled kernel fuses (found by probing it bit-exactly):
# 1D is scalar code; 2D's float2 is scalar too but only x contracts; 3D and 4D add a SIMD vector.
_FUSED_DISTORTION = {1: (True,), 2: (True, False), 3: (False,) * 3, 4: (False,) * 4}


def _distort(c, s, distortion, d: int, axis: int):
    """Distortion along one axis: c + s * distortion, rounded as Cycles rounds it."""
    return fma(s, distortion, c) if _FUSED_DISTORTION[d][axis] else c + s * distortion


def noise_texture(vector, w=0.0, scale=5.0, detail=2.0, roughness=0.5, lacunarity=2.0, offset=0.0,
                  gain=1.0, distortion=0.0, *, dimensions="3D", noise_type="FBM", normalize=True,
                  outputs=("Fac", "Color"), cycles_version=None):
    """The Noise Texture node: {"Fac": (N,), "Color": (N, 3)} (Color costs two more fractals), rounded as
    the Cycles of Blender `cycles_version` (cycles_rounding)."""
    with cycles_rounding(cycles_version):
        return _noise_texture(vector, w, scale, detail, roughness, lacunarity, offset, gain, distortion,
                              dimensions, noise_type, normalize, outputs)


def _noise_texture(vector, w, scale, detail, roughness, lacunarity, offset, gain, distortion, dimensions,
                   noise_type, normalize, outputs):
    d = DIMENSIONS[dimensions]
    n = _hit_count(vector, w, scale, detail, roughness, lacunarity, offset, gain, distortion)
    if n == 0:
        return {"Fac": np.zeros(0, F32), "Color": np.zeros((0, 3), F32)}
    scale = np.asarray(scale, F32)
    p = tuple(c * scale for c in _coords(vector, w, d, n))
    detail = np.fmin(np.fmax(np.asarray(detail, F32), ZERO), F32(15.0))   # NaN: 0, as Cycles' clamp
    roughness = np.maximum(np.asarray(roughness, F32), ZERO)
    lacunarity, offset, gain = (np.asarray(x, F32) for x in (lacunarity, offset, gain))
    distortion = np.asarray(distortion, F32)
    if distortion.any():
        # Cycles skips this where distortion is 0; adding 0 * snoise leaves p unchanged all the same.
        shifted = noise_at([(None, _shift(p, axis)) for axis in range(d)])
        p = tuple(_distort(c, s, distortion, d, axis) for axis, (c, s) in enumerate(zip(p, shifted)))
    params = (detail, roughness, lacunarity, offset, gain)
    options = (noise_type, normalize)
    if "Color" not in outputs:
        return {"Fac": fractal(p, *params, *options)} if "Fac" in outputs else {}
    # The colour's channels are the Fac and two more fractals at shifted points (the distortion used
    # seeds 0 .. d-1, the colour takes the next two): one fractal over the three point sets end to end.
    seed = d
    points = [p, _shift(p, seed), _shift(p, seed + 1)]
    stacked = tuple(np.concatenate(axis) for axis in zip(*points))
    params = tuple(np.tile(x, 3) if x.size > 1 else x for x in params)
    channels = fractal(stacked, *params, *options).reshape(3, n)
    result = {"Fac": channels[0]} if "Fac" in outputs else {}
    result["Color"] = np.ascontiguousarray(channels.T)
    return result


# ---- White Noise Texture node (white_noise.h) -----------------------------------------------------

_WHITE_VALUE = {1: lambda k: H.hash_float_to_float(k[0]), 2: H.hash_float2_to_float,
                3: H.hash_float3_to_float, 4: H.hash_float4_to_float}
_WHITE_COLOR = {1: lambda k: H.hash_float_to_float3(k[0]), 2: H.hash_float2_to_float3,
                3: H.hash_float3_to_float3, 4: H.hash_float4_to_float3}


def white_noise_texture(vector, w=0.0, *, dimensions="3D", outputs=("Value", "Color")):
    """The White Noise node: hashes of the input's float bits. {"Value": (N,), "Color": (N, 3)}."""
    d = DIMENSIONS[dimensions]
    k = _coords(vector, w, d, _hit_count(vector, w))
    result = {}
    if "Value" in outputs:
        result["Value"] = _WHITE_VALUE[d](k)
    if "Color" in outputs:
        result["Color"] = np.stack(_WHITE_COLOR[d](k), axis=1)
    return result


# ---- Wave Texture node (wave.h) -------------------------------------------------------------------

_RING_AXES = {"X": (1, 2), "Y": (0, 2), "Z": (0, 1), "SPHERICAL": (0, 1, 2)}
_BAND_AXIS = {"X": 0, "Y": 1, "Z": 2}


def _sinf(x):
    """float32 sine via float64, correctly rounded: within an ulp of the glibc sinf Cycles calls."""
    return np.sin(x.astype(np.float64)).astype(F32)


def wave(vector, scale, distortion, detail, detail_scale, detail_roughness, phase, *, wave_type="BANDS",
         bands_direction="X", rings_direction="X", wave_profile="SIN"):
    """Cycles' svm_wave(co * scale, ...) at vector = (x, y, z) -> Fac (N,).

    Rounded as Cycles' kernel is compiled: co * scale + 1e-6 and the distortion's multiply-add are
    fused, the division by 2 pi is a multiplication by its reciprocal (-freciprocal-math)."""
    scale, distortion, detail_scale, detail_roughness, phase = (
        np.asarray(x, F32) for x in (scale, distortion, detail_scale, detail_roughness, phase))
    # Cycles nudges p off unit coordinates, where the bands would sit on their discontinuities.
    p = tuple(fma(c, scale, F32(0.000001)) * F32(0.999999) for c in vector)
    if wave_type == "BANDS":
        if bands_direction == "DIAGONAL":
            n = (p[0] + p[1] + p[2]) * F32(10.0)
        else:
            n = p[_BAND_AXIS[bands_direction]] * F32(20.0)
    elif wave_type == "RINGS":
        squares = [p[a] * p[a] for a in _RING_AXES[rings_direction]]
        n = np.sqrt(sum(squares[1:], squares[0])) * F32(20.0)
    else:
        raise ValueError(f"unknown wave_type {wave_type!r}")
    n += phase
    if distortion.any():
        f = fbm(scaled(p, detail_scale), detail, detail_roughness, F32(2.0), True)
        n = fma(distortion, f * F32(2.0) - ONE, n)
    if wave_profile == "SIN":
        return HALF + HALF * _sinf(n - HALF_PI)
    n *= INV_2PI
    if wave_profile == "SAW":
        return n - np.floor(n)
    if wave_profile == "TRI":
        return np.abs(n - np.floor(n + HALF)) * F32(2.0)
    raise ValueError(f"unknown wave_profile {wave_profile!r}")


def wave_texture(vector, scale=5.0, distortion=0.0, detail=2.0, detail_scale=1.0, detail_roughness=0.5,
                 phase_offset=0.0, *, wave_type="BANDS", bands_direction="X", rings_direction="X",
                 wave_profile="SIN", cycles_version=None):
    """The Wave Texture node: {"Color": (N, 3) grey, "Fac": (N,)}, its noise rounded as the Cycles of
    Blender `cycles_version` (cycles_rounding)."""
    n = _hit_count(vector, scale, distortion, detail, detail_scale, detail_roughness, phase_offset)
    if n == 0:
        return {"Color": np.zeros((0, 3), F32), "Fac": np.zeros(0, F32)}
    with cycles_rounding(cycles_version):
        fac = wave(_coords(vector, 0.0, 3, n), scale, distortion, detail, detail_scale, detail_roughness,
                   phase_offset, wave_type=wave_type, bands_direction=bands_direction,
                   rings_direction=rings_direction, wave_profile=wave_profile)
    return {"Color": np.repeat(fac[:, None], 3, axis=1), "Fac": fac}
