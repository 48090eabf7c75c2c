"""Image files on disk: whether a file Blender wrote is whole, and OpenEXR headers.

Blender's image writers log a failed write (a full disk, a quota, an I/O error) and return as if they had
succeeded, leaving a truncated or empty file. written_file_problem() tells a whole file from such a one
without decoding it: the structure each format declares must lie within the file and end where it ends
(PNG's chunks up to IEND, OpenEXR's chunk offset table and chunk sizes, TIFF's strips and tiles, the file
size BMP, DPX, Cineon and WebP state in their headers, JPEG's and JPEG 2000's end markers and boxes). The
few formats without such a structure (Radiance HDR, SGI, Targa) are decoded with the OpenImageIO Blender
bundles. A file with a hole (a range never written) is incomplete whatever its format.
"""
from __future__ import annotations

import os
import struct

# OpenEXR scanlines per chunk, by compression (NONE, RLE, ZIPS, ZIP, PIZ, PXR24, B44, B44A, DWAA, DWAB).
_EXR_LINES = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}
_EXR_MAGIC = b"\x76\x2f\x31\x01"
EXR_MULTIPART = 0x1000
_EXR_TILED = 0x200
_TARGA_FOOTER = b"TRUEVISION-XFILE.\0"


class Incomplete(Exception):
    """Why a file is not whole, in a few words."""


class _Reader:
    """Random access to a file's bytes; reading past its end raises Incomplete."""

    def __init__(self, file):
        self.file = file
        self.size = os.fstat(file.fileno()).st_size

    def at(self, offset: int, n: int) -> bytes:
        if offset < 0 or offset + n > self.size:
            raise Incomplete(f"it ends at byte {self.size}, inside data it declares up to byte {offset + n}")
        self.file.seek(offset)
        data = self.file.read(n)
        if len(data) != n:
            raise Incomplete(f"it could not be read back at byte {offset}")
        return data

    def unpack(self, fmt: str, offset: int) -> tuple:
        return struct.unpack(fmt, self.at(offset, struct.calcsize(fmt)))


def written_file_problem(path: str, file_format: str) -> str | None:
    """None when the image file at `path`, written as Blender's `file_format` (ImageFormatSettings
    .file_format: PNG, OPEN_EXR, ...), is whole; else why it is not, in a few words."""
    try:
        with open(path, "rb") as file:
            reader = _Reader(file)
            if reader.size == 0:
                return "it is empty"
            _check_no_hole(file.fileno(), reader.size)
            _CHECKS.get(file_format, _decodes)(reader, path)
    except Incomplete as err:
        return str(err)
    except OSError as err:
        return f"it cannot be read back ({err.strerror or err})"
    return None


def _check_no_hole(fd: int, size: int) -> None:
    """A range of the file that was never written (the writer seeked past a failed write)."""
    try:
        hole = os.lseek(fd, 0, os.SEEK_HOLE)
    except (OSError, AttributeError):  # a file system (or platform) that cannot tell
        return
    if hole < size:
        raise Incomplete(f"bytes from {hole} on were never written")


def _png(r: _Reader, path: str) -> None:
    if r.at(0, 8) != b"\x89PNG\r\n\x1a\n":
        raise Incomplete("it is not a PNG file")
    pos = 8
    while True:
        length, kind = r.unpack(">I4s", pos)
        pos += 12 + length
        if pos > r.size:
            raise Incomplete(f"it ends at byte {r.size}, inside a PNG chunk that ends at byte {pos}")
        if kind == b"IEND":
            return


def _jpeg(r: _Reader, path: str) -> None:
    if r.at(0, 2) != b"\xff\xd8":
        raise Incomplete("it is not a JPEG file")
    if r.size < 4 or r.at(r.size - 2, 2) != b"\xff\xd9":
        raise Incomplete("it lacks JPEG's end marker")


