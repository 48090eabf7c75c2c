"""Denoising with the OpenImageDenoise (OIDN) 2.x library that Blender ships, called through ctypes.

    ok, why = available()
    clean = denoise(color, albedo, normal, quality="HIGH", prefilter="ACCURATE", threads=2)
    finished = denoise_image(read, height, width, write, aux=("albedo", "normal"), progress=progress)

Memory: an image is denoised a tile at a time (denoise_tiles: windows of at most TILE_PIXELS pixels with
OIDN's overlaps, so that the result is the whole image's), read and written through callbacks by
denoise_image: what a denoise takes is bounded by its tiles, whatever the image's size. OIDN 2.3.3's own
maxMemoryMB would bound only OIDN's scratch memory, and OIDN needs its input and output images whole.

Progress and stopping: every OIDN run executes on a helper thread while the caller's thread polls
OIDN's progress monitor (oidnSetFilterProgressMonitorFunction) and calls progress(fraction) a few times a
second; False from it cancels the run through the monitor and the denoise returns without its image.

No new dependency: the library is the one beside Blender's own libraries, found with find_library() (or
in a directory given explicitly, in which case bpy is never imported). Images are (H, W, 3) float arrays,
rows in any order as long as all images agree; color is linear scene-referred HDR (OIDN's RT filter
with hdr=true), albedo in [0, 1], normal in [-1, 1] (world or view space, any length). They are handed
to OIDN as shared images: float32 arrays whose channels are contiguous (an RGBA render's [..., :3] view
included) are read in place; anything else is first made a contiguous float32 array.

Non-finite input: NaN and +-inf pixel channels (of color, albedo and normal) are replaced by 0 before
OIDN sees them, in a copy, so one bad sample can neither spread over the CNN's receptive field nor
poison the auto-exposure. (OIDN 2.3.3's CPU device happens to map NaN to 0 and clamp inf to the largest
float itself, devices/cpu/cpu_input_process.ispc, but an infinite pixel would then glow; other versions
and devices promise nothing.) Negative colour values are clamped to 0 by OIDN.

Prefilter, as Cycles offers it (src/integrator/denoiser_oidn.cpp, v5.0.0, and the enum's descriptions in
Blender's UI):
    NONE      the auxiliary images are used as they are and declared noise-free (cleanAux=true)
    FAST      colour and noisy auxiliary images denoised together (cleanAux=false, OIDN's default)
    ACCURATE  albedo and normal first denoised by their own RT filters (same quality), then cleanAux=true
A normal image needs an albedo image (OIDN's rule, which Cycles' set_guiding_passes notes too).

Library locations (only Linux can be run here):
- Verified by running: the bpy module (Blender 5.0.1, Linux) keeps libOpenImageDenoise.so.2 with
  libOpenImageDenoise_core.so.2.3.3, libOpenImageDenoise_device_cpu.so.2.3.3 and libtbb.so.12 in bpy/lib/,
  beside bpy/__init__.so (RUNPATH $ORIGIN); the core dlopens the device module from its own directory by
  the name lib<...>_device_cpu.so.<version> (oidn core/module.cpp, v2.3.3).
- Read in Blender's build files (blender/blender, build_files/): OIDN is built as shared libraries on
  every platform (build_environment/cmake/openimagedenoise.cmake); platform_unix.cmake and
  platform_apple.cmake bundle openimagedenoise/lib with add_bundled_libraries (every *.so* / *.dylib*
  of it); Linux sets the install rpath $ORIGIN/lib, i.e. <blender dir>/lib/ for the application and
  bpy/lib/ for the module; macOS sets @loader_path/../Resources/lib for the application
  (Blender.app/Contents/Resources/lib/) and @loader_path/lib for the module. Windows: the 4.x libraries
  ship OpenImageDenoise/bin/OpenImageDenoise.dll, and shared libraries live in blender.shared/ beside
  blender.exe (blender.exe's manifest depends on a "blender.shared" assembly; PLATFORM_ENV_INSTALL puts
  <install>/blender.shared/ on PATH, platform_win32.cmake). The rule copying OpenImageDenoise.dll there
  was not among the indexed sources; third-party add-ons load <Blender>/blender.shared/OpenImageDenoise.dll.
- Read in Blender's manual (advanced/blender_directory_layout): resource_path('LOCAL') is ./<version>/
  beside the executable on Linux and Windows and Blender.app/Contents/Resources/<version>/ on macOS, so
  its parent is the directory the lib/ or blender.shared/ folder sits in.
- Not verified: the exact macOS file names (CMake's VERSION/SOVERSION give libOpenImageDenoise.2.3.3.dylib
  with a libOpenImageDenoise.2.dylib link, both looked for by pattern); where the bpy module keeps its
  DLLs on Windows (blender.shared/ and the package directory are both tried); that the core finds
  OpenImageDenoise_device_cpu.dll's own dependency (tbb12.dll) outside Blender's process on Windows
  (the directory is added with os.add_dll_directory to help).
"""
from __future__ import annotations

