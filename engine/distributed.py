"""Renders split over a Ray cluster: `python -m ember render FILE.blend --frames 1-240 --ray ADDRESS`.

Three parts:
- RenderWorker, the Ray actor: one process with its own bpy, which opens the .blend once (from its path,
  or from the bytes the driver sends), registers Ember, and renders many tasks through Blender's render
  pipeline as the single-process command line does. A task is a frame, or a sample range of a frame
  (--split-samples); it returns the frame as float32 RGBA pixels, the sample count and Ember's metadata.
- Driver, in the command line's process: keeps a queue of tasks, gives each worker one task at a time,
  prints progress on stderr, merges the sample ranges of a frame by sample count (merge.merge_arrays)
  and writes every finished frame at once, so nothing finished is lost. A worker that dies (its process
  killed, its node lost) has its task put back at the head of the queue and a replacement started.
- FrameWriter: frames reach the files through Blender's own writer in the driver's bpy, which opened the
  same .blend: a small render engine hands the worker's pixels to Blender as its render result, and the
  command line's own save (frame_save.save_render_result) writes them, so colour management, format, metadata
  and file naming are exactly those of `python -m ember render` without --ray.

Ray is an optional dependency of the command line (requirements-ray.txt, `python3 dev.py --blender 5.0 setup --ray`):
ray_cluster.py imports it, lazily, and connects to the cluster; the extension never imports this module. What
the single-process command line does alike (opening the file with the options, skipping frames on disk, the
errors and exit codes) is batch.py's.
"""
from __future__ import annotations

import contextlib
import copy
import io
import os
import re
import socket
import sys
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..kernels.accel import usable_cores
from . import stop_signals
from .batch import (CliError, RenderJob, UsageError, frame_ranges, frames_outcome, interrupted, open_scene,
                    saved_frames, skip_existing)
from .frame_save import SaveError, first_line, save_render_result
from .merge import MergeError, exr_strings, load_pixels, merge_arrays, read_exr_channels
from .ray_cluster import connected, node_count, parse_cluster, require_ray
from .session import format_time

POLL_S = 0.2                 # how often the driver looks for Ctrl-C while it waits for results
PROGRESS_INTERVAL_S = 10.0   # a progress line at least this often, besides one per saved frame
START_TIMEOUT_S = 300.0      # with no worker left, how long to wait for a replacement to start
MAX_ATTEMPTS = 3             # a task whose worker died this many times is a failure, not bad luck
WRITER_ENGINE = "EMBER_RAY_WRITER"


# ---------------------------------------------------------------------------------------------- options
def check_ray_options(args) -> None:
    """What can be checked before the file opens; Ray missing is one line (exit 1)."""
    args.cluster = parse_cluster(args.ray)
    if args.samples is not None and args.split_samples is not None and args.split_samples > args.samples:
        raise UsageError(f"--split-samples {args.split_samples} is more than the {args.samples} samples per pixel")
    if args.passes:
        raise CliError("--passes cannot be used with --ray yet: the workers send back the image alone")
    if args.cluster.local:
        # Ray of this machine alone: keep it on the loopback interface (read when ray is imported; by
        # default Ray advertises the machine's network address even for a local instance).
        os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    require_ray()


def sample_ranges(offset: int, samples: int, parts: int) -> list[tuple[int, int]]:
    """`samples` samples from `offset` in `parts` (offset, count) ranges, the first ones one larger."""
    base, extra = divmod(samples, parts)
    out = []
    for i in range(parts):
        count = base + (i < extra)
        out.append((offset, count))
        offset += count
    return out


