"""`python -m ember render`: render a .blend file, or the built-in demo scene, headless with Ember.

The same path as `blender -b file.blend -E EMBER -f 1`: register the add-on, open the file, select
Ember, render through bpy.ops.render.render so Blender's colour management and file output apply
(PNG gets the scene's view transform, EXR stays linear). The .blend is never saved.

Without -o, frames go where `blender -b file.blend -a` would put them: the file's output path with
Blender's own rules (`//` relative to the .blend, `#` padding, the frame number appended when there is
no `#`, the extension when the file asks for one) in the file's output format. Every output directory is
created, and every output path checked, before the first frame renders. Frames are saved through
engine/frame_save.py (a temporary name, a whole-file check, a rename), so an interrupted or failed frame
never leaves a file behind nor replaces an earlier one; a failed save stops the render with one line naming
the frames saved and the frames lost.

Bad input gets one line on stderr and a non-zero exit (2 for a malformed command line); Ctrl-C, SIGTERM
and SIGHUP stop the frame being rendered, keep the frames finished before it, and exit with 130, 143 or 129
(engine/stop_signals.py).

With --ray the frames (or sample ranges of them, --split-samples) are rendered by a Ray cluster's workers
(engine/distributed.py; engine/ray_cluster.py imports Ray, the rest of Ember never does); this process opens
the file all the same (prepare) and writes the frames with the same save_render_result. What both share (the
job, opening the file with the options, the errors and exit codes) is engine/batch.py's.
"""
from __future__ import annotations

import argparse
import errno
import os
import re
import sys
import tempfile

import bpy

from . import stop_signals
from .batch import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_USAGE, CliError, RenderJob, UsageError, frames_outcome,
                    interrupted, match_option, open_scene, saved_frames, skip_existing)
from .bake_cli import add_parser as add_bake_parser, bake_file, check_bake_options
from .frame_save import SaveError, existing_part, first_line, partial_prefix, save_render_result
from .properties import SAMPLING_MODE_ITEMS

FORMATS = {".png": "PNG", ".exr": "OPEN_EXR", ".jpg": "JPEG", ".jpeg": "JPEG", ".tif": "TIFF", ".tiff": "TIFF"}
SEED_MAX = 2**31 - 1             # Blender's integer properties are 32-bit signed


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
    render.add_argument("-o", "--output", help="output image path; '#' marks the frame number (default: the "
                                                "file's own output path and format, as blender -b would use; "
                                                "out/demo.png for the demo)")
    render.add_argument("--samples", type=int, help="samples per pixel")
    frames = render.add_mutually_exclusive_group()
    frames.add_argument("--frames", help="frame or range, e.g. 1 or 1-24 (default: the current frame)")
    frames.add_argument("-a", "--animation", action="store_true",
                        help="the file's frame range and step, as blender -b FILE -a")
    render.add_argument("--resolution", help="WIDTHxHEIGHT in pixels, e.g. 1280x720 (percentage set to 100)")
    render.add_argument("--max-bounces", type=int, help="bounces after the first hit (0 = direct light only)")
    render.add_argument("--mode", choices=[item[0] for item in SAMPLING_MODE_ITEMS], help="sampling mode")
    render.add_argument("--seed", type=int, help=f"random seed, 0 to {SEED_MAX}")
    render.add_argument("--pattern", choices=("automatic", "sobol-burley"),
                        help="sampling pattern: automatic (the default: neighbouring pixels' noise is blue noise, "
                             "as Cycles' final renders) or sobol-burley (a sequence per pixel, what sample "
                             "ranges use: a render to compare with merged ranges)")
    render.add_argument("--time-limit", type=float, help="seconds per frame, 0 for none (the first full pass "
                                                         "always completes)")
    render.add_argument("--threads", type=int, help="render threads (default or 0: all cores)")
    render.add_argument("--scene", help="scene name inside the file (default: the active scene)")
    render.add_argument("--denoise", action=argparse.BooleanOptionalAction, default=None,
                        help="denoise with OpenImageDenoise (default: the file's setting, on in a new scene)")
    render.add_argument("--passes", help="comma-separated passes to write besides the image, as a multilayer "
                                         f"OpenEXR (-o must end in .exr): {', '.join(CLI_PASSES)} or all")
    render.add_argument("--sample-offset", type=int,
                        help="render samples OFFSET .. OFFSET + --samples - 1 of each pixel: a sample range, to "
                             "merge with others (python -m ember merge); turns adaptive sampling and denoising "
                             "off, which ranges cannot merge, and gives each pixel a sequence of its own "
                             "(the Sobol-Burley pattern), so that ranges merge into exactly the whole")
    ray = render.add_argument_group(
        "many machines", "Spread the frames over a Ray cluster (Ray is optional: "
                         "python3 dev.py --blender 5.0 setup --ray). Frames are written by this process, as they "
                         "arrive, exactly as without --ray.")
    ray.add_argument("--ray", metavar="ADDRESS",
                     help="render on a Ray cluster: auto, HOST:6379, ray://HOST:10001 (Ray Client), or local[:N] "
                          "to start Ray here with N workers (default: the cores)")
    ray.add_argument("--workers", type=int, metavar="N",
                     help="workers (Ray actors, one process each; default: N of local:N, else one per node)")
    ray.add_argument("--split-samples", type=int, metavar="N",
                     help="split each frame's samples into N sample ranges rendered as separate tasks and merged "
                          "here by sample count; ranges render without adaptive sampling and denoising (as "
                          "--sample-offset), so --denoise denoises each merged frame here instead")
    ray.add_argument("--shared-path", action=argparse.BooleanOptionalAction, default=None,
                     help="the workers open the .blend at its path (a file system all nodes see) instead of "
                          "receiving its bytes (default: the path with local, the bytes on a cluster)")
    add_bake_parser(sub)
    merge = sub.add_parser("merge", help="merge sample ranges of one frame (renders made with --sample-offset)",
                           description="Average renders of sample ranges of one frame, weighted by the sample "
                                       "counts they hold (OpenEXR files written by Ember), into one image.")
    merge.add_argument("inputs", nargs="+", help="the ranges' OpenEXR files")
    merge.add_argument("-o", "--output", required=True, help="the merged OpenEXR file")
    return parser


