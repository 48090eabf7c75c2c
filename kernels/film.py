"""Progressive film: float64 sums per pixel over a region of the frame, resolved to float32 RGBA.

Axes are (row, col, channel) with row 0 at the top of the region.
"""
from __future__ import annotations

import numpy as np

from . import passes as _passes
from . import shadow_catcher
from .cryptomatte import CryptoFilm


# Memory per pixel: the float64 RGBA sums; with adaptive sampling also the odd samples' float32 RGB,
# an int32 sample count and the converged flag (without it, counts are kept per row).
BYTES_PER_PIXEL = 32
ADAPTIVE_BYTES_PER_PIXEL = BYTES_PER_PIXEL + 12 + 4 + 1


class Film:
    """Accumulates RGBA sample sums for a width x height region, with the sample counts.

    pixel_samples : (H, W) int32 samples per pixel with adaptive sampling; (H, 1) per row without.
    half : (H, W, 3) float32 RGB sums of the odd-numbered samples only, for adaptive sampling's error
        estimate (Cycles' adaptive aux buffer); None without adaptive sampling.
    converged : (H, W) bool, the pixels adaptive sampling has stopped ((H, 1) all False without).
    """

    def __init__(self, width: int, height: int, adaptive: bool = False, passes: tuple = (), cryptomatte: tuple = (),
                 cryptomatte_depth: int = 6, transparent: bool = False, exposure: float = 1.0):
        self.width, self.height = width, height
        # Film > Exposure, applied where the film is read, as Cycles' pass accessor applies it: the sums stay
        # the radiance's, so that the shadow catcher's ratios and the merged ranges are the same either way.
        self.exposure = float(exposure)
        columns = width if adaptive else 1
        self.sums = np.zeros((height, width, 4), np.float64)
        self.half = np.zeros((height, width, 3), np.float32) if adaptive else None
        self.pixel_samples = np.zeros((height, columns), np.int32)
        self.converged = np.zeros((height, columns), bool)
        # Data passes (kernels.passes): float32 sums for averaged ones (normals, albedo and UVs need no more),
        # sample 0's values for the others; float64 for the light groups, which add up to Combined's sums.
        self.aux = {name: np.zeros((height, width, _passes.channels(name)),
                                   np.float64 if _passes.kind(name) in ("NOISE", "LIGHTGROUP") else np.float32)
                    for name in passes if _passes.recorded(name)}
        # With shadow catchers Combined is read from their planes, as Cycles' (kernels/shadow_catcher.py): the
        # approximate one of an opaque film (transparent: the film's) over the Environment pass.
        self.catchers = shadow_catcher.MATTE in self.aux
        self.approximate_catchers = shadow_catcher.approximate(passes)
        self.catcher_background = self.approximate_catchers and not transparent
        # Cryptomatte: ranked (id, weight) slots per kind (kernels.cryptomatte).
        self.crypto = {kind: CryptoFilm(height, width, cryptomatte_depth) for kind in cryptomatte}

    def add_rows(self, rows: range, row_sums: np.ndarray, samples, half_sums: np.ndarray | None = None,
                 aux: dict | None = None) -> None:
        """Add (rows, width, 4) sums to the region rows `rows` (a wave's band), holding `samples` samples per
        pixel (an int, or (rows, width) counts with adaptive sampling), and then (rows, width, 3) sums of
        their odd samples."""
        assert len(rows) == row_sums.shape[0]
        at = slice(rows.start, rows.stop, rows.step)
        self.sums[at] += row_sums
        self.pixel_samples[at] += np.asarray(samples, np.int32)
        if half_sums is not None:
            self.half[at] += half_sums.astype(np.float32)
        for name, values in (aux or {}).items():
            if name.startswith("crypto_"):
                self.crypto[name[len("crypto_"):]].merge(values, rows)
                continue
            if _passes.is_first(name):
                plane, written = values
                target = self.aux[name][at]     # a view: written into the film
                target[written] = plane[written]
            else:
                self.aux[name][at] += values.astype(self.aux[name].dtype)

    def resolve_crypto(self, kind: str, row0: int = 0, row1: int | None = None) -> np.ndarray:
        """(rows, width, 4 x layers) float32 Cryptomatte layers of one kind (ids ranked by coverage)."""
        row1 = self.height if row1 is None else row1
        return self.crypto[kind].layers(self.pixel_samples[row0:row1], row0, row1)

    def resolve_pass(self, name: str, row0: int = 0, row1: int | None = None) -> np.ndarray:
        """(rows, width, C) float32 of a data pass, as Cycles reads its passes: averaged ones divided by the
        pixel's samples; Depth 1e10 where sample 0 saw no surface; light passes times Film > Exposure."""
        values = self._pass(name, row0, row1)
        if self.exposure != 1.0:
            if _passes.exposed(name):
                values[..., :3] *= np.float32(self.exposure)
            elif _passes.kind(name) == "NOISE":   # the variance of Combined, which the exposure scales
                values *= np.float32(self.exposure ** 2)
        return values

    def _pass(self, name: str, row0: int, row1: int | None) -> np.ndarray:
        """resolve_pass before the exposure."""
        row1 = self.height if row1 is None else row1
        if name == shadow_catcher.PASS:
            if not self.catchers:   # no shadow catcher: nothing to divide, 1 everywhere (as Cycles)
                return np.ones((row1 - row0, self.width, 3), np.float32)
            return shadow_catcher.shadow_pass(self.mean(row0, row1), *self.catcher_planes(row0, row1)[:3])
        values = self.aux[name][row0:row1]
        if _passes.is_first(name):
            if name == "depth":
                return np.where(values == 0, np.float32(_passes.BACKGROUND_DEPTH), values).astype(np.float32)
            return values.copy()
        count = self.pixel_samples[row0:row1].astype(np.float64)
        scale = np.divide(1.0, count, out=np.zeros_like(count), where=count > 0)
        mean = values * scale[:, :, None]
        if _passes.kind(name) == "WEIGHTED":  # averaged over the samples that wrote it (Cycles' motion weight)
            weight = self.aux[name + "_weight"][row0:row1]
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(weight > 0, values / weight, 0.0).astype(np.float32)
        if _passes.kind(name) == "MIST":
            return (1.0 - mean).astype(np.float32)
        if _passes.kind(name) == "LIGHT" and not name.startswith("volume_"):
            # Divided by the class's colour, as Cycles' pass accessor does (Volume has no colour pass).
            colour = self.aux[name.split("_")[0] + "_color"][row0:row1] * scale[:, :, None]
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(colour != 0, mean / colour, 0.0).astype(np.float32)
        if _passes.kind(name) == "NOISE":
            # values hold the odd-numbered samples' sums. Their mean and the whole mean differ by half the
            # difference of two independent half estimates, whose square's expectation is the variance of
            # the whole mean, stratified sampling included (an i.i.d. sample variance would overstate it).
            odd = np.floor(count / 2)
            odd_mean = values * np.divide(1.0, odd, out=np.zeros_like(odd), where=odd > 0)[:, :, None]
            colour = self.sums[row0:row1, :, :3] * scale[:, :, None]
            return np.where((odd > 0)[:, :, None], (odd_mean - colour) ** 2, 0.0).astype(np.float32)
        return mean.astype(np.float32)

    def resolve(self, row0: int = 0, row1: int | None = None) -> np.ndarray:
        """(rows, width, 4) float32 Combined of rows [row0, row1): the mean of the samples, or where the scene has
        shadow catchers, what Cycles shows of them (kernels/shadow_catcher.py); pixels without samples are zero."""
        mean = self.mean(row0, row1)
        if self.catchers:
            row1 = self.height if row1 is None else row1
            mean = shadow_catcher.combined(mean, *self.catcher_planes(row0, row1), self.approximate_catchers)
            mean[np.broadcast_to(self.pixel_samples[row0:row1] == 0, mean.shape[:2])] = 0.0
        if self.exposure != 1.0:   # RGB, not alpha (Cycles' film_get_pass_pixel_combined)
            mean[..., :3] *= np.float32(self.exposure)
        return mean

    def mean(self, row0: int = 0, row1: int | None = None) -> np.ndarray:
        """(rows, width, 4) float32 mean of the samples of rows [row0, row1); pixels without samples are zero."""
        row1 = self.height if row1 is None else row1
        count = self.pixel_samples[row0:row1].astype(np.float64)
        scale = np.divide(1.0, count, out=np.zeros_like(count), where=count > 0)
        return (self.sums[row0:row1] * scale[:, :, None]).astype(np.float32)

    def catcher_planes(self, row0: int, row1: int):
        """The means of the shadow catchers' planes: matte, catcher, splits, and background (None without)."""
        planes = [self._pass(name, row0, row1) for name in
                  (shadow_catcher.MATTE, shadow_catcher.CATCHER, shadow_catcher.SPLITS)]
        background = self._pass(shadow_catcher.BACKGROUND, row0, row1) if self.catcher_background else None
        return (*planes, background)

    @property
    def samples_done(self) -> int:
        """Samples every pixel still sampling has (a pass that stopped part-way counts for no pixel);
        once adaptive sampling has stopped them all, the most any pixel took."""
        if not self.height:
            return 0
        active = ~self.converged
        if active.any():
            return int(self.pixel_samples[active].min())
        return int(self.pixel_samples.max())

    def update_convergence(self, threshold: float) -> None:
        """Cycles' adaptive sampling check (film_adaptive_sampling_convergence_check and its filters): a
        pixel converges when |mean - mean of its odd samples| summed over RGB, over sqrt of its summed mean
        (the mean itself above 1), is below 5 x threshold; a converged pixel beside an unconverged one
        (in its row or column) goes on. Film > Exposure scales the mean it judges, as Cycles'."""
        n = np.maximum(self.pixel_samples, 1).astype(np.float64)[:, :, None]
        mean = self.sums[:, :, :3] / n
        # The odd samples are every second one: their mean estimates the same value from half as many.
        odd = 2.0 * self.half / n
        if self.exposure != 1.0:
            mean, odd = mean * self.exposure, odd * self.exposure
        difference = np.abs(mean - odd).sum(axis=2)
        intensity = mean.sum(axis=2)
        normalize = np.where(intensity < 1.0, np.sqrt(np.maximum(intensity, 0.0)), intensity)
        converged = difference / (1e-4 + normalize) < 5.0 * threshold
        busy = ~converged
        grown = busy.copy()
        grown[:, 1:] |= busy[:, :-1]
        grown[:, :-1] |= busy[:, 1:]
        grown[1:, :] |= busy[:-1, :]
        grown[:-1, :] |= busy[1:, :]
        self.converged = ~grown


