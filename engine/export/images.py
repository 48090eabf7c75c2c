"""Images: Blender images -> the texture arrays the kernel keeps (kernels.textures.Texture), in as little
memory as their pixels need, as Cycles keeps them.

8-bit images stay bytes, uint8 (Cycles' uchar4; 1 byte per channel where Blender's image.pixels hands out
4-byte floats), and 16-bit image files uint16 (Cycles' ushort4). A plain image file (PNG, JPEG, TIFF, not
packed, not edited in Blender) is read straight from the file with Blender's own OpenImageIO, as Blender's
loader reads it (the same decoder and options, grey expanded as Blender expands it, row 0 at the bottom), a
block of rows at a time: never held as floats, and Blender need not load its own copy. A packed 8-bit file is
read the same way; any other image (a packed 16-bit one, generated, painted, another format) comes from
image.pixels: 8-bit ones as k / 255 float32, turned back into their bytes, float ones (EXR, HDR, packed 16-bit)
as float32, as Cycles takes those from Blender. Channels no texture reads (alpha that is 1 everywhere, the
copies of grey) are dropped in the array's own memory. The tiles of a tiled (UDIM) image are read one by one
from their files (read_tile).

Colour: 8- and 16-bit images in the sRGB space are handed to the kernel sRGB-encoded and flagged, so that it
decodes them after filtering as Cycles does; Non-Color and scene-linear ones are used as stored; those in any
other space of Blender's configuration are converted to scene linear at load, as Cycles converts them (half
floats); float images are scene linear already. Alpha is kept for images that have it (the Image Texture's
Alpha output): straight colour is associated in its bytes as Cycles rounds it (associated_bytes); data,
channel-packed and premultiplied colour stays as stored.
"""
from __future__ import annotations

import functools
import os
import tempfile
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ...kernels.textures import BYTE_SCALE, WORD_SCALE, srgb_to_linear
from ..version import blender_version

# Byte images in these colour spaces (besides data ones such as Non-Color) hold linear values already.
LINEAR_BYTE_SPACES = ("Linear Rec.709", "scene_linear")
# File formats read straight from the file, with Blender's read options for each (imbuf/intern/oiio:
# imb_load_png, imb_load_jpeg, imb_load_tiff); anything else comes through image.pixels.
FILE_FORMATS = {"png": {"oiio:UnassociatedAlpha": 1}, "jpeg": {"jpeg:com_attributes": 0},
                "tiff": {"oiio:UnassociatedAlpha": 1}}
# Values per block when a whole image is walked: a few MB of temporaries at a time.
_BLOCK = 1 << 22


_UNREAD = object()   # read_image's file_pixels: not read yet


@dataclass(frozen=True)
class ImagePixels:
    """An image's pixels as the kernel keeps them.

    array : (H, W, C), C in {1, 3, 4} (alpha only where asked for and not all 1; grey as one channel),
        row 0 at the bottom: uint8 for 8-bit images (k stands for k / 255), uint16 for 16-bit image files in
        sRGB, a data or the scene-linear space (k / 65535; reads_words), with 4 channels colour associated as
        Cycles stores it (associated_bytes); float32 otherwise (finite and non-negative for float images; colour associated
        where Cycles associates it).
    srgb : the values are sRGB-encoded (an 8- or 16-bit image in an sRGB space); the kernel decodes them after
        filtering, as Cycles does. Otherwise they are linear.
    """
    array: np.ndarray
    srgb: bool

    def linear(self) -> np.ndarray:
        """(H, W, C) float32 linear values (colour associated with alpha)."""
        values = _as_float(self.array)
        return srgb_to_linear(values) if self.srgb else values


