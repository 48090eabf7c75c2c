"""Denoising a render's film with OpenImageDenoise (engine/denoise.py): reading the film a window at a time,
and what a final render denoises with once it has stopped.

    finished = denoise_film(film, write, ("HIGH", "ACCURATE"), threads, progress)   # tile by tile
    image = denoised_film(film, "HIGH", "ACCURATE", threads, should_stop)           # (H, W, 4), or None
    options = final_options(scene.ember, stopped_early, user_stopped)                # (quality, prefilter) or None

The film's colour, albedo and normal are resolved for one window at a time, in bands of rows, so that the
memory a denoise takes beside the film is bounded by its tiles (denoise.TILE_PIXELS), not by the image.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from .denoise import denoise_image

# The film's passes the denoiser reads, by OIDN's names.
AUX_PASSES = {"albedo": "denoising_albedo", "normal": "denoising_normal"}
# Rows are resolved in bands of about this many pixels (their float64 temporaries: 32 bytes a pixel).
READ_BAND_PIXELS = 1 << 18
# After a time limit: OIDN's fast network, the albedo and normal denoised together with the colour (they
# carry the render's noise: cleanAux off); a tenth of the time of Cycles' default (HIGH, ACCURATE) or less.
FAST_OPTIONS = ("FAST", "FAST")


def film_aux(film) -> tuple:
    """OIDN's names of the auxiliary images the film holds ('albedo', 'normal')."""
    return tuple(name for name, kernel in AUX_PASSES.items() if kernel in film.aux)


def film_window(film, name: str, rows: slice, cols: slice) -> np.ndarray:
    """(h, w, C) float32 window of the film: 'combined' RGBA, or the RGB of 'color', 'albedo' or 'normal'."""
    channels = 4 if name == "combined" else 3
    window = np.empty((rows.stop - rows.start, cols.stop - cols.start, channels), np.float32)
    step = max(1, READ_BAND_PIXELS // max(film.width, 1))
    for r0 in range(rows.start, rows.stop, step):
        r1 = min(rows.stop, r0 + step)
        band = film.resolve(r0, r1) if name in ("combined", "color") else film.resolve_pass(AUX_PASSES[name], r0, r1)
        window[r0 - rows.start:r1 - rows.start] = band[:, cols, :channels]
    return window


class NonFiniteTile(Exception):
    """The denoiser gave NaN or infinite pixels, or black for a lit tile (the tile is not written)."""


def denoise_film(film, write: Callable, options: tuple, threads: int,
                 progress: Callable[[float], bool] | None = None) -> bool:
    """Denoise the film's colour, guided by its albedo and normal passes when it has them, a tile at a time:
    write(rows, cols, rgb) gets each denoised tile, progress(fraction) -> bool as denoise.denoise_image,
    whose errors it raises, and NonFiniteTile. options: (quality, prefilter). True when every tile was
    written."""
    def write_finite(rows, cols, rgb):
        if not np.isfinite(rgb).all():
            raise NonFiniteTile("denoising gave non-finite pixels")
        # OIDN's exposure estimate overflows its float32 sums for pixels near the float32 limit (~1e37): it
        # then returns zeros for a lit image.
        if not np.any(rgb > 0) and np.any(film_window(film, "combined", rows, cols)[..., :3] > 0):
            raise NonFiniteTile("denoising returned a black image for a lit one (pixels near the float32 limit)")
        write(rows, cols, rgb)

    quality, prefilter = options
    return denoise_image(lambda name, rows, cols: film_window(film, name, rows, cols), film.height, film.width,
                         write_finite, aux=film_aux(film), quality=quality, prefilter=prefilter, threads=threads,
                         progress=progress)


def denoised_film(film, quality: str, prefilter: str, threads: int,
                  should_stop: Callable[[], bool] | None = None) -> np.ndarray | None:
    """The film's image (H, W, 4) with its colour denoised, or None when should_stop() said so first;
    raises what the denoiser raises."""
    image = film_window(film, "combined", slice(0, film.height), slice(0, film.width))

    def write(rows, cols, rgb):
        image[rows, cols, :3] = rgb

    progress = None if should_stop is None else lambda fraction: not should_stop()
    return image if denoise_film(film, write, (quality, prefilter), threads, progress) else None


def final_options(ember, stopped_early: bool, user_stopped: bool) -> tuple | None:
    """(quality, prefilter) a final render denoises with, or None. None when denoising is off, or when the
    user stopped the render (Esc, Ctrl-C): Cycles then keeps what was rendered, undenoised. FAST_OPTIONS
    when a time limit ended it early: the image is wanted by then, and a full denoise could take longer
    than the render. Else the scene's settings."""
    if not ember.use_denoising or user_stopped:
        return None
    if stopped_early:
        return FAST_OPTIONS
    return ember.denoising_quality, ember.denoising_prefilter
