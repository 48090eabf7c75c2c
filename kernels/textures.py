"""Bilinear texture lookups on linear float32 images stored row 0 at the bottom (Blender's order).

Texel centres sit at (i + 0.5) / W, as in Cycles' linear interpolation.
"""
from __future__ import annotations

import numpy as np


# Luminance weights of Blender's default scene-linear space (Rec. 709 primaries).
LUMINANCE_REC709 = np.array([0.2126, 0.7152, 0.0722], np.float32)


def luminance(rgb) -> np.ndarray:
    """Luminance of (..., 3) linear Rec. 709 colours."""
    return np.tensordot(LUMINANCE_REC709, np.asarray(rgb, np.float32), axes=([0], [-1]))


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function's inverse (IEC 61966-2-1), elementwise, float32."""
    c = np.asarray(c, np.float32)
    return np.where(c <= np.float32(0.04045), c * np.float32(1 / 12.92),
                    np.power(np.maximum(c + np.float32(0.055), 0) * np.float32(1 / 1.055), np.float32(2.4)))


class Texture:
    """A texture prepared for lookups: one contiguous float32 row of H*W texels per channel, RGB and,
    for 4-channel images, alpha (straight, never sRGB-encoded).

    srgb=True: colour texels are sRGB-encoded and decoded after filtering, like Cycles' 8-bit sRGB images.
    The colour of 4-channel images is stored as the engine hands it over: associated (premultiplied by
    alpha) for ordinary images, as Cycles stores them; lookup(unassociate=True) divides the filtered
    colour by the filtered alpha, as Cycles does when an Image Texture's Alpha output is used.
    """

    def __init__(self, image: np.ndarray, srgb: bool = False):
        self.srgb = srgb
        h, w, c = image.shape
        rgb = image[:, :, :3] if c >= 3 else np.repeat(image[:, :, :1], 3, axis=2)
        self.height, self.width = h, w
        # (H*W, 3): a texel's three channels side by side, so that a gather reads one cache line per texel
        # (a third less time than three channel rows on an HDRI); channels is its (3, H*W) view.
        self.texels = np.ascontiguousarray(rgb.reshape(h * w, 3), np.float32)
        self.channels = self.texels.T
        self.alpha = np.ascontiguousarray(image[:, :, 3].reshape(1, h * w), np.float32) if c == 4 else None

    def lookup_alpha(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(N,) float32 bilinear alpha at u, v (repeat); 1 for images without alpha."""
        if self.alpha is None:
            return np.ones(len(u), np.float32)
        return self._bilinear(self.alpha, u, v, True)[0]

    def lookup(self, u: np.ndarray, v: np.ndarray, wrap_v: bool = True, unassociate: bool = False) -> np.ndarray:
        """(3, N) float32 bilinear samples at texture coordinates u, v (repeat wrap in u; in v repeat
        or clamp to edge)."""
        corners = self._corners(u, v, wrap_v)
        (i00, i01, i10, i11), fx, fy = corners
        # Gathered from the interleaved texels, (n, 3), then (3, n) again.
        t, fx, fy = self.texels, fx[:, None], fy[:, None]
        top = np.take(t, i00, axis=0) * (1 - fx) + np.take(t, i01, axis=0) * fx
        bot = np.take(t, i10, axis=0) * (1 - fx) + np.take(t, i11, axis=0) * fx
        value = np.ascontiguousarray((top * (1 - fy) + bot * fy).T)
        if unassociate and self.alpha is not None:
            a = self._planes(self.alpha, corners)[0]
            partial = (a != 0) & (a != 1)
            value = np.where(partial, value / np.where(partial, a, np.float32(1.0)), value)
        return srgb_to_linear(value) if self.srgb else value

    def _bilinear(self, c: np.ndarray, u: np.ndarray, v: np.ndarray, wrap_v: bool) -> np.ndarray:
        """Bilinear samples of the planes c (k, H*W): (k, N)."""
        return self._planes(c, self._corners(u, v, wrap_v))

    @staticmethod
    def _planes(c: np.ndarray, corners) -> np.ndarray:
        (i00, i01, i10, i11), fx, fy = corners
        fx, fy = fx[None, :], fy[None, :]
        top = np.take(c, i00, axis=1) * (1 - fx) + np.take(c, i01, axis=1) * fx
        bot = np.take(c, i10, axis=1) * (1 - fx) + np.take(c, i11, axis=1) * fx
        return top * (1 - fy) + bot * fy

    def _corners(self, u: np.ndarray, v: np.ndarray, wrap_v: bool):
        """The flat texel indices of the four texels around u, v (top left, top right, bottom left, bottom
        right) and the weights (fx, fy) toward the right and bottom ones."""
        w, h = self.width, self.height
        x = u * np.float32(w) - np.float32(0.5)
        y = v * np.float32(h) - np.float32(0.5)
        x0f = np.floor(x)
        y0f = np.floor(y)
        fx = x - x0f
        fy = y - y0f
        x0 = np.mod(x0f.astype(np.int64), w)
        x1 = x0 + 1
        x1[x1 == w] = 0
        y0i = y0f.astype(np.int64)
        if wrap_v:
            y0 = np.mod(y0i, h)
            y1 = y0 + 1
            y1[y1 == h] = 0
        else:
            y0 = np.clip(y0i, 0, h - 1)
            y1 = np.clip(y0i + 1, 0, h - 1)
        r0 = y0 * w
        r1 = y1 * w
        return (r0 + x0, r0 + x1, r1 + x0, r1 + x1), fx, fy


def finite_uv(u: np.ndarray, v: np.ndarray):
    """Guard against non-finite or huge UVs (they would overflow the integer texel index)."""
    big = np.float32(1e6)
    return (np.nan_to_num(np.clip(u, -big, big), nan=0.0), np.nan_to_num(np.clip(v, -big, big), nan=0.0))