# ---------------------------------------------------------------------------------------------- worker
class RenderWorker:
    """A Ray actor: one process, one bpy, the .blend opened once, many tasks. Expected failures come back
    as {"error": one line}, so the driver can tell them from a worker that died."""

    def __init__(self, blend: bytes | None, args, aux: tuple[str, ...]):
        self.error = None
        self.scene = None
        self.aux = aux
        try:
            self.scene = self._open(blend, args)
        except CliError as err:
            self.error = str(err)
        except Exception as err:  # a bug: the driver reports it in one line
            self.error = f"worker {socket.gethostname()}: {type(err).__name__}: {err}"

    def _open(self, blend: bytes | None, args):
        if blend is None:
            scene = open_scene(args)  # the file at its path (seen by every node), or the demo scene
        else:  # a private copy, removed once Blender has read it: nothing is ever saved
            with tempfile.TemporaryDirectory(prefix="ember-ray-") as tmp:
                local = os.path.join(tmp, os.path.basename(args.file))
                with open(local, "wb") as f:
                    f.write(blend)
                scene = open_scene(args, local)
        scene.render.use_stamp = False  # burnt-in stamps: the driver's save draws them, once
        if self.aux:  # Denoising Albedo / Normal, for the driver's denoiser
            for layer in scene.view_layers:
                layer.ember.denoising_store_passes = True
        return scene

    def ready(self) -> dict:
        return {"pid": os.getpid(), "host": socket.gethostname(), "error": self.error}

    def render(self, frame: int, offset: int | None, samples: int | None) -> dict:
        """Render `frame` (samples offset .. offset + samples - 1 when offset is given) and return its pixels:
        (H * W * 4) float32, Blender's order (rows bottom-up)."""
        scene, ember = self.scene, self.scene.ember
        if offset is not None:  # a range: every pixel holds all its samples, none denoised (they merge)
            ember.sample_offset, ember.samples = offset, samples
            ember.use_adaptive_sampling = ember.use_denoising = False
            ember.sampling_pattern = "SOBOL_BURLEY"   # each pixel its own sequence, as the command line's ranges
        start = time.perf_counter()
        scene.frame_set(frame)
        printed = io.StringIO()
        try:
            # Blender keeps a render's passes only when the output format is multilayer.
            _use_exr(scene.render.image_settings, multilayer=bool(self.aux))
            with contextlib.redirect_stdout(printed):
                bpy.ops.render.render(write_still=False, scene=scene.name)
            with tempfile.TemporaryDirectory(prefix="ember-ray-") as tmp:
                out = self._aux_passes(os.path.join(tmp, "passes.exr")) if self.aux else {}
                _use_exr(scene.render.image_settings, multilayer=False)
                path = os.path.join(tmp, "frame.exr")
                save_render_result(scene, path)
                pixels, width, height = load_pixels(path)
                fields = exr_strings(path)
        except (CliError, SaveError, MergeError, RuntimeError) as err:
            return {"error": f"frame {frame}: {first_line(err)}"}
        out.update(pixels=pixels, width=width, height=height, samples=int(fields.get("ember.samples", 0)),
                   metadata={k: v for k, v in fields.items() if k.startswith("ember.")},
                   warnings=_warnings(printed.getvalue()), seconds=time.perf_counter() - start)
        return out

    def _aux_passes(self, path: str) -> dict:
        """The denoiser's albedo and normal passes, (H, W, 3) rows bottom-up, through a multilayer file."""
        save_render_result(self.scene, path)
        layer = self.scene.view_layers[0].name
        wanted = {"albedo": ("Denoising Albedo", "RGB"), "normal": ("Denoising Normal", "XYZ")}
        names = {kind: [f"{layer}.{wanted[kind][0]}.{c}" for c in wanted[kind][1]] for kind in self.aux}
        channels = read_exr_channels(path, [n for group in names.values() for n in group])
        return {kind: np.stack([channels[n] for n in group], axis=-1) for kind, group in names.items()}


def _use_exr(settings, multilayer: bool) -> None:
    """32-bit float OpenEXR, uncompressed, scene-linear: the worker's files carry the floats back exactly
    (the driver applies the output format)."""
    settings.media_type = "MULTI_LAYER_IMAGE" if multilayer else "IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER" if multilayer else "OPEN_EXR"
    settings.color_depth = "32"
    settings.exr_codec = "NONE"
    if not multilayer:
        settings.color_mode = "RGBA"
    settings.color_management = "FOLLOW_SCENE"


def _warnings(printed: str) -> list[str]:
    """Ember's warnings among what a render printed ('Ember | Frame 3 | Warning: ...')."""
    return [line.split("| Warning: ", 1)[1] for line in printed.splitlines() if "| Warning: " in line]