def _exr(r: _Reader, path: str) -> None:
    head = r.at(0, min(r.size, 1 << 16))
    if head[:4] != _EXR_MAGIC:
        raise Incomplete("it is not an OpenEXR file")
    while True:
        try:
            parts, flags, table = exr_headers(head)
            break
        except (IndexError, ValueError, struct.error):
            if len(head) == r.size:
                raise Incomplete("its OpenEXR header is cut short") from None
            head = r.at(0, min(r.size, 2 * len(head)))
    counts, leaders = [], []
    for header in parts:
        try:
            count, leader = _exr_chunks(header, flags)
        except (KeyError, IndexError, struct.error):
            raise Incomplete("its OpenEXR header lacks the image's layout") from None
        if count is None:   # deep or multi-level images: what Blender does not write
            return _decodes(r, path)
        counts.append(count)
        leaders.append(leader + (4 if flags & EXR_MULTIPART else 0))
    data_start = table + 8 * sum(counts)
    offsets = r.unpack(f"<{sum(counts)}Q", table)
    first = 0
    for count, leader in zip(counts, leaders):
        for offset in offsets[first:first + count]:
            if offset < data_start:
                raise Incomplete("its OpenEXR chunk table was not written")
            size = r.unpack("<i", offset + leader - 4)[0]
            if size < 0 or offset + leader + size > r.size:
                raise Incomplete(f"it ends at byte {r.size}, inside an OpenEXR chunk that ends at byte "
                                 f"{offset + leader + size}")
        first += count


