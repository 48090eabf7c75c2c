"""Named sample dimensions: which random numbers each decision of a path uses.

Every decision owns a 2D dimension, named here once:

    CAMERA        the jitter inside the pixel (warped by the pixel filter)
    LENS          the point on the lens (only with depth of field)
    TIME          the time in the shutter (only with motion blur; its second number is spare)
    LIGHT         (light selection, Russian roulette)
    LIGHT_POINT   the point on the chosen light
    BSDF          the direction sampled from the chosen lobe
    LOBE          (lobe selection, spare)
    VOLUME_*      the camera ray's light sample in a medium: where along the ray, which light and where on it

The first vertex of an NEE_MIS path takes its numbers from a stratified sequence (Owen-scrambled Sobol, laid
out over the pixels by sample_strata), one sequence per dimension (rng.stratified_2d with the dimension's id),
so that numbers of one dimension are independent of the others whatever is added. Deeper vertices draw the
dimensions of their mode's block from the path's PCG2D stream, always the whole block in the order below, so a
decision's numbers never depend on which decisions were taken before. LECTURE and COSINE draw only BSDF (and
LOBE where materials mix lobes): on diffuse scenes one PCG2D pair per bounce, the lecture's estimator exactly.
"""
from __future__ import annotations

import numpy as np

from .rng import PathRng, blue_noise_offsets, reverse_bits, stratified_2d
from .vec import HALF

CAMERA, LIGHT, LIGHT_POINT, BSDF, LOBE, LENS, TIME = 0, 1, 2, 3, 4, 5, 6
# The camera ray's segment through media (kernels.media.stage.direct_light): the distance and its strategy,
# the light's choice and the point on it.
VOLUME_DISTANCE, VOLUME_LIGHT = 7, 8
# The dimensions a bounce draws from the PCG2D stream, in order, with and without next-event estimation;
# LOBE comes last, drawn only in scenes whose materials have more than one lobe to choose from.
NEE_BLOCK = (LIGHT, LIGHT_POINT, BSDF)
PLAIN_BLOCK = (BSDF,)
STRATIFIED = (LIGHT, LIGHT_POINT, BSDF, LOBE)
SAMPLING_PATTERNS = ("AUTOMATIC", "SOBOL_BURLEY")


# The scramble keys of the shared sequences (rng.stratified_2d's pixel argument): the blue-noise layout's, and
# the viewport's one-sample sequence's (a key no pixel index reaches in an image of under 2^32 - 1 pixels).
SHARED_KEY, FIRST_SAMPLE_KEY = np.uint32(0), np.uint32(0xFFFFFFFF)


def sample_strata(pattern: str, seed: int, width: int, height: int, length: int, row: np.ndarray,
                  col: np.ndarray, pixel_index: np.ndarray, sample: np.ndarray, ranged: bool = False,
                  first: bool = False, repeats: int = 1):
    """(pixel, sample, index) per path, what Samples reads the first vertex's numbers with: sample
    `index` of the Owen-scrambled Sobol sequence scrambled by `pixel` (rng.stratified_2d; one value for all
    paths where they share the sequence).

    SOBOL_BURLEY (Cycles' Sobol-Burley): each pixel its own sequence (scrambled by its pixel index), read
    at the sample number. AUTOMATIC (Cycles' default for final renders, its Blue-Noise pattern,
    kernel/sample/pattern.h): one sequence for all pixels (scrambled alike), of which each pixel reads
    `length` samples (the render's count) from its own place, blue_noise_offsets. Each aligned 2^k x 2^k
    square of pixels then reads one aligned block of the sequence, so the samples of neighbouring pixels
    are stratified together and their errors are blue noise (what a denoiser removes best); each pixel's
    own samples are as well stratified as before. The places must fit the sequence's 2^32 numbers: where
    the image's Morton square times length does not (an unlimited viewport, a huge frame at many samples),
    and for a range of a frame's samples (ranged: the whole frame's count is not known here), AUTOMATIC
    falls back to SOBOL_BURLEY.

    first (the viewport, as Cycles' interactive renders: its Blue-Noise First pattern): sample 0 of every
    pixel comes from a one-sample sequence of its own, laid out as above, so that the first image is blue
    noise on its own; the other samples are laid out as above for length - 1 samples.

    repeats: each pixel's paths are that many consecutive entries (a wave's samples of a pixel), whose
    place is then computed once."""
    side = 1 << max(int(width - 1).bit_length(), int(height - 1).bit_length())
    if pattern == "SOBOL_BURLEY" or ranged:
        return pixel_index, sample, sample
    def pixel_places():
        if repeats == 1:
            return blue_noise_offsets(col, row, seed)
        return np.repeat(blue_noise_offsets(col[::repeats], row[::repeats], seed), repeats)

    places = None
    if first:
        length -= 1
    if side * side * int(length) <= (1 << 32) and length > 0:
        places = pixel_places()
        key, index = np.full(1, SHARED_KEY), places * np.uint32(length) + (sample - np.uint32(first))
    else:
        key, index = pixel_index, sample
    if not first:
        return key, sample, index
    zero = sample == 0
    if not zero.any():
        return key, sample, index
    if places is None:
        places = pixel_places()
    return (np.where(zero, FIRST_SAMPLE_KEY, np.broadcast_to(key, zero.shape)).astype(np.uint32), sample,
            np.where(zero, places, index).astype(np.uint32))