def parse_frames(text: str | None):
    if text is None:
        return None
    m = match_option("--frames", text, r"\s*(-?\d+)\s*(?:-\s*(-?\d+)\s*)?", "5 or 1-24")
    start = int(m.group(1))
    end = int(m.group(2)) if m.group(2) is not None else start
    if end < start:
        raise UsageError(f"--frames range {text!r} ends before it starts")
    limit = 1_048_574  # Blender's MAXFRAME
    if not (-limit <= start and end <= limit):
        raise UsageError(f"--frames must lie within -{limit} to {limit}, got {text!r}")
    return start, end


def check_options(args) -> None:
    """Numbers Blender would clamp or overflow on, rejected with the range instead."""
    def within(name, value, lo, hi):
        if value is not None and not lo <= value <= hi:
            raise UsageError(f"{name} must be from {lo} to {hi}, got {value}")
    within("--samples", args.samples, 1, 1 << 24)
    within("--max-bounces", args.max_bounces, 0, 1024)
    within("--seed", args.seed, 0, SEED_MAX)
    within("--sample-offset", args.sample_offset, 0, 1 << 24)
    within("--threads", args.threads, 0, 1024)
    within("--split-samples", args.split_samples, 1, 1 << 24)
    within("--workers", args.workers, 1, 4096)
    if args.pattern == "automatic" and (args.sample_offset is not None or (args.split_samples or 1) > 1):
        raise UsageError("--pattern automatic cannot render sample ranges (--sample-offset, --split-samples): its "
                         "layout depends on the whole frame's sample count; ranges use sobol-burley")
    if args.time_limit is not None and not (0 <= args.time_limit < float("inf")):
        raise UsageError(f"--time-limit must be 0 (none) or a positive number of seconds, got {args.time_limit:g}")


def check_output(path: str) -> str:
    """Absolute output path for -o, with a known extension, whose directory is writable, or CliError."""
    path = os.path.abspath(os.path.expanduser(path))
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise CliError(f"output {path!r} needs one of the extensions {', '.join(sorted(FORMATS))}")
    partial_prefix(frame_path(path, 0, False))  # a name or path too long, before its directories are made
    ensure_writable_directory(os.path.dirname(path))
    return path


def ensure_writable_directory(directory: str) -> None:
    """Create `directory` (and its parents) and check a file can be written in it, or CliError
    naming the real obstacle: a parent that is a file, a missing permission, a place that cannot
    hold directories."""
    directory = os.path.abspath(directory or ".")
    existing = existing_part(directory)
    if not os.path.isdir(existing):
        raise CliError(f"cannot write to {directory!r}: {existing!r} is a file, not a directory")
    try:
        os.makedirs(directory, exist_ok=True)
    except OSError as err:
        raise CliError(f"cannot create the directory {directory!r} in {existing!r}: {_reason(err)}") from None
    try:
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as err:
        raise CliError(f"cannot write files in {directory!r}: {_reason(err)}") from None