def read_image(image, warnings: list[str], alpha: bool = False, file_pixels=_UNREAD) -> ImagePixels | None:
    """An image's pixels; None (with a warning) when Blender cannot load it. alpha: keep the alpha
    channel when the image has one that is not 1 everywhere. file_pixels: file_bytes(image), when it was
    read already (ImageTextures.read)."""
    pixels = file_bytes(image) if file_pixels is _UNREAD else file_pixels
    if pixels is None:
        pixels = _blender_pixels(image)
    if pixels is None:
        warnings.append(f"Image '{image.name}' could not be loaded ({image.filepath or 'no file'}): "
                        f"rendered magenta")
        return None
    channels = pixels.shape[2]
    integer = pixels.dtype in (np.uint8, np.uint16)
    one = np.iinfo(pixels.dtype).max if integer else 1.0
    keep_alpha = alpha and channels == 4 and image.alpha_mode != "NONE" and pixels[:, :, 3].min() < one
    pixels = _narrowed(pixels, 4 if keep_alpha else 3 if channels >= 3 else 1)
    if not integer:  # float files (EXR, HDR) may hold negative or non-finite values; light cannot
        pixels = _cleaned(pixels)
        if keep_alpha and _associates_float_alpha(image):
            pixels[:, :, :3] *= pixels[:, :, 3:4]
        return ImagePixels(pixels, False)
    matrix = _linear_space_matrix(image.colorspace_settings.name)
    if matrix is not None and not image.colorspace_settings.is_data:
        # A linear space other than scene linear: converted at load, as Cycles converts such byte images
        # (to half floats; out-of-gamut values stay negative, as there).
        pixels = _as_float(pixels, associate=keep_alpha and _associates_alpha(image))
        pixels[:, :, :3] = (pixels[:, :, :3] @ matrix.T).astype(np.float16)
        return ImagePixels(pixels, False)
    name = image.colorspace_settings.name
    if not image.colorspace_settings.is_data and name not in ("sRGB",) + LINEAR_BYTE_SPACES:
        processor = _to_scene_linear(name)
        if processor is not None:
            return ImagePixels(_converted(pixels, processor, keep_alpha and _associates_alpha(image)), False)
    srgb = _is_srgb(image, warnings)
    if keep_alpha and _associates_alpha(image):
        pixels = associated_bytes(pixels)
    return ImagePixels(pixels, srgb)


