"""What the command line (cli.py) and the Ray driver (distributed.py) share: a batch render's job (the file
opened with the command line's options applied, its frames and where each goes), skipping frames already on
disk, the one-line errors and the exit codes, and the words for which frames were saved and which lost.

cli.py and distributed.py import this module (cli imports distributed lazily, for --ray); it imports neither.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from typing import Any

import bpy

from ..kernels.accel import capped_threads
from . import stop_signals
from .frame_save import first_line

EXIT_USAGE = 2
EXIT_FAILED = 1
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for a process stopped by Ctrl-C
RESOLUTION_RANGE = (4, 65536)    # what scene.render.resolution_x/y accept


class CliError(Exception):
    """A one-line message for the user."""


class UsageError(CliError):
    """A malformed command line: exit status 2, as argparse's own errors."""


@dataclass
class RenderJob:
    """What a render of frames needs once the file is open: the scene (options applied) and where each
    frame goes. The single-process loop and the Ray driver (engine/distributed.py) share it."""
    scene: Any
    frames: list[int]
    targets: list[str]


def match_option(option: str, text: str, pattern: str, example: str) -> re.Match:
    """An option's text matched in full by `pattern`, or a UsageError saying what it must look like."""
    m = re.fullmatch(pattern, text)
    if m is None:
        raise UsageError(f"{option} must look like {example}, got {text!r}")
    return m


def parse_resolution(text: str | None):
    if text is None:
        return None
    m = match_option("--resolution", text, r"\s*(\d+)\s*[xX]\s*(\d+)\s*", "1280x720")
    lo, hi = RESOLUTION_RANGE
    width, height = int(m.group(1)), int(m.group(2))
    if not (lo <= width <= hi and lo <= height <= hi):
        raise UsageError(f"--resolution must be from {lo}x{lo} to {hi}x{hi} pixels (Blender's limits), got {text!r}")
    return width, height


def open_scene(args, path: str | None = None, need_camera: bool = True):
    """Register Ember, open `path` (default: args.file; none: build the demo scene), select the scene
    args.scene names and apply the command line's options to it (need_camera: a scene without a camera is
    an error, as it is for a render, not for a bake). The file is never saved."""
    resolution = parse_resolution(args.resolution)
    path = path if path is not None else args.file
    register_ember()
    if path is not None:
        try:
            bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False)
        except RuntimeError as err:
            raise CliError(f"cannot open {args.file or path}: {first_line(err)}") from None
    else:
        from .demo import build_demo_scene
        build_demo_scene()

    scene = bpy.data.scenes.get(args.scene) if args.scene else bpy.context.scene
    if scene is None:
        raise CliError(f"no scene named {args.scene!r} in {args.file}")
    if bpy.context.window is not None and bpy.context.window.scene != scene:
        bpy.context.window.scene = scene
    _apply_options(scene, args, resolution)
    if scene.camera is None and need_camera:
        raise CliError(f"scene {scene.name!r} has no camera")
    return scene


def register_ember() -> None:
    """Register the add-on unless an enabled Ember extension already did. The engine package's register() is
    the add-on's (the root package only delegates to it); imported here, lazily, so that the dependency stays
    one way: engine/__init__.py never imports this module."""
    if not hasattr(bpy.types.Scene, "ember"):
        from . import register
        register()


# Command-line options -> the scene.ember property each sets (when given), and how its value is written there.
EMBER_OPTIONS = (("samples", "samples", None), ("max_bounces", "max_bounces", None), ("mode", "sampling_mode", None),
                 ("seed", "seed", None), ("pattern", "sampling_pattern", lambda p: p.upper().replace("-", "_")),
                 ("time_limit", "time_limit", None), ("denoise", "use_denoising", None))


def _apply_options(scene, args, resolution) -> None:
    scene.render.engine = "EMBER"
    ember = scene.ember
    for option, prop, convert in EMBER_OPTIONS:
        value = getattr(args, option)
        if value is not None:
            setattr(ember, prop, value if convert is None else convert(value))
    if args.sample_offset is not None:
        ember.sample_offset = args.sample_offset
        # Ranges merge by sample count: every pixel must hold them all, and none may be denoised; and each
        # pixel reads its own sequence (the blue-noise layout depends on the whole frame's sample count,
        # which a range does not know), so that ranges merge into exactly the whole rendered alike.
        ember.use_adaptive_sampling = ember.use_denoising = False
        ember.sampling_pattern = "SOBOL_BURLEY"
    if args.threads is not None:
        scene.render.threads_mode = "FIXED" if args.threads > 0 else "AUTO"
        if args.threads > 0:
            scene.render.threads = capped_threads(args.threads)
            if scene.render.threads < args.threads:
                print(f"Ember | Warning: --threads {args.threads} is more than the {scene.render.threads} "
                      f"core{'s' if scene.render.threads > 1 else ''} usable here: rendering with "
                      f"{scene.render.threads} threads", flush=True)
    if resolution is not None:
        scene.render.resolution_x, scene.render.resolution_y = resolution
        scene.render.resolution_percentage = 100


def skip_existing(scene, frame: int, target: str) -> bool:
    """True (with a line saying so) when `target` exists and the file's Overwrite option is off."""
    if scene.render.use_overwrite or not os.path.exists(target):
        return False
    print(f"Ember | Frame {frame} | {target} exists and the file's Overwrite option is off: skipped", flush=True)
    return True


def interrupted() -> bool:
    return stop_signals.stopped()


def frames_outcome(saved: list[int], lost: list[int]) -> str:
    """'frames 1-6 were saved; frames 7-8 were not'."""
    text = saved_frames(saved)
    if lost:
        text += f"; frame{'s' if len(lost) > 1 else ''} {frame_ranges(lost)} {'were' if len(lost) > 1 else 'was'} not"
    return text


def saved_frames(done: list[int]) -> str:
    if not done:
        return "no frame was saved"
    return f"frame {done[0]} was saved" if len(done) == 1 else f"frames {frame_ranges(done)} were saved"


def frame_ranges(frames: list[int]) -> str:
    """[1, 2, 3, 5] -> '1-3, 5'."""
    parts, start = [], None
    for i, f in enumerate(frames):
        if start is None:
            start = f
        if i + 1 == len(frames) or frames[i + 1] != f + 1:
            parts.append(str(start) if start == f else f"{start}-{f}")
            start = None
    return ", ".join(parts)
