"""Denoising a render's film with OpenImageDenoise (engine/denoise.py): reading the film a window at a time,
and what a final render denoises with once it has stopped.

    finished = denoise_film(film, write, ("HIGH", "ACCURATE"), threads, progress)   # tile by tile
    image = denoised_film(film, "HIGH", "ACCURATE", threads, should_stop)           # (H, W, 4), or None
    options = final_options(scene.ember, stopped_early, user_stopped)                # (quality, prefilter) or None

The film's colour, albedo and normal are resolved for one window at a time, in bands of rows, so that the
memory a denoise takes beside the film is bounded by its tiles (denoise.TILE_PIXELS), not by the image. A film
with shadow catchers is denoised as Cycles denoises it (denoise_film): its Shadow Catcher pass, kept whole
(12 bytes a pixel), then its matte's colour a tile at a time.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ..kernels import shadow_catcher
from .denoise import denoise_image

# The film's passes a denoise reads, by the names film_window knows them: OIDN's auxiliary images, and what a film
# with shadow catchers denoises in place of Combined's colour.
FILM_PASSES = {"albedo": "denoising_albedo", "normal": "denoising_normal", "matte": shadow_catcher.MATTE,
               "shadow_catcher": shadow_catcher.PASS}
AUX_PASSES = {name: FILM_PASSES[name] for name in ("albedo", "normal")}
# Cycles denoises the Shadow Catcher pass without its albedo: where the real one is asked for, a constant stand-in
# (src/integrator/denoiser_oidn.cpp, set_fake_albedo_pass), not prefiltered.
STAND_IN_ALBEDO = 0.5
# The denoised passes besides Combined a tile carries, by Blender's pass names.
SHADOW_CATCHER_PASS = "Shadow Catcher"
# Rows are resolved in bands of about this many pixels (their float64 temporaries: 32 bytes a pixel).
READ_BAND_PIXELS = 1 << 18
# After a time limit: OIDN's fast network, the albedo and normal denoised together with the colour (they
# carry the render's noise: cleanAux off); a tenth of the time of Cycles' default (HIGH, ACCURATE) or less.
FAST_OPTIONS = ("FAST", "FAST")


def film_aux(film) -> tuple:
    """OIDN's names of the auxiliary images the film holds ('albedo', 'normal')."""
    return tuple(name for name, kernel in AUX_PASSES.items() if kernel in film.aux)


