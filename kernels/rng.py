"""The lecture's PCG2D random numbers, vectorised over paths.

Each path owns a uvec2 state (two uint32 arrays). `next_2d` is the slide's get_random_numbers: the
exact uint32 mixing, the state updated in place so it can be reused for the next 2D sample.
"""
from __future__ import annotations

import numpy as np

_MUL = np.uint32(1664525)
_INC = np.uint32(1013904223)
_GOLDEN = np.uint32(0x9E3779B9)
_FLOAT_ONE_BITS = np.uint32(0x3F800000)


def pcg2d(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The slide's mixing of a uvec2, as pure uint32 arithmetic (wraps mod 2^32 like GLSL)."""
    x = x * _MUL + _INC
    y = y * _MUL + _INC
    x += _MUL * y
    y += _MUL * x
    x ^= x >> np.uint32(16)
    y ^= y >> np.uint32(16)
    x += _MUL * y
    y += _MUL * x
    x ^= x >> np.uint32(16)
    y ^= y >> np.uint32(16)
    return x, y


def to_unit_float(bits: np.ndarray) -> np.ndarray:
    """uint32 -> float32 uniform in [0, 1) from the top 23 bits.

    The slide's `vec2(seed) * 2^-32` rounds values near 2^32 up to exactly 1.0 in float32; putting the
    bits in the mantissa keeps the result strictly below 1 and costs less.
    """
    return ((bits >> np.uint32(9)) | _FLOAT_ONE_BITS).view(np.float32) - np.float32(1.0)


def seed_paths(pixel_index: np.ndarray, sample_index: np.ndarray | int, user_seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Initial uvec2 state for each path.

    x follows the slide: pixel_index + 2^16 * sample pass. That alone repeats across passes once an
    image has more than 2^16 pixels, so y carries the pass again (times an odd constant, a bijection)
    plus the user seed: (x, y) is then distinct for every (pixel, pass) pair.
    """
    pixel_index = np.asarray(pixel_index, dtype=np.uint32)
    sample = np.asarray(sample_index, dtype=np.uint32)
    x = pixel_index + (sample << np.uint32(16))
    y = (sample * _GOLDEN + np.uint32(user_seed & 0xFFFFFFFF)) + np.zeros_like(pixel_index)
    return x.astype(np.uint32, copy=False), y.astype(np.uint32, copy=False)


class PathRng:
    """The per-path PCG2D state of a wave, updated in place by each draw."""

    def __init__(self, x: np.ndarray, y: np.ndarray):
        self.x = x
        self.y = y

    def next_2d(self) -> tuple[np.ndarray, np.ndarray]:
        """Two float32 arrays uniform in [0, 1), one pair per path."""
        self.x, self.y = pcg2d(self.x, self.y)
        return to_unit_float(self.x), to_unit_float(self.y)

    def take(self, idx: np.ndarray) -> "PathRng":
        return PathRng(np.take(self.x, idx), np.take(self.y, idx))


# The R2 sequence (Roberts 2018): point s is frac(s / g, s / g^2), g the plastic number 1.3247...; its
# steps as 32-bit fixed point, so that point s is an exact uint32 sum however large s grows.
_R2_STEP_X = np.uint32(3242174889)   # round(2^32 / g)
_R2_STEP_Y = np.uint32(2447445414)   # round(2^32 / g^2)
_DIMENSION_SALT = np.uint32(0x68E31DA4)


_BIT_MASKS = tuple((np.uint32(s), np.uint32(m)) for s, m in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F)))


def reverse_bits(x: np.ndarray) -> np.ndarray:
    """Bit reversal of uint32 values: the bytes swapped, then the bits of each byte reversed (in place on
    one copy: a third faster than five shift-and-mask rounds)."""
    x = np.asarray(x, np.uint32).byteswap()
    t = np.empty_like(x)
    for shift, mask in _BIT_MASKS:
        np.right_shift(x, shift, out=t)
        t &= mask
        x &= mask
        x <<= shift
        x |= t
    return x


def _laine_karras(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """The Laine-Karras permutation (Burley 2020's hash): each bit of x flipped by a hash of the bits
    below it, so applied to reversed bits it is an Owen scramble."""
    x = x ^ (x * np.uint32(0x3D20ADEA))
    x = x + seed
    x = x * ((seed >> np.uint32(16)) | np.uint32(1))
    x = x ^ (x * np.uint32(0x05526C56))
    return x ^ (x * np.uint32(0x53A22864))


def nested_uniform_scramble(index: np.ndarray, seed: np.ndarray, reversed_index: np.ndarray | None = None) -> np.ndarray:
    """Owen-scramble sample indices (Burley 2020: a Laine-Karras permutation on the reversed bits).
    Every power-of-two prefix 0..2^k-1 maps onto itself, shuffled differently for every seed.
    reversed_index: reverse_bits(index), when the caller has it."""
    return reverse_bits(_laine_karras(reverse_bits(index) if reversed_index is None else reversed_index, seed))


def stratified_2d(pixel_index: np.ndarray, sample_index: np.ndarray, user_seed: int, dimension: int,
                  reversed_index: np.ndarray | None = None):
    """Sample s of a pixel's low-discrepancy 2D sequence for one dimension pair. Returns two float32
    arrays in [0, 1). reversed_index: reverse_bits(sample_index), when the caller has it (the same for
    every dimension).

    The R2 sequence, rotated (Cranley-Patterson) by a PCG2D hash of (pixel, dimension, seed), and read
    in an order shuffled per pixel and dimension by an Owen scramble of the sample index. The rotation
    makes pixels independent; the shuffle makes dimension pairs independent (without it, every pair
    would step through the same sequence and the light choice would be tied to the point on the
    light); the first 2^k samples of each pair still cover the square evenly.
    """
    pixel_index = np.asarray(pixel_index, np.uint32)
    salt = np.uint32((dimension * int(_DIMENSION_SALT)) & 0xFFFFFFFF)
    rx, ry = pcg2d(pixel_index ^ salt,
                   np.zeros_like(pixel_index) + np.uint32((user_seed + dimension * 0x9E3779B9) & 0xFFFFFFFF))
    s = nested_uniform_scramble(np.asarray(sample_index, np.uint32), rx ^ (ry >> np.uint32(3)), reversed_index)
    return to_unit_float(rx + s * _R2_STEP_X), to_unit_float(ry + s * _R2_STEP_Y)