def associated_bytes(pixels: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 or uint16 straight RGBA as Cycles stores an 8- or 16-bit image whose alpha it associates:
    each colour value times the alpha value over 255 (65,535), rounded down, still of its type
    (scene/image_oiio.cpp and blender/image.cpp load_pixels, util/image.h util_image_multiply_native; the
    colour is then filtered and, for sRGB images, decoded in the kernel). Rounding down leaves a partly
    transparent texel's colour up to one step darker than c x a / 255."""
    one = np.iinfo(pixels.dtype).max
    wide = np.uint16 if pixels.dtype == np.uint8 else np.uint32
    out = np.empty_like(pixels)
    alpha = pixels[:, :, 3].astype(wide)
    for c in range(3):
        out[:, :, c] = pixels[:, :, c].astype(wide) * alpha // one
    out[:, :, 3] = pixels[:, :, 3]
    return out


# From Blender 5.2, Cycles honours the image's alpha mode for float pixels too: Straight colour is
# associated at load (Cycles a50e77ae5, util/image_metadata.cpp); before, float pixels were taken as
# associated whatever the mode. Loaded EXR files are Premultiplied; generated and painted float images
# are Straight.
FLOAT_STRAIGHT_ASSOCIATED_FROM = (5, 2)


def _associates_float_alpha(image) -> bool:
    """Whether the Cycles of this Blender multiplies a float image's colour by its alpha at load."""
    return _associates_alpha(image) and blender_version()[:2] >= FLOAT_STRAIGHT_ASSOCIATED_FROM


def _associates_alpha(image) -> bool:
    """Whether Cycles stores this image's colour premultiplied by its alpha (not for data, channel-packed
    or ignored alpha), and the image holds it straight."""
    return not image.colorspace_settings.is_data and image.alpha_mode == "STRAIGHT"


# Linear colour spaces of Blender's configuration, with the mathutils conversion to scene linear (Blender's
# OCIO): a byte image in one of them holds linear values in those primaries.
_LINEAR_SPACES = {"ACEScg": "from_acescg_to_scene_linear", "ACES2065-1": "from_aces_to_scene_linear",
                  "Linear Rec.2020": "from_rec2020_linear_to_scene_linear",
                  "Linear CIE-XYZ D65": "from_xyz_d65_to_scene_linear"}


@functools.lru_cache(maxsize=None)
def _to_scene_linear(name: str):
    """An OpenColorIO CPU processor taking colour space `name` of Blender's configuration to scene linear, None
    where there is none (the space is unknown, or OpenColorIO cannot be imported)."""
    try:
        import bpy
        bpy.utils.expose_bundled_modules()
        import PyOpenColorIO as OCIO
        config = OCIO.Config.CreateFromFile(os.path.join(bpy.utils.resource_path("LOCAL"), "datafiles",
                                                         "colormanagement", "config.ocio"))
        return config.getProcessor(name, OCIO.ROLE_SCENE_LINEAR).getDefaultCPUProcessor()
    except Exception:  # noqa: BLE001 - any failure: the image is read as sRGB, with _is_srgb's warning
        return None


def _converted(pixels: np.ndarray, processor, associate: bool) -> np.ndarray:
    """(H, W, 3 or 4) float32 scene-linear values of 8- or 16-bit pixels in another colour space, converted at
    load as Cycles converts them (util/colorspace.cpp processor_apply_pixels_rgba: the straight colour through
    OpenColorIO, then times alpha where it associates; stored as half floats, so rounded to float16; out-of-gamut
    values stay negative). Grey becomes RGB."""
    height, width, channels = pixels.shape
    out = np.empty((height, width, 4 if channels == 4 else 3), np.float32)
    rows = max(1, _BLOCK // (width * 4))
    for y0 in range(0, height, rows):
        block = _as_float(pixels[y0:y0 + rows])
        rgb = np.ascontiguousarray(np.repeat(block, 3, axis=2) if channels == 1 else block[:, :, :3])
        processor.applyRGB(rgb)
        if associate:
            rgb *= block[:, :, 3:4]
        out[y0:y0 + rows, :, :3] = rgb.astype(np.float16)
        if channels == 4:
            out[y0:y0 + rows, :, 3] = block[:, :, 3]
    return out


def _linear_space_matrix(name: str) -> np.ndarray | None:
    """(3, 3) float32 matrix taking RGB in the linear space `name` to scene linear, None for others."""
    method = _LINEAR_SPACES.get(name)
    if method is None:
        return None
    from mathutils import Color
    convert = getattr(Color, method)
    return np.array([tuple(convert(Color(e))) for e in np.eye(3)], np.float32).T


def _is_srgb(image, warnings: list[str]) -> bool:
    """Whether an 8-bit (or 16-bit, from its file) image holds sRGB-encoded values (Blender returns 8-bit ones
    undecoded)."""
    settings = image.colorspace_settings
    if settings.is_data or settings.name in LINEAR_BYTE_SPACES:
        return False
    if settings.name != "sRGB":
        warnings.append(f"Image '{image.name}': colour space '{settings.name}' could not be converted with "
                        f"Blender's OpenColorIO configuration, read as sRGB")
    return True


# ---------------------------------------------------------------- reading
def file_bytes(image) -> np.ndarray | None:
    """(H, W, C) uint8 of an 8-bit image read from its file, or from the file packed in the .blend, as Blender
    reads it (C = 1 for grey, where Blender repeats it in R, G and B; grey with alpha becomes RGBA, as there),
    row 0 at the bottom; uint16 likewise for a 16-bit image file that Cycles reads as it is stored
    (reads_words); None when the image is not a plain file of FILE_FORMATS of those that OpenImageIO opens
    (Blender reads it)."""
    oiio = _openimageio()
    if oiio is None:
        return None
    with tempfile.TemporaryDirectory(prefix="ember-") as folder:
        path = _file_of(image, folder)
        return None if path is None else _read_file(oiio, path, reads_words(image))


def reads_words(image) -> bool:
    """Whether a 16-bit file of this image is read as it is stored (uint16): an image file, not a packed one.
    Cycles reads image files through OpenImageIO, colour straight, and keeps them 16-bit (USHORT4: sRGB ones
    filtered before they are decoded, as 8-bit ones, util/image_metadata.cpp finalize, is_compressible_as_srgb;
    scene-linear and data ones as they are) or converts them to half floats at load (other spaces, as 8-bit
    ones: read_image); a packed image it takes from Blender, which decodes it to linear floats at load, colour
    associated (blender/image.cpp), so packed ones come through image.pixels."""
    return image.packed_file is None


def _file_of(image, folder: str) -> str | None:
    """The file to read an image from (a packed one written into `folder` first), None when the image is not
    read from a file. Touches bpy: on the export's thread only."""
    if image.source != "FILE" or image.is_dirty or image.use_deinterlace or image.is_multiview:
        return None
    if image.packed_file is None:
        path = image.filepath_from_user()
        return path if path and os.path.isfile(path) else None
    if len(image.packed_files) != 1:
        return None
    # A packed file (glTF and .blend files carry their textures so) goes through a file of its own: Blender's
    # OpenImageIO module reads files, not memory. Through image.pixels it would be decoded to floats, four
    # channels, the whole image at once (about 0.1 s and 64 MB per 2048 x 2048 texture).
    extension = os.path.splitext(image.filepath or image.name)[1].lower()
    path = os.path.join(folder, f"packed{len(os.listdir(folder))}{extension}")
    with open(path, "wb") as f:
        f.write(image.packed_file.data)
    return path


def _tile_file(image, number: int, folder: str) -> str | None:
    """The file of UDIM tile `number` of a tiled image (its <UDIM> or <UVTILE> token filled in; a packed tile
    written into `folder` first), None when it has none."""
    for packed in image.packed_files:
        if getattr(packed, "tile_number", None) == number:
            extension = os.path.splitext(image.filepath or image.name)[1].lower()
            path = os.path.join(folder, f"tile{number}_{len(os.listdir(folder))}{extension}")
            with open(path, "wb") as f:
                f.write(packed.packed_file.data)
            return path
    pattern = _abspath(image)
    u, v = (number - 1001) % 10 + 1, (number - 1001) // 10 + 1
    path = pattern.replace("<UDIM>", str(number)).replace("<UVTILE>", f"u{u}_v{v}")
    return path if path != pattern and os.path.isfile(path) else None


def _abspath(image) -> str:
    """The image's path made absolute as Blender makes it (relative to the .blend or its library)."""
    import bpy
    return bpy.path.abspath(image.filepath, library=image.library)


def sequence_frame(user, scene_frame: int) -> int:
    """The file frame number an Image Texture's image user reads from an image sequence at the scene's frame:
    Blender's BKE_image_user_frame_get, which Cycles' sync calls (blender/shader.cpp image_user_frame_number):
    the scene frame counted from Start Frame, held at 0 and Frames (wrapped with Cyclic), then Offset added."""
    length = int(user.frame_duration)
    if length == 0:
        return 0
    frame = int(scene_frame) - int(user.frame_start) + 1
    if user.use_cyclic:
        frame %= length
        frame = frame or length
    frame = min(max(frame, 0), length)
    return frame + int(user.frame_offset)


def sequence_file(image, frame: int) -> str:
    """The file of frame `frame` of an image sequence: the last run of digits in its file name replaced by the
    frame number, padded to as many digits (Blender's BLI_path_sequence_decode and _encode)."""
    path = _abspath(image)
    folder, name = os.path.split(path)
    stem, extension = os.path.splitext(name)
    end = len(stem)
    while end and not stem[end - 1].isdigit():
        end -= 1
    start = end
    while start and stem[start - 1].isdigit():
        start -= 1
    if start == end:
        return path
    return os.path.join(folder, f"{stem[:start]}{frame:0{end - start}d}{stem[end:]}{extension}")


def texture_limit(scene, viewport: bool = False) -> int:
    """Simplify > Texture Limit in pixels (Cycles' own setting, read with Simplify on as Cycles' sync reads it:
    the viewport's or the render's), 0 for none."""
    value = getattr(getattr(scene, "cycles", None), "texture_limit" if viewport else "texture_limit_render", "OFF")
    return int(value) if scene.render.use_simplify and value != "OFF" else 0


def limited(pixels: ImagePixels | None, limit: int) -> ImagePixels | None:
    """Pixels whose longer side exceeds `limit` (0: none) scaled down as Cycles' image manager scales them for
    Simplify > Texture Limit (scene/image.cpp, util/image_impl.h util_image_resize_pixels): by the power of two
    2^floor(log2(limit / longer side)), the sides floored (at least 1), each pixel the plain mean of the k x k
    block at its corner (k = 1 / that factor), stored as before (8- and 16-bit values rounded to nearest)."""
    if pixels is None or not limit:
        return pixels
    a = pixels.array
    h, w = a.shape[:2]
    if max(w, h) <= limit:
        return pixels
    scale = float(2.0 ** np.floor(np.log2(np.float32(limit) / np.float32(max(w, h)))))
    k = int(1.0 / scale + 0.5)
    ow, oh = max(int(w * scale), 1), max(int(h * scale), 1)
    if ow * k > w or oh * k > h:   # a side shorter than a block: its one pixel takes what there is
        padded = np.zeros((oh * k, ow * k, a.shape[2]), np.float64)
        counts = np.zeros((oh * k, ow * k, 1), np.float64)
        padded[:min(h, oh * k), :min(w, ow * k)] = a[:oh * k, :ow * k]
        counts[:min(h, oh * k), :min(w, ow * k)] = 1.0
        total = padded.reshape(oh, k, ow, k, -1).sum(axis=(1, 3))
        mean = total / np.maximum(counts.reshape(oh, k, ow, k, 1).sum(axis=(1, 3)), 1.0)
    else:
        mean = a[:oh * k, :ow * k].astype(np.float64).reshape(oh, k, ow, k, -1).mean(axis=(1, 3))
    if a.dtype in (np.uint8, np.uint16):
        top = np.iinfo(a.dtype).max
        out = np.clip(np.floor(mean + 0.5), 0, top).astype(a.dtype)
    else:
        out = mean.astype(a.dtype)
    return ImagePixels(np.ascontiguousarray(out), pixels.srgb)


def read_frame(image, frame: int, warnings: list[str], alpha: bool = False) -> ImagePixels | None:
    """Frame `frame` of an image sequence (_read_part)."""
    path = sequence_file(image, frame)
    return _read_part(image, lambda folder: path, f"frame {frame} of the sequence ({path})", warnings, alpha)


def read_tile(image, number: int, warnings: list[str], alpha: bool = False) -> ImagePixels | None:
    """UDIM tile `number` of a tiled image (_read_part)."""
    return _read_part(image, lambda folder: _tile_file(image, number, folder), f"UDIM tile {number}", warnings,
                      alpha)


def _read_part(image, file_of, what: str, warnings: list[str], alpha: bool) -> ImagePixels | None:
    """A file of an image that has several (a sequence's frame, a UDIM tile: file_of(folder) -> its path, a packed
    one written into `folder`, or None), read as read_image reads an image (8- and 16-bit files as stored, float
    files such as OpenEXR as linear floats); None, with a warning naming the image and `what`, when it cannot be
    read (Cycles renders it magenta)."""
    oiio = _openimageio()
    pixels = None
    if oiio is not None:
        with tempfile.TemporaryDirectory(prefix="ember-") as folder:
            path = file_of(folder)
            if path is not None and os.path.isfile(path):
                pixels = _read_file(oiio, path, reads_words(image), floats=True)
    if pixels is None:
        warnings.append(f"Image '{image.name}': {what} could not be read: rendered magenta")
        return None
    return read_image(image, warnings, alpha, file_pixels=pixels)


def _read_file(oiio, path: str, words: bool = False, floats: bool = False) -> np.ndarray | None:
    """The file's pixels (_read_rows): uint8 for an 8-bit file, uint16 for a 16-bit one where `words`, float32 for a
    half or float one (OpenEXR too) where `floats`, else None."""
    reader = oiio.ImageInput.open(path)
    if reader is None:
        oiio.geterror()
        return None
    try:
        options = FILE_FORMATS.get(reader.format_name(), {} if floats else None)
        spec = reader.spec()
        formats = (oiio.UINT8, oiio.UINT16) if words else (oiio.UINT8,)
        if floats:
            formats += (oiio.HALF, oiio.FLOAT)
        if options is None or not any(spec.format == f for f in formats) or not 1 <= spec.nchannels <= 4 \
                or spec.depth > 1:
            return None
        reader.close()
        config = oiio.ImageSpec()
        for name, value in options.items():
            config.attribute(name, value)
        reader = oiio.ImageInput.open(path, config)
        return None if reader is None else _read_rows(reader, reader.spec())
    finally:
        if reader is not None:
            reader.close()


def _read_rows(reader, spec) -> np.ndarray | None:
    """The image's rows (uint8; uint16 for a 16-bit file, float32 for a half or float one), a block at a time,
    bottom row first; grey with alpha expanded to RGBA."""
    height, width, channels = spec.height, spec.width, spec.nchannels
    kind = {"uint16": "uint16", "half": "float32", "float": "float32"}.get(str(spec.format), "uint8")
    read_as = "float" if kind == "float32" else kind
    out = np.empty((height, width, 4 if channels == 2 else channels), kind)
    rows = max(1, _BLOCK // (width * channels))
    for y0 in range(0, height, rows):
        y1 = min(height, y0 + rows)
        block = reader.read_scanlines(0, 0, y0, y1, 0, 0, channels, read_as)
        if block is None or block.shape[:2] != (y1 - y0, width):
            return None
        block = block.reshape(y1 - y0, width, channels)[::-1]
        target = out[height - y1:height - y0]
        if channels == 2:
            target[:, :, :3] = block[:, :, :1]
            target[:, :, 3] = block[:, :, 1]
        else:
            target[...] = block
    return out


def _openimageio():
    """Blender's own OpenImageIO module, None where it cannot be imported."""
    try:
        import bpy
        bpy.utils.expose_bundled_modules()
        import OpenImageIO
    except (ImportError, AttributeError):
        return None
    return OpenImageIO


def _blender_pixels(image) -> np.ndarray | None:
    """(H, W, C) of image.pixels (Blender loads the image for it): uint8 for 8-bit images, float32 for
    float ones; None when Blender cannot load it."""
    n = len(image.pixels)  # asking for the pixels loads the image (file, packed or generated)
    width, height = image.size
    if n == 0 or width * height == 0:
        return None
    flat = np.empty(n, np.float32)
    image.pixels.foreach_get(flat)
    shape = (height, width, n // (width * height))
    if image.is_float:
        return flat.reshape(shape)
    out = np.empty(n, np.uint8)   # Blender gave k * (1 / 255): back to k
    for start in range(0, n, _BLOCK):
        out[start:start + _BLOCK] = np.rint(flat[start:start + _BLOCK] * np.float32(255.0))
    return out.reshape(shape)


# ---------------------------------------------------------------- in place, a block at a time
def _narrowed(pixels: np.ndarray, channels: int) -> np.ndarray:
    """pixels[:, :, :channels], contiguous, made in pixels' own memory (which shrinks to it) when pixels
    owns it: a big image is never held twice."""
    height, width, have = pixels.shape
    if have == channels:
        return pixels
    owner = pixels if pixels.base is None else pixels.base
    if owner.base is not None or not owner.flags.c_contiguous or owner.size != pixels.size:
        return np.ascontiguousarray(pixels[:, :, :channels])
    flat = owner.reshape(-1)
    rows = max(1, _BLOCK // (width * have))
    for y0 in range(0, height, rows):
        y1 = min(height, y0 + rows)
        # The block lands at or before where it was read from, and is copied out first.
        flat[y0 * width * channels:y1 * width * channels] = pixels[y0:y1, :, :channels].reshape(-1)
    del flat, pixels
    owner.resize(height * width * channels, refcheck=False)
    return owner.reshape(height, width, channels)


def _cleaned(pixels: np.ndarray) -> np.ndarray:
    """Float pixels with every value that is not finite and positive set to 0, in place."""
    flat = pixels.reshape(-1)
    for start in range(0, len(flat), _BLOCK):
        block = flat[start:start + _BLOCK]
        block[~(np.isfinite(block) & (block > 0))] = 0.0
    return pixels


def _as_float(pixels: np.ndarray, associate: bool = False) -> np.ndarray:
    """float32 values of pixels (k / 255 for uint8, as Blender gives them, k / 65535 for uint16; colour times alpha
    when associate); float pixels as they are."""
    if pixels.dtype not in (np.uint8, np.uint16):
        return pixels
    out = pixels.astype(np.float32)
    out *= BYTE_SCALE if pixels.dtype == np.uint8 else WORD_SCALE
    if associate:
        out[:, :, :3] *= out[:, :, 3:4]
    return out


class ImageTextures:
    """The texture list of one export: one array per image, shared by every material using it."""

    # Simplify > Texture Limit in pixels (0: none): larger images are scaled down as Cycles' image manager does
    # (limited): set by the export.
    limit: int = 0

    def __init__(self, warnings: list[str], frame: int = 1):
        """frame: the scene frame, at which image sequences are read (sequence_frame)."""
        self.frame = int(frame)
        self.loaded: list[ImagePixels] = []
        self._index: dict = {}
        self._tiles: dict[str, tuple] = {}
        self._warnings = warnings
        self._decoding: dict[str, Future] = {}
        self._pool = None
        self._folder = None

    def prefetch(self, images) -> None:
        """Start decoding these images' files on threads while the export goes on (index() then waits for
        its image, if it is still being read). OpenImageIO releases the GIL: two threads read the
        stained-glass lamp's nineteen 8-bit textures in half the time one takes, and beside the export of
        the meshes. Call close() when the export is over."""
        oiio = _openimageio()
        if oiio is None:
            return
        for image in images:
            key = image.name_full
            if key in self._decoding or key in self._index:
                continue
            if self._folder is None:
                self._folder = tempfile.TemporaryDirectory(prefix="ember-")
                self._pool = ThreadPoolExecutor(PREFETCH_THREADS, "ember-images")
            path = _file_of(image, self._folder.name)
            if path is not None:
                self._decoding[key] = self._pool.submit(_read_file, oiio, path, reads_words(image))

    def read(self, image, alpha: bool = False, user=None) -> ImagePixels | None:
        """read_image(image), from the file's bytes prefetch decoded when it did; an image sequence's frame that
        the image user `user` (an Image Texture's) reads at the scene frame."""
        if image.source == "SEQUENCE" and user is not None:
            return limited(read_frame(image, sequence_frame(user, self.frame), self._warnings, alpha), self.limit)
        decoding = self._decoding.pop(image.name_full, None)
        return limited(read_image(image, self._warnings, alpha,
                                  decoding.result() if decoding is not None else file_bytes(image)), self.limit)

    def tiles(self, image) -> tuple:
        """((tile number, texture index), ...) of a tiled (UDIM) image's tiles that could be read."""
        key = image.name_full
        if key not in self._tiles:
            found = []
            for tile in image.tiles:
                pixels = limited(read_tile(image, tile.number, self._warnings, alpha=True), self.limit)
                if pixels is not None:
                    found.append((int(tile.number), len(self.loaded)))
                    self.loaded.append(pixels)
            self._tiles[key] = tuple(found)
        return self._tiles[key]

    def index(self, image, user=None) -> int | None:
        """The image's texture index, None when it cannot be loaded; for an image sequence, that of the frame the
        image user `user` reads (read)."""
        key = image.name_full
        if image.source == "SEQUENCE" and user is not None:
            key = (key, sequence_frame(user, self.frame))
        if key not in self._index:
            pixels = self.read(image, alpha=True, user=user)
            self._index[key] = None if pixels is None else len(self.loaded)
            if pixels is not None:
                self.loaded.append(pixels)
        return self._index[key]

    def close(self) -> None:
        """Drop what prefetch read that no material used, and its files."""
        if self._pool is not None:
            for decoding in self._decoding.values():
                decoding.cancel()
            self._pool.shutdown(wait=True)
            self._pool = None
        self._decoding.clear()
        if self._folder is not None:
            self._folder.cleanup()
            self._folder = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# Threads that decode image files during an export: OpenImageIO's own decoders are single-threaded per file.
PREFETCH_THREADS = max(1, min(4, os.cpu_count() or 1))


def shader_images(trees) -> list:
    """The images of the Image and Environment Texture nodes in these node trees and the groups they use
    (each once, in the order met)."""
    found, seen = {}, set()
    stack = [tree for tree in trees if tree is not None]
    while stack:
        tree = stack.pop()
        if tree.as_pointer() in seen:    # (a material's own tree is named "Shader Nodetree", as all are)
            continue
        seen.add(tree.as_pointer())
        for node in tree.nodes:
            if node.type in ("TEX_IMAGE", "TEX_ENVIRONMENT") and node.image is not None:
                found.setdefault(node.image.name_full, node.image)
            elif node.type == "GROUP" and node.node_tree is not None:
                stack.append(node.node_tree)
    return list(found.values())