import atexit
import ctypes
import glob
import os
import sys
import threading
from contextlib import contextmanager
from typing import Callable

import numpy as np

from .denoise_tiles import TILE_PIXELS, Tile, auto_exposure, plan_tiles

# OIDNQuality (oidn.h)
QUALITIES = {"HIGH": 6, "BALANCED": 5, "FAST": 4}
PREFILTERS = ("NONE", "FAST", "ACCURATE")

_DEVICE_TYPE_CPU = 1   # OIDN_DEVICE_TYPE_CPU
_FORMAT_FLOAT3 = 3     # OIDN_FORMAT_FLOAT3
_ERROR_NAMES = {1: "unknown error", 2: "invalid argument", 3: "invalid operation", 4: "out of memory",
                5: "unsupported hardware", 6: "cancelled"}   # OIDNError
_ERROR_CANCELLED = 6
# How often the caller's thread looks at a running denoise's progress (and whether to stop it), in seconds.
POLL_S = 0.1

_p, _s, _i, _b, _z = ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_bool, ctypes.c_size_t
# OIDNProgressMonitorFunction: (userPtr, fraction of the filter's run done) -> whether to go on
_PROGRESS_MONITOR = ctypes.CFUNCTYPE(_b, _p, ctypes.c_double)
# name -> (restype, argtypes), written from oidn.h of OIDN 2.x. Enums are C ints; handles opaque pointers.
_PROTOTYPES = {
    "oidnIsCPUDeviceSupported": (_b, ()),
    "oidnNewDevice": (_p, (_i,)),
    "oidnSetDeviceInt": (None, (_p, _s, _i)),
    "oidnSetDeviceBool": (None, (_p, _s, _b)),
    "oidnGetDeviceInt": (_i, (_p, _s)),
    "oidnCommitDevice": (None, (_p,)),
    "oidnGetDeviceError": (_i, (_p, ctypes.POINTER(_s))),
    "oidnReleaseDevice": (None, (_p,)),
    "oidnNewFilter": (_p, (_p, _s)),
    # filter, name, devPtr, format, width, height, byteOffset, pixelByteStride, rowByteStride
    "oidnSetSharedFilterImage": (None, (_p, _s, _p, _i, _z, _z, _z, _z, _z)),
    "oidnSetFilterBool": (None, (_p, _s, _b)),
    "oidnSetFilterInt": (None, (_p, _s, _i)),
    "oidnGetFilterInt": (_i, (_p, _s)),
    "oidnSetFilterFloat": (None, (_p, _s, ctypes.c_float)),
    "oidnSetFilterProgressMonitorFunction": (None, (_p, _PROGRESS_MONITOR, _p)),
    "oidnCommitFilter": (None, (_p,)),
    "oidnExecuteFilter": (None, (_p,)),
    "oidnReleaseFilter": (None, (_p,)),
}


class DenoiseError(RuntimeError):
    """OpenImageDenoise is missing or unusable, or reported an error (its message is in the text)."""


# ---------------------------------------------------------------- finding the library
def library_names(platform: str = sys.platform) -> tuple[str, ...]:
    """File names (glob patterns) of OIDN's API library on a platform, most specific first."""
    if platform.startswith("win"):
        return ("OpenImageDenoise.dll",)
    if platform == "darwin":
        return ("libOpenImageDenoise.2.dylib", "libOpenImageDenoise.dylib", "libOpenImageDenoise.2.*.dylib")
    return ("libOpenImageDenoise.so.2", "libOpenImageDenoise.so", "libOpenImageDenoise.so.2.*")