def _reason(err: OSError) -> str:
    """errno in words that fit a directory that exists (ENOENT there means a file system such as /proc
    that refuses new entries, not a missing path)."""
    return {errno.EACCES: "permission denied", errno.EPERM: "permission denied", errno.EROFS: "read-only file system",
            errno.ENOENT: "its file system does not allow new files or directories"}.get(err.errno, err.strerror or str(err))


def frame_path(path: str, frame: int, many: bool) -> str:
    """-o paths: replace a run of '#' with the zero-padded frame; several frames without '#' get _####."""
    if "#" not in path and many:
        root, ext = os.path.splitext(path)
        path = f"{root}_####{ext}"
    return re.sub(r"#+", lambda m: f"{frame:0{len(m.group(0))}d}", path)


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    previous = stop_signals.install()
    try:
        if args.command == "bake":
            return bake(args)
        return merge_command(args) if args.command == "merge" else render(args)
    except UsageError as err:
        print(f"ember: error: {err} (see --help)", file=sys.stderr)
        return EXIT_USAGE
    except (CliError, SaveError) as err:
        print(f"ember: error: {err}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:  # Ctrl-C before Ember's handler was in place
        print("ember: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        stop_signals.restore(previous)


def merge_command(args) -> int:
    from .merge import MergeError, merge
    for path in args.inputs:
        if not os.path.isfile(path):
            raise CliError(f"no such file: {path}")
    output = check_output(args.output)
    try:
        total = merge(args.inputs, output)
    except MergeError as err:
        raise CliError(str(err)) from None
    print(f"Ember | merged {len(args.inputs)} renders, {total} samples -> {output}", flush=True)
    return 0


def bake(args) -> int:
    """python -m ember bake (engine/bake_cli.py): the options checked, the output's directory made writable."""
    for name, value, lo, hi in (("--samples", args.samples, 1, 1 << 24), ("--seed", args.seed, 0, SEED_MAX),
                                ("--max-bounces", args.max_bounces, 0, 1024), ("--threads", args.threads, 0, 1024)):
        if value is not None and not lo <= value <= hi:
            raise UsageError(f"{name} must be from {lo} to {hi}, got {value}")
    output, width, height = check_bake_options(args)
    partial_prefix(output)
    ensure_writable_directory(os.path.dirname(output))
    return bake_file(args, output, width, height)


def render(args) -> int:
    check_options(args)
    distributed = args.ray is not None
    if distributed:
        from .distributed import check_ray_options
        check_ray_options(args)  # before the file opens: a missing Ray fails at once
    else:
        for option, value in (("--split-samples", args.split_samples), ("--workers", args.workers),
                              ("--shared-path", args.shared_path)):
            if value is not None:
                raise UsageError(f"{option} goes with --ray")
    job = prepare(args)
    if distributed:
        from .distributed import render_on_ray
        return render_on_ray(args, job)
    return render_frames(job)


def prepare(args) -> RenderJob:
    """Open the file (or the demo), apply the options, and check every frame's output directory."""
    frames = parse_frames(args.frames)
    if args.file is not None and not os.path.isfile(args.file):
        raise CliError(f"no such file: {args.file}")
    output = check_output(args.output) if args.output else None
    scene = open_scene(args)
    if args.file is None and output is None:
        output = check_output(os.path.join("out", "demo.png"))

    if frames:
        frame_list = list(range(frames[0], frames[1] + 1))
    elif args.animation:
        frame_list = list(range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step)))
    else:
        frame_list = [scene.frame_current]
    if output is not None:
        _use_format_of(scene, output)
    if args.passes:
        _use_passes(scene, args.passes, output)
    if output is not None:
        targets = [frame_path(output, f, len(frame_list) > 1) for f in frame_list]
    else:
        targets = [_file_output_path(scene, f) for f in frame_list]
    for target in targets:  # before any frame renders
        partial_prefix(target)
    for directory in dict.fromkeys(os.path.dirname(t) for t in targets):
        ensure_writable_directory(directory)
    return RenderJob(scene, frame_list, targets)