# Paths per block where a wave's per-path results are summed per pixel in float64.
_SUM_BLOCK = 1 << 16


def pixel_sums(radiance, alpha, pixels, npix: int, first_sample: int, spp: int, half: bool):
    """A wave's per-pixel sums from its paths' radiance (3, N) and alpha (N,), pixel-major (spp paths per pixel
    of `pixels`, the wave's pixels that took samples): ((npix, 4) float64 RGBA sums, and with `half` the (npix, 3)
    sums of the odd-numbered samples, for adaptive sampling's noise estimate, else None)."""
    sums = np.zeros((npix, 4), np.float64)
    half_sums = np.zeros((npix, 3), np.float64) if half else None
    odd = (np.arange(first_sample, first_sample + spp) & 1).astype(bool)   # by a path's place in its pixel
    # Whole pixels at a time, in float64: each pixel's sums are the same as over the whole wave at once.
    step = max(1, _SUM_BLOCK // spp)
    for lo in range(0, len(pixels), step):
        hi = min(len(pixels), lo + step)
        rgba = np.empty((4, (hi - lo) * spp), np.float64)
        rgba[:3] = radiance[:, lo * spp:hi * spp]
        rgba[3] = alpha[lo * spp:hi * spp]
        block = rgba.reshape(4, hi - lo, spp)
        sums[pixels[lo:hi]] = block.sum(axis=2).T
        if half_sums is not None:
            half_sums[pixels[lo:hi]] = np.where(odd, block[:3], 0.0).sum(axis=2).T
        del rgba, block
    return sums, half_sums