def blender_library_dirs(platform: str, local_root: str = "", binary_path: str = "") -> list[str]:
    """Where Blender keeps its shared libraries. local_root: the parent of resource_path('LOCAL') (the
    bpy package for the Python module, the install directory of the application, Contents/Resources on
    macOS); binary_path: bpy.app.binary_path ('' for the module)."""
    windows = platform.startswith("win")
    dirs = []
    if local_root and windows:
        dirs += [os.path.join(local_root, "blender.shared"), local_root]
    elif local_root:
        dirs.append(os.path.join(local_root, "lib"))
    if binary_path:
        here = os.path.dirname(binary_path)
        if windows:
            dirs.append(os.path.join(here, "blender.shared"))
        elif platform == "darwin":  # Contents/MacOS/Blender -> Contents/Resources/lib
            dirs.append(os.path.normpath(os.path.join(here, "..", "Resources", "lib")))
        else:
            dirs.append(os.path.join(here, "lib"))
    return list(dict.fromkeys(dirs))


def _running_blender_dirs() -> list[str]:
    try:
        import bpy
    except ImportError:
        return []
    local = bpy.utils.resource_path("LOCAL")
    return blender_library_dirs(sys.platform, os.path.dirname(local.rstrip("/\\")) if local else "",
                                bpy.app.binary_path)


def _search_dirs(library_dir: str | None) -> list[str]:
    return [os.fspath(library_dir)] if library_dir is not None else _running_blender_dirs()


def find_library(library_dir: str | None = None) -> str | None:
    """The path of OIDN's API library in library_dir, or (None) in the running Blender's library
    directory; None when there is none."""
    for folder in _search_dirs(library_dir):
        for name in library_names():
            for path in sorted(glob.glob(os.path.join(glob.escape(folder), name))):
                if os.path.isfile(path):
                    return path
    return None


# ---------------------------------------------------------------- the library and its devices
class _Library:
    """OIDN's C API from one shared library, with the prototypes set."""

    def __init__(self, path: str):
        self.path = path
        if sys.platform.startswith("win"):  # the core, device and TBB DLLs sit beside it
            self._dll_directory = os.add_dll_directory(os.path.dirname(path))
        try:
            dll = ctypes.CDLL(path)
        except OSError as error:
            raise DenoiseError(f"could not load OpenImageDenoise from {path}: {error}") from None
        for name, (restype, argtypes) in _PROTOTYPES.items():
            try:
                function = getattr(dll, name)
            except AttributeError:
                raise DenoiseError(f"{path} is not OpenImageDenoise 2.x: it has no {name}") from None
            function.restype, function.argtypes = restype, argtypes
            setattr(self, name, function)
        self.dll = dll

    def error(self, device) -> tuple[int, str]:
        """OIDN's first unqueried error of this thread on the device (None: the global one), cleared."""
        message = _s()
        code = self.oidnGetDeviceError(device, ctypes.byref(message))
        text = message.value.decode("utf-8", "replace") if message.value else ""
        return code, text