def render_frames(job: RenderJob) -> int:
    """The single-process loop: render each frame in this process and save it."""
    scene, frame_list = job.scene, job.frames
    done = []
    for frame, target in zip(frame_list, job.targets):
        if interrupted():
            break
        if skip_existing(scene, frame, target):
            continue
        scene.frame_set(frame)
        try:
            bpy.ops.render.render(write_still=False, scene=scene.name)
        except RuntimeError as err:
            raise CliError(_with_outcome(f"frame {frame}: {first_line(err)}", job, done, frame)) from None
        if interrupted():  # the render stopped early: its frame is incomplete, so it is not saved
            kept = saved_frames(done)
            print(f"ember: {stop_signals.interrupted_by()} during frame {frame}: nothing saved for it; {kept}",
                  file=sys.stderr)
            return stop_signals.exit_status()
        try:  # a frame that finished rendering is saved even if Ctrl-C comes now
            save_render_result(scene, target)
        except SaveError as err:  # a failed save stops the render, as Blender's own animation render does
            raise CliError(_with_outcome(f"frame {frame}: {err}", job, done, frame)) from None
        done.append(frame)
        print(f"Ember | Frame {frame} | saved {target}", flush=True)
    if interrupted() and len(done) < len(frame_list):
        print(f"ember: {stop_signals.interrupted_by()} after frame {done[-1] if done else frame_list[0]}: "
              f"{saved_frames(done)}", file=sys.stderr)
        return stop_signals.exit_status()
    return 0


def _file_output_path(scene, frame: int) -> str:
    """Where blender -b FILE -a writes `frame`: Blender's own rules, absolute."""
    if scene.render.is_movie_format:
        raise CliError(f"the file's output format is a video ({scene.render.image_settings.file_format}), which "
                       f"Ember's command line cannot write: pass -o with an image path such as out/frame_####.png")
    return os.path.abspath(bpy.path.abspath(scene.render.frame_path(frame=frame)))


def _use_format_of(scene, output: str) -> None:
    settings = scene.render.image_settings
    if getattr(settings, "media_type", "IMAGE") != "IMAGE":
        settings.media_type = "IMAGE"
    settings.file_format = FORMATS[os.path.splitext(output)[1].lower()]
    if settings.file_format == "OPEN_EXR":
        settings.color_depth = "32"


# --passes names -> View Layer toggles (and Ember's Denoising Data)
CLI_PASSES = {"depth": "use_pass_z", "position": "use_pass_position", "normal": "use_pass_normal",
              "uv": "use_pass_uv", "object_index": "use_pass_object_index",
              "material_index": "use_pass_material_index", "mist": "use_pass_mist", "emission": "use_pass_emit",
              "environment": "use_pass_environment", "noise": "use_pass_noise",
              "crypto_object": "use_pass_cryptomatte_object", "crypto_material": "use_pass_cryptomatte_material",
              "crypto_asset": "use_pass_cryptomatte_asset",
              **{f"{c}_{k}": f"use_pass_{c}_{k}" for c in ("diffuse", "glossy", "transmission")
                 for k in ("direct", "indirect", "color")},
              "volume_direct": "use_pass_volume_direct", "volume_indirect": "use_pass_volume_indirect",
              "shadow_catcher": "use_pass_shadow_catcher", "denoising": "denoising_store_passes"}


def _use_passes(scene, text: str, output: str | None) -> None:
    """Turn the named passes on in every view layer and write a multilayer OpenEXR."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    if names == ["all"]:
        names = list(CLI_PASSES)
    unknown = [n for n in names if n not in CLI_PASSES]
    if unknown:
        raise CliError(f"--passes: unknown {', '.join(unknown)}; known: {', '.join(CLI_PASSES)} or all")
    if output is not None and os.path.splitext(output)[1].lower() != ".exr":
        raise CliError("--passes writes a multilayer OpenEXR: give -o a path ending in .exr")
    for layer in scene.view_layers:
        for name in names:
            toggle = CLI_PASSES[name]
            setattr(layer.ember if toggle in ("denoising_store_passes", "use_pass_noise", "use_pass_volume_direct",
                                              "use_pass_volume_indirect", "use_pass_shadow_catcher") else layer,
                    toggle, True)
    settings = scene.render.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.color_depth = "32"


def _with_outcome(message: str, job: RenderJob, done: list[int], failed: int) -> str:
    """`message`, and for several frames which were saved and which were lost (`failed` and the ones
    after it)."""
    if len(job.frames) == 1:
        return message
    return f"{message}; {frames_outcome(done, job.frames[job.frames.index(failed):])}"
