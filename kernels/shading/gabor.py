"""The Gabor Texture node over arrays of hits, as Cycles evaluates it (`kernel/svm/gabor.h`).

    gabor_texture(vector, scale, frequency, anisotropy, orientation_2d, orientation_3d, gabor_type="2D")
        -> {"Value": (N,), "Phase": (N,), "Intensity": (N,)}

Sparse Gabor convolution: every unit cell holds 8 impulses at hashed centres with hashed ±1 weights; a hit
sums the Hann-windowed Gaussian-times-phasor kernels of the impulses within unit distance, over its 3^d
neighbour cells. The kernel's orientation is the node's, plus a hashed random angle scaled by isotropy
(1 - Anisotropy). Value is the phasor's imaginary part, Phase its angle, Intensity its length, normalised
by 6 standard deviations of the noise (Cycles' empirical constant).

Hashes (float bits of the cell, impulse seed 3i, 3i+1, 3i+2) depend on the cell only, so they are
computed once per distinct cell of the wave and gathered per hit: 4 (2D) or up to 6 (3D) Jenkins hashes
per impulse, which neighbouring hits share. What stays per hit is 9 (2D) or 27 (3D) cells x 8 impulses of
distance tests, and the kernel (exp, 2 cos, sin; 3D isotropic adds 4 trig) only for the impulses that
reach the hit (pi/9 of them in 2D, 4.19/27 in 3D). A wave spread over about as many cells as hits shares
nothing and pays the hashes per hit.
"""
from __future__ import annotations

import itertools

import numpy as np

from ..vec import F32, HALF, ONE, PI, TWO_PI, ZERO
from .hash import hash_float3_to_float, hash_float3_to_float2, hash_float4_to_float, \
    hash_float4_to_float2, hash_float4_to_float3

IMPULSES_COUNT = 8
MIN_FREQUENCY = F32(0.001)
# 6 standard deviations of the noise: sqrt(impulses * E[w^2] (= 1/2) * integral of the squared kernel)
# with the integral's limit for large frequencies: 1/4 in 2D, 1/(4 sqrt 2) in 3D.
NORMALIZATION_2D = F32(6.0) * np.sqrt(F32(IMPULSES_COUNT) * HALF * F32(0.25), dtype=F32)
NORMALIZATION_3D = F32(6.0) * np.sqrt(F32(IMPULSES_COUNT) * HALF * (ONE / (F32(4.0) * np.sqrt(F32(2.0)))),
                                      dtype=F32)
OUTPUTS = ("Value", "Phase", "Intensity")
DEFAULT_ORIENTATION_3D = (1.4142135, 1.4142135, 0.0)


def _param(x) -> np.ndarray:
    a = np.asarray(x, F32)
    return a.reshape(()) if a.size == 1 else a.reshape(-1)


def _take(a, idx):
    return a if a.ndim == 0 else a[idx]


def _distinct_cells(floor_cols):
    """The distinct cells among the hits' cells (d arrays (N,) of integral floats): (d arrays (U,), the
    (N,) index of each hit's cell). One cell's float bits come from one of its hits."""
    n = len(floor_cols[0])
    big = F32(1 << 20)
    if all(np.all(np.abs(c) < big) for c in floor_cols):
        key = np.zeros(n, np.int64)
        for c in floor_cols:          # 21 bits per axis: exact for |cell| < 2^20
            key = (key << 21) | (c.astype(np.int64) + (1 << 20))
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    else:
        bits = np.ascontiguousarray(np.stack(floor_cols, axis=1)).view(np.uint32)
        rows = bits.view(np.dtype((np.void, bits.shape[1] * 4))).ravel()
        _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    return [c[first] for c in floor_cols], inverse.reshape(-1)


def _kernel_envelope(dist_sq):
    """The Hann-windowed Gaussian of the kernel at squared distance dist_sq (< 1)."""
    hann = HALF + HALF * np.cos(PI * dist_sq)
    return np.exp(-PI * dist_sq) * hann


