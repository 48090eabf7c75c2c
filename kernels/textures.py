"""Textures: images stored as the kernel keeps them (8-bit ones as bytes, 16-bit ones as uint16), and lookups on
them, row 0 at the bottom (Blender's order): Texture.lookup (bilinear), sample_texture (Cycles' filters and
extensions, kernel/device/cpu/image.h).

Texel centres sit at (i + 0.5) / W, as in Cycles' linear interpolation.
"""
from __future__ import annotations

import numpy as np

from .vec import F32, HALF, ONE


# Luminance weights of Blender's default scene-linear space (Rec. 709 primaries).
LUMINANCE_REC709 = np.array([0.2126, 0.7152, 0.0722], np.float32)


def luminance(rgb) -> np.ndarray:
    """Luminance of (..., 3) linear Rec. 709 colours. Three products, not a matrix product: NumPy hands those
    to its BLAS, whose threads then spin on the other cores (see kernels/workers.py's child environment)."""
    rgb = np.asarray(rgb, np.float32)
    r, g, b = LUMINANCE_REC709
    return rgb[..., 0] * r + rgb[..., 1] * g + rgb[..., 2] * b


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function's inverse (IEC 61966-2-1), elementwise, float32."""
    c = np.asarray(c, np.float32)
    return np.where(c <= np.float32(0.04045), c * np.float32(1 / 12.92),
                    np.power(np.maximum(c + np.float32(0.055), 0) * np.float32(1 / 1.055), np.float32(2.4)))


# An 8-bit texel k reads k x (1/255) in float32: what Blender's image.pixels gives for it.
BYTE_SCALE = np.float32(1.0 / 255.0)
# A 16-bit texel k reads k x (1/65535), as Cycles reads its ushort textures (kernel/device/cpu/image.h).
WORD_SCALE = np.float32(1.0 / 65535.0)
# Texels per block when a whole texture is walked (means): a few MB of float32 at a time.
BLOCK_TEXELS = 1 << 20