class Samples:
    """The random numbers of a wave's live paths, by dimension name.

    rng : PathRng, the per-path PCG2D stream (seeded per pixel and pass).
    strata : (pixel, sample, index) per path (sample_strata), or None: the first vertex then draws from
        rng too.
    """

    def __init__(self, rng: PathRng, strata, seed: int, nee: bool, lobes: bool = False):
        self.rng = rng
        self.block = (NEE_BLOCK if nee else PLAIN_BLOCK) + ((LOBE,) if lobes else ())
        self._strata = strata
        self._seed = seed
        self._first: dict | None = None  # the first vertex's numbers per dimension, once drawn

    def camera(self) -> tuple[np.ndarray, np.ndarray]:
        """The pixel jitter of every path (drawn before any other dimension)."""
        if self._strata is None:
            return self.rng.next_2d()
        pixel, sample, index = self._strata
        reversed_index = reverse_bits(index)  # the same for every dimension
        self._first = {d: stratified_2d(pixel, index, self._seed, d, reversed_index)
                       for d in STRATIFIED if d in self.block}
        jx, jy = stratified_2d(pixel, index, self._seed, CAMERA, reversed_index)
        # Sample 0 of every pixel looks through its centre, as Cycles' does (init_from_camera.h): a first
        # sample without jitter, and the same expected image as Cycles' at every sample count.
        first = sample == 0
        if first.any():
            jx, jy = np.where(first, HALF, jx), np.where(first, HALF, jy)
        return jx, jy

    def camera_extra(self, dimension: int) -> tuple[np.ndarray, np.ndarray]:
        """The lens or time numbers of every path; drawn after the jitter and only by cameras that use
        them, so that a camera without depth of field or motion blur renders as before, bit for bit."""
        if self._strata is None:
            return self.rng.next_2d()
        pixel, _, index = self._strata
        return stratified_2d(pixel, index, self._seed, dimension)

    def bounce(self, depth: int) -> dict:
        """{dimension: (u, v)} for this vertex of every live path."""
        if depth == 0 and self._first is not None:
            first, self._first = self._first, None
            return first
        return {d: self.rng.next_2d() for d in self.block}

    @staticmethod
    def concat(a: "Samples", b: "Samples") -> "Samples":
        """The numbers of a's paths, then b's; both past their first vertex (its stratified numbers drawn)."""
        if a._first is not None or b._first is not None or a.block != b.block:
            raise ValueError("Samples.concat: batches before their first vertex, or of other dimensions")
        joined = Samples.__new__(Samples)
        joined.rng = PathRng(np.concatenate([a.rng.x, b.rng.x]), np.concatenate([a.rng.y, b.rng.y]))
        joined.block, joined._strata, joined._seed, joined._first = a.block, None, a._seed, None
        return joined

    def take(self, idx: np.ndarray) -> "Samples":
        """The numbers of the paths idx only."""
        kept = Samples.__new__(Samples)
        kept.rng = self.rng.take(idx)
        kept.block, kept._strata, kept._seed = self.block, None, self._seed
        kept._first = None if self._first is None else \
            {d: (np.take(u, idx), np.take(v, idx)) for d, (u, v) in self._first.items()}
        return kept