def film_window(film, name: str, rows: slice, cols: slice) -> np.ndarray:
    """(h, w, C) float32 window of the film: 'combined' RGBA, or the RGB of 'color' (Combined's), 'albedo',
    'normal', or, with shadow catchers, 'matte' (the matte's) and 'shadow_catcher' (the Shadow Catcher pass)."""
    channels = 4 if name == "combined" else 3
    window = np.empty((rows.stop - rows.start, cols.stop - cols.start, channels), np.float32)
    step = max(1, READ_BAND_PIXELS // max(film.width, 1))
    for r0 in range(rows.start, rows.stop, step):
        r1 = min(rows.stop, r0 + step)
        band = film.resolve(r0, r1) if name in ("combined", "color") else film.resolve_pass(FILM_PASSES[name], r0, r1)
        window[r0 - rows.start:r1 - rows.start] = band[:, cols, :channels]
    return window


class NonFiniteTile(Exception):
    """The denoiser gave NaN or infinite pixels, or black for a lit tile (the tile is not written)."""


def _checked(film, noisy: str, rows: slice, cols: slice, rgb: np.ndarray) -> None:
    """Raise NonFiniteTile for a denoised tile that is not finite, or black where the noisy one (film_window's
    `noisy`) is lit."""
    if not np.isfinite(rgb).all():
        raise NonFiniteTile("denoising gave non-finite pixels")
    # OIDN's exposure estimate overflows its float32 sums for pixels near the float32 limit (~1e37): it then
    # returns zeros for a lit image.
    if not np.any(rgb > 0) and np.any(film_window(film, noisy, rows, cols)[..., :3] > 0):
        raise NonFiniteTile("denoising returned a black image for a lit one (pixels near the float32 limit)")


def _reader(film, color: str, stand_in_albedo: bool = False) -> Callable:
    """denoise_image's read(name, rows, cols) of a film, its 'color' being film_window's `color`."""
    def read(name, rows, cols):
        if name == "albedo" and stand_in_albedo:
            return np.full((rows.stop - rows.start, cols.stop - cols.start, 3), STAND_IN_ALBEDO, np.float32)
        return film_window(film, color if name == "color" else name, rows, cols)
    return read


def denoise_film(film, write: Callable, options: tuple, threads: int,
                 progress: Callable[[float], bool] | None = None) -> bool:
    """Denoise the film's colour, guided by its albedo and normal passes when it has them, a tile at a time:
    write(rows, cols, pixels, passes) gets each denoised tile, pixels (h, w, 3) the colour of Combined (its alpha
    the film's) or (h, w, 4) all of it, passes the denoised passes besides it by Blender's names ({} or the
    Shadow Catcher pass). progress(fraction) -> bool as denoise.denoise_image, whose errors it raises, and
    NonFiniteTile. options: (quality, prefilter). True when every tile was written.

    With shadow catchers, what Cycles denoises (src/integrator/denoiser_oidn.cpp, denoise_buffer): the Shadow
    Catcher pass (PASS_SHADOW_CATCHER, read as the film reads it: the catchers' light ratio over white by
    Combined's alpha) with the normal and a stand-in albedo, then the matte's colour (PASS_SHADOW_CATCHER_MATTE)
    with the albedo and normal; Combined is then made from them (kernel/film/read.h,
    film_calculate_shadow_catcher_matte_with_shadow, reading the denoised pass): the matte's alpha and the
    Environment pass stay as rendered, the shadow in a transparent film's alpha and over an opaque film's world
    comes from the denoised pass."""
    quality, prefilter = options
    aux = film_aux(film)
    common = dict(aux=aux, quality=quality, prefilter=prefilter, threads=threads)
    if not film.catchers:
        def write_colour(rows, cols, rgb):
            _checked(film, "combined", rows, cols, rgb)
            write(rows, cols, rgb, {})
        return denoise_image(_reader(film, "color"), film.height, film.width, write_colour, progress=progress,
                             **common)

    # Progress: each denoise's share is its networks (the colour's, and each prefiltered image's).
    accurate = prefilter == "ACCURATE"
    shadow_work = 1 + (accurate and "normal" in aux)
    matte_work = 1 + (len(aux) if accurate else 0)
    share = shadow_work / (shadow_work + matte_work)

    def part(lo: float, hi: float):
        return None if progress is None else lambda fraction: progress(lo + (hi - lo) * fraction)

    shadow = np.empty((film.height, film.width, 3), np.float32)

    def keep(rows, cols, rgb):
        _checked(film, "shadow_catcher", rows, cols, rgb)
        shadow[rows, cols] = rgb

    if not denoise_image(_reader(film, "shadow_catcher", stand_in_albedo=True), film.height, film.width, keep,
                         progress=part(0.0, share), noise_free=("albedo",), **common):
        return False

    def compose(rows, cols, rgb):
        pixels = denoised_combined(film, rows, cols, rgb, shadow[rows, cols])
        _checked(film, "combined", rows, cols, pixels[..., :3])
        write(rows, cols, pixels, {SHADOW_CATCHER_PASS: shadow[rows, cols]})

    return denoise_image(_reader(film, "matte"), film.height, film.width, compose, progress=part(share, 1.0),
                         **common)


def denoised_combined(film, rows: slice, cols: slice, matte_rgb: np.ndarray, shadow: np.ndarray) -> np.ndarray:
    """(h, w, 4) Combined of a window of a film with shadow catchers, made as the film makes it
    (kernels/shadow_catcher.py combined) from the denoised matte colour and Shadow Catcher pass of the window."""
    matte, catcher, splits, background = film.catcher_planes(rows.start, rows.stop)
    window = [None if plane is None else plane[:, cols] for plane in (matte, catcher, splits, background)]
    window[0] = np.concatenate([matte_rgb, window[0][..., 3:]], axis=-1)
    out = shadow_catcher.combined(None, *window, film.approximate_catchers, shadow=shadow)
    counts = film.pixel_samples[rows]
    counts = counts[:, cols] if counts.shape[1] > 1 else counts   # (H, 1) without adaptive sampling
    out[np.broadcast_to(counts == 0, out.shape[:2])] = 0.0
    return out


def denoised_film(film, quality: str, prefilter: str, threads: int,
                  should_stop: Callable[[], bool] | None = None) -> np.ndarray | None:
    """The film's image (H, W, 4) with its colour denoised (and with shadow catchers, the shadow made from the
    denoised Shadow Catcher pass), or None when should_stop() said so first; raises what the denoiser raises."""
    image = film_window(film, "combined", slice(0, film.height), slice(0, film.width))

    def write(rows, cols, pixels, passes):
        image[rows, cols, :pixels.shape[-1]] = pixels

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