class Texture:
    """A texture prepared for lookups: its texels as they are stored, (H*W, C) with C = 1 (grey), 3 (RGB)
    or 4 (RGBA), row 0 at the bottom, a texel's channels side by side (a gather reads one cache line per
    texel). Nothing is converted up front: each lookup gathers the texels it needs and makes them float32
rows, one per channel (gather).

    uint8 texels are 8-bit images as Blender holds them (k reads k / 255), 1 byte per channel, as Cycles
    keeps them (uchar4); uint16 texels 16-bit image files (k / 65535), as Cycles keeps them (ushort4); float32
    texels are read as they are. A grey texture reads its one channel as the
    three of its colour. srgb=True: colour texels are sRGB-encoded and decoded after filtering, like Cycles'
    8-bit sRGB images. Alpha is never encoded. The colour of a 4-channel texture is as the engine hands it
    over: associated (premultiplied by alpha) where Cycles stores it so, uint8 ones in bytes as Cycles rounds
    them (engine/export/images.py associated_bytes), straight where Cycles keeps it so (channel-packed alpha).
    lookup(unassociate=True) divides the filtered colour by the filtered alpha, as Cycles does when an
    Image Texture's Alpha output is used.
    """

    def __init__(self, image: np.ndarray, srgb: bool = False):
        self.srgb = srgb
        h, w, c = image.shape
        self.height, self.width = h, w
        # The float32 step of an integer texel (None: float32 texels).
        self._scale = BYTE_SCALE if image.dtype == np.uint8 else WORD_SCALE if image.dtype == np.uint16 else None
        # No copy for a contiguous uint8, uint16 or float32 image (what the export hands over).
        self.texels = np.ascontiguousarray(image, None if self._scale is not None else np.float32).reshape(h * w, c)
        self.has_alpha = c == 4

    @property
    def nbytes(self) -> int:
        """Bytes the texture keeps."""
        return self.texels.nbytes

    def gather(self, index: np.ndarray) -> np.ndarray:
        """(3, n) float32 colours, or (4, n) with alpha last for RGBA textures, of the texels at flat
        indices `index` (row * width + column); colour as stored, still sRGB-encoded when srgb."""
        return self._decoded(np.take(self.texels, index, axis=0))

    def _decoded(self, t: np.ndarray) -> np.ndarray:
        """Stored texels (n, C) as gather returns them: one contiguous float32 row per channel."""
        planes = np.ascontiguousarray(t.T, dtype=np.float32)
        if self._scale is not None:
            planes *= self._scale
        if len(planes) == 1:
            planes = np.repeat(planes, 3, axis=0)
        return planes

    def means(self) -> np.ndarray:
        """(4,) float32: the mean colour (R, G, B, associated, as stored) and alpha (1 without one), a
        block of texels at a time (float32 sums within a block, float64 across)."""
        total = np.zeros(4 if self.has_alpha else 3, np.float64)
        for start in range(0, len(self.texels), BLOCK_TEXELS):
            total += self._decoded(self.texels[start:start + BLOCK_TEXELS]).sum(axis=1)
        mean = total / max(len(self.texels), 1)
        return np.append(mean[:3], mean[3] if self.has_alpha else 1.0).astype(np.float32)

    def lookup_alpha(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(N,) float32 bilinear alpha at u, v (repeat); 1 for images without alpha."""
        if not self.has_alpha:
            return np.ones(len(u), np.float32)
        return self._filtered(self._corners(u, v, True))[3]

    def lookup(self, u: np.ndarray, v: np.ndarray, wrap_v: bool = True, unassociate: bool = False) -> np.ndarray:
        """(3, N) float32 bilinear samples at texture coordinates u, v (repeat wrap in u; in v repeat
        or clamp to edge)."""
        filtered = self._filtered(self._corners(u, v, wrap_v))
        value = filtered[:3]
        if unassociate and self.has_alpha:
            a = filtered[3]
            partial = (a != 0) & (a != 1)
            value = np.where(partial, value / np.where(partial, a, np.float32(1.0)), value)
        return srgb_to_linear(value) if self.srgb else np.ascontiguousarray(value)

    def _filtered(self, corners) -> np.ndarray:
        """(3 or 4, N) bilinear blend of the four gathered corners."""
        (i00, i01, i10, i11), fx, fy = corners
        top = self.gather(i00) * (1 - fx) + self.gather(i01) * fx
        bot = self.gather(i10) * (1 - fx) + self.gather(i11) * fx
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


# ---------------------------------------------------------------- filters (Cycles' kernel/device/cpu/image.h)
def _wrap(i: np.ndarray, size: int, extension: str):
    """Texel indices under the extension mode, and which are inside (CLIP reads zero outside)."""
    if extension == "REPEAT":
        return np.mod(i, size), None
    if extension == "MIRROR":
        m = np.abs(i + (i < 0)) % (2 * size)
        return np.where(m >= size, 2 * size - m - 1, m), None
    inside = (i >= 0) & (i < size)
    return np.clip(i, 0, size - 1), (inside if extension == "CLIP" else None)


def _taps(x: np.ndarray, size: int, interpolation: str):
    """Per axis: texel indices (k, n) int64 and weights (k, n) float32 of the filter."""
    if interpolation == "Closest":
        return np.floor(x * F32(size)).astype(np.int64)[None], np.ones((1, len(x)), F32)
    s = x * F32(size) - HALF
    i = np.floor(s)
    t = (s - i).astype(F32)
    i = i.astype(np.int64)
    if interpolation in ("Cubic", "Smart"):
        t2, t3 = t * t, t * t * t
        w = np.stack([(ONE - t) ** 3 / F32(6.0), (F32(3.0) * t3 - F32(6.0) * t2 + F32(4.0)) / F32(6.0),
                      (F32(-3.0) * t3 + F32(3.0) * t2 + F32(3.0) * t + ONE) / F32(6.0), t3 / F32(6.0)])
        return np.stack([i - 1, i, i + 1, i + 2]), w.astype(F32)
    return np.stack([i, i + 1]), np.stack([ONE - t, t])


def sample_texture(tex, u, v, interpolation: str, extension: str):
    """(C, n) filtered values of a kernels.textures.Texture at (u, v): colour (3 rows) and, for RGBA
    textures, alpha. Each filter tap gathers just the n texels it reads (Texture.gather: as float32,
    associated), weighs and sums them; the texture itself is never copied or converted whole."""
    width, height = tex.width, tex.height
    u = np.nan_to_num(np.clip(u, -1e6, 1e6), nan=0.0).astype(F32)
    v = np.nan_to_num(np.clip(v, -1e6, 1e6), nan=0.0).astype(F32)
    xi, xw = _taps(u, width, interpolation)
    yi, yw = _taps(v, height, interpolation)
    xi, x_in = _wrap(xi, width, extension)
    yi, y_in = _wrap(yi, height, extension)
    if extension == "CLIP":
        xw = xw * x_in
        yw = yw * y_in
    out = np.zeros((4 if tex.has_alpha else 3, len(u)), F32)
    for a in range(len(yi)):
        row = yi[a] * width
        for b in range(len(xi)):
            out += tex.gather(row + xi[b]) * (yw[a] * xw[b])
    return out