def _noise_2d(coords, frequency, isotropy, orientation):
    """The summed phasor (real, imaginary) at 2D coordinates."""
    floor = [np.floor(c) for c in coords]
    local = [c - f for c, f in zip(coords, floor)]
    cells, inverse = _distinct_cells(floor)
    n = len(coords[0])
    isotropic = isotropy.ndim > 0 or isotropy != 0
    total = [np.zeros(n, F32), np.zeros(n, F32)]
    for j, i in itertools.product((-1, 0, 1), repeat=2):
        cx, cy = cells[0] + F32(i), cells[1] + F32(j)
        px, py = local[0] - F32(i), local[1] - F32(j)
        cell_sum = [np.zeros(n, F32), np.zeros(n, F32)]
        for impulse in range(IMPULSES_COUNT):
            seed = F32(3 * impulse)
            centre = hash_float3_to_float2((cx, cy, seed + ONE))
            kx = px - centre[0][inverse]
            ky = py - centre[1][inverse]
            dist_sq = kx * kx + ky * ky
            near = np.flatnonzero(dist_sq < ONE)
            if len(near) == 0:
                continue
            cell_of = inverse[near]
            kx, ky, dist_sq = kx[near], ky[near], dist_sq[near]
            angle = _take(orientation, near)
            if isotropic:
                random = (hash_float3_to_float((cx, cy, seed)) - HALF) * PI
                angle = angle + random[cell_of] * _take(isotropy, near)
            f = _take(frequency, near)
            phase = TWO_PI * (kx * (f * np.cos(angle)) + ky * (f * np.sin(angle)))
            envelope = _kernel_envelope(dist_sq)
            negative = hash_float3_to_float((cx, cy, seed + F32(2.0)))[cell_of] < HALF
            envelope = np.where(negative, -envelope, envelope)
            cell_sum[0][near] += envelope * np.cos(phase)
            cell_sum[1][near] += envelope * np.sin(phase)
        total[0] += cell_sum[0]
        total[1] += cell_sum[1]
    return total


def _orientation_3d(orientation, isotropy, near, random_angles):
    """Kernel directions of impulses reaching hits `near`: the node's direction, its spherical angles
    moved by the impulse's random angles times isotropy (Cycles' compute_3d_orientation)."""
    direction, inclination, azimuth = orientation
    iso = _take(isotropy, near)
    incl = _take(inclination, near) + random_angles[0] * PI * iso
    azim = _take(azimuth, near) + random_angles[1] * PI * iso
    sin_incl = np.sin(incl)
    out = [sin_incl * np.cos(azim), sin_incl * np.sin(azim), np.cos(incl)]
    if iso.ndim > 0 and not np.all(iso != 0):
        fixed = iso == 0
        out = [np.where(fixed, _take(c, near), o) for c, o in zip(direction, out)]
    return out


def _noise_3d(coords, frequency, isotropy, orientation):
    floor = [np.floor(c) for c in coords]
    local = [c - f for c, f in zip(coords, floor)]
    cells, inverse = _distinct_cells(floor)
    n = len(coords[0])
    isotropic = isotropy.ndim > 0 or isotropy != 0
    total = [np.zeros(n, F32), np.zeros(n, F32)]
    for k, j, i in itertools.product((-1, 0, 1), repeat=3):
        cell = (cells[0] + F32(i), cells[1] + F32(j), cells[2] + F32(k))
        p = (local[0] - F32(i), local[1] - F32(j), local[2] - F32(k))
        cell_sum = [np.zeros(n, F32), np.zeros(n, F32)]
        for impulse in range(IMPULSES_COUNT):
            seed = F32(3 * impulse)
            centre = hash_float4_to_float3(cell + (seed + ONE,))
            kp = [pc - cc[inverse] for pc, cc in zip(p, centre)]
            dist_sq = (kp[0] * kp[0] + kp[1] * kp[1]) + kp[2] * kp[2]
            near = np.flatnonzero(dist_sq < ONE)
            if len(near) == 0:
                continue
            cell_of = inverse[near]
            kp = [c[near] for c in kp]
            dist_sq = dist_sq[near]
            if isotropic:
                angles = [a[cell_of] for a in hash_float4_to_float2(cell + (seed,))]
                direction = _orientation_3d(orientation, isotropy, near, angles)
            else:
                direction = [_take(c, near) for c in orientation[0]]
            f = _take(frequency, near)
            phase = TWO_PI * ((kp[0] * (f * direction[0]) + kp[1] * (f * direction[1]))
                              + kp[2] * (f * direction[2]))
            envelope = _kernel_envelope(dist_sq)
            negative = hash_float4_to_float(cell + (seed + F32(2.0),))[cell_of] < HALF
            envelope = np.where(negative, -envelope, envelope)
            cell_sum[0][near] += envelope * np.cos(phase)
            cell_sum[1][near] += envelope * np.sin(phase)
        total[0] += cell_sum[0]
        total[1] += cell_sum[1]
    return total


