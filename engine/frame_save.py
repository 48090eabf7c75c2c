"""Writing a rendered frame to its file, as the command line and the Ray driver do: under a hidden temporary
name in the target's directory (shortened to fit the file system's and Blender's limits on names and paths),
checked to be whole (Blender's writers log a failed write, a full disk, and return as if they had succeeded:
engine/image_files.py), flushed to the disk, then renamed over the target. A failure or an interrupt never
leaves a partial file, nor replaces an earlier file with a broken one; the temporary file is registered with
engine/stop_signals.py, which removes it when a second signal quits at once.
"""
from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile

import bpy

from . import stop_signals
from .image_files import written_file_problem

# A write that failed with less than this free on its disk is reported as a full disk.
FULL_DISK_BYTES = 1 << 20
# Blender's paths hold at most this many bytes (FILE_MAX - 1); it cuts longer ones and writes elsewhere.
BLENDER_PATH_MAX = 1023
PARTIAL_SUFFIX = ".partial"


class SaveError(Exception):
    """A one-line reason a frame was not saved (or its path cannot be written)."""


def save_render_result(scene, target: str) -> None:
    """Write the render result with the scene's output settings to `target`, as the module says; SaveError
    (one line: why, and whether an earlier file was kept) when it cannot be."""
    result = bpy.data.images.get("Render Result")
    if result is None:
        raise SaveError("Blender produced no render result")
    save_file(target, lambda path: result.save_render(path, scene=scene), scene.render.image_settings.file_format)


def save_file(target: str, write, file_format: str) -> None:
    """What save_render_result does, for any file write(path) writes in Blender's `file_format` (a baked image:
    engine/bake_cli.py)."""
    directory = os.path.dirname(target)
    try:
        with stop_signals.saving_to(lambda: tempfile.mkstemp(prefix=partial_prefix(target), suffix=PARTIAL_SUFFIX,
                                                             dir=directory)) as (fd, partial):
            os.close(fd)
            _write_whole(write, file_format, target, partial)
    except OSError as err:
        raise SaveError(f"cannot save {target}: {first_line(err)}{_kept(target)}") from None


def _write_whole(write, file_format: str, target: str, partial: str) -> None:
    """save_file's write, check and rename of `partial` (removed whatever happens)."""
    directory = os.path.dirname(target)
    try:
        with _blender_log() as log:
            write(partial)
        problem = written_file_problem(partial, file_format)
        if problem is not None:
            raise SaveError(f"cannot save {target}: {_write_failure(directory, log, partial, target)}the file "
                            f"Blender wrote is incomplete ({problem}){_kept(target)}")
        os.chmod(partial, 0o666 & ~_umask())  # mkstemp's file is private; a saved frame is not
        _flush_to_disk(partial)
        os.replace(partial, target)
    except (RuntimeError, OSError) as err:
        raise SaveError(f"cannot save {target}: {first_line(err)}{_kept(target)}") from None
    finally:
        if os.path.exists(partial):
            os.remove(partial)


def partial_prefix(target: str) -> str:
    """The start of the hidden name `target` is written under before it is renamed ('.NAME.', then mkstemp's
    random letters and PARTIAL_SUFFIX), NAME shortened as needed to fit the file system's limit on names and
    Blender's on paths; SaveError when the target's own name or path cannot be written."""
    directory, name = os.path.split(target)
    encoded = os.fsencode(name)
    try:
        name_max = os.pathconf(existing_part(directory), "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):   # AttributeError: no pathconf (Windows)
        name_max = 255
    if len(encoded) > name_max:
        raise SaveError(f"the output file name {_abridged(name)} is {len(encoded)} bytes: the file system of "
                       f"{_abridged(directory)} allows {name_max}")
    if len(os.fsencode(target)) > BLENDER_PATH_MAX:
        raise SaveError(f"the output path {_abridged(target)} is {len(os.fsencode(target))} bytes: Blender writes "
                       f"paths of up to {BLENDER_PATH_MAX}")
    fixed = len(".." + "12345678" + PARTIAL_SUFFIX)
    room = min(name_max, BLENDER_PATH_MAX - len(os.fsencode(directory)) - 1) - fixed
    if room < 0:
        raise SaveError(f"the output directory {_abridged(directory)} is {len(os.fsencode(directory))} bytes: the "
                       f"temporary file each frame is first written to needs a path of "
                       f"{len(os.fsencode(directory)) + 1 + fixed}, and Blender writes paths of up to "
                       f"{BLENDER_PATH_MAX}")
    return "." + encoded[:room].decode("utf-8", "ignore") + "."


def _abridged(text: str) -> str:
    return repr(text if len(text) <= 80 else f"{text[:40]}...{text[-30:]}")


def _flush_to_disk(path: str) -> None:
    """fsync: a write error the file system reports late (a network disk, delayed allocation) raises
    OSError here, and the frame is on the disk before its name replaces an earlier one."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_failure(directory: str, log: list[str], partial: str, target: str) -> str:
    """Why a write failed, as far as can be told: a (nearly) full disk, else the error Blender logged."""
    try:
        stats = os.statvfs(directory)
        free = stats.f_bavail * stats.f_frsize
    except OSError:
        free = FULL_DISK_BYTES
    if free < FULL_DISK_BYTES:
        return f"no space left on device ({free >> 10} KB free); "
    errors = [re.sub(r"^\w+: ", "", line.split("ERROR", 1)[1].strip(" :")) for line in log if "ERROR" in line]
    return f"Blender: {errors[-1].replace(partial, target).rstrip('.')}; " if errors else ""


@contextlib.contextmanager
def _blender_log():
    """The lines Blender's C code writes to stdout and stderr in the block (its log, where it reports a
    failed write and carries on), passed on to the same streams at its end and collected for the caller."""
    lines: list[str] = []
    with contextlib.ExitStack() as stack:
        for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
            stack.enter_context(_copied(fd, stream, lines))
        yield lines


@contextlib.contextmanager
def _copied(fd: int, stream, lines: list[str]):
    try:
        held = tempfile.TemporaryFile()
    except OSError:  # nowhere to hold them: the lines go straight through
        held = None
    if held is None:
        yield
        return
    with held:
        stream.flush()
        saved = os.dup(fd)
        os.dup2(held.fileno(), fd)
        try:
            yield
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            held.seek(0)
            text = held.read().decode("utf-8", "replace")
            stream.write(text)
            stream.flush()
            lines.extend(text.splitlines())


def _kept(target: str) -> str:
    return "; the existing file is kept" if os.path.exists(target) else ""


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def existing_part(path: str) -> str:
    """`path`, or the nearest of its parents that exists."""
    while not os.path.exists(path):
        path = os.path.dirname(path)
    return path


def first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    line = text[0] if text else type(err).__name__
    return line.removeprefix("Error: ").strip()
