"""`python -m ember merge`: sample ranges of one frame, rendered apart (--sample-offset, several machines),
merged into the frame they make together.

Ember's sample sequence is indexed by sample number, so ranges 0-31 and 32-63 are exactly the samples of a
0-63 render: their images weighted by their sample counts (the `ember.samples` field Ember writes into each
render's metadata) average to that render's, up to float rounding. Single-layer OpenEXR files; adaptive
sampling and denoising must be off in the ranges (the command line's --sample-offset turns them off):
per-pixel counts are not stored, and a denoised image does not average.
"""
from __future__ import annotations

import os
import struct

import numpy as np


class MergeError(Exception):
    """A one-line reason the merge cannot be done."""


def exr_strings(path: str) -> dict[str, str]:
    """The string attributes of an OpenEXR file's (first) header: Blender writes its stamp fields there."""
    with open(path, "rb") as f:
        data = f.read(1 << 20)
    if data[:4] != b"\x76\x2f\x31\x01":
        raise MergeError(f"{path} is not an OpenEXR file")
    out, pos = {}, 8
    try:
        while data[pos] != 0:
            end = data.index(b"\0", pos)
            kind_end = data.index(b"\0", end + 1)
            size = struct.unpack_from("<i", data, kind_end + 1)[0]
            if data[end + 1:kind_end] == b"string":
                out[data[pos:end].decode("utf-8", "replace")] = \
                    data[kind_end + 5:kind_end + 5 + size].decode("utf-8", "replace")
            pos = kind_end + 5 + size
    except (ValueError, IndexError, struct.error):
        raise MergeError(f"{path}: unreadable OpenEXR header") from None
    return out


def samples_of(path: str) -> int:
    fields = exr_strings(path)
    if "ember.samples" not in fields:
        raise MergeError(f"{path} holds no sample count (ember.samples): not an Ember render of a sample range")
    if int(fields.get("ember.adaptive", "0")):
        raise MergeError(f"{path} was rendered with adaptive sampling: its pixels hold different sample counts")
    if int(fields.get("ember.denoised", "0")):
        raise MergeError(f"{path} is denoised: denoised images do not average (render ranges without denoising)")
    return int(fields["ember.samples"])


def merge(inputs: list[str], output: str) -> int:
    """Merge the renders `inputs` into `output` (OpenEXR, 32-bit float); returns the total sample count."""
    import bpy
    if len(inputs) < 2:
        raise MergeError("merge needs at least two renders")
    counts = [samples_of(path) for path in inputs]
    total, merged, size = sum(counts), None, None
    for path, count in zip(inputs, counts):
        image = bpy.data.images.load(path, check_existing=False)
        try:
            if image.type == "MULTILAYER":
                raise MergeError(f"{path} is a multilayer OpenEXR: merge reads single-layer ones (the image)")
            if size is not None and tuple(image.size) != size:
                raise MergeError(f"{path} is {image.size[0]}x{image.size[1]}, the others {size[0]}x{size[1]}")
            size = tuple(image.size)
            pixels = np.empty(size[0] * size[1] * 4, np.float32)
            image.pixels.foreach_get(pixels)
        finally:
            bpy.data.images.remove(image)
        weighted = pixels.astype(np.float64) * count
        merged = weighted if merged is None else merged + weighted
    result = bpy.data.images.new("ember-merged", size[0], size[1], alpha=True, float_buffer=True)
    try:
        result.colorspace_settings.is_data = True  # written as it is: scene-linear values, untouched
        result.pixels.foreach_set((merged / total).astype(np.float32))
        result.filepath_raw = os.path.abspath(output)
        result.file_format = "OPEN_EXR"
        result.save()
    finally:
        bpy.data.images.remove(result)
    return total
