"""Cryptomatte: the ids of names and the ranked (id, coverage) slots a render accumulates per pixel.

Ids (Cryptomatte specification 1.1.0, "ID Generation"; Cycles util/murmurhash.cpp): MurmurHash3_x86_32 of the
name's UTF-8 bytes with seed 0, and the float32 with the same bits except that the exponent is clamped to
[1, 254], so that no id is a denormal, an infinity or a NaN (nor 0.0, which means "no id").

Accumulation (Cycles kernel/film/cryptomatte_passes.h): each pixel keeps `slots` (id, summed matte weight)
pairs, 2 per RGBA layer (Cryptomatte Levels rounded up to even, at most 16). A sample's id claims the
pixel's first free slot, or adds to the slot already holding it. At the end the slots are ranked by
weight, and the weights divided by the pixel's sample count become coverages.

Where Ember differs, on purpose:
- an id that finds every slot taken is dropped. Cycles adds its weight to the last slot, so that slot's
  matte also covers whatever did not fit; dropping keeps every written coverage exact (the pixel's
  coverages then sum to less than 1, the ids past the levels being absent as the specification has it).
- the ids new to a pixel within one `add` claim its free slots in decreasing order of their weight in that
  call (Cycles: in sample order), so a call holding several samples of a pixel keeps its heaviest ids.
- every kind is ranked: Cycles 5.0 ranks only the first enabled kind's slots (its post-process sorts
  2 * cryptomatte_depth slots from the first Cryptomatte pass) and leaves Material and Asset in first-seen
  order when Object is on too.
"""
from __future__ import annotations

import struct

import numpy as np

DEFAULT_LEVELS = 6          # Blender's ViewLayer.pass_cryptomatte_depth default (the specification's)
MAX_LEVELS = 16             # Cycles' clamp (blender/addon/engine.py, blender/sync.cpp)

_MASK = 0xFFFFFFFF


def layer_count(levels: int) -> int:
    """RGBA layers ("00", "01", ...) that hold `levels` ranked ids: 2 ids a layer, as Cycles."""
    return (min(MAX_LEVELS, int(levels)) + 1) // 2


def bytes_per_pixel(levels: int) -> int:
    """Memory of CryptoFilm per pixel: a float32 id and a float64 weight per slot."""
    return 2 * layer_count(levels) * 12


# ---------------------------------------------------------------- ids
def _rotl(x: int, r: int) -> int:
    return ((x << r) | (x >> (32 - r))) & _MASK


def murmur3_32(data: bytes, seed: int = 0) -> int:
    """MurmurHash3_x86_32 of `data` (blocks read little-endian, as on the x86 Blender runs on)."""
    c1, c2 = 0xCC9E2D51, 0x1B873593
    h = seed & _MASK
    body = len(data) & ~3
    for (k,) in struct.iter_unpack("<I", data[:body]):
        k = (_rotl((k * c1) & _MASK, 15) * c2) & _MASK
        h = (_rotl(h ^ k, 13) * 5 + 0xE6546B64) & _MASK
    tail = data[body:]
    if tail:
        k = int.from_bytes(tail, "little")
        h ^= (_rotl((k * c1) & _MASK, 15) * c2) & _MASK
    h ^= len(data)
    h = ((h ^ (h >> 16)) * 0x85EBCA6B) & _MASK
    h = ((h ^ (h >> 13)) * 0xC2B2AE35) & _MASK
    return h ^ (h >> 16)


def hash_name_u32(name: str) -> int:
    """The uint32 hash of a name: what the manifest writes, as 8 hex digits."""
    return murmur3_32(name.encode("utf-8"), 0)


def hash_to_float(hashes) -> np.ndarray:
    """uint32 hashes -> float32 ids: the same bits with the exponent clamped to [1, 254]."""
    h = np.asarray(hashes, np.uint32)
    exponent = np.clip((h >> np.uint32(23)) & np.uint32(0xFF), 1, 254).astype(np.uint32)
    bits = (h & np.uint32(0x807FFFFF)) | (exponent << np.uint32(23))
    return bits.view(np.float32)


def hash_name(name: str) -> np.float32:
    """The float32 id Cycles writes for `name` (an object, material or asset name)."""
    return hash_to_float(np.uint32(hash_name_u32(name)))[()]


def hash_names(names) -> np.ndarray:
    """(K,) float32 ids of K names; a name repeated (instances of one object) is hashed once."""
    names = list(names)
    cache = {n: hash_name_u32(n) for n in dict.fromkeys(names)}
    return hash_to_float(np.array([cache[n] for n in names], np.uint32)).reshape(len(names))


