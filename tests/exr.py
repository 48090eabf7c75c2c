"""A minimal reader of scanline OpenEXR files without compression or with ZIP/ZIPS (Blender's multilayer
output), for tests that check render passes: Blender headless cannot hand passes back to Python otherwise, and
OpenImageIO's Python module is not in the bpy wheel."""
from __future__ import annotations

import struct
import zlib

import numpy as np

_TYPES = {0: np.uint32, 1: np.float16, 2: np.float32}


def read_exr(path: str) -> dict:
    """{channel name: (H, W) float32}, row 0 at the top."""
    data = open(path, "rb").read()
    assert data[:4] == b"\x76\x2f\x31\x01", "not an OpenEXR file"
    pos = 8
    header = {}
    while data[pos] != 0:
        end = data.index(b"\0", pos)
        name = data[pos:end].decode()
        tend = data.index(b"\0", end + 1)
        kind = data[end + 1:tend].decode()
        size = struct.unpack_from("<i", data, tend + 1)[0]
        header[name] = (kind, data[tend + 5:tend + 5 + size])
        pos = tend + 5 + size
    pos += 1
    compression = header["compression"][1][0]
    lines_per_block = {0: 1, 2: 1, 3: 16}.get(compression)
    assert lines_per_block is not None, f"compression {compression} is not read (NONE, ZIPS and ZIP are)"
    channels = []
    raw = header["channels"][1]
    i = 0
    while raw[i] != 0:
        end = raw.index(b"\0", i)
        name = raw[i:end].decode()
        pixel_type = struct.unpack_from("<i", raw, end + 1)[0]
        channels.append((name, pixel_type))
        i = end + 1 + 16
    x0, y0, x1, y1 = struct.unpack("<4i", header["dataWindow"][1])
    width, height = x1 - x0 + 1, y1 - y0 + 1
    blocks = -(-height // lines_per_block)
    pos += 8 * blocks  # the offset table
    out = {name: np.zeros((height, width), np.float32) for name, _ in channels}
    for _ in range(blocks):
        y, size = struct.unpack_from("<ii", data, pos)
        pos += 8
        chunk = data[pos:pos + size]
        pos += size
        lines = min(lines_per_block, y0 + height - y)
        expected = lines * width * sum(np.dtype(_TYPES[t]).itemsize for _, t in channels)
        if compression and size < expected:
            chunk = _unzip(chunk)
        block = 0
        for line in range(lines):
            for name, pixel_type in channels:
                dtype = _TYPES[pixel_type]
                out[name][y - y0 + line] = np.frombuffer(chunk, dtype, width, block).astype(np.float32)
                block += width * np.dtype(dtype).itemsize
    return out


def _unzip(chunk: bytes) -> bytes:
    """EXR's ZIP: zlib, then a byte predictor, then the two halves of the bytes interleaved."""
    raw = np.frombuffer(zlib.decompress(chunk), np.uint8).astype(np.int64)
    raw[1:] -= 128
    t = (np.cumsum(raw) & 0xFF).astype(np.uint8)
    out = np.empty_like(t)
    half = (len(t) + 1) // 2
    out[0::2] = t[:half]
    out[1::2] = t[half:]
    return out.tobytes()


def read_multilayer(path):
    """({part name: {channel: (H, W) float32}}, the first part's string attributes) of a multipart scanline
    EXR, as Blender 5 writes multilayer files (read_exr reads single-part files)."""
    data = open(path, "rb").read()
    assert struct.unpack_from("<i", data, 4)[0] & 0x1000, "not a multipart EXR"
    pos, headers = 8, []
    while data[pos] != 0:
        header = {}
        while data[pos] != 0:
            end = data.index(b"\0", pos)
            kind_end = data.index(b"\0", end + 1)
            size = struct.unpack_from("<i", data, kind_end + 1)[0]
            header[data[pos:end].decode()] = (data[end + 1:kind_end].decode(),
                                              data[kind_end + 5:kind_end + 5 + size])
            pos = kind_end + 5 + size
        headers.append(header)
        pos += 1
    pos += 1
    counts = [struct.unpack("<i", h["chunkCount"][1])[0] for h in headers]
    pos += 8 * sum(counts)                                   # the offset tables
    parts = {}
    for _ in range(sum(counts)):
        part, y, size = struct.unpack_from("<iii", data, pos)
        chunk, pos = data[pos + 12:pos + 12 + size], pos + 12 + size
        header = headers[part]
        channels, raw, i = [], header["channels"][1], 0
        while raw[i] != 0:
            end = raw.index(b"\0", i)
            channels.append((raw[i:end].decode(), _TYPES[struct.unpack_from("<i", raw, end + 1)[0]]))
            i = end + 17
        x0, y0, x1, y1 = struct.unpack("<4i", header["dataWindow"][1])
        width, height = x1 - x0 + 1, y1 - y0 + 1
        lines = min({0: 1, 2: 1, 3: 16}[header["compression"][1][0]], y0 + height - y)
        if size < lines * width * sum(np.dtype(t).itemsize for _, t in channels):
            chunk = _unzip(chunk)
        planes = parts.setdefault(header["name"][1].decode(), {})
        offset = 0
        for line in range(lines):
            for name, dtype in channels:
                plane = planes.setdefault(name.rsplit(".", 1)[-1], np.zeros((height, width), np.float32))
                plane[y - y0 + line] = np.frombuffer(chunk, dtype, width, offset)
                offset += width * np.dtype(dtype).itemsize
    strings = {k: v.decode() for k, (kind, v) in headers[0].items() if kind == "string"}
    return parts, strings


def render_multilayer(scene):
    """Render the scene (its engine as set) to a multilayer OpenEXR of 32-bit floats and read it back:
    read_multilayer's (parts, strings)."""
    import os
    import tempfile

    import bpy
    settings = scene.render.image_settings
    settings.media_type, settings.color_depth = "MULTI_LAYER_IMAGE", "32"
    with tempfile.TemporaryDirectory() as tmp:
        scene.render.filepath = os.path.join(tmp, "layers.exr")
        bpy.ops.render.render(write_still=True)
        return read_multilayer(scene.render.filepath)