class _Device:
    """A committed CPU device. OIDN serialises the work of one device; the lock keeps one denoise()
    call's filters and error checks together."""

    def __init__(self, library: _Library, threads: int):
        self.library = library
        self.lock = threading.Lock()
        if not library.oidnIsCPUDeviceSupported():
            code, text = library.error(None)
            raise DenoiseError(f"OpenImageDenoise ({library.path}) has no usable CPU device"
                               + (f": {text}" if text else " (SSE4.1 or NEON needed, or its device module"
                                                            " is missing)"))
        self.handle = library.oidnNewDevice(_DEVICE_TYPE_CPU)
        if not self.handle:
            raise DenoiseError(f"OpenImageDenoise could not create a CPU device: {library.error(None)[1]}")
        try:
            library.oidnSetDeviceInt(self.handle, b"numThreads", threads)
            # Ember's own render threads share the process: pinning OIDN's would fight them (Cycles too
            # turns it off).
            library.oidnSetDeviceBool(self.handle, b"setAffinity", False)
            library.oidnCommitDevice(self.handle)
            self.check("committing the device")
            version = library.oidnGetDeviceInt(self.handle, b"version")
            self.version = f"{version // 10000}.{version // 100 % 100}.{version % 100}"
        except BaseException:
            self.release()
            raise

    def check(self, doing: str) -> None:
        code, text = self.library.error(self.handle)
        if code != 0:
            raise DenoiseError(f"OpenImageDenoise error while {doing} "
                               f"({_ERROR_NAMES.get(code, f'error {code}')}): {text}")

    @contextmanager
    def filter(self):
        """A new RT filter, released on exit."""
        handle = self.library.oidnNewFilter(self.handle, b"RT")
        self.check("creating an RT filter")
        try:
            yield handle
        finally:
            self.library.oidnReleaseFilter(handle)

    def execute(self, flt, watch: "_Watch", doing: str) -> bool:
        """Run a committed filter on a helper thread while this one polls the watch, so that progress
        and stops (Esc, an interrupt's handler) are answered on this thread while OIDN works. False when
        the watch cancelled the run. OIDN keeps errors per thread: the helper reads them."""
        outcome = []

        def work():
            self.library.oidnExecuteFilter(flt)
            outcome.append(self.library.error(self.handle))

        helper = threading.Thread(target=work, name="ember-denoise", daemon=True)
        helper.start()
        try:
            while helper.is_alive():
                helper.join(POLL_S)
                watch.poll()
        except BaseException:   # stop OIDN before its images go away
            watch.stopped = True
            helper.join()
            raise
        code, text = outcome[0]
        if code == _ERROR_CANCELLED:
            return False
        if code != 0:
            raise DenoiseError(f"OpenImageDenoise error while denoising {doing} "
                               f"({_ERROR_NAMES.get(code, f'error {code}')}): {text}")
        return not watch.stopped

    def release(self) -> None:
        if self.handle:
            self.library.oidnReleaseDevice(self.handle)
            self.handle = None


_lock = threading.Lock()
_libraries: dict[str, _Library] = {}
_devices: dict[tuple[str, int], _Device] = {}
_availability: dict[str | None, tuple[bool, str]] = {}


def _device(threads: int, library_dir: str | None) -> _Device:
    path = find_library(library_dir)
    if path is None:
        looked = ", ".join(_search_dirs(library_dir)) or "nowhere (bpy is not importable; pass library_dir)"
        raise DenoiseError(f"OpenImageDenoise not found: no {' / '.join(library_names())} in {looked}")
    with _lock:
        device = _devices.get((path, threads))
        if device is None:
            library = _libraries.get(path)
            if library is None:
                library = _libraries[path] = _Library(path)
            device = _devices[(path, threads)] = _Device(library, threads)
        return device


def available(library_dir: str | None = None) -> tuple[bool, str]:
    """(True, 'OpenImageDenoise <version> (<path>)') when a CPU device can be made, else (False, the
    reason). Cached per library_dir."""
    with _lock:
        known = _availability.get(library_dir)
    if known is not None:
        return known
    try:
        device = _device(0, library_dir)
        answer = (True, f"OpenImageDenoise {device.version} ({device.library.path})")
    except DenoiseError as error:
        answer = (False, str(error))
    with _lock:
        return _availability.setdefault(library_dir, answer)


@atexit.register
def release_devices() -> None:
    """Release the cached devices (the next denoise() makes new ones)."""
    with _lock:
        devices = list(_devices.values())
        _devices.clear()
    for device in devices:
        with device.lock:
            device.release()