# ---------------------------------------------------------------------------------------------- writer
_pending_frame: dict | None = None  # what the writer engine hands to Blender next


class _WriterEngine(bpy.types.RenderEngine):
    """Hands a worker's finished pixels to Blender as the render result, for Blender's writer."""
    bl_idname = WRITER_ENGINE
    bl_label = "Ember (Ray frame writer)"
    # The workers' pixels are already composited (what the single-process render would save): once is enough.
    bl_use_postprocess = False
    bl_use_preview = False

    def render(self, depsgraph):
        frame = _pending_frame
        result = self.begin_result(0, 0, self.resolution_x, self.resolution_y, layer=depsgraph.view_layer.name)
        try:
            result.layers[0].passes["Combined"].rect.foreach_set(frame["pixels"])
        finally:
            self.end_result(result)
        full = self.get_result()
        for key, value in frame["metadata"].items():  # ember.samples & co, as Ember stamps them
            full.stamp_data_add_field(key, str(value))


class FrameWriter:
    """Writes frames through the driver's own bpy and the command line's save."""

    def __init__(self, scene):
        self.scene = scene
        if not _WriterEngine.is_registered:
            bpy.utils.register_class(_WriterEngine)

    def write(self, frame: int, target: str, pixels: np.ndarray, width: int, height: int, metadata: dict) -> None:
        global _pending_frame
        render = self.scene.render
        render.engine = WRITER_ENGINE
        # The result is the pixels' size: a border region was already cropped (or not) by the worker.
        render.use_border = False
        render.resolution_x, render.resolution_y, render.resolution_percentage = width, height, 100
        self.scene.frame_current = frame  # for the file's metadata (Frame), as the single-process render
        _pending_frame = {"pixels": pixels, "metadata": metadata}
        try:
            bpy.ops.render.render(write_still=False, scene=self.scene.name)
        except RuntimeError as err:
            raise CliError(f"cannot write it: {first_line(err)}") from None
        finally:
            _pending_frame = None
        save_render_result(self.scene, target)


# ---------------------------------------------------------------------------------------------- driver
@dataclass
class Task:
    frame: int
    index: int                 # its range of the frame (0 without --split-samples)
    offset: int | None = None  # None: the whole frame as the file and options say
    samples: int | None = None
    attempts: int = 0

    def label(self) -> str:
        if self.offset is None:
            return f"frame {self.frame}"
        return f"frame {self.frame} samples {self.offset}-{self.offset + self.samples - 1}"


@dataclass
class Worker:
    number: int
    actor: object
    started: float
    pid: int = 0
    host: str = ""
    ready: bool = False
    task: Task | None = None
    done: int = 0
    busy_s: float = 0.0  # the tasks' render time, as the worker measured it


@dataclass
class Plan:
    frames: list[int]
    targets: dict[int, str]
    ranges: list[tuple[int, int]] | None  # per frame, None: whole frames
    denoise: tuple[str, ...] | None       # merged frames are denoised here, with these passes
    tasks: deque = field(default_factory=deque)


