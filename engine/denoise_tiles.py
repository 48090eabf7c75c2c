"""How a denoise is cut into tiles, and the one figure the tiles must share: OIDN's auto-exposure.

    tiles = plan_tiles(height, width, color_overlap, aux_overlap, alignment)   # Tile: rows, cols, windows
    scale = auto_exposure(read, height, width)                                 # OIDN's inputScale

OIDN's network sees a pixel's neighbourhood up to its receptive field: a tile denoised within a window that
reaches OIDN's tileOverlap beyond it, at offsets that are multiples of its tileAlignment, comes out as in
the whole image (OIDN tiles large images itself the same way, unet_filter.cpp). With prefiltered albedo and
normal, the colour's window needs them clean over its whole extent: they are denoised over a window that
reaches their own overlap beyond the colour's. An HDR image's exposure is measured over the whole image
(OIDN's auto-exposure), so a tiled denoise measures it first and hands it to every tile.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

# A window (a tile with its overlaps) holds at most this many pixels: OIDN 2.3.3's own largest tile
# (unet_filter.h, defaultMaxTileSize). OIDN never tiles a window again, an image up to that size is
# denoised whole, and OIDN's working memory, which grows with the window (about 0.8 kB a pixel at HIGH
# quality, 0.35 kB at FAST), stays what OIDN itself spends on any image: about 3.5 GB at HIGH.
TILE_PIXELS = 2160 * 2160
# A tiled image's colour is read in bands of at most this many pixels for its auto-exposure.
BAND_PIXELS = 1 << 20


@dataclass(frozen=True)
class Tile:
    """Output rows and columns, the colour window around them and the auxiliary window around that."""
    rows: slice
    cols: slice
    color_rows: slice
    color_cols: slice
    aux_rows: slice
    aux_cols: slice


def _spans(length: int, size: int) -> list[tuple[int, int]]:
    """[start, end) spans of `size` covering [0, length), the last one cut at length."""
    count = -(-length // size)
    return [(i * size, min(length, (i + 1) * size)) for i in range(count)]


def _grow(span: tuple[int, int], margin: int, length: int) -> slice:
    return slice(max(0, span[0] - margin), min(length, span[1] + margin))


def plan_tiles(height: int, width: int, color_overlap: int, aux_overlap: int, alignment: int,
               tile_pixels: int = TILE_PIXELS, tile_size: int | None = None) -> list[Tile]:
    """Tiles of an image and their windows, in rows top-down: one window, the whole image, when it has at
    most tile_pixels pixels (or fits in one tile of tile_size); else square tiles of tile_size (rounded up
    to a multiple of `alignment`; None: the largest whose auxiliary windows hold at most tile_pixels) at
    offsets that are multiples of `alignment`, so that OIDN's network sees every pixel as in the whole
    image. A tile's colour window reaches color_overlap beyond it on every side where there is image, its
    auxiliary window aux_overlap beyond that."""
    margin = color_overlap + aux_overlap
    if tile_size is None:
        if height * width <= tile_pixels:
            return [Tile(*(slice(0, height), slice(0, width)) * 3)]
        size = max(alignment, (int(np.sqrt(tile_pixels)) - 2 * margin) // alignment * alignment)
    else:
        size = max(alignment, -(-tile_size // alignment) * alignment)
    tiles = []
    for rows in _spans(height, _even(height, size, alignment)):
        for cols in _spans(width, _even(width, size, alignment)):
            color_rows, color_cols = _grow(rows, color_overlap, height), _grow(cols, color_overlap, width)
            tiles.append(Tile(slice(*rows), slice(*cols), color_rows, color_cols,
                               _grow(rows, margin, height), _grow(cols, margin, width)))
    return tiles


def _even(length: int, size: int, alignment: int) -> int:
    """A multiple of `alignment` that covers `length` with as many tiles as `size` needs, the tiles as
    equal as the alignment lets them be."""
    count = -(-length // size)
    even = -(-length // count)
    return -(-even // alignment) * alignment


def auto_exposure(read: Callable, height: int, width: int, band_pixels: int = BAND_PIXELS,
                  poll: Callable[[], bool] | None = None) -> float:
    """OIDN's auto-exposure of an HDR colour image, computed as OIDN 2.3.3 does
    (devices/cpu/cpu_autoexposure.cpp): the image cut into ceil(H/16) x ceil(W/16) bins at
    floor(i H / bins) boundaries, each bin's mean luminance (0.212671 R + 0.715160 G + 0.072169 B, of the
    colour clamped at 0), the mean of log2 of those above 1e-8, and the scale 0.18 / 2^mean (1 without such
    bins). A tiled denoise hands it to every window as inputScale: each window's own would differ, and the
    tiles would show. read(rows, cols) -> (h, w, 3) finite colour, read in bands of whole bins of at most
    band_pixels pixels (one row of bins when that is more); poll() -> False stops it (the result is then
    1)."""
    bins_h, bins_w = -(-height // 16), -(-width // 16)
    row_edges = np.arange(bins_h + 1, dtype=np.int64) * height // bins_h
    col_edges = np.arange(bins_w + 1, dtype=np.int64) * width // bins_w
    areas_w = np.diff(col_edges)
    band_bins = max(1, band_pixels // max(1, width * (height // bins_h + 1)))
    log_sum, count = 0.0, 0
    for b0 in range(0, bins_h, band_bins):
        b1 = min(bins_h, b0 + band_bins)
        r0, r1 = int(row_edges[b0]), int(row_edges[b1])
        color = np.maximum(read(slice(r0, r1), slice(0, width)), 0)
        luminance = color @ np.array([0.212671, 0.715160, 0.072169], np.float64)
        sums = np.add.reduceat(np.add.reduceat(luminance, row_edges[b0:b1] - r0, axis=0), col_edges[:-1], axis=1)
        means = sums / np.diff(row_edges[b0:b1 + 1])[:, None] / areas_w[None, :]
        lit = means[means > 1e-8]
        log_sum += float(np.log2(lit).sum())
        count += lit.size
        if poll is not None and not poll():
            return 1.0
    return 0.18 / 2.0 ** (log_sum / count) if count else 1.0