def _base_orientation_3d(orientation):
    """The node's direction normalised, with its inclination and signed azimuth."""
    o = np.asarray(orientation, F32).reshape(-1, 3)
    x, y, z = (np.ascontiguousarray(o[:, k]) for k in range(3))
    with np.errstate(invalid="ignore", divide="ignore"):
        length = np.sqrt((x * x + y * y) + z * z)
        x, y, z = x / length, y / length, z / length
        inclination = np.arccos(z)
        azimuth = np.where(y < ZERO, -ONE, ONE) * np.arccos(x / np.sqrt(x * x + y * y))
    squeeze = (lambda a: a.reshape(())) if len(o) == 1 else (lambda a: a)
    return [squeeze(x), squeeze(y), squeeze(z)], squeeze(inclination), squeeze(azimuth)


def gabor_texture(vector=0.0, scale=5.0, frequency=2.0, anisotropy=1.0, orientation_2d=np.pi / 4,
                  orientation_3d=DEFAULT_ORIENTATION_3D, *, gabor_type: str = "2D", outputs=None) -> dict:
    """Cycles' Gabor Texture at N hits.

    vector : (N, 3) float32 (or a constant (3,)); scale, frequency, anisotropy, orientation_2d (socket
        "Orientation 2D"): (N,) float32 or constants; orientation_3d (socket "Orientation 3D"): (N, 3) or
        a constant (3,). Defaults are Blender's.
    gabor_type : "2D" (x, y only) or "3D".
    outputs : a subset of OUTPUTS to return (default all three; they cost the same noise).
    """
    if gabor_type not in ("2D", "3D"):
        raise ValueError(f"unknown Gabor type {gabor_type!r}")
    d = 2 if gabor_type == "2D" else 3
    vec = np.asarray(vector, F32)
    vec = np.broadcast_to(vec, (1, 3)) if vec.size == 1 else vec.reshape(-1, 3)
    scale, frequency, anisotropy = _param(scale), _param(frequency), _param(anisotropy)
    isotropy = ONE - np.clip(anisotropy, ZERO, ONE)
    frequency = np.maximum(MIN_FREQUENCY, frequency)
    if d == 2:
        orientation = _param(orientation_2d)
        o3_size = 1
    else:
        orientation = _base_orientation_3d(orientation_3d)
        o3_size = orientation[1].size
    sizes = (len(vec), scale.size, frequency.size, isotropy.size, o3_size, orientation.size if d == 2 else 1)
    n = max((s for s in sizes if s != 1), default=1)
    wanted = OUTPUTS if outputs is None else outputs
    if n == 0:
        return {name: np.zeros(0, F32) for name in wanted}
    coords = [np.ascontiguousarray(np.broadcast_to(vec[:, k] * scale, (n,)), F32) for k in range(d)]

    if d == 2:
        # An anisotropic kernel keeps the node's angle: base + random * 0, with the + 0 kept (-0 -> +0).
        if isotropy.ndim == 0 and isotropy == 0:
            orientation = orientation + ZERO
        real, imag = _noise_2d(coords, frequency, isotropy, orientation)
        normalization = NORMALIZATION_2D
    else:
        real, imag = _noise_3d(coords, frequency, isotropy, orientation)
        normalization = NORMALIZATION_3D

    result = {}
    if "Value" in wanted:
        result["Value"] = (imag / normalization) * HALF + HALF
    if "Phase" in wanted:
        result["Phase"] = (np.arctan2(imag, real) + PI) / TWO_PI
    if "Intensity" in wanted:
        result["Intensity"] = np.sqrt(real * real + imag * imag) / normalization
    return result