def _exr_chunks(header: dict, flags: int) -> tuple[int | None, int]:
    """(chunks of one part, bytes of a chunk's leader before its data, its size field included); None chunks
    for parts this check does not read (deep data, mipmaps)."""
    kind = header.get("type", ("", b""))[1].rstrip(b"\0")
    tiled = kind == b"tiledimage" or (not kind and flags & _EXR_TILED)
    if kind.startswith(b"deep"):
        return None, 0
    if "chunkCount" in header:
        return struct.unpack("<i", header["chunkCount"][1])[0], 20 if tiled else 8
    x0, y0, x1, y1 = struct.unpack("<4i", header["dataWindow"][1])
    width, height = x1 - x0 + 1, y1 - y0 + 1
    if tiled:
        tile_w, tile_h, mode = struct.unpack("<IIB", header["tiles"][1])
        if mode & 0xF:
            return None, 0
        return -(-width // tile_w) * -(-height // tile_h), 20
    lines = _EXR_LINES.get(header["compression"][1][0])
    return (None, 0) if lines is None else (-(-height // lines), 8)


def exr_headers(data: bytes) -> tuple[list[dict[str, tuple[str, bytes]]], int, int]:
    """The headers of the OpenEXR file that starts with `data` ({attribute name: (its type, its raw value)},
    one per part), the version field's flags, and where the chunk offset table begins. IndexError, ValueError or
    struct.error when `data` ends before the headers do."""
    flags = struct.unpack_from("<I", data, 4)[0]
    multipart = bool(flags & EXR_MULTIPART)
    parts, pos = [], 8
    while True:  # attributes (name\0 type\0 size value) up to a \0; multi-part: headers up to an empty one
        header = {}
        while data[pos] != 0:
            end = data.index(b"\0", pos)
            kind_end = data.index(b"\0", end + 1)
            size = struct.unpack_from("<i", data, kind_end + 1)[0]
            value = data[kind_end + 5:kind_end + 5 + size]
            if len(value) != size:
                raise IndexError("the header goes on past the data")
            header[data[pos:end].decode("utf-8", "replace")] = (data[end + 1:kind_end].decode("ascii", "replace"),
                                                                value)
            pos = kind_end + 5 + size
        pos += 1
        parts.append(header)
        if not multipart or data[pos] == 0:
            return parts, flags, pos + multipart


def _tiff(r: _Reader, path: str) -> None:
    magic = r.at(0, 4)
    if magic in (b"II+\0", b"MM\0+"):   # BigTIFF, which Blender does not write
        return _decodes(r, path)
    order = {b"II*\0": "<", b"MM\0*": ">"}.get(magic)
    if order is None:
        raise Incomplete("it is not a TIFF file")
    ifd = r.unpack(order + "I", 4)[0]
    seen = set()
    while ifd and ifd not in seen:
        seen.add(ifd)
        count = r.unpack(order + "H", ifd)[0]
        fields = {}
        for i in range(count):
            tag, kind, n, value = r.unpack(order + "HHI4s", ifd + 2 + 12 * i)
            fields[tag] = (kind, n, value)
        starts = _tiff_values(r, order, fields.get(273) or fields.get(324))
        sizes = _tiff_values(r, order, fields.get(279) or fields.get(325))
        if len(starts) != len(sizes):
            raise Incomplete("its TIFF strips are not all listed")
        for start, size in zip(starts, sizes):
            if start + size > r.size:
                raise Incomplete(f"it ends at byte {r.size}, inside a TIFF strip that ends at byte {start + size}")
        ifd = r.unpack(order + "I", ifd + 2 + 12 * count)[0]


def _tiff_values(r: _Reader, order: str, field) -> tuple:
    """A TIFF field of SHORT or LONG values, inline or elsewhere in the file."""
    if field is None:
        return ()
    kind, n, value = field
    code = {3: "H", 4: "I"}.get(kind)
    if code is None:
        raise Incomplete("its TIFF strips are of an unknown type")
    fmt = f"{order}{n}{code}"
    size = struct.calcsize(fmt)
    raw = value[:size] if size <= 4 else r.at(struct.unpack(order + "I", value)[0], size)
    return struct.unpack(fmt, raw)


def _declared_size(r: _Reader, offset: int, order: str, name: str) -> None:
    declared = r.unpack(order + "I", offset)[0]
    if declared and r.size < declared:
        raise Incomplete(f"it ends at byte {r.size} of the {declared} its {name} header declares")


def _bmp(r: _Reader, path: str) -> None:
    if r.at(0, 2) != b"BM":
        raise Incomplete("it is not a BMP file")
    _declared_size(r, 2, "<", "BMP")


def _dpx(r: _Reader, path: str) -> None:
    order = {b"SDPX": ">", b"XPDS": "<"}.get(r.at(0, 4))
    if order is None:
        raise Incomplete("it is not a DPX file")
    _declared_size(r, 16, order, "DPX")


def _cineon(r: _Reader, path: str) -> None:
    order = {b"\x80\x2a\x5f\xd7": ">", b"\xd7\x5f\x2a\x80": "<"}.get(r.at(0, 4))
    if order is None:
        raise Incomplete("it is not a Cineon file")
    _declared_size(r, 20, order, "Cineon")


def _webp(r: _Reader, path: str) -> None:
    if r.at(0, 4) != b"RIFF" or r.at(8, 4) != b"WEBP":
        raise Incomplete("it is not a WebP file")
    declared = r.unpack("<I", 4)[0] + 8
    if r.size < declared:
        raise Incomplete(f"it ends at byte {r.size} of the {declared} its WebP header declares")


def _jpeg2000(r: _Reader, path: str) -> None:
    if r.at(0, 4) == b"\xff\x4f\xff\x51":   # a bare codestream: SOC ... EOC
        if r.at(r.size - 2, 2) != b"\xff\xd9":
            raise Incomplete("it lacks JPEG 2000's end marker")
        return
    if r.at(4, 4) != b"jP  ":
        raise Incomplete("it is not a JPEG 2000 file")
    pos = 0
    while pos < r.size:  # boxes: length (0: to the end, 1: a 64-bit length follows), type
        length = r.unpack(">I", pos)[0]
        if length == 0:
            return
        if length == 1:
            length = r.unpack(">Q", pos + 8)[0]
        if length < 8:
            raise Incomplete("a JPEG 2000 box is damaged")
        pos += length
    if pos != r.size:
        raise Incomplete(f"it ends at byte {r.size}, inside a JPEG 2000 box that ends at byte {pos}")


def _targa(r: _Reader, path: str) -> None:
    if r.size < len(_TARGA_FOOTER) or r.at(r.size - len(_TARGA_FOOTER), len(_TARGA_FOOTER)) != _TARGA_FOOTER:
        raise Incomplete("it lacks the Targa footer Blender writes last")
    _decodes(r, path)


def _decodes(r: _Reader, path: str) -> None:
    """Formats without a declared structure: the whole image decoded by OpenImageIO (unchecked when
    Blender's bundled OpenImageIO cannot be imported)."""
    try:
        import bpy
        bpy.utils.expose_bundled_modules()
        import OpenImageIO as oiio
    except (ImportError, AttributeError):
        return
    image = oiio.ImageInput.open(path)
    if image is None:
        oiio.geterror()
        raise Incomplete("it cannot be opened as an image")
    try:
        pixels = image.read_image(format=oiio.FLOAT)
        error = image.geterror()
    finally:
        image.close()
    if pixels is None or error:
        raise Incomplete(f"it cannot be decoded ({error.splitlines()[0] if error else 'no pixels'})")


_CHECKS = {"PNG": _png, "JPEG": _jpeg, "OPEN_EXR": _exr, "OPEN_EXR_MULTILAYER": _exr, "TIFF": _tiff, "BMP": _bmp,
           "DPX": _dpx, "CINEON": _cineon, "WEBP": _webp, "JPEG2000": _jpeg2000, "TARGA": _targa,
           "TARGA_RAW": _targa}