def render_on_ray(args, job: RenderJob) -> int:
    """The --ray hook of the command line: plan, connect, run the driver, disconnect."""
    ray = require_ray()
    scene, cluster = job.scene, args.cluster
    plan = _plan(args, job)
    if not plan.frames:
        return 0
    shared = args.shared_path if args.shared_path is not None else cluster.local
    blend = None
    if args.file is not None:
        args.file = os.path.abspath(args.file)
        if not shared:
            with open(args.file, "rb") as f:
                blend = f.read()
            _warn_external_files(args.file)
    local_workers = args.workers or cluster.workers or usable_cores()
    if cluster.local and local_workers > usable_cores():  # each a process with its own Blender: no more than the cores
        _status(f"{local_workers} workers asked for, but {usable_cores()} cores can be used here: starting "
                f"{usable_cores()}")
        local_workers = usable_cores()
    with connected(ray, cluster, local_workers):
        workers = local_workers if cluster.local else args.workers or node_count(ray)
        cpus = int(ray.cluster_resources().get("CPU", 0))
        if workers > cpus:
            raise CliError(f"{workers} workers need {workers} CPUs of the Ray cluster, which has {cpus}: "
                           f"pass --workers {max(cpus, 1)}")
        worker_args = copy.copy(args)
        if cluster.local and args.threads is None:  # the cores shared among the workers of this machine
            worker_args.threads = max(1, usable_cores() // workers)
        driver = Driver(ray, plan, FrameWriter(scene), scene.ember,
                        ray.put(blend) if blend is not None else None, worker_args, workers)
        return driver.run()


def _plan(args, job) -> Plan:
    scene = job.scene
    split = args.split_samples or 1
    samples = int(scene.ember.samples)
    if split > samples:
        raise UsageError(f"--split-samples {split} is more than the {samples} samples per pixel")
    settings = scene.render.image_settings
    if settings.media_type != "IMAGE":
        raise CliError("--ray writes single-layer images: the file's output is a multilayer OpenEXR; pass -o "
                       "with an image path such as out/frame_####.exr")
    ranges = sample_ranges(int(scene.ember.sample_offset), samples, split) if split > 1 else None
    denoise = None
    if ranges is not None and args.denoise:
        from .denoise import available
        ok, why = available()
        if not ok:
            raise CliError(f"--denoise with --split-samples denoises here, but: {why}")
        inputs = scene.ember.denoising_input_passes
        denoise = {"RGB": (), "RGB_ALBEDO": ("albedo",)}.get(inputs, ("albedo", "normal"))
    plan = Plan([], {}, ranges, denoise)
    for frame, target in zip(job.frames, job.targets):
        if skip_existing(scene, frame, target):
            continue
        plan.frames.append(frame)
        plan.targets[frame] = target
        if ranges is None:
            plan.tasks.append(Task(frame, 0))
        else:
            plan.tasks.extend(Task(frame, i, o, n) for i, (o, n) in enumerate(ranges))
    return plan


def _warn_external_files(path: str) -> None:
    relative = [p for p in bpy.utils.blend_paths(absolute=False, packed=False, local=False) if p.startswith("//")]
    if relative:
        print(f"Ember | Ray | Warning: the workers receive {os.path.basename(path)}'s bytes, not the {len(relative)} "
              f"file(s) it names relative to itself ({relative[0]}): pack them (File > External Data > Pack "
              f"Resources) or keep the .blend where every node sees it and pass --shared-path", file=sys.stderr)


class Driver:
    """The queue, the workers and the frames in progress; one task per worker at a time."""

    def __init__(self, ray, plan: Plan, writer: FrameWriter, ember, blend_ref, worker_args, workers: int):
        self.ray, self.plan, self.writer, self.ember = ray, plan, writer, ember
        self.blend_ref, self.worker_args = blend_ref, worker_args
        self.actor_class = ray.remote(RenderWorker).options(num_cpus=1, scheduling_strategy="SPREAD")
        self.workers: list[Worker] = []
        self.pending: dict = {}          # ObjectRef -> (worker, task or None for the actor's start)
        self.parts: dict[int, list] = {}  # frame -> results of its ranges so far
        self.saved: list[int] = []
        self.replacements_left = 2 * workers
        self.numbers = 0
        self.start = self.last_event = self.last_progress = time.perf_counter()
        self.start_failures = 0
        lost = ray.exceptions
        self.lost_errors = (lost.RayActorError, lost.WorkerCrashedError, lost.ObjectLostError, lost.OwnerDiedError,
                            lost.NodeDiedError, lost.LocalRayletDiedError)
        for _ in range(workers):
            self._start_worker()

    # ------------------------------------------------------------------ the loop
    def run(self) -> int:
        try:
            while len(self.saved) < len(self.plan.frames):
                if interrupted():
                    return self._interrupted()
                self._dispatch()
                self._check_alive()
                done, _ = self.ray.wait(list(self.pending), num_returns=1, timeout=POLL_S)
                for ref in done:
                    self._collect(ref)
                if time.perf_counter() - self.last_progress >= PROGRESS_INTERVAL_S:
                    self._progress()
            return 0
        except CliError as err:  # which frames were saved and which were lost, on the same line
            if len(self.plan.frames) == 1:
                raise
            lost = [f for f in self.plan.frames if f not in self.saved]
            raise CliError(f"{err}; {frames_outcome(sorted(self.saved), lost)}") from None
        finally:
            for worker in self.workers:
                self._kill(worker)

    def _dispatch(self) -> None:
        for worker in self.workers:
            if worker.ready and worker.task is None and self.plan.tasks:
                task = worker.task = self.plan.tasks.popleft()
                self.pending[worker.actor.render.remote(task.frame, task.offset, task.samples)] = (worker, task)

    def _check_alive(self) -> None:
        if any(w.ready for w in self.workers):
            return
        if not self.workers:
            raise CliError("every Ray worker was lost and no replacement can be started")
        if time.perf_counter() - self.last_event > START_TIMEOUT_S:
            raise CliError(f"no Ray worker started in {START_TIMEOUT_S:.0f} s: is a CPU free in the cluster?")

    def _collect(self, ref) -> None:
        worker, task = self.pending.pop(ref)
        self.last_event = time.perf_counter()
        try:
            value = self.ray.get(ref)
        except self.lost_errors as err:
            return self._lost(worker, err)
        except self.ray.exceptions.RayTaskError as err:
            cause = err.cause if getattr(err, "cause", None) is not None else err
            raise CliError(f"worker {worker.number} failed on {task.label() if task else 'start'}: "
                           f"{type(cause).__name__}: {first_line(cause)}") from None
        if value.get("error"):
            raise CliError(value["error"])
        if task is None:
            worker.ready, worker.pid, worker.host = True, value["pid"], value["host"]
            _status(f"worker {worker.number} ready: pid {worker.pid} on {worker.host} "
                    f"({time.perf_counter() - worker.started:.1f} s)")
            return
        worker.task = None
        worker.done += 1
        worker.busy_s += value["seconds"]
        if task.index == 0:  # once per frame, not once per range
            for line in dict.fromkeys(value["warnings"]):
                print(f"Ember | Frame {task.frame} | Warning: {line}", flush=True)
        self._add(task, value)

    # ------------------------------------------------------------------ frames
    def _add(self, task: Task, value: dict) -> None:
        parts = self.parts.setdefault(task.frame, [])
        parts.append((task.index, value))
        if len(parts) < (len(self.plan.ranges) if self.plan.ranges else 1):
            return
        del self.parts[task.frame]
        parts = [v for _, v in sorted(parts, key=lambda p: p[0])]
        first = parts[0]
        if self.plan.ranges is None:
            pixels, metadata = first["pixels"], first["metadata"]
        else:
            pixels, metadata = self._merge(task.frame, parts)
        target = self.plan.targets[task.frame]
        try:
            self.writer.write(task.frame, target, pixels, first["width"], first["height"], metadata)
        except (CliError, SaveError) as err:
            raise CliError(f"frame {task.frame}: {err}") from None
        self.saved.append(task.frame)
        print(f"Ember | Frame {task.frame} | saved {target}", flush=True)
        self._progress()

    def _merge(self, frame: int, parts: list[dict]):
        """Sample ranges -> the frame, weighted by sample count; denoised here when asked."""
        try:
            pixels = merge_arrays([(p["pixels"], p["samples"]) for p in parts])
        except MergeError as err:
            raise CliError(f"frame {frame}: {err}") from None
        total = sum(p["samples"] for p in parts)
        metadata = {"ember.samples": total, "ember.sample_offset": self.plan.ranges[0][0],
                    "ember.adaptive": 0, "ember.denoised": 0}
        if self.plan.denoise is not None:
            pixels = self._denoise(frame, parts, pixels)
            metadata["ember.denoised"] = 1
        return pixels, metadata

    def _denoise(self, frame: int, parts: list[dict], pixels: np.ndarray) -> np.ndarray:
        """OIDN over the merged frame and passes, rows top-down as the single-process render hands them
        (the network is not symmetric under a flip: the same rows give the same image)."""
        from .denoise import DenoiseError, denoise
        height, width = parts[0]["height"], parts[0]["width"]
        image = pixels.reshape(height, width, 4)[::-1].copy()
        aux = {kind: merge_arrays([(p[kind], p["samples"]) for p in parts])[::-1] for kind in self.plan.denoise}
        try:
            image[..., :3] = denoise(image[..., :3], aux.get("albedo"), aux.get("normal"),
                                     quality=self.ember.denoising_quality, prefilter=self.ember.denoising_prefilter,
                                     threads=usable_cores())
        except (DenoiseError, ValueError) as err:
            raise CliError(f"cannot denoise frame {frame}: {err}") from None
        return np.ascontiguousarray(image[::-1]).reshape(-1)

    # ------------------------------------------------------------------ workers
    def _start_worker(self) -> None:
        self.numbers += 1
        actor = self.actor_class.remote(self.blend_ref, self.worker_args, self.plan.denoise or ())
        worker = Worker(self.numbers, actor, time.perf_counter())
        self.workers.append(worker)
        self.pending[actor.ready.remote()] = (worker, None)

    def _lost(self, worker: Worker, err) -> None:
        """A worker died (or its node): its task goes back to the head of the queue, a replacement starts."""
        self.workers.remove(worker)
        self._kill(worker)
        for ref, (owner, _) in list(self.pending.items()):
            if owner is worker:
                del self.pending[ref]
        reason = _reason(err)
        if not worker.ready:  # it died starting: Ember not importable on that node, a crash opening the file
            self.start_failures += 1
            if self.start_failures >= MAX_ATTEMPTS:
                raise CliError(f"Ray workers cannot start: {reason}")
        message = f"worker {worker.number} (pid {worker.pid or '?'} on {worker.host or '?'}) lost: {reason}"
        task = worker.task
        if task is not None:
            task.attempts += 1
            if task.attempts >= MAX_ATTEMPTS:
                raise CliError(f"{task.label()} was lost with {MAX_ATTEMPTS} workers; the last: {reason}")
            self.plan.tasks.appendleft(task)
            message += f"; {task.label()} goes to another worker"
        if self.replacements_left > 0:
            self.replacements_left -= 1
            self._start_worker()
            message += f"; starting worker {self.numbers}"
        _status(message)

    def _kill(self, worker: Worker) -> None:
        with contextlib.suppress(Exception):
            self.ray.kill(worker.actor)

    # ------------------------------------------------------------------ reporting
    def _progress(self) -> None:
        self.last_progress = time.perf_counter()
        busy = []
        for w in self.workers:
            doing = w.task.label() if w.task else ("idle" if w.ready else "starting")
            pace = f" ({w.busy_s / w.done:.1f} s each)" if w.done else ""
            busy.append(f"worker {w.number}: {doing}, {w.done} done{pace}")
        _status(f"{len(self.saved)}/{len(self.plan.frames)} frames | " + " | ".join(busy)
                + f" | {format_time(time.perf_counter() - self.start)}")

    def _interrupted(self) -> int:
        dropped = sorted({w.task.frame for w in self.workers if w.task} | set(self.parts))
        what = ""
        if dropped:
            what = f"frame{'s' if len(dropped) > 1 else ''} {frame_ranges(dropped)} {'were' if len(dropped) > 1 else 'was'} " \
                   "not finished; "
        print(f"ember: {stop_signals.interrupted_by()}: {what}{saved_frames(sorted(self.saved))}",
              file=sys.stderr)
        return stop_signals.exit_status()


def _reason(err) -> str:
    """One line from a Ray error: the Python exception at its core when there is one (Ray's own text
    around it spans many lines), else its first line."""
    lines = str(err).strip().splitlines()
    errors = [line.strip() for line in lines if re.match(r"\s*\w+(Error|Exception): ", line)]
    line = errors[-1] if errors else (lines[0] if lines else type(err).__name__)
    return line.rstrip(".")[:200]


def _status(line: str) -> None:
    print(f"Ember | Ray | {line}", file=sys.stderr, flush=True)