# ---------------------------------------------------------------- filters and their runs
class _Watch:
    """Progress and stop of one denoise over all its filter runs. OIDN calls monitor() on its own thread
    (the run's fraction done; False cancels the run); poll(), on the caller's thread, hands the whole
    denoise's fraction to `progress` and stops everything once it answers False."""

    def __init__(self, progress: Callable[[float], bool] | None):
        self.progress = progress
        self.total_work = 1.0       # set once the tiles are planned
        self.done_work = 0.0
        self.run_work = 0.0
        self.run_fraction = 0.0
        self.stopped = False
        self.monitor = _PROGRESS_MONITOR(self._monitor)   # kept alive while OIDN may call it

    def _monitor(self, _user, fraction) -> bool:
        self.run_fraction = fraction
        return not self.stopped

    def begin(self, work: float) -> None:
        self.run_work, self.run_fraction = float(work), 0.0

    def end(self) -> None:
        self.done_work += self.run_work
        self.run_work = self.run_fraction = 0.0

    def poll(self) -> bool:
        """False once the denoise is to stop."""
        if self.progress is not None and not self.stopped:
            done = (self.done_work + self.run_fraction * self.run_work) / self.total_work
            self.stopped = not self.progress(min(done, 1.0))
        return not self.stopped


class _Filter:
    """One RT filter of a denoise, run over each of its windows: OIDN builds its network again only when
    the window's size changes."""

    def __init__(self, device: _Device, names: tuple, quality: int, watch: _Watch, hdr: bool | None = None,
                 clean_aux: bool | None = None):
        lib = device.library
        self.device, self.names, self.watch = device, names, watch
        self.handle = lib.oidnNewFilter(device.handle, b"RT")
        device.check("creating an RT filter")
        try:
            if hdr is not None:
                lib.oidnSetFilterBool(self.handle, b"hdr", hdr)
            if clean_aux is not None:
                lib.oidnSetFilterBool(self.handle, b"cleanAux", clean_aux)
            lib.oidnSetFilterInt(self.handle, b"quality", quality)
            lib.oidnSetFilterProgressMonitorFunction(self.handle, watch.monitor, None)
            device.check("setting up an RT filter")
        except BaseException:
            self.release()
            raise

    def overlap(self) -> tuple[int, int]:
        """(tileOverlap, tileAlignment) of this filter's network: how far a window must reach beyond the
        tile it denoises, and the multiple of pixels its offsets keep. OIDN knows them once the filter is
        committed (they depend on the network it picks for its images and quality): a 16 x 16 stand-in
        of each image tells."""
        stand_in = np.zeros((16, 16, 3), np.float32)
        self._commit({name: stand_in for name in self.names + ("output",)})
        lib = self.device.library
        overlap, alignment = (lib.oidnGetFilterInt(self.handle, b"tileOverlap"),
                              lib.oidnGetFilterInt(self.handle, b"tileAlignment"))
        self.device.check("reading the filter's tile overlap")
        return overlap, max(alignment, 1)

    def _commit(self, images: dict, input_scale: float | None = None) -> None:
        lib = self.device.library
        for name, image in images.items():
            height, width = image.shape[:2]
            lib.oidnSetSharedFilterImage(self.handle, name.encode(), image.ctypes.data, _FORMAT_FLOAT3,
                                         width, height, 0, image.strides[1], image.strides[0])
        if input_scale is not None:
            lib.oidnSetFilterFloat(self.handle, b"inputScale", input_scale)
        lib.oidnCommitFilter(self.handle)
        self.device.check(f"committing the filter of {', '.join(images)}")

    def run(self, images: dict, input_scale: float | None = None) -> bool:
        """Denoise shared (h, w, 3) float32 images keyed by OIDN's names (the inputs and output); input_scale
        None: OIDN's own (its auto-exposure). False when the watch stopped it."""
        self._commit(images, input_scale)
        self.watch.begin(images["output"].shape[0] * images["output"].shape[1])
        finished = self.device.execute(self.handle, self.watch, ", ".join(n for n in images if n != "output"))
        self.watch.end()
        return finished

    def release(self) -> None:
        if self.handle:
            self.device.library.oidnReleaseFilter(self.handle)
            self.handle = None


# ---------------------------------------------------------------- denoising
def _shareable(image: np.ndarray) -> bool:
    """OIDN can read it in place: float32, channels contiguous, pixels and rows at positive strides."""
    row, pixel, channel = image.strides
    return (image.dtype == np.float32 and image.flags.aligned and channel == 4 and pixel >= 12
            and pixel % 4 == 0 and row >= image.shape[1] * pixel)


