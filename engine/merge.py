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

from .image_files import EXR_MULTIPART, exr_headers


class MergeError(Exception):
    """A one-line reason the merge cannot be done."""


def exr_strings(path: str) -> dict[str, str]:
    """The string attributes of an OpenEXR file's (first) header: Blender writes its stamp fields there."""
    with open(path, "rb") as f:
        data = f.read(1 << 20)
    if data[:4] != b"\x76\x2f\x31\x01":
        raise MergeError(f"{path} is not an OpenEXR file")
    try:
        header = exr_headers(data)[0][0]
    except (ValueError, IndexError, struct.error):
        raise MergeError(f"{path}: unreadable OpenEXR header") from None
    return {name: value.decode("utf-8", "replace") for name, (kind, value) in header.items() if kind == "string"}


def samples_of(path: str) -> int:
    fields = exr_strings(path)
    if "ember.samples" not in fields:
        raise MergeError(f"{path} holds no sample count (ember.samples): not an Ember render of a sample range")
    if int(fields.get("ember.adaptive", "0")):
        raise MergeError(f"{path} was rendered with adaptive sampling: its pixels hold different sample counts")
    if int(fields.get("ember.denoised", "0")):
        raise MergeError(f"{path} is denoised: denoised images do not average (render ranges without denoising)")
    return int(fields["ember.samples"])


def merge_arrays(parts) -> np.ndarray:
    """The average of sample ranges' images, each weighted by its sample count: `parts` is a sequence of
    (image, samples) with images of one shape (any layout, float); float64 sums, float32 result. The same
    arithmetic for files (merge) and for the Ray driver's in-memory ranges."""
    total, merged = 0, None
    for image, count in parts:
        if merged is not None and np.shape(image) != merged.shape:
            raise MergeError(f"ranges of different sizes: {np.shape(image)} and {merged.shape}")
        weighted = np.asarray(image, np.float64) * count
        merged = weighted if merged is None else merged + weighted
        total += count
    if merged is None or total <= 0:
        raise MergeError("nothing to merge: the ranges hold no samples")
    return (merged / total).astype(np.float32)


def read_exr_channels(path: str, names) -> dict[str, np.ndarray]:
    """Channels of an uncompressed scanline OpenEXR file, single- or multi-part (Blender writes a multilayer
    file as one part per layer): {name: (H, W) float32}, row 0 at the bottom as Blender's pixel buffers.
    What Ember's Ray workers write for the passes Blender cannot hand back to Python headless."""
    with open(path, "rb") as f:
        data = f.read()
    parts, flags, pos = exr_headers(data)
    multipart = bool(flags & EXR_MULTIPART)
    found = {}
    for header in parts:
        header = {name: value for name, (_, value) in header.items()}
        if header["compression"][0] != 0:
            raise MergeError(f"{path}: compressed OpenEXR (only uncompressed files are read)")
        channels, raw, i = [], header["channels"], 0
        while raw[i] != 0:  # name\0 pixel_type(i32) pLinear(u8) reserved(3) xSampling(i32) ySampling(i32)
            end = raw.index(b"\0", i)
            channels.append((raw[i:end].decode(), struct.unpack_from("<i", raw, end + 1)[0]))
            i = end + 17
        x0, y0, x1, y1 = struct.unpack("<4i", header["dataWindow"])
        width, height = x1 - x0 + 1, y1 - y0 + 1
        offsets = struct.unpack_from(f"<{height}Q", data, pos)  # one chunk per scanline when uncompressed
        pos += 8 * height
        sizes = [4 if kind != 1 else 2 for _, kind in channels]  # UINT and FLOAT: 4 bytes, HALF: 2
        for c, (name, kind) in enumerate(channels):
            if name not in names:
                continue
            if kind != 2:
                raise MergeError(f"{path}: channel {name!r} is not 32-bit float")
            skip = 4 * multipart + 8 + width * sum(sizes[:c])  # [part], y, size, the channels before it
            image = np.empty((height, width), np.float32)
            for offset in offsets:
                y = struct.unpack_from("<i", data, offset + 4 * multipart)[0]
                image[y1 - y] = np.frombuffer(data, np.float32, width, offset + skip)  # file rows go down
            found[name] = image
    missing = [n for n in names if n not in found]
    if missing:
        raise MergeError(f"{path} has no channel {missing[0]!r}")
    return found


def load_pixels(path: str) -> tuple[np.ndarray, int, int]:
    """A single-layer image file through Blender: (W * H * 4,) float32 RGBA, rows from the bottom, as
    Image.pixels holds them, and its width and height. The image is removed from bpy.data again."""
    import bpy
    image = bpy.data.images.load(path, check_existing=False)
    try:
        if image.type == "MULTILAYER":
            raise MergeError(f"{path} is a multilayer OpenEXR: merge reads single-layer ones (the image)")
        width, height = image.size
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    return pixels, width, height


def merge(inputs: list[str], output: str) -> int:
    """Merge the renders `inputs` into `output` (OpenEXR, 32-bit float); returns the total sample count."""
    import bpy
    if len(inputs) < 2:
        raise MergeError("merge needs at least two renders")
    counts = [samples_of(path) for path in inputs]
    parts, size = [], None
    for path, count in zip(inputs, counts):
        pixels, width, height = load_pixels(path)
        if size is not None and (width, height) != size:
            raise MergeError(f"{path} is {width}x{height}, the others {size[0]}x{size[1]}")
        size = (width, height)
        parts.append((pixels, count))
    merged = merge_arrays(parts)
    result = bpy.data.images.new("ember-merged", size[0], size[1], alpha=True, float_buffer=True)
    try:
        result.colorspace_settings.is_data = True  # written as it is: scene-linear values, untouched
        result.pixels.foreach_set(merged)
        result.filepath_raw = os.path.abspath(output)
        result.file_format = "OPEN_EXR"
        result.save()
    finally:
        bpy.data.images.remove(result)
    return sum(counts)