# ---------------------------------------------------------------- accumulation
class CryptoFilm:
    """The ranked id slots of one Cryptomatte kind over a height x width region (row 0 at the top).

    ids : (H * W, S) float32 ids by slot, 0.0 where the slot is free; a pixel's slots fill from slot 0.
    weights : (H * W, S) float64 summed matte weights of those ids.
    """

    def __init__(self, height: int, width: int, depth: int = DEFAULT_LEVELS):
        self.height, self.width = height, width
        self.slots = 2 * layer_count(depth)
        self.ids = np.zeros((height * width, self.slots), np.float32)
        self.weights = np.zeros((height * width, self.slots), np.float64)

    def add(self, pixels, ids, weights) -> None:
        """Accumulate N samples: pixels (N,) int64 flat region index (row * width + col), ids (N,) float32,
        weights (N,) float32 matte weights. Samples of weight 0 (the background, a holdout) or id 0 (no
        id, as the specification writes it) are skipped; several samples may share a pixel."""
        pixels = np.asarray(pixels, np.int64).reshape(-1)
        ids = np.asarray(ids, np.float32).reshape(-1)
        weights = np.asarray(weights, np.float32).reshape(-1)
        keep = (weights > 0) & (ids != 0)
        self._insert(pixels[keep], ids[keep], weights[keep].astype(np.float64))

    def merge(self, other: "CryptoFilm", rows: range) -> None:
        """Add another accumulator's slots (its rows going to the rows `rows`) as one call of `add` would."""
        assert other.width == self.width and len(rows) == other.height and (not rows or rows[-1] < self.height)
        pixel, slot = np.nonzero(other.ids)
        row = np.asarray(rows, np.int64)[pixel // self.width]
        self._insert(row * self.width + pixel % self.width, other.ids[pixel, slot], other.weights[pixel, slot])

    def _insert(self, pixels: np.ndarray, ids: np.ndarray, weights: np.ndarray) -> None:
        if not len(pixels):
            return
        # One entry per (pixel, id) with its summed weight and its first position in the call.
        key = (pixels << 32) | ids.view(np.uint32).astype(np.int64)
        key, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        weight = np.bincount(inverse.reshape(-1), weights, minlength=len(key))
        pixel = key >> 32
        uid = (key & _MASK).astype(np.uint32).view(np.float32)

        held = self.ids[pixel]                                    # (U, S)
        match = held == uid[:, None]
        found = match.any(axis=1)
        # (pixel, slot) pairs are distinct here: a pixel holds an id in one slot at most.
        self.weights[pixel[found], match[found].argmax(axis=1)] += weight[found]

        new = ~found
        if not new.any():
            return
        pixel, uid, weight, first = pixel[new], uid[new], weight[new], first[new]
        used = np.count_nonzero(held[new], axis=1)
        order = np.lexsort((first, -weight, pixel))               # by pixel, heaviest first, then by arrival
        pixel, uid, weight, used = pixel[order], uid[order], weight[order], used[order]
        n = np.arange(len(pixel))
        run_start = np.maximum.accumulate(np.where(np.r_[True, pixel[1:] != pixel[:-1]], n, 0))
        slot = used + (n - run_start)
        fits = slot < self.slots
        self.ids[pixel[fits], slot[fits]] = uid[fits]
        self.weights[pixel[fits], slot[fits]] = weight[fits]

    def layers(self, samples_per_pixel, row0: int = 0, row1: int | None = None) -> np.ndarray:
        """(rows, W, 2 * S) float32 of rows [row0, row1): per pixel the ids ranked by weight (ties keep slot
        order), each followed by its weight over the pixel's samples: channels 4 l .. 4 l + 3 are Cycles'
        layer l ("00", "01", ...) RGBA = (id 2l, coverage 2l, id 2l+1, coverage 2l+1); free slots are
        (0, 0). samples_per_pixel: broadcastable to (rows, W), e.g. Film.pixel_samples' rows; a pixel
        without samples has coverage 0."""
        row1 = self.height if row1 is None else row1
        rows = row1 - row0
        span = slice(row0 * self.width, row1 * self.width)
        weights, ids = self.weights[span], self.ids[span]
        order = np.argsort(-weights, axis=1, kind="stable")
        count = np.broadcast_to(np.asarray(samples_per_pixel, np.float64), (rows, self.width)).reshape(-1)
        scale = np.divide(1.0, count, out=np.zeros_like(count), where=count > 0)
        out = np.empty((rows * self.width, self.slots, 2), np.float32)
        out[:, :, 0] = np.take_along_axis(ids, order, axis=1)
        out[:, :, 1] = np.take_along_axis(weights, order, axis=1) * scale[:, None]
        return out.reshape(rows, self.width, 2 * self.slots)
