"""`python -m ember render`: render a .blend file, or the built-in demo scene, headless with Ember.

The same path as `blender -b file.blend -E EMBER -f 1`: register the add-on, open the file, select
Ember, render through bpy.ops.render.render so Blender's colour management and file output apply
(PNG gets the scene's view transform, EXR stays linear). The .blend is never saved.
Bad input gets one line on stderr and a non-zero exit.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile

import bpy

from .properties import SAMPLING_MODE_ITEMS

EXIT_USAGE = 2
EXIT_FAILED = 1
FORMATS = {".png": "PNG", ".exr": "OPEN_EXR", ".jpg": "JPEG", ".jpeg": "JPEG", ".tif": "TIFF", ".tiff": "TIFF"}


class CliError(Exception):
    """A one-line message for the user."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, not argparse's usage block
        print(f"ember: error: {message} (see --help)", file=sys.stderr)
        sys.exit(EXIT_USAGE)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="python -m ember", description="Ember, a path tracer for Blender")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    render = sub.add_parser("render", help="render a .blend file (or the demo scene) with Ember",
                            description="Render FILE.blend with Ember; without a file, the built-in demo scene.")
    render.add_argument("file", nargs="?", help=".blend file to render (default: the built-in demo scene)")
    render.add_argument("-o", "--output", help="output image path; '#' marks the frame number "
                                                "(default: the file's own output path; out/demo.png for the demo)")
    render.add_argument("--samples", type=int, help="samples per pixel")
    render.add_argument("--frames", help="frame or range, e.g. 1 or 1-24 (default: the current frame)")
    render.add_argument("--resolution", help="WIDTHxHEIGHT in pixels, e.g. 1280x720 (percentage set to 100)")
    render.add_argument("--max-bounces", type=int, help="bounces after the first hit (0 = direct light only)")
    render.add_argument("--mode", choices=[item[0] for item in SAMPLING_MODE_ITEMS], help="sampling mode")
    render.add_argument("--seed", type=int, help="random seed")
    render.add_argument("--time-limit", type=float, help="seconds per frame, 0 for none")
    render.add_argument("--threads", type=int, help="render threads (default: all cores)")
    render.add_argument("--scene", help="scene name inside the file (default: the active scene)")
    return parser


def parse_frames(text: str | None):
    if text is None:
        return None
    m = re.fullmatch(r"\s*(-?\d+)\s*(?:-\s*(-?\d+)\s*)?", text)
    if not m:
        raise CliError(f"--frames must look like 5 or 1-24, got {text!r}")
    start = int(m.group(1))
    end = int(m.group(2)) if m.group(2) is not None else start
    if end < start:
        raise CliError(f"--frames range {text!r} ends before it starts")
    return start, end


def parse_resolution(text: str | None):
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or int(m.group(1)) < 1 or int(m.group(2)) < 1:
        raise CliError(f"--resolution must look like 1280x720, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def check_output(path: str) -> str:
    """Absolute output path whose directory exists and is writable, or CliError."""
    path = os.path.abspath(os.path.expanduser(path))
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise CliError(f"output {path!r} needs one of the extensions {', '.join(sorted(FORMATS))}")
    directory = os.path.dirname(path)
    try:
        os.makedirs(directory, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as err:
        raise CliError(f"cannot write to {directory!r}: {err.strerror or err}") from None
    return path


def frame_path(path: str, frame: int, many: bool) -> str:
    """Replace a run of '#' with the zero-padded frame; several frames without '#' get _#### added."""
    if "#" not in path and many:
        root, ext = os.path.splitext(path)
        path = f"{root}_####{ext}"
    return re.sub(r"#+", lambda m: f"{frame:0{len(m.group(0))}d}", path)


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    try:
        return render(args)
    except CliError as err:
        print(f"ember: error: {err}", file=sys.stderr)
        return EXIT_FAILED


def render(args) -> int:
    frames = parse_frames(args.frames)
    resolution = parse_resolution(args.resolution)
    if args.samples is not None and args.samples < 1:
        raise CliError("--samples must be at least 1")
    if args.file is not None and not os.path.isfile(args.file):
        raise CliError(f"no such file: {args.file}")
    output = check_output(args.output) if args.output else None

    _register_ember()
    if args.file is not None:
        try:
            bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.file), load_ui=False)
        except RuntimeError as err:
            raise CliError(f"cannot open {args.file}: {_first_line(err)}") from None
    else:
        from .demo import build_demo_scene
        build_demo_scene()
        if output is None:
            output = check_output(os.path.join("out", "demo.png"))

    scene = bpy.data.scenes.get(args.scene) if args.scene else bpy.context.scene
    if scene is None:
        raise CliError(f"no scene named {args.scene!r} in {args.file}")
    if bpy.context.window is not None and bpy.context.window.scene != scene:
        bpy.context.window.scene = scene
    _apply_options(scene, args, resolution)
    if scene.camera is None:
        raise CliError(f"scene {scene.name!r} has no camera")

    first, last = frames if frames else (scene.frame_current, scene.frame_current)
    many = last > first
    for frame in range(first, last + 1):
        scene.frame_set(frame)
        if output is not None:
            target = frame_path(output, frame, many)
            scene.render.filepath = target
            scene.render.use_file_extension = False
            scene.render.image_settings.file_format = FORMATS[os.path.splitext(target)[1].lower()]
            if scene.render.image_settings.file_format == "OPEN_EXR":
                scene.render.image_settings.color_depth = "32"
        else:
            target = bpy.path.abspath(scene.render.frame_path(frame=frame))
            os.makedirs(os.path.dirname(target) or ".", exist_ok=True)
        try:
            bpy.ops.render.render(write_still=True, scene=scene.name)
        except RuntimeError as err:
            raise CliError(_first_line(err)) from None
        if not os.path.exists(target):
            raise CliError(f"frame {frame} rendered but {target} was not written")
        print(f"Ember | Frame {frame} | saved {target}", flush=True)
    return 0


def _register_ember() -> None:
    """Register the add-on unless an enabled Ember extension already did."""
    if not hasattr(bpy.types.Scene, "ember"):
        from .. import register
        register()


def _apply_options(scene, args, resolution) -> None:
    scene.render.engine = "EMBER"
    ember = scene.ember
    if args.samples is not None:
        ember.samples = args.samples
    if args.max_bounces is not None:
        ember.max_bounces = max(0, args.max_bounces)
    if args.mode is not None:
        ember.sampling_mode = args.mode
    if args.seed is not None:
        ember.seed = max(0, args.seed)
    if args.time_limit is not None:
        ember.time_limit = max(0.0, args.time_limit)
    if args.threads is not None:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = max(1, args.threads)
    if resolution is not None:
        scene.render.resolution_x, scene.render.resolution_y = resolution
        scene.render.resolution_percentage = 100


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    line = text[0] if text else type(err).__name__
    return line.removeprefix("Error: ").strip()
