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


def keyed_uniforms(seeds, k: int, salt: int = 0):
    """Two uniform float32 numbers per path for draw k of the decision `salt`, hashed from keys (x, y) (the
    paths' PCG2D states, paths.ray_keys) without advancing any stream: media collisions, shader nodes that
    trace rays. k may be an integer array that broadcasts against the keys ((K, 1): K draws of every path at
    once, each the same as drawn alone)."""
    x, y = seeds
    key = np.uint32((k * 0x9E3779B9 + salt * 0x85EBCA6B) & 0xFFFFFFFF)
    a, b = pcg2d(x ^ key, y + np.uint32((k + 0x68E31DA4 * (salt + 1)) & 0xFFFFFFFF))
    return to_unit_float(a), to_unit_float(b)


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


_SUPERSET_STEPS = tuple((np.uint32(1 << b), np.uint32(m))
                        for b, m in enumerate((0x55555555, 0x33333333, 0x0F0F0F0F, 0x00FF00FF, 0x0000FFFF)))


def sobol_y_reversed(index: np.ndarray) -> np.ndarray:
    """reverse_bits of the second Sobol dimension at uint32 indices, without tables: its generator matrix
    is Pascal's triangle mod 2, whose entry (i, j) is 1 where the bits of i are a subset of those of j
    (Lucas), so bit i of the result is the xor of the index's bits j over the supersets j of i: five
    shift-and-xor steps, one per bit of the position. Equal to the dimension built from its direction numbers
    (tests/test_rng.py), four times faster than reading it from two 16-bit tables."""
    x = np.asarray(index, np.uint32)
    for shift, mask in _SUPERSET_STEPS:
        x = x ^ ((x >> shift) & mask)
    return x


def _laine_karras(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """The Laine-Karras permutation (Burley 2020's hash): each bit of x flipped by a hash of the bits
    below it, so applied to reversed bits it is an Owen scramble."""
    x = x ^ (x * np.uint32(0x3D20ADEA))
    x = x + seed
    x = x * ((seed >> np.uint32(16)) | np.uint32(1))
    x = x ^ (x * np.uint32(0x05526C56))
    return x ^ (x * np.uint32(0x53A22864))


_EVEN_BITS = np.uint32(0x55555555)


def _laine_karras_base4(x: np.ndarray, seed) -> np.ndarray:
    """The Laine-Karras hash on base-4 digits (pairs of bits): each digit permuted by a hash of the
    digits below it, so applied to reversed digits it is a base-4 Owen scramble (psychopath.io, 2022:
    Owen-scrambling-based dithered blue noise, as Cycles' blue-noise pattern uses)."""
    one = np.uint32(1)
    x = x ^ (x * np.uint32(0x3D20ADEA))
    x = x ^ ((x >> one) & (x << one) & _EVEN_BITS)
    x = x + seed
    x = x * ((seed >> np.uint32(16)) | one)
    x = x ^ ((x >> one) & (x << one) & _EVEN_BITS)
    x = x ^ (x * np.uint32(0x05526C56))
    return x ^ (x * np.uint32(0x53A22864))


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """The low 16 bits of v moved to the even bit positions (bit i to bit 2i)."""
    v = v & np.uint32(0xFFFF)
    for shift, mask in ((8, 0x00FF00FF), (4, 0x0F0F0F0F), (2, 0x33333333), (1, 0x55555555)):
        v = (v ^ (v << np.uint32(shift))) & np.uint32(mask)
    return v


def morton_2d(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The Morton (Z-order) code of pixel (x, y): x's bits at the odd positions, y's at the even ones."""
    return (_spread_bits(np.asarray(x, np.uint32)) << np.uint32(1)) | _spread_bits(np.asarray(y, np.uint32))


def blue_noise_offsets(x: np.ndarray, y: np.ndarray, user_seed: int) -> np.ndarray:
    """Each pixel's place along the one sequence all pixels share (Cycles' blue-noise pattern,
    kernel/sample/pattern.h): its Morton code, Owen-scrambled in base 4. Pixels of every aligned 2^k x 2^k
    square of the image get one aligned block of 4^k places, so their samples together form one aligned
    block of the sequence: a finer net than each pixel's alone, and errors that are blue noise."""
    seed = pcg2d(np.array([user_seed & 0xFFFFFFFF], np.uint32) ^ np.uint32(0x2C1B3C6D),
                 np.array([0x297A2D39], np.uint32))[0]
    return reverse_bits(_laine_karras_base4(reverse_bits(morton_2d(x, y)), seed))


def nested_uniform_scramble(index: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Owen-scramble sample indices (Burley 2020: a Laine-Karras permutation on the reversed bits).
    Every power-of-two prefix 0..2^k-1 maps onto itself, shuffled differently for every seed."""
    return reverse_bits(_laine_karras(reverse_bits(index), seed))


def stratified_2d(pixel_index: np.ndarray, sample_index: np.ndarray, user_seed: int, dimension: int,
                  reversed_index: np.ndarray | None = None):
    """Sample s of a pixel's low-discrepancy 2D sequence for one dimension pair. Returns two float32
    arrays in [0, 1). reversed_index: reverse_bits(sample_index), when the caller has it (it is the same
    for every dimension).

    Owen-scrambled Sobol, shuffled (Burley 2020, "Practical Hash-based Owen Scrambling"), as Cycles'
    Sobol-Burley pattern: the sample index is Owen-scrambled per pixel and dimension (a shuffle that
    keeps every aligned block of 2^k indices together, so each prefix of 2^k samples is still a
    (0, k, 2)-net), and each coordinate of the Sobol point is Owen-scrambled with its own seed. The
    shuffle makes dimension pairs independent (without it the light choice would be tied to the point on
    the light), the scrambles make pixels independent. Against the R2 sequence rotated per pixel, used
    before: direct light from an HDRI 180x less variance per 64 samples at a point, a pixel on an edge
    1.7x less.

    Computed with three bit reversals instead of seven, the same numbers: Sobol's x is the reversed
    index, so the shuffle's last reversal and x's cancel, and so do x's and its scramble's first; y's
    scramble starts from its reversed value (sobol_y_reversed).

    pixel_index may be a single value that every path shares (the blue-noise layout: samples.sample_strata),
    whose scrambles are then computed once.
    """
    pixel_index = np.asarray(pixel_index, np.uint32)
    salt = np.uint32((dimension * int(_DIMENSION_SALT)) & 0xFFFFFFFF)
    rx, ry = pcg2d(pixel_index ^ salt,
                   np.zeros_like(pixel_index) + np.uint32((user_seed + dimension * 0x9E3779B9) & 0xFFFFFFFF))
    if reversed_index is None:
        reversed_index = reverse_bits(np.asarray(sample_index, np.uint32))
    x_sobol = _laine_karras(reversed_index, rx ^ (ry >> np.uint32(3)))   # = reverse(shuffled index)
    s = reverse_bits(x_sobol)                                            # the shuffled index
    reversed_y = sobol_y_reversed(s)
    sx, sy = pcg2d(rx, ry)
    return (to_unit_float(reverse_bits(_laine_karras(s, sx))),
            to_unit_float(reverse_bits(_laine_karras(reversed_y, sy))))