def _image(name: str, image, shape: tuple | None = None) -> np.ndarray:
    """The (H, W, 3) float32 image OIDN reads: validated, shared when possible, non-finite values -> 0."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.size == 0:
        raise ValueError(f"{name}: expected an (H, W, 3) image, got shape {image.shape}")
    if shape is not None and image.shape[:2] != shape:
        raise ValueError(f"{name}: shape {image.shape} differs from color's {shape + (3,)}")
    if image.dtype.kind != "f":
        raise ValueError(f"{name}: expected floating-point values, got dtype {image.dtype}")
    if not _shareable(image):
        image = np.ascontiguousarray(image, dtype=np.float32)
    finite = np.isfinite(image)
    if not finite.all():
        image = np.where(finite, image, np.float32(0.0))
    return image


def _check_options(quality: str, prefilter: str, threads) -> None:
    if quality not in QUALITIES:
        raise ValueError(f"quality: expected one of {tuple(QUALITIES)}, got {quality!r}")
    if prefilter not in PREFILTERS:
        raise ValueError(f"prefilter: expected one of {PREFILTERS}, got {prefilter!r}")
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 0:
        raise ValueError(f"threads: expected a non-negative integer (0: all cores), got {threads!r}")


def denoise_image(read: Callable, height: int, width: int, write: Callable, *, aux: tuple = (),
                  quality: str = "HIGH", prefilter: str = "ACCURATE", threads: int = 0,
                  library_dir: str | None = None, tile_pixels: int = TILE_PIXELS, tile_size: int | None = None,
                  progress: Callable[[float], bool] | None = None, noise_free: tuple = ()) -> bool:
    """Denoise an H x W image read and written a tile at a time, so that memory is bounded by the tile,
    whatever the image's size (plan_tiles: the whole image when it has at most tile_pixels pixels;
    tile_size forces smaller tiles).

    read(name, rows, cols) -> (h, w, 3) float array of that window of 'color' or of an auxiliary image
    named in aux ('albedo', or 'albedo' and 'normal'); write(rows, cols, image) gets each tile's denoised
    (h, w, 3) float32 colour, once, tiles in rows top-down. progress(fraction) -> bool is called on this
    thread a few times a second while OIDN runs (every OIDN call runs on a helper thread): False stops the
    denoise (OIDN's run is cancelled) and denoise_image returns False, having written the tiles before.
    True when every tile was written. noise_free: auxiliary images that are never prefiltered (Cycles' stand-in
    albedo of 0.5 for passes denoised without albedo, set after the real one was filtered). Options and errors as
    denoise()."""
    _check_options(quality, prefilter, threads)
    if "normal" in aux and "albedo" not in aux:
        raise ValueError("normal: OpenImageDenoise uses a normal image only together with an albedo image")
    aux = tuple(name for name in ("albedo", "normal") if name in aux)
    level = QUALITIES[quality]
    prefiltered = tuple(name for name in aux if name not in noise_free) if prefilter == "ACCURATE" else ()
    device = _device(int(threads), library_dir)
    watch = _Watch(progress)
    with device.lock:
        filters = {}
        try:
            for name in prefiltered:
                filters[name] = _Filter(device, (name,), level, watch)
            filters["color"] = _Filter(device, ("color",) + aux, level, watch, hdr=True,
                                       clean_aux=(prefilter != "FAST") if aux else None)
            tiles = _plan(filters, prefiltered, height, width, tile_pixels, tile_size)
            watch.total_work = float(sum(_work(tile, len(prefiltered)) for tile in tiles))
            input_scale = auto_exposure(lambda rows, cols: _image("color", read("color", rows, cols)),
                                        height, width, tile_pixels, watch.poll) if len(tiles) > 1 else None
            for tile in tiles:
                if not watch.poll() or not _denoise_tile(filters, tile, read, write, aux, prefiltered, input_scale):
                    return False
            return True
        finally:
            for flt in filters.values():
                flt.release()


def _plan(filters: dict, prefiltered: tuple, height: int, width: int, tile_pixels: int,
          tile_size: int | None) -> list[Tile]:
    """plan_tiles with the overlaps and alignment of the denoise's networks (read only when it tiles)."""
    if tile_size is None and height * width <= tile_pixels:
        return plan_tiles(height, width, 0, 0, 1, tile_pixels)
    color_overlap, alignment = filters["color"].overlap()
    aux_overlap = 0
    for name in prefiltered:
        overlap, align = filters[name].overlap()
        aux_overlap, alignment = max(aux_overlap, overlap), int(np.lcm(alignment, align))
    return plan_tiles(height, width, color_overlap, aux_overlap, alignment, tile_pixels, tile_size)


def _work(tile: Tile, prefilters: int) -> int:
    """Pixels OIDN runs its network over for a tile: the colour window, and the auxiliary window once per
    prefiltered image (a progress measure: every network costs about the same per pixel)."""
    def pixels(rows, cols):
        return (rows.stop - rows.start) * (cols.stop - cols.start)
    return pixels(tile.color_rows, tile.color_cols) + prefilters * pixels(tile.aux_rows, tile.aux_cols)


def _denoise_tile(filters: dict, tile: Tile, read, write, aux: tuple, prefiltered: tuple,
                  input_scale: float | None) -> bool:
    """One tile: its auxiliary images prefiltered over their window, the colour over its own, the tile
    written; False when stopped."""
    rows, cols = tile.color_rows, tile.color_cols
    shape = (rows.stop - rows.start, cols.stop - cols.start)
    images = {"color": _image("color", read("color", rows, cols), shape)}
    for name in aux:
        if name in prefiltered:
            noisy = _image(name, read(name, tile.aux_rows, tile.aux_cols),
                           (tile.aux_rows.stop - tile.aux_rows.start, tile.aux_cols.stop - tile.aux_cols.start))
            clean = np.empty_like(noisy)
            if not filters[name].run({name: noisy, "output": clean}):
                return False
            del noisy
            images[name] = clean[rows.start - tile.aux_rows.start:rows.stop - tile.aux_rows.start,
                                 cols.start - tile.aux_cols.start:cols.stop - tile.aux_cols.start]
        else:
            images[name] = _image(name, read(name, rows, cols), shape)
    output = np.empty(shape + (3,), np.float32)
    if not filters["color"].run({**images, "output": output}, input_scale):
        return False
    write(tile.rows, tile.cols, output[tile.rows.start - rows.start:tile.rows.stop - rows.start,
                                       tile.cols.start - cols.start:tile.cols.stop - cols.start])
    return True


def denoise(color, albedo=None, normal=None, *, quality: str = "HIGH", prefilter: str = "ACCURATE",
            threads: int = 0, library_dir: str | None = None, tile_pixels: int = TILE_PIXELS,
            tile_size: int | None = None, progress: Callable[[float], bool] | None = None,
            noise_free: tuple = ()) -> np.ndarray | None:
    """Denoise color (H, W, 3) linear HDR with OIDN's RT filter, guided by albedo (H, W, 3) in [0, 1] and
    normal (H, W, 3) in [-1, 1] when given. quality: HIGH, BALANCED or FAST; prefilter: NONE, FAST or
    ACCURATE (see the module docstring); threads: OIDN's numThreads (0: all cores); library_dir: the
    directory holding OIDN (None: the running Blender's); tile_pixels, tile_size, progress and noise_free as
    denoise_image().
    Returns a new (H, W, 3) float32 image, or None when progress stopped it.
    Raises ValueError for bad arguments (named in the message) and DenoiseError when OIDN is missing or
    reports an error."""
    _check_options(quality, prefilter, threads)
    if normal is not None and albedo is None:
        raise ValueError("normal: OpenImageDenoise uses a normal image only together with an albedo image")
    images = {"color": _image("color", color)}
    shape = images["color"].shape[:2]
    for name, image in (("albedo", albedo), ("normal", normal)):
        if image is not None:
            images[name] = _image(name, image, shape)
    output = np.empty(shape + (3,), np.float32)

    def write(rows, cols, tile):
        output[rows, cols] = tile

    finished = denoise_image(lambda name, rows, cols: images[name][rows, cols], *shape, write,
                             aux=tuple(images)[1:], quality=quality, prefilter=prefilter, threads=threads,
                             library_dir=library_dir, tile_pixels=tile_pixels, tile_size=tile_size,
                             progress=progress, noise_free=noise_free)
    return output if finished else None
